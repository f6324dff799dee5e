//! False lanes and tracked lines against the density of uniform clutter, on the soak's roads
//! (`stjpdacf_test_support::soak::Road`; the soak's false lane-frames judged some of the
//! tracker's rules, but no parameter was chosen on these fixed densities), the default tracker
//! next to the per-frame RANSAC fit of the tools (`stjpdacf_tools::baseline`, its default
//! parameters) on the same BEV points (the fit sees all of them; the tracker uses the first 256
//! and counts the rest).
//!
//! Each cell drives `--drives` seeded roads of `--frames` frames (30 fps) with the uniform
//! clutter held at one density (points per metre per BEV row over ±12 m, on every stretch) and
//! the lines all solid or all dashed (3 m dashes, 9 m gaps; `soak::Forced::dashed`);
//! everything else — lines, weave, lane changes, detection rate 0.6–0.97, point noise 3–15 cm,
//! blackouts, dropped frames — varies as in the soak. Published lanes (the tracker's
//! filtered lanes; the fit's quadratics over their inliers' extent) are matched to the true lines
//! by the soak's rule (`soak::match_truth`: mean |Δx| < 0.5 m over the lane's observed index
//! points, greedy). Per cell: points a frame and how many of them exceeded the tracker's budget
//! (`MEAS` = 256, `StepReport::over_budget_points`), the true line-frames matched, false lanes a
//! frame (published lanes matched to no line; in brackets those of lanes at least 1 s old), and
//! the tracker's id switches on a line seen without interruption, per 1,000 frames.
//!
//! ```sh
//! cargo run --release -p stjpdacf-test-support --example clutter_curve -- [--frames 9000] [--drives 3] [--clutter 0,0.01,…]
//! ```

use std::sync::Mutex;

use anyhow::Result;
use clap::Parser;
use stjpdacf::persist::PersistConfig;
use stjpdacf::spatial::row::Association;
use stjpdacf::tables::{DEFAULT, UNCOUPLED};
use stjpdacf::temporal::identity::LaneId;
use stjpdacf::tracker::{
    Instant, LaneEstimate, Rank3Tracker, ReferenceTracker, Tracker, TrackerConfig,
};
use stjpdacf_test_support::invariants::POINTS;
use stjpdacf_test_support::soak::{id_switches, match_truth, Forced, Road};
use stjpdacf_tools::baseline::{fit_frame, BaselineParams, Lane};

/// Clutter curve on the soak's roads: tracker against the per-frame RANSAC fit.
#[derive(Debug, Parser)]
struct Args {
    /// Frames per drive (30 fps: 9,000 frames = 5 min).
    #[arg(long, default_value_t = 9_000)]
    frames: u64,
    /// Drives per cell (seeds `seed`, `seed + 1`, …).
    #[arg(long, default_value_t = 3)]
    drives: u64,
    /// Base seed.
    #[arg(long, default_value_t = 100)]
    seed: u64,
    /// The model: `default` (`ReferenceTracker`, the default tables), `uncoupled` (the same on
    /// `tables::UNCOUPLED`) or `rank3` (`Rank3Tracker` on the uncoupled tables with LBP on every
    /// known-lane row: the model that meets the MCU's instruction targets).
    #[arg(long, default_value = "default", value_parser = ["default", "uncoupled", "rank3"])]
    model: String,
    /// Hold the lateral point noise at this standard deviation, metres (> 0; default: drawn
    /// 0.03–0.15 per stretch as in the soak).
    #[arg(long, value_parser = positive)]
    sigma: Option<f64>,
    /// Hold the lines' detection probability per row at this value (in (0, 1]; default: drawn
    /// 0.6–0.97 per stretch).
    #[arg(long, value_parser = probability)]
    pd: Option<f64>,
    /// Clutter densities, points per metre per row (the soak draws 0–0.05 per stretch).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0,0.01,0.02,0.03,0.05,0.08"
    )]
    clutter: Vec<f64>,
}

/// Counts of one cell.
#[derive(Debug, Default, Clone, Copy)]
struct Cell {
    frames: u64,
    points: u64,
    over_budget: u64,
    line_frames: u64,
    matched: [u64; 2],
    false_lanes: [u64; 2],
    /// The tracker's false lane-frames of lanes at least 30 frames old (1 s).
    false_old: u64,
    id_switches: u64,
}

impl Cell {
    fn add(&mut self, o: &Cell) {
        self.frames += o.frames;
        self.points += o.points;
        self.over_budget += o.over_budget;
        self.line_frames += o.line_frames;
        for k in 0..2 {
            self.matched[k] += o.matched[k];
            self.false_lanes[k] += o.false_lanes[k];
        }
        self.false_old += o.false_old;
        self.id_switches += o.id_switches;
    }
}

/// A fitted quadratic as a published lane (its mean at the index points, its inliers' extent),
/// so that both are matched to the truth by the same rule.
fn as_estimate(l: &Lane, k: usize) -> LaneEstimate<POINTS> {
    LaneEstimate {
        id: LaneId(k as u32),
        slot: 0,
        z: nalgebra::SVector::from_fn(|i, _| l.x_at(f64::from(DEFAULT.index_u[i])) as f32),
        var: nalgebra::SVector::zeros(),
        u_first: l.u_min as f32,
        u_last: l.u_max as f32,
        existence: 1.0,
        misses: 0,
        age: 0,
        hits: 1,
    }
}

