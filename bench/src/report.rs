//! From measurements to `docs/bench/`: the side files the benches write
//! (`target/stjpdacf-bench/*.json`), criterion's estimates (`target/criterion/**/new/`), their
//! union `results.json`, the Markdown tables, the CSV and the scaling plot.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use serde::{de::DeserializeOwned, Deserialize, Serialize};

use crate::harness::{FrameSummary, StageProfile};

mod plot;

pub use plot::{plot_scaling, register_fonts};

/// Schema tag of `results.json`.
pub const SCHEMA: &str = "stjpdacf-bench/v1";

/// The machine and its load when a bench started or ended.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Machine {
    /// `std::thread::available_parallelism`.
    pub cpus: usize,
    /// `model name` from `/proc/cpuinfo`.
    pub cpu: String,
    /// `rustc -V`.
    pub rustc: String,
    /// 1, 5 and 15 minute load averages (`/proc/loadavg`).
    pub load: [f64; 3],
    /// Seconds since the Unix epoch.
    pub unix_time: u64,
}

impl Machine {
    /// Reads the machine's state now (fields that cannot be read stay empty or 0).
    pub fn now() -> Self {
        let cpu = std::fs::read_to_string("/proc/cpuinfo")
            .ok()
            .and_then(|s| {
                s.lines()
                    .find(|l| l.starts_with("model name"))
                    .and_then(|l| l.split(':').nth(1))
                    .map(|v| v.trim().to_string())
            })
            .unwrap_or_default();
        let mut load = [0.0; 3];
        if let Ok(s) = std::fs::read_to_string("/proc/loadavg") {
            for (l, v) in load.iter_mut().zip(s.split_whitespace()) {
                *l = v.parse().unwrap_or(0.0);
            }
        }
        let rustc =
            std::process::Command::new(std::env::var_os("RUSTC").unwrap_or_else(|| "rustc".into()))
                .arg("-V")
                .output()
                .ok()
                .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
                .unwrap_or_default();
        Self {
            cpus: std::thread::available_parallelism().map_or(0, usize::from),
            cpu,
            rustc,
            load,
            unix_time: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs()),
        }
    }
}

/// The machine at the start and at the end of a bench.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Span {
    /// At the start.
    pub machine_start: Machine,
    /// At the end.
    pub machine_end: Machine,
}

impl Span {
    /// From `machine_start` to now.
    pub fn since(machine_start: Machine) -> Self {
        Self {
            machine_start,
            machine_end: Machine::now(),
        }
    }

    /// The machine and its load at the start and the end, for the report.
    fn line(&self) -> String {
        let (m, end) = (&self.machine_start, &self.machine_end);
        format!(
            "{} × {}, {}; load average {:.1} at the start, {:.1} at the end",
            m.cpus, m.cpu, m.rustc, m.load[0], end.load[0]
        )
    }
}

/// What one sequence of the tracker bench did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SequenceMeta {
    /// Sequence name.
    pub name: String,
    /// Description.
    pub what: String,
    /// Frames.
    pub frames: usize,
    /// Fewest points in a frame (before the M cut).
    pub points_min: usize,
    /// Most points in a frame.
    pub points_max: usize,
    /// The core's frames (one pass after warm-up).
    pub core: Vec<FrameSummary>,
    /// Whether the reference ran on it.
    pub reference_run: bool,
    /// The reference's filtered lanes per frame.
    pub reference_lanes: Vec<usize>,
    /// The reference's events per frame.
    pub reference_events: Vec<usize>,
    /// Whether the reference's fixed-lag output was computed (its window was comparable).
    pub reference_fixed_lag_computed: Vec<bool>,
    /// Lanes of the dense temporal stage bench.
    pub reference_dense_lanes: usize,
}

/// `target/stjpdacf-bench/tracker.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrackerMeta {
    /// The machine at the start and at the end.
    #[serde(flatten)]
    pub span: Span,
    /// The sequences.
    pub sequences: Vec<SequenceMeta>,
}

