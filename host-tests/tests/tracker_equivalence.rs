//! The core's `Tracker::step` (`ReferenceTracker` on `stjpdacf::tables::DEFAULT`) against the
//! dense f64 reference pipeline (`reference::pipeline`, all N index points), frame by frame on
//! seeded multi-frame sequences: 2 → 3 lanes (one appears mid-way) with lateral drift, dropped
//! frames (steps of 2× and 5× the nominal 50 ms) and a blackout of 3 frames.
//!
//! Per frame: the number of lanes, their slots and misses exactly; ids as a bijection core ↔
//! reference that stays consistent over the whole sequence; existence within 1e-5; filtered means
//! and variances at the index points; smoothed lanes (L = 4) on every fourth frame where the
//! reference can compare (lane set and order unchanged in the window; the frames where it cannot
//! are counted).
//!
//! Two references:
//! * **the model the core filters**: the dense pipeline with `K_u` replaced by its rank-r
//!   truncation `V_r Λ_r V_rᵀ` (r = 7, the tables' `gram_rank`). Only f32 separates the two:
//!   means within 5e-4 m, variances within 3e-3 relative + 1e-6 m² (measured 1.3e-4 m, 1.0e-3);
//! * **the full dense model** (full `K_u`): the difference is f32 plus the truncation. Means
//!   within 2e-3 m and variances within 2e-3 relative + 1e-5 m² at index points 1…15 (as in
//!   `temporal_core.rs`), but at index point 0 (u = 3 m, in front of the first pseudo-measurement
//!   in these scenes, so the lane is extrapolated there) the core's variance is *below* the full
//!   model's by up to 1.8 % (measured; tolerance 3e-2 relative there). That is the truncation and
//!   nothing else: against the truncated reference the same point agrees within f32 (first
//!   comparison). The truncated basis ties point 0 to the observed points more rigidly than the
//!   full `K_u`, whose small eigen-directions leave an extrapolated point a little more freedom;
//!   over many frames the retained part's posterior shrinks and the relative gap grows.
//!
//! The measured maxima are printed
//! (`cargo test -p stjpdacf-test-support --test tracker_equivalence -- --nocapture`).

use std::collections::BTreeMap;

use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::{Instant, LaneEstimate, ReferenceTracker, TrackerConfig};
use stjpdacf_reference::hyper::HyperFile;
use stjpdacf_reference::pipeline::{PipelineConfig, RefLane, ReferencePipeline};
use stjpdacf_tools::repo_root;
use stjpdacf_tools::scenario::equivalence_sequence;
use stjpdacf_tools::tablegen::{ModelTables, DEFAULT_HYPER};

const N: usize = 16;
const K: usize = 4;
const EXIST_ABS: f64 = 1e-5;
/// The smoothed lanes are compared every fourth frame: each reference fixed-lag output is four RTS
/// steps with an SVD of a 96×96 predicted covariance, ~0.8 s in a debug build.
const SMOOTH_EVERY: usize = 4;

/// Tolerances of one comparison.
#[derive(Debug, Clone, Copy)]
struct Tol {
    mean: f64,
    var_rel: f64,
    var_abs: f64,
    /// Relative variance tolerance at index point 0.
    var_rel_point0: f64,
}

/// Against the dense reference with the truncated Gram matrix (the core's model): f32 only.
const TRUNCATED: Tol = Tol {
    mean: 5e-4,
    var_rel: 3e-3,
    var_abs: 1e-6,
    var_rel_point0: 3e-3,
};

/// Against the full dense reference: f32 plus the truncation (module docs).
const FULL: Tol = Tol {
    mean: 2e-3,
    var_rel: 2e-3,
    var_abs: 1e-5,
    var_rel_point0: 3e-2,
};

/// One sequence: frame times (µs) and points.
struct Sequence {
    name: &'static str,
    frames: Vec<(i64, Vec<[f32; 2]>)>,
}