/// One drive through `tracker` (any Gram rank of the reference configuration).
fn drive<const RANK: usize, const NX: usize, const NA: usize>(
    tracker: &mut Tracker<2, 3, 6, 16, 64, 16, 256, RANK, NX, NA, 4>,
    seed: u64,
    frames: u64,
    forced: Forced,
) -> Cell {
    let mut road = Road::with_forced(seed, forced);
    let fit = BaselineParams::default();
    let mut c = Cell::default();
    let mut last_id = std::collections::BTreeMap::new();
    for _ in 0..frames {
        let f = road.next_frame();
        let out = tracker.step(Instant::from_micros(f.t_us), &f.points);
        if f.blackout {
            id_switches(&mut last_id, &f.visible_lines(), &[]);
            continue;
        }
        c.frames += 1;
        c.points += f.points.len() as u64;
        c.line_frames += f.truth.len() as u64;
        if let Ok(out) = out {
            c.over_budget += u64::from(out.report.over_budget_points);
            let (m, [unmatched, _]) = match_truth(&out.filtered, &f.truth);
            c.matched[0] += m.len() as u64;
            c.false_lanes[0] += unmatched;
            c.false_old += out
                .filtered
                .iter()
                .filter(|l| l.age >= 30 && m.iter().all(|(_, id, _)| *id != l.id.0))
                .count() as u64;
            c.id_switches += id_switches(&mut last_id, &f.visible_lines(), &m);
        }
        let pts: Vec<(f64, f64)> = f
            .points
            .iter()
            .map(|p| (f64::from(p[0]), f64::from(p[1])))
            .collect();
        let lanes: Vec<LaneEstimate<POINTS>> = fit_frame(&pts, &fit)
            .iter()
            .enumerate()
            .map(|(k, l)| as_estimate(l, k))
            .collect();
        let (m, [unmatched, _]) = match_truth(&lanes, &f.truth);
        c.matched[1] += m.len() as u64;
        c.false_lanes[1] += unmatched;
    }
    c
}

fn positive(v: &str) -> Result<f64, String> {
    match v.parse::<f64>() {
        Ok(x) if x.is_finite() && x > 0.0 => Ok(x),
        _ => Err(format!("{v} is not a positive number")),
    }
}

fn probability(v: &str) -> Result<f64, String> {
    match v.parse::<f64>() {
        Ok(x) if x > 0.0 && x <= 1.0 => Ok(x),
        _ => Err(format!("{v} is not in (0, 1]")),
    }
}

/// The MCU model's configuration: LBP on every known-lane row (as the firmware's small budget).
fn mcu_config() -> TrackerConfig {
    TrackerConfig {
        persist: PersistConfig {
            association: Association::Lbp,
            ..PersistConfig::DEFAULT
        },
        ..TrackerConfig::DEFAULT
    }
}

fn main() -> Result<()> {
    let a = Args::parse();
    let frames = a.frames;
    println!(
        "model {}: {} drives × {} frames a cell (30 fps), soak roads, seeds {}…; point noise {}, detection {}",
        a.model,
        a.drives,
        a.frames,
        a.seed,
        a.sigma.map_or("drawn 0.03–0.15".to_string(), |v| format!("{v}")),
        a.pd.map_or("drawn 0.6–0.97".to_string(), |v| format!("{v}")),
    );
    println!();
    println!("| clutter /m/row | lines | points a frame (over MEAS) | tracker: line-frames tracked | false lanes a frame (of lanes ≥ 1 s old) | id switches / 1,000 frames | RANSAC fit: line-frames tracked | false lanes a frame |");
    println!("|---|---|---|---|---|---|---|---|");
    for dashed in [false, true] {
        for &clutter in &a.clutter {
            let forced = Forced {
                clutter: Some(clutter),
                dashed: Some(dashed),
                sigma: a.sigma,
                pd: a.pd,
            };
            let total = Mutex::new(Cell::default());
            std::thread::scope(|s| {
                for d in 0..a.drives {
                    let total = &total;
                    let seed = a.seed + d;
                    let model = a.model.as_str();
                    s.spawn(move || {
                        let c = match model {
                            "uncoupled" => drive(
                                &mut Box::new(ReferenceTracker::new(&UNCOUPLED)),
                                seed,
                                frames,
                                forced,
                            ),
                            "rank3" => drive(
                                &mut Box::new(Rank3Tracker::with_config(&UNCOUPLED, mcu_config())),
                                seed,
                                frames,
                                forced,
                            ),
                            _ => drive(
                                &mut Box::new(ReferenceTracker::new(&DEFAULT)),
                                seed,
                                frames,
                                forced,
                            ),
                        };
                        if let Ok(mut t) = total.lock() {
                            t.add(&c);
                        }
                    });
                }
            });
            let t = total.into_inner().unwrap_or_default();
            let n = t.frames.max(1) as f64;
            let lf = t.line_frames.max(1) as f64;
            println!(
                "| {clutter} | {} | {:.0} ({:.1}) | {:.1} % | {:.3} ({:.3}) | {:.2} | {:.1} % | {:.3} |",
                if dashed { "dashed" } else { "solid" },
                t.points as f64 / n,
                t.over_budget as f64 / n,
                100.0 * t.matched[0] as f64 / lf,
                t.false_lanes[0] as f64 / n,
                t.false_old as f64 / n,
                1000.0 * t.id_switches as f64 / n,
                100.0 * t.matched[1] as f64 / lf,
                t.false_lanes[1] as f64 / n,
            );
        }
    }
    Ok(())
}