/// `target/stjpdacf-bench/stages.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StagesOut {
    /// The machine at the start and at the end.
    #[serde(flatten)]
    pub span: Span,
    /// One profile per sequence.
    pub profiles: Vec<StageProfile>,
}

/// One point of a scaling curve (its input; the time comes from criterion).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScalingInput {
    /// `M`, `D`, `N` or `E`.
    pub axis: String,
    /// The value on the axis.
    pub value: usize,
    /// The curve it belongs to (the input family).
    pub series: String,
    /// Criterion id of its bench.
    pub id: String,
    /// Whether this is the reference configuration (D = 6, N = 16, M = 256, E = 512).
    pub reference: bool,
    /// Sequence.
    pub sequence: String,
    /// The other capacities (`RANK` for the N axis, rows per interval).
    pub note: String,
    /// The frames (one pass after warm-up).
    pub frames: Vec<FrameSummary>,
}

/// `target/stjpdacf-bench/scaling.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScalingOut {
    /// The machine at the start and at the end.
    #[serde(flatten)]
    pub span: Span,
    /// The points.
    pub points: Vec<ScalingInput>,
}

/// Instructions per frame of one sequence (callgrind, `examples/icount.rs`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IcountRow {
    /// Sequence.
    pub sequence: String,
    /// Frames counted (one pass).
    pub frames: usize,
    /// Core `Tracker::step`, instructions per frame.
    pub core_per_frame: u64,
    /// Reference step + fixed-lag output, instructions per frame.
    pub reference_per_frame: u64,
}

/// `target/stjpdacf-bench/icount.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IcountOut {
    /// The machine (the counts do not depend on its load).
    pub machine: Machine,
    /// One row per sequence.
    pub rows: Vec<IcountRow>,
}

/// A criterion estimate, nanoseconds per iteration.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Estimate {
    /// Median of the samples.
    pub median_ns: f64,
    /// Lower bound of its 95 % confidence interval.
    pub median_lo_ns: f64,
    /// Upper bound.
    pub median_hi_ns: f64,
    /// Mean of the samples.
    pub mean_ns: f64,
}

/// A point of a scaling curve with its time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScalingPoint {
    /// The input.
    #[serde(flatten)]
    pub input: ScalingInput,
    /// Criterion's estimate (`None` when the bench has not run).
    pub time: Option<Estimate>,
}

/// Everything `docs/bench/` is made from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Results {
    /// [`SCHEMA`].
    pub schema: String,
    /// The tracker bench's inputs.
    pub tracker: Option<TrackerMeta>,
    /// The per-stage profiles.
    pub stages: Option<StagesOut>,
    /// The scaling curves.
    pub scaling: Option<ScalingOut>,
    /// Instruction counts (callgrind).
    #[serde(default)]
    pub icount: Option<IcountOut>,
    /// The scaling points with their times.
    pub scaling_points: Vec<ScalingPoint>,
    /// Criterion estimates of the tracker and scaling benches, by id.
    pub criterion: BTreeMap<String, Estimate>,
}

/// The cargo target folder (`CARGO_TARGET_DIR`, else `target/` in the repository).
pub fn target_dir() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| stjpdacf_tools::repo_root().join("target"))
}

/// Where the benches write their side files: `<target>/stjpdacf-bench/`.
pub fn out_dir() -> PathBuf {
    target_dir().join("stjpdacf-bench")
}

/// Writes `value` as pretty JSON to `out_dir()/name`.
///
/// # Errors
/// File system or serialisation errors.
pub fn write_side_file<T: Serialize>(name: &str, value: &T) -> Result<()> {
    let dir = out_dir();
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let path = dir.join(name);
    std::fs::write(&path, serde_json::to_string_pretty(value)?)
        .with_context(|| format!("writing {}", path.display()))?;
    println!("wrote {}", path.display());
    Ok(())
}

fn read_json<T: DeserializeOwned>(path: &Path) -> Result<Option<T>> {
    if !path.exists() {
        return Ok(None);
    }
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    Ok(Some(
        serde_json::from_str(&text).with_context(|| format!("parsing {}", path.display()))?,
    ))
}

