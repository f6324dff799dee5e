//! Driving trackers of any configuration over a sequence, with or without probes, and the
//! per-stage profile of a sequence (`cargo bench -p stjpdacf-bench --bench stages`).

use std::time::{Duration, Instant as WallClock};

use serde::{Deserialize, Serialize};
use stjpdacf::probe::{NoProbe, Probe, Stage};
use stjpdacf::tracker::{Instant, Tracker};

use crate::cputime::{ran_throughout, thread_cpu};
use crate::inputs::{Frame, STEP_US};
use crate::probes::{CallCounter, StageGroup, StageTimer};

/// What one frame did (from the tracker's `StepReport`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct FrameSummary {
    /// Points given to the spatial filter (after the `MEAS` cut).
    pub points: u32,
    /// Joint events scored over the frame: the known-lane rows' (almost all of them at steady
    /// state) and the spatial walk's on the points those rows leave.
    pub events: u32,
    /// Rows over E: the spatial walk's pruned rows and the known-lane rows pruned or (with
    /// `Association::ExactOrLbp`, the default) weighed by LBP instead.
    pub rows_approximated: u32,
    /// Filtered lanes published.
    pub lanes: u32,
    /// Smoothed lanes published.
    pub smoothed: u32,
}

/// A tracker of any configuration, stepped through a probe.
pub trait Step {
    /// One frame at `now`; `None` when the tracker refuses it.
    fn step_with<P: Probe>(
        &mut self,
        now: Instant,
        points: &[[f32; 2]],
        probe: &mut P,
    ) -> Option<FrameSummary>;
}

impl<
        const NT: usize,
        const NS: usize,
        const LANES: usize,
        const POINTS: usize,
        const ROWS: usize,
        const PER_ROW: usize,
        const MEAS: usize,
        const RANK: usize,
        const NX: usize,
        const NA: usize,
        const LAG: usize,
    > Step for Tracker<NT, NS, LANES, POINTS, ROWS, PER_ROW, MEAS, RANK, NX, NA, LAG>
{
    fn step_with<P: Probe>(
        &mut self,
        now: Instant,
        points: &[[f32; 2]],
        probe: &mut P,
    ) -> Option<FrameSummary> {
        let out = self.step_probed(now, points, probe).ok()?;
        let r = &out.report;
        Some(FrameSummary {
            points: r.spatial.points_in,
            events: r.spatial.events + r.known.events,
            rows_approximated: r.spatial.rows_approximated + r.known.pruned_rows + r.known.lbp_rows,
            lanes: out.filtered.len() as u32,
            smoothed: out.smoothed.len() as u32,
        })
    }
}

/// A tracker and its clock, cycling through a sequence.
#[derive(Debug)]
pub struct Driver<S> {
    /// The tracker.
    pub tracker: Box<S>,
    now: i64,
    next: usize,
}

impl<S: Step> Driver<S> {
    /// Wraps `tracker`; the first frame is at 50 ms.
    pub fn new(tracker: Box<S>) -> Self {
        Self {
            tracker,
            now: 0,
            next: 0,
        }
    }

    /// The next frame of `frames` (cyclic), 50 ms after the previous one.
    ///
    /// # Panics
    /// When `frames` is empty or the tracker refuses the frame (it cannot: time increases).
    pub fn step<P: Probe>(&mut self, frames: &[Frame], probe: &mut P) -> FrameSummary {
        self.now += STEP_US;
        let f = &frames[self.next % frames.len()];
        self.next = (self.next + 1) % frames.len();
        self.tracker
            .step_with(Instant::from_micros(self.now), &f.p32, probe)
            .expect("time increases")
    }

    /// Steps frames until one runs without the thread being descheduled
    /// ([`ran_throughout`]; at most 50 tries, then the last one is taken), each with a fresh
    /// probe from `probe`; returns that frame's probe. The frames stepped meanwhile advance the
    /// tracker as usual.
    pub fn step_clean<P: Probe>(&mut self, frames: &[Frame], probe: impl Fn() -> P) -> P {
        let mut tries = 0;
        loop {
            let mut p = probe();
            let (w0, c0) = (WallClock::now(), thread_cpu());
            self.step(frames, &mut p);
            let (w, c) = (w0.elapsed(), thread_cpu().saturating_sub(c0));
            tries += 1;
            if ran_throughout(w, c) || tries >= 50 {
                return p;
            }
        }
    }