/// The named sequence `equivalence_sequence(seed, clutter, appear)` (25 frames at 20 fps with
/// 2× and 5× steps, a blackout and a lane appearing at frame `appear`).
fn sequence(name: &'static str, seed: u64, clutter: f64, appear: usize) -> Sequence {
    Sequence {
        name,
        frames: equivalence_sequence(seed, clutter, appear),
    }
}

#[derive(Debug, Default, Clone, Copy)]
struct Dev {
    mean: f64,
    var_rel: f64,
    sm_mean: f64,
    sm_var_rel: f64,
    exist: f64,
    compared: usize,
    smoothed_compared: usize,
    smoothed_skipped: usize,
}

fn compare_lane(
    tol: Tol,
    what: &str,
    c: &LaneEstimate<N>,
    r: &RefLane,
    mean: &mut f64,
    var_rel: &mut f64,
) -> Result<(), String> {
    for i in 0..N {
        let (cz, cv) = (f64::from(c.z[i]), f64::from(c.var[i]));
        let dm = (cz - r.z[i]).abs();
        let dv = (cv - r.var[i]).abs();
        *mean = mean.max(dm);
        *var_rel = var_rel.max(dv / r.var[i].max(1e-12));
        let var_rel = if i == 0 {
            tol.var_rel_point0
        } else {
            tol.var_rel
        };
        if dm > tol.mean {
            return Err(format!("{what} point {i}: mean {cz} vs {}", r.z[i]));
        }
        if dv > var_rel * r.var[i] + tol.var_abs {
            return Err(format!("{what} point {i}: var {cv} vs {}", r.var[i]));
        }
    }
    Ok(())
}

fn run(seq: &Sequence, tables: &ModelTables, tol: Tol) -> Result<Dev, String> {
    // The reference pipeline is the round-1 pipeline (docs/design.md §1–§4.3); the known-lane
    // stage (§11) has its own reference (`tests/persist_reference.rs`).
    let mut core = Box::new(ReferenceTracker::with_config(
        &DEFAULT,
        TrackerConfig::ROUND1,
    ));
    let mut reference = ReferencePipeline::new(tables, K, PipelineConfig::from_tables(tables))
        .map_err(|e| e.to_string())?;
    let mut c2r: BTreeMap<u32, u32> = BTreeMap::new();
    let mut r2c: BTreeMap<u32, u32> = BTreeMap::new();
    let mut dev = Dev::default();
    for (k, (us, pts)) in seq.frames.iter().enumerate() {
        let co = core
            .step(Instant::from_micros(*us), pts)
            .map_err(|e| e.to_string())?;
        let pts64: Vec<(f64, f64)> = pts
            .iter()
            .map(|p| (f64::from(p[0]), f64::from(p[1])))
            .collect();
        let ro = reference
            .step(*us as f64 * 1e-6, &pts64)
            .map_err(|e| format!("frame {k}: reference: {e:#}"))?;
        let at = |s: &str| format!("{}: frame {k}: {s}", seq.name);
        let cslots: Vec<usize> = co.filtered.iter().map(|l| usize::from(l.slot)).collect();
        let rslots: Vec<usize> = ro.filtered.iter().map(|l| l.slot).collect();
        if cslots != rslots {
            return Err(at(&format!("lane slots {cslots:?} vs {rslots:?}")));
        }
        for (c, r) in co.filtered.iter().zip(&ro.filtered) {
            let (ci, ri) = (c.id.0, r.id);
            if *c2r.entry(ci).or_insert(ri) != ri || *r2c.entry(ri).or_insert(ci) != ci {
                return Err(at(&format!("id {ci} ↔ {ri} breaks the bijection {c2r:?}")));
            }
            if usize::from(c.misses) != r.misses {
                return Err(at(&format!(
                    "slot {}: misses {} vs {}",
                    r.slot, c.misses, r.misses
                )));
            }
            let de = (f64::from(c.existence) - r.existence).abs();
            dev.exist = dev.exist.max(de);
            if de > EXIST_ABS {
                return Err(at(&format!(
                    "slot {}: existence {} vs {}",
                    r.slot, c.existence, r.existence
                )));
            }
            let what = at(&format!("filtered slot {}", r.slot));
            compare_lane(tol, &what, c, r, &mut dev.mean, &mut dev.var_rel)?;
            dev.compared += 1;
        }
        if reference.window_comparable() == Some(false) {
            dev.smoothed_skipped += 1;
        }
        let sm = if k % SMOOTH_EVERY == 0 {
            reference
                .lagged()
                .map_err(|e| at(&format!("reference smoother: {e:#}")))?
        } else {
            None
        };
        if let Some(sm) = &sm {
            let cs: Vec<usize> = co.smoothed.iter().map(|l| usize::from(l.slot)).collect();
            let rs: Vec<usize> = sm.iter().map(|l| l.slot).collect();
            if cs != rs {
                return Err(at(&format!("smoothed slots {cs:?} vs {rs:?}")));
            }
            for (c, r) in co.smoothed.iter().zip(sm) {
                if c2r.get(&c.id.0) != Some(&r.id) {
                    return Err(at(&format!("smoothed id {} vs {}", c.id.0, r.id)));
                }
                let what = at(&format!("smoothed slot {}", r.slot));
                compare_lane(tol, &what, c, r, &mut dev.sm_mean, &mut dev.sm_var_rel)?;
                dev.smoothed_compared += 1;
            }
        }
    }
    Ok(dev)
}