#[derive(Deserialize)]
struct CritId {
    full_id: String,
}

#[derive(Deserialize)]
struct CritStat {
    point_estimate: f64,
    confidence_interval: CritInterval,
}

#[derive(Deserialize)]
struct CritInterval {
    lower_bound: f64,
    upper_bound: f64,
}

#[derive(Deserialize)]
struct CritEstimates {
    mean: CritStat,
    median: CritStat,
}

/// Criterion's latest estimates under `dir` (`**/new/benchmark.json` + `estimates.json`) whose
/// id starts with one of `prefixes`.
///
/// # Errors
/// Unreadable files.
pub fn read_criterion(dir: &Path, prefixes: &[&str]) -> Result<BTreeMap<String, Estimate>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(rd) = std::fs::read_dir(&d) else {
            continue;
        };
        for e in rd.flatten() {
            let p = e.path();
            if !p.is_dir() {
                continue;
            }
            if p.file_name().is_some_and(|n| n == "new") {
                let (Some(id), Some(est)) = (
                    read_json::<CritId>(&p.join("benchmark.json"))?,
                    read_json::<CritEstimates>(&p.join("estimates.json"))?,
                ) else {
                    continue;
                };
                if prefixes.iter().any(|x| id.full_id.starts_with(x)) {
                    out.insert(
                        id.full_id,
                        Estimate {
                            median_ns: est.median.point_estimate,
                            median_lo_ns: est.median.confidence_interval.lower_bound,
                            median_hi_ns: est.median.confidence_interval.upper_bound,
                            mean_ns: est.mean.point_estimate,
                        },
                    );
                }
            } else {
                stack.push(p);
            }
        }
    }
    Ok(out)
}

impl Results {
    /// Collects the side files and criterion's estimates from the target folder.
    ///
    /// # Errors
    /// Unreadable or malformed files.
    pub fn collect() -> Result<Self> {
        let dir = out_dir();
        let tracker: Option<TrackerMeta> = read_json(&dir.join("tracker.json"))?;
        let stages: Option<StagesOut> = read_json(&dir.join("stages.json"))?;
        let scaling: Option<ScalingOut> = read_json(&dir.join("scaling.json"))?;
        let icount: Option<IcountOut> = read_json(&dir.join("icount.json"))?;
        let criterion = read_criterion(
            &target_dir().join("criterion"),
            &["tracker_step_", "stage_", "scaling_"],
        )?;
        Ok(Self::assemble(tracker, stages, scaling, icount, criterion))
    }

    /// `self`, with what it lacks taken from `old` (benches that were not run again keep their
    /// earlier figures; criterion estimates are merged by id, the newer winning).
    pub fn merged_over(self, old: Results) -> Results {
        let mut criterion = old.criterion;
        criterion.extend(self.criterion);
        let scaling = self.scaling.or(old.scaling);
        // Scaling estimates of points that are no longer on the curves (renamed benches).
        if let Some(sc) = &scaling {
            criterion.retain(|id, _| {
                !id.starts_with("scaling_") || sc.points.iter().any(|p| &p.id == id)
            });
        }
        Self::assemble(
            self.tracker.or(old.tracker),
            self.stages.or(old.stages),
            scaling,
            self.icount.or(old.icount),
            criterion,
        )
    }

    /// The results of the side files and the estimates, with each scaling point's time.
    fn assemble(
        tracker: Option<TrackerMeta>,
        stages: Option<StagesOut>,
        scaling: Option<ScalingOut>,
        icount: Option<IcountOut>,
        criterion: BTreeMap<String, Estimate>,
    ) -> Self {
        let scaling_points = scaling
            .as_ref()
            .map(|s| {
                s.points
                    .iter()
                    .map(|p| ScalingPoint {
                        input: p.clone(),
                        time: criterion.get(&p.id).copied(),
                    })
                    .collect()
            })
            .unwrap_or_default();
        Self {
            schema: SCHEMA.to_string(),
            tracker,
            stages,
            scaling,
            icount,
            scaling_points,
            criterion,
        }
    }