    /// `passes` passes over `frames` (to reach the sequence's steady state); returns the last
    /// frame's summary.
    pub fn warm_up(&mut self, frames: &[Frame], passes: usize) -> FrameSummary {
        let mut last = FrameSummary::default();
        for _ in 0..passes * frames.len() {
            last = self.step(frames, &mut NoProbe);
        }
        last
    }

    /// Summaries of one pass over `frames` (state advances).
    pub fn summaries(&mut self, frames: &[Frame]) -> Vec<FrameSummary> {
        (0..frames.len())
            .map(|_| self.step(frames, &mut NoProbe))
            .collect()
    }
}

/// Per-stage time of a sequence (see [`profile`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageProfile {
    /// Sequence name.
    pub sequence: String,
    /// Frames in the sequence.
    pub frames: usize,
    /// Timed passes over it.
    pub passes: usize,
    /// Share of the timed steps that ran without being descheduled (only those are used).
    #[serde(default)]
    pub clean_fraction: f64,
    /// Probe calls per frame (mean over the sequence).
    pub calls_per_frame: f64,
    /// Step time without a probe, µs per frame.
    pub total_no_probe_us: f64,
    /// Step time with the counting probe, µs per frame.
    pub total_count_probe_us: f64,
    /// Step time with the timing probe, µs per frame.
    pub total_timing_probe_us: f64,
    /// Cost of one `Instant::now()` + the timer's bookkeeping, ns (median of 21 runs of
    /// 100,000 [`StageTimer::enter`] calls): `calls_per_frame ×` this is the timing probe's
    /// overhead per frame, free of the step's own noise.
    #[serde(default)]
    pub timer_call_ns: f64,
    /// Per stage (`Stage::name`, Binning … Output), µs per frame.
    pub stage_us: Vec<(String, f64)>,
    /// Per group (spatial, identity, temporal, smoother, output), µs per frame.
    pub group_us: Vec<(String, f64)>,
    /// What the frames did (first timed pass).
    pub summary: Vec<FrameSummary>,
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn us(d: Duration) -> f64 {
    d.as_secs_f64() * 1e6
}

/// Cost of one [`StageTimer::enter`] call, ns of thread CPU time (median of 21 runs of 100,000
/// calls).
pub fn timer_call_ns() -> f64 {
    const CALLS: u32 = 100_000;
    let mut runs: Vec<f64> = (0..21)
        .map(|_| {
            let mut p = StageTimer::new();
            let t0 = thread_cpu();
            for i in 0..CALLS {
                p.enter(if i % 2 == 0 {
                    Stage::Gating
                } else {
                    Stage::Events
                });
            }
            std::hint::black_box(p.all());
            thread_cpu().saturating_sub(t0).as_secs_f64() * 1e9 / f64::from(CALLS)
        })
        .collect();
    median(&mut runs)
}

/// The clean passes `v[i]` (those with `clean[i]`), or all of them when none is clean.
fn keep_clean(v: &[f64], clean: &[bool]) -> Vec<f64> {
    let c: Vec<f64> = v.iter().zip(clean).filter(|x| *x.1).map(|x| *x.0).collect();
    if c.is_empty() {
        v.to_vec()
    } else {
        c
    }
}

/// One tracker's step times over the passes, µs, `[frame][pass]`, each with its "ran
/// throughout" flag ([`ran_throughout`]).
struct Samples {
    t: Vec<Vec<f64>>,
    ok: Vec<Vec<bool>>,
}

impl Samples {
    fn new(frames: usize) -> Self {
        Self {
            t: vec![Vec::new(); frames],
            ok: vec![Vec::new(); frames],
        }
    }

    /// Steps `d` through `probe` as frame `k` and records the step's wall time and flag;
    /// returns the step's summary and the flag.
    fn step<S: Step, P: Probe>(
        &mut self,
        k: usize,
        d: &mut Driver<S>,
        frames: &[Frame],
        probe: &mut P,
    ) -> (FrameSummary, bool) {
        let (w0, c0) = (WallClock::now(), thread_cpu());
        let s = d.step(frames, probe);
        let (w, c) = (w0.elapsed(), thread_cpu().saturating_sub(c0));
        let ok = ran_throughout(w, c);
        self.t[k].push(us(w));
        self.ok[k].push(ok);
        (s, ok)
    }

    /// Per frame, the clean passes' times ([`keep_clean`]).
    fn kept(&self) -> Vec<Vec<f64>> {
        self.t
            .iter()
            .zip(&self.ok)
            .map(|(v, f)| keep_clean(v, f))
            .collect()
    }
}