fn tables(truncated: bool) -> ModelTables {
    let h = HyperFile::load(&repo_root().join(DEFAULT_HYPER)).unwrap();
    let mut t = ModelTables::from_hyper(&h).unwrap();
    if truncated {
        let r = t.gram_rank;
        let v = t.gram_eigvec.columns(0, r).into_owned();
        let l = nalgebra::DMatrix::from_diagonal(&t.gram_eigval.rows(0, r).into_owned());
        let g = &v * l * v.transpose();
        t.gram = (&g + g.transpose()) * 0.5;
    }
    t
}

fn check(label: &str, truncated: bool, tol: Tol) {
    let t = tables(truncated);
    let seqs = [
        sequence("clean, lane at frame 8", 1, 0.0, 8),
        sequence("light clutter, lane at frame 5", 2, 0.005, 5),
    ];
    let mut total = Dev::default();
    for seq in &seqs {
        let d = run(seq, &t, tol).unwrap_or_else(|e| panic!("{label}: {e}"));
        println!(
            "{label} / {}: {} filtered lanes, max |Δmean| {:.2e} m, max rel |Δvar| {:.2e}; {} smoothed lanes, max |Δmean| {:.2e} m, max rel |Δvar| {:.2e}; {} frames' smoothed output not comparable; max |Δexistence| {:.1e}",
            seq.name, d.compared, d.mean, d.var_rel, d.smoothed_compared, d.sm_mean, d.sm_var_rel, d.smoothed_skipped, d.exist
        );
        total.compared += d.compared;
        total.smoothed_compared += d.smoothed_compared;
        total.smoothed_skipped += d.smoothed_skipped;
        total.mean = total.mean.max(d.mean);
        total.var_rel = total.var_rel.max(d.var_rel);
        total.sm_mean = total.sm_mean.max(d.sm_mean);
        total.sm_var_rel = total.sm_var_rel.max(d.sm_var_rel);
        total.exist = total.exist.max(d.exist);
    }
    println!("{label} TOTAL: {total:?}");
    // The sequences exercise what they claim: lanes compared, smoothed output compared and skipped.
    assert!(total.compared >= 2 * 60, "{total:?}");
    assert!(total.smoothed_compared >= 15, "{total:?}");
    assert!(total.smoothed_skipped > 0, "{total:?}");
}

#[test]
fn tracker_matches_dense_pipeline_of_its_truncated_model() {
    check("truncated K_u", true, TRUNCATED);
}

#[test]
fn tracker_matches_full_dense_pipeline() {
    check("full K_u", false, FULL);
}