    fn est(&self, id: &str) -> Option<Estimate> {
        self.criterion.get(id).copied()
    }
}

/// A duration in ns as µs or ms with 3 significant digits.
pub fn fmt_ns(ns: f64) -> String {
    let us = ns / 1e3;
    if us >= 1000.0 {
        format!("{:.3} ms", us / 1e3)
    } else if us >= 100.0 {
        format!("{us:.0} µs")
    } else if us >= 10.0 {
        format!("{us:.1} µs")
    } else {
        format!("{us:.2} µs")
    }
}

fn fmt_est(e: Option<Estimate>) -> String {
    e.map_or_else(|| "—".to_string(), |e| fmt_ns(e.median_ns))
}

/// One cell of a per-stage table: a figure of a profile.
type ProfileCell = dyn Fn(&StageProfile) -> String;

/// The 95 % interval of an estimate's median, `[lo, hi]`, or `—`.
fn fmt_ci(e: Option<Estimate>) -> String {
    e.map_or_else(
        || "—".to_string(),
        |e| format!("[{}, {}]", fmt_ns(e.median_lo_ns), fmt_ns(e.median_hi_ns)),
    )
}

fn ratio(a: Option<Estimate>, b: Option<Estimate>) -> String {
    match (a, b) {
        (Some(a), Some(b)) if a.median_ns > 0.0 => format!("{:.1}×", b.median_ns / a.median_ns),
        _ => "—".to_string(),
    }
}

fn range(v: impl Iterator<Item = u32> + Clone) -> String {
    let lo = v.clone().min().unwrap_or(0);
    let hi = v.max().unwrap_or(0);
    if lo == hi {
        format!("{lo}")
    } else {
        format!("{lo}–{hi}")
    }
}

fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    if n == 0 {
        f64::NAN
    } else {
        s / n as f64
    }
}

/// Start of the generated part of `docs/bench/README.md`.
pub const BEGIN_MARKER: &str = "<!-- bench_report:begin -->";
/// End of the generated part.
pub const END_MARKER: &str = "<!-- bench_report:end -->";

/// `doc` with the text between [`BEGIN_MARKER`] and [`END_MARKER`] replaced by `generated`.
///
/// # Errors
/// When the markers are missing or out of order.
pub fn splice(doc: &str, generated: &str) -> Result<String> {
    let a = doc.find(BEGIN_MARKER).context("no begin marker")? + BEGIN_MARKER.len();
    let b = doc.find(END_MARKER).context("no end marker")?;
    anyhow::ensure!(a <= b, "markers out of order");
    Ok(format!(
        "{}\n{}\n{}",
        &doc[..a],
        generated.trim_end(),
        &doc[b..]
    ))
}