/// Per-stage time of `frames` on three identical trackers made by `make` (one without a probe,
/// one with [`CallCounter`], one with [`StageTimer`]), fed the same frames at the same times, so
/// their states stay identical. After `warm` untimed passes, `passes` passes are timed; in each,
/// every frame is stepped on the three trackers one after the other (the order rotates from pass
/// to pass), so the three see the same machine load. A step during which the thread was
/// descheduled (wall-clock time above its CPU time: [`ran_throughout`]) is dropped. Every figure
/// is the **mean over the sequence's frames of the frame's median over the kept passes** (the
/// mean over frames is the sequence's average cost, as a criterion iteration that cycles through
/// the sequence measures it); a frame with no kept pass uses all its passes.
///
/// # Panics
/// When `frames` is empty or `passes` is 0.
pub fn profile<S: Step>(
    name: &str,
    make: impl Fn() -> Box<S>,
    frames: &[Frame],
    warm: usize,
    passes: usize,
) -> StageProfile {
    assert!(!frames.is_empty() && passes > 0);
    let mut plain = Driver::new(make());
    let mut counted = Driver::new(make());
    let mut timed = Driver::new(make());
    for d in [&mut plain, &mut counted, &mut timed] {
        d.warm_up(frames, warm);
    }
    let n = frames.len();
    let mut s_plain = Samples::new(n);
    let mut s_count = Samples::new(n);
    let mut s_timed = Samples::new(n);
    // [frame][stage][pass]
    let mut t_stage = vec![vec![Vec::new(); Stage::COUNT]; n];
    let mut calls = vec![0u64; n];
    let mut summary = Vec::with_capacity(n);
    let mut kept = 0usize;
    for pass in 0..passes {
        for k in 0..n {
            for v in 0..3 {
                match (v + pass) % 3 {
                    0 => {
                        let (s, ok) = s_plain.step(k, &mut plain, frames, &mut NoProbe);
                        kept += usize::from(ok);
                        if pass == 0 {
                            summary.push(s);
                        }
                    }
                    1 => {
                        let mut c = CallCounter::default();
                        kept += usize::from(s_count.step(k, &mut counted, frames, &mut c).1);
                        calls[k] = c.total();
                    }
                    _ => {
                        let mut p = StageTimer::new();
                        kept += usize::from(s_timed.step(k, &mut timed, frames, &mut p).1);
                        for s in Stage::ALL {
                            t_stage[k][s as usize].push(us(p.get(s)));
                        }
                    }
                }
            }
        }
    }
    let mut t_plain = s_plain.kept();
    let mut t_count = s_count.kept();
    let mut t_timed_kept = s_timed.kept();
    let t_stage: Vec<Vec<Vec<f64>>> = t_stage
        .iter()
        .zip(&s_timed.ok)
        .map(|(per_stage, f)| per_stage.iter().map(|v| keep_clean(v, f)).collect())
        .collect();
    let mean_of_medians =
        |v: &mut [Vec<f64>]| -> f64 { v.iter_mut().map(|x| median(x)).sum::<f64>() / n as f64 };
    let stage_med: Vec<f64> = (0..Stage::COUNT)
        .map(|s| {
            let mut per_frame: Vec<Vec<f64>> = t_stage.iter().map(|f| f[s].clone()).collect();
            mean_of_medians(&mut per_frame)
        })
        .collect();
    let stage_us: Vec<(String, f64)> = Stage::ALL
        .iter()
        .filter(|s| **s != Stage::Done)
        .map(|s| (s.name().to_string(), stage_med[*s as usize]))
        .collect();
    let group_us = StageGroup::ALL
        .iter()
        .map(|g| {
            let v: f64 = Stage::ALL
                .iter()
                .filter(|s| g.contains(**s))
                .map(|s| stage_med[*s as usize])
                .sum();
            (g.name().to_string(), v)
        })
        .collect();
    StageProfile {
        timer_call_ns: timer_call_ns(),
        sequence: name.to_string(),
        frames: n,
        passes,
        clean_fraction: kept as f64 / (3 * n * passes) as f64,
        calls_per_frame: calls.iter().sum::<u64>() as f64 / n as f64,
        total_no_probe_us: mean_of_medians(&mut t_plain),
        total_count_probe_us: mean_of_medians(&mut t_count),
        total_timing_probe_us: mean_of_medians(&mut t_timed_kept),
        stage_us,
        group_us,
        summary,
    }
}