/// The Markdown tables of the generated part of `docs/bench/README.md`.
#[allow(clippy::too_many_lines)]
pub fn render_markdown(r: &Results) -> Result<String> {
    let mut s = String::new();
    writeln!(
        s,
        "Generated by `cargo xtask bench-report` from \
         `docs/bench/results.json` (do not edit between the markers). Times are per frame, \
         thread CPU time; criterion figures are medians of 10 samples (95 % interval of the \
         median in brackets).\n"
    )?;
    if let Some(t) = &r.tracker {
        writeln!(s, "### Full step, core f32 vs dense f64 reference\n")?;
        writeln!(
            s,
            "`cargo bench -p stjpdacf-bench --bench tracker` — {}.\n",
            t.span.line()
        )?;
        writeln!(
            s,
            "| sequence | core f32 | [95 % CI] | core f32, uncoupled tables (design §4.2.6) | reference f64 (step + fixed-lag output) | speed-up | core lanes / events / rows over E | reference lanes / fixed-lag output computed |"
        )?;
        writeln!(s, "|---|---:|---|---:|---:|---:|---|---|")?;
        for q in &t.sequences {
            let g = match q.name.as_str() {
                "typical" => "tracker_step_typical".to_string(),
                "worst" => "tracker_step_worst_6lanes_256points".to_string(),
                other => format!("tracker_step_{other}_256points"),
            };
            let core = r.est(&format!("{g}/core_f32"));
            let uncoupled = r.est(&format!("{g}/core_f32_uncoupled"));
            let reference = r.est(&format!("{g}/reference_f64"));
            let ci = fmt_ci(core);
            let ref_info = if q.reference_run {
                let lanes = range(q.reference_lanes.iter().map(|&v| v as u32));
                let done = q
                    .reference_fixed_lag_computed
                    .iter()
                    .filter(|b| **b)
                    .count();
                format!("{lanes} / {done} of {} frames", q.frames)
            } else {
                "not run".to_string()
            };
            writeln!(
                s,
                "| {} ({}) | **{}** | {} | {} | {} | {} | {} / {} / {} | {} |",
                q.name,
                q.what,
                fmt_est(core),
                ci,
                fmt_est(uncoupled),
                fmt_est(reference),
                ratio(core, reference),
                range(q.core.iter().map(|f| f.lanes)),
                range(q.core.iter().map(|f| f.events)),
                range(q.core.iter().map(|f| f.rows_approximated)),
                ref_info
            )?;
        }
        let plain = r.est("tracker_step_typical/core_f32");
        let count = r.est("tracker_step_typical/core_f32_count_probe");
        let timing = r.est("tracker_step_typical/core_f32_timing_probe");
        writeln!(
            s,
            "\nProbe overhead (typical): no probe {}, counting probe {}, timing probe {}.\n",
            fmt_est(plain),
            fmt_est(count),
            fmt_est(timing)
        )?;

        writeln!(s, "### Each stage, core f32 vs dense f64 reference\n")?;
        writeln!(
            s,
            "`core in step`: the stage's time inside the core's full step (timing probe; \
             spatial = the known-lane rows + the JPDACF walk on the points they leave); \
             `core alone`: `SpatialFilter::run` by itself; `reference`: the reference's piece \
             alone on the same frames (spatial `run_frame`; identity `assign` against the dense \
             predictions; dense predict + update over the lanes it carries; fixed-lag RTS \
             output). Ratio = reference / core in step.\n"
        )?;
        writeln!(
            s,
            "| stage | sequence | core in step | core alone | reference f64 | ratio |"
        )?;
        writeln!(s, "|---|---|---:|---:|---:|---:|")?;
        for stage in ["spatial", "identity", "temporal", "smoother"] {
            for q in &t.sequences {
                let g = format!("stage_{stage}_{}", q.name);
                let inside = r.est(&format!("{g}/core_f32_in_step"));
                let alone = r.est(&format!("{g}/core_f32"));
                let reference = r
                    .est(&format!("{g}/reference_f64"))
                    .or_else(|| r.est(&format!("{g}/reference_f64_predict_update")))
                    .or_else(|| r.est(&format!("{g}/reference_f64_fixed_lag_rts")));
                writeln!(
                    s,
                    "| {stage} | {} | {} | {} | {} | {} |",
                    q.name,
                    fmt_est(inside),
                    fmt_est(alone),
                    fmt_est(reference),
                    ratio(inside, reference)
                )?;
            }
        }
        let c3 = r.est("stage_temporal_3lanes/core_f32_predict_update_window");
        let r3 = r.est("stage_temporal_3lanes/reference_f64_predict_update");
        writeln!(
            s,
            "\nTemporal stage alone, 3 lanes, typical frames (`stage_temporal_3lanes`, kept from \
             the first benches): core predict + 3 updates with the smoother window {}, dense \
             predict + update {} ({}).\n",
            fmt_est(c3),
            fmt_est(r3),
            ratio(c3, r3)
        )?;
    }
    if let Some(ic) = &r.icount {
        writeln!(
            s,
            "### Instructions per frame (callgrind, load-independent)\n"
        )?;
        writeln!(
            s,
            "`cargo build --release -p stjpdacf-bench --example icount && \
             target/release/examples/icount` — x86-64 instructions retired per frame (one pass \
             over the sequence after a warm-up pass), {}. A cross-check of the speed-up that does \
             not depend on the machine's load; instructions are not time.\n",
            ic.machine.rustc
        )?;
        writeln!(
            s,
            "| sequence | core f32 | reference f64 (step + fixed-lag output) | ratio |"
        )?;
        writeln!(s, "|---|---:|---:|---:|")?;
        for row in &ic.rows {
            writeln!(
                s,
                "| {} | {:.3} M | {:.1} M | {:.1}× |",
                row.sequence,
                row.core_per_frame as f64 * 1e-6,
                row.reference_per_frame as f64 * 1e-6,
                row.reference_per_frame as f64 / row.core_per_frame.max(1) as f64
            )?;
        }
        writeln!(s)?;
    }
    if let Some(st) = &r.stages {
        writeln!(s, "### Per-stage split of the core's step (timing probe)\n")?;
        writeln!(
            s,
            "`cargo bench -p stjpdacf-bench --bench stages` — {}. Mean over the sequence's \
             frames of each frame's median over the timed passes, µs per frame.\n",
            st.span.line()
        )?;
        let names: Vec<&str> = st.profiles.iter().map(|p| p.sequence.as_str()).collect();
        writeln!(s, "| stage | {} |", names.join(" | "))?;
        writeln!(s, "|---|{}", "---:|".repeat(names.len()))?;
        let cell = |v: f64, total: f64| format!("{v:.1} ({:.0} %)", 100.0 * v / total);
        // One row per name of `split` (stages, then groups of stages): each profile's time and
        // its share of the profile's total.
        let split_rows = |s: &mut String,
                          split: fn(&StageProfile) -> &[(String, f64)],
                          label: &dyn Fn(&str) -> String|
         -> Result<()> {
            let names: Vec<String> = st
                .profiles
                .first()
                .map(|p| split(p).iter().map(|(n, _)| n.clone()).collect())
                .unwrap_or_default();
            for n in &names {
                let cells: Vec<String> = st
                    .profiles
                    .iter()
                    .map(|p| {
                        let v = split(p)
                            .iter()
                            .find(|(m, _)| m == n)
                            .map_or(f64::NAN, |x| x.1);
                        let total: f64 = split(p).iter().map(|x| x.1).sum();
                        cell(v, total)
                    })
                    .collect();
                writeln!(s, "| {} | {} |", label(n), cells.join(" | "))?;
            }
            Ok(())
        };
        split_rows(&mut s, |p| &p.stage_us, &|n| n.to_string())?;
        split_rows(&mut s, |p| &p.group_us, &|n| format!("**= {n}**"))?;
        let totals: [(&str, &ProfileCell); 7] = [
            ("sum of stages", &|p| {
                format!("{:.1}", p.stage_us.iter().map(|x| x.1).sum::<f64>())
            }),
            ("step, no probe", &|p| format!("{:.1}", p.total_no_probe_us)),
            ("step, counting probe", &|p| {
                format!(
                    "{:.1} ({:+.1} %)",
                    p.total_count_probe_us,
                    100.0 * (p.total_count_probe_us / p.total_no_probe_us - 1.0)
                )
            }),
            ("step, timing probe", &|p| {
                format!(
                    "{:.1} ({:+.1} %)",
                    p.total_timing_probe_us,
                    100.0 * (p.total_timing_probe_us / p.total_no_probe_us - 1.0)
                )
            }),
            ("probe calls per frame", &|p| {
                format!("{:.0}", p.calls_per_frame)
            }),
            ("timing probe cost (calls × one call)", &|p| {
                format!(
                    "{:.1} ({:.1} ns a call, {:.1} % of the step)",
                    p.calls_per_frame * p.timer_call_ns * 1e-3,
                    p.timer_call_ns,
                    100.0 * p.calls_per_frame * p.timer_call_ns * 1e-3 / p.total_no_probe_us
                )
            }),
            ("frames × timed passes", &|p| {
                format!("{} × {}", p.frames, p.passes)
            }),
        ];
        for (label, f) in totals {
            let cells: Vec<String> = st.profiles.iter().map(f).collect();
            writeln!(s, "| {label} | {} |", cells.join(" | "))?;
        }
        writeln!(s)?;
    }
    if let Some(sc) = &r.scaling {
        writeln!(s, "### Scaling: time per frame against M, D, N, E\n")?;
        writeln!(
            s,
            "`cargo bench -p stjpdacf-bench --bench scaling` — {}. The other parameters at the \
             reference configuration (D = 6, N = 16, M = 256, E = 512, L = 4); **bold** = the \
             reference configuration. Plot: `docs/bench/scaling.png`.\n",
            sc.span.line()
        )?;
        writeln!(
            s,
            "| axis | value | time per frame | [95 % CI] | input | capacities | points used | events / frame | rows over E / frame | lanes |"
        )?;
        writeln!(s, "|---|---:|---:|---|---|---|---|---:|---:|---|")?;
        for p in &r.scaling_points {
            let i = &p.input;
            let b = if i.reference { "**" } else { "" };
            let ci = fmt_ci(p.time);
            writeln!(
                s,
                "| {} | {b}{}{b} | {b}{}{b} | {} | {} | {} | {} | {:.0} | {:.1} | {} |",
                i.axis,
                i.value,
                fmt_est(p.time),
                ci,
                i.sequence,
                i.note,
                range(i.frames.iter().map(|f| f.points)),
                mean(i.frames.iter().map(|f| f64::from(f.events))),
                mean(i.frames.iter().map(|f| f64::from(f.rows_approximated))),
                range(i.frames.iter().map(|f| f.lanes)),
            )?;
        }
    }
    Ok(s)
}

/// The scaling points as CSV (`axis,value,series,reference,median_us,median_lo_us,
/// median_hi_us,events_per_frame,rows_over_e_per_frame,sequence`).
pub fn render_csv(r: &Results) -> String {
    let mut s = String::from(
        "axis,value,series,reference,median_us,median_lo_us,median_hi_us,events_per_frame,rows_over_e_per_frame,sequence\n",
    );
    for p in &r.scaling_points {
        let i = &p.input;
        let (m, lo, hi) = p.time.map_or((f64::NAN, f64::NAN, f64::NAN), |e| {
            (
                e.median_ns / 1e3,
                e.median_lo_ns / 1e3,
                e.median_hi_ns / 1e3,
            )
        });
        let _ = writeln!(
            s,
            "{},{},{},{},{m:.3},{lo:.3},{hi:.3},{:.1},{:.2},{}",
            i.axis,
            i.value,
            i.series,
            i.reference,
            mean(i.frames.iter().map(|f| f64::from(f.events))),
            mean(i.frames.iter().map(|f| f64::from(f.rows_approximated))),
            i.sequence
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splice_replaces_between_markers_only() {
        let doc = format!("a\n{BEGIN_MARKER}\nold\n{END_MARKER}\nb\n");
        let out = splice(&doc, "new\n").unwrap();
        assert_eq!(out, format!("a\n{BEGIN_MARKER}\nnew\n{END_MARKER}\nb\n"));
        assert!(splice("no markers", "x").is_err());
    }

    #[test]
    fn committed_results_render() {
        // The committed measurements parse, render and plot (no figure is checked: they are
        // measurements of a shared machine).
        let path = stjpdacf_tools::repo_root().join("docs/bench/results.json");
        let r: Results = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
        let md = render_markdown(&r).unwrap();
        assert!(md.contains("### Scaling"));
        assert!(render_csv(&r).lines().count() > 20);
        let png = std::env::temp_dir().join(format!("stjpdacf-scaling-{}.png", std::process::id()));
        plot_scaling(&r.scaling_points, &png).unwrap();
        assert!(std::fs::metadata(&png).unwrap().len() > 10_000);
        let _ = std::fs::remove_file(png);
    }
}
