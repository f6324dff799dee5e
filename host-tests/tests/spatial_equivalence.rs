//! The f32 core's per-frame spatial filter (`stjpdacf::spatial::filter::SpatialFilter<3, 6, 64, 16>`
//! on `stjpdacf::tables::DEFAULT`, `Config::default()`) against the f64 reference
//! (`reference::spatial::run_frame` on `ModelTables::from_hyper(data/hyper/default.json)`, K = 4,
//! PER_ROW = 16, every joint event enumerated), frame by frame on seeded scenes from `scenario`.
//!
//! # What is compared, and the tolerances
//! Exactly: the number of confirmed lanes, each lane's rank, status, hit extent (first and last
//! row, recovered from `u_first`/`u_last`), which index points carry a pseudo-measurement, and the
//! frame counters (started, confirmed, deleted, ended, merged, no-slot, clutter points,
//! rejections, rows whose event count exceeds E, failed rows; the core's `deleted` also counts
//! tentative tracks removed by a merge). Existence (`hits/(hits + misses)`, a ratio of
//! integers) within 1e-6.
//!
//! Within f32 tolerances:
//! * pseudo-measurement means: `|z_core − z_ref| ≤ 1e-3 m + 1e-3·|z_ref|`;
//! * covariance blocks: `max |C_core − C_ref| ≤ 1e-3 · max |C_ref|` (the N×N block of the lane).
//!
//! Why these: one f32 rounding is 6e-8 relative; a frame is 61 rows of prediction, a coupled
//! update with up to six tracks and a certain-association update whose posterior offset variance
//! comes from `25 − 25²/(25 + s)` (a cancellation that loses about `log10(25/0.1)` ≈ 2.4 digits),
//! and then 60 RTS steps, each with a 3×3 Cholesky solve of a predicted covariance whose
//! condition number reaches ~1e4. Errors of 1e-5…1e-4 relative are expected; 1e-3 is one order
//! above that and still two orders below anything the temporal filter could notice (the
//! pseudo-measurement standard deviations are ≥ 3 cm, i.e. variances ≥ 1e-3 m²). The measured
//! maxima are printed (`cargo test … -- --nocapture`).
//!
//! # Discrete decisions
//! A hit (`1 − β_miss ≥ 0.5`), a gate (`d² ≤ γ`), consistency (`|x − x_b| ≤ init_gate`), a rank
//! (`h·x < x`) and a merge test (`|Δ h·x| ≤ merge_distance`) can go the other way in f32 when the
//! f64 value sits on the threshold. The reference records, per row, how close each decision came
//! ([`RowDiag::margins`]); a scene with a decision within 1e-3 of its threshold (absolute: d²,
//! probability, metres) is *near*. A scene that disagrees is excluded (and counted) only when it is
//! near; a disagreeing scene that is not near fails the test. Likewise a scene whose core rows were
//! approximated (event budget E = 512, `SpatialReport::rows_approximated`) is reported and, if it
//! disagrees, excluded as such.

use stjpdacf::spatial::filter::{
    Config as CoreConfig, LaneObservation, SpatialFilter, SpatialReport, Status as CoreStatus,
};
use stjpdacf::tables::DEFAULT;
use stjpdacf_reference::hyper::HyperFile;
use stjpdacf_reference::spatial::{
    run_frame, Config, FrameResult, Margins, Model, Status, TrackOutput,
};
use stjpdacf_tools::repo_root;
use stjpdacf_tools::scenario::{Gap, Junction, Scenario, ScenarioConfig, Shape};
use stjpdacf_tools::tablegen::{ModelTables, DEFAULT_HYPER};

type Filter = SpatialFilter<3, 6, 64, 16>;
const K: usize = 4;
const PER_ROW: usize = 16;
const N: usize = 16;

const MEAN_ABS: f64 = 1e-3;
const MEAN_REL: f64 = 1e-3;
const COV_REL: f64 = 1e-3;
const EXIST_ABS: f64 = 1e-6;
/// A decision this close to its threshold may flip between f32 and f64.
const NEAR: f64 = 1e-3;

fn reference() -> (Model, Config) {
    let h = HyperFile::load(&repo_root().join(DEFAULT_HYPER)).unwrap();
    let t = ModelTables::from_hyper(&h).unwrap();
    let cfg = Config::from_tables(&t);
    (Model::new(&t, K).unwrap(), cfg)
}

fn run_core(points: &[(f64, f64)]) -> (Vec<LaneObservation<N>>, SpatialReport) {
    run_core_with(points, &CoreConfig::default())
}

fn run_core_with(
    points: &[(f64, f64)],
    cfg: &CoreConfig,
) -> (Vec<LaneObservation<N>>, SpatialReport) {
    let mut f = Box::new(Filter::new());
    let pts: Vec<[f32; 2]> = points.iter().map(|&(u, x)| [u as f32, x as f32]).collect();
    let mut out = [LaneObservation {
        status: CoreStatus::Tentative,
        present: [false; N],
        z: nalgebra::SVector::zeros(),
        cov: nalgebra::SMatrix::zeros(),
        u_first: 0.0,
        u_last: 0.0,
        existence: 0.0,
        rank: 0,
        llr: 0.0,
    }; 6];
    let (n, rep) = f.run(&DEFAULT, cfg, &pts, &mut out);
    (out[..n].to_vec(), rep)
}

/// Largest deviations of one scene (or of all), each also as a fraction of its tolerance.
#[derive(Debug, Clone, Copy, Default)]
struct Dev {
    mean_abs: f64,
    mean_frac: f64,
    cov_rel: f64,
    exist_abs: f64,
    lanes: usize,
}

impl Dev {
    fn max(self, o: Dev) -> Dev {
        Dev {
            mean_abs: self.mean_abs.max(o.mean_abs),
            mean_frac: self.mean_frac.max(o.mean_frac),
            cov_rel: self.cov_rel.max(o.cov_rel),
            exist_abs: self.exist_abs.max(o.exist_abs),
            lanes: self.lanes + o.lanes,
        }
    }
}

fn status_eq(c: CoreStatus, r: Status) -> bool {
    matches!(
        (c, r),
        (CoreStatus::Tentative, Status::Tentative)
            | (CoreStatus::Confirmed, Status::Confirmed)
            | (CoreStatus::Ended, Status::Ended)
    )
}

fn row_of(model: &Model, u: f32) -> usize {
    ((f64::from(u) - model.u_min) / model.du).round() as usize
}

fn compare_lane(
    model: &Model,
    c: &LaneObservation<N>,
    t: &TrackOutput,
    k: usize,
) -> Result<Dev, String> {
    let id = format!("lane {k}");
    if usize::from(c.rank) != t.rank {
        return Err(format!("{id}: rank {} vs {}", c.rank, t.rank));
    }
    if !status_eq(c.status, t.status) {
        return Err(format!("{id}: status {:?} vs {:?}", c.status, t.status));
    }
    let (f, l) = (row_of(model, c.u_first), row_of(model, c.u_last));
    if (f, l) != (t.first_row, t.last_row) {
        return Err(format!(
            "{id}: extent rows {f}..{l} vs {}..{}",
            t.first_row, t.last_row
        ));
    }
    let present: Vec<bool> = t.pseudo.iter().map(Option::is_some).collect();
    if c.present.as_slice() != present.as_slice() {
        return Err(format!("{id}: present {:?} vs {present:?}", c.present));
    }
    let mut dev = Dev {
        lanes: 1,
        exist_abs: (f64::from(c.existence) - t.existence).abs(),
        ..Dev::default()
    };
    if dev.exist_abs > EXIST_ABS {
        return Err(format!(
            "{id}: existence {} vs {}",
            c.existence, t.existence
        ));
    }
    for (i, p) in t.pseudo.iter().enumerate() {
        if let Some(p) = p {
            let e = (f64::from(c.z[i]) - p).abs();
            dev.mean_abs = dev.mean_abs.max(e);
            dev.mean_frac = dev.mean_frac.max(e / (MEAN_ABS + MEAN_REL * p.abs()));
        }
    }
    let big = t.pseudo_cov.abs().max();
    let mut worst = 0.0f64;
    for i in 0..N {
        for j in 0..N {
            worst = worst.max((f64::from(c.cov[(i, j)]) - t.pseudo_cov[(i, j)]).abs());
        }
    }
    dev.cov_rel = worst / big;
    if dev.mean_frac > 1.0 {
        return Err(format!(
            "{id}: pseudo-measurement off by {:.3e} m ({:.2} of the tolerance)",
            dev.mean_abs, dev.mean_frac
        ));
    }
    if dev.cov_rel > COV_REL {
        return Err(format!(
            "{id}: covariance off by {:.3e} of its largest entry",
            dev.cov_rel
        ));
    }
    Ok(dev)
}

/// Every comparison of one frame; `Err` names the first disagreement.
fn compare(
    model: &Model,
    core: &(Vec<LaneObservation<N>>, SpatialReport),
    r: &FrameResult,
) -> Result<Dev, String> {
    let (lanes, rep) = core;
    let c = &r.counters;
    let failed = r.rows.iter().filter(|d| d.failed).count();
    // (name, core, reference)
    let counters = [
        ("started", rep.started as usize, c.initiated),
        ("confirmed", rep.confirmed as usize, c.confirmed),
        (
            "deleted (misses + tentative merged)",
            rep.deleted as usize,
            c.deleted + c.merged_tentative,
        ),
        ("ended", rep.ended as usize, c.ended),
        ("merged", rep.merged as usize, c.merged),
        ("no_slot", rep.no_slot as usize, c.no_slot),
        (
            "clutter_points",
            rep.clutter_points as usize,
            c.clutter_points,
        ),
        (
            "rejected_non_finite",
            rep.rejected_non_finite as usize,
            c.rejected.non_finite,
        ),
        (
            "rejected_window",
            rep.rejected_window as usize,
            c.rejected.out_of_window,
        ),
        (
            "rejected_duplicate",
            rep.rejected_duplicate as usize,
            c.rejected.duplicate,
        ),
        (
            "rejected_row_full",
            rep.rejected_row_full as usize,
            c.rejected.row_full,
        ),
        (
            "rows_over_budget",
            rep.rows_approximated as usize,
            c.over_budget_rows,
        ),
        ("rows_failed", rep.rows_failed as usize, failed),
    ];
    for (name, vc, vr) in counters {
        if vc != vr {
            return Err(format!("counter {name}: core {vc} vs reference {vr}"));
        }
    }
    if lanes.len() != r.tracks.len() {
        return Err(format!(
            "{} lanes vs {} in the reference",
            lanes.len(),
            r.tracks.len()
        ));
    }
    let mut dev = Dev::default();
    for (k, (cl, t)) in lanes.iter().zip(&r.tracks).enumerate() {
        dev = dev.max(compare_lane(model, cl, t, k)?);
    }
    Ok(dev)
}

/// Rows of the reference whose decisions came within [`NEAR`] of a threshold, with what.
fn near_rows(r: &FrameResult) -> Vec<String> {
    r.rows
        .iter()
        .filter_map(|d| {
            let Margins {
                gate,
                hit,
                init_gate,
                rank,
                merge,
            } = d.margins;
            let what: Vec<String> = [
                ("d²−γ", gate),
                ("β_miss−0.5", hit),
                ("init_gate", init_gate),
                ("rank", rank),
                ("merge", merge),
            ]
            .iter()
            .filter(|(_, m)| *m <= NEAR)
            .map(|(n, m)| format!("{n} {m:.1e}"))
            .collect();
            (!what.is_empty()).then(|| format!("row {}: {}", d.row, what.join(", ")))
        })
        .collect()
}

fn base() -> ScenarioConfig {
    ScenarioConfig::default()
}

fn rbf(variance: f64, lengthscale: f64) -> Shape {
    Shape::Rbf {
        variance,
        lengthscale,
    }
}

/// The scene families and their seeds.
fn scenes() -> Vec<(&'static str, ScenarioConfig, Vec<u64>)> {
    vec![
        ("parallel", base(), vec![1, 2, 3, 4]),
        (
            "curves",
            ScenarioConfig {
                lanes: 4,
                shape: rbf(1.0, 25.0),
                ..base()
            },
            vec![5, 6, 7],
        ),
        (
            "curves+clutter",
            ScenarioConfig {
                shape: rbf(4.0, 35.0),
                clutter_density: 0.05,
                ..base()
            },
            vec![8, 9, 10],
        ),
        (
            "clutter",
            ScenarioConfig {
                clutter_density: 0.1,
                row_jitter: 0.8,
                ..base()
            },
            vec![11, 12, 13],
        ),
        (
            "gaps",
            ScenarioConfig {
                gaps: vec![
                    Gap {
                        lane: None,
                        u0: 40.5,
                        u1: 46.5,
                    },
                    Gap {
                        lane: Some(1),
                        u0: 55.0,
                        u1: 100.0,
                    },
                ],
                clutter_density: 0.02,
                ..base()
            },
            vec![14, 15, 16],
        ),
        (
            "merge",
            ScenarioConfig {
                pd: 0.95,
                junction: Some(Junction {
                    lane: 1,
                    merge: true,
                    u_start: 30.0,
                    u_end: 45.0,
                }),
                ..base()
            },
            vec![17, 18, 19],
        ),
        (
            "split",
            ScenarioConfig {
                pd: 0.95,
                junction: Some(Junction {
                    lane: 1,
                    merge: false,
                    u_start: 25.0,
                    u_end: 40.0,
                }),
                ..base()
            },
            vec![20, 21, 22],
        ),
        (
            "more lanes than D",
            ScenarioConfig {
                lanes: 8,
                left: -13.0,
                spacing: (3.4, 3.6),
                clutter_x: (-15.0, 16.0),
                clutter_density: 0.02,
                ..base()
            },
            vec![23, 24],
        ),
        (
            "clutter only",
            ScenarioConfig {
                lanes: 0,
                clutter_density: 0.1,
                ..base()
            },
            vec![25, 26, 27],
        ),
    ]
}

#[test]
fn core_matches_reference_on_seeded_scenes() {
    let (model, cfg) = reference();
    assert_eq!(
        cfg.confirm_hits,
        usize::from(CoreConfig::default().confirm_hits)
    );
    assert_eq!(cfg.max_events, CoreConfig::default().max_events);
    let mut total = Dev::default();
    let (mut compared, mut matched, mut near_scenes) = (0, 0, 0);
    let mut excluded: Vec<String> = Vec::new();
    let mut failures: Vec<String> = Vec::new();
    let (mut ended, mut merged, mut no_slot, mut approx_scenes) = (0, 0, 0, 0);
    for (name, scfg, seeds) in scenes() {
        let mut fam = Dev::default();
        for seed in seeds {
            let sc = Scenario::generate(&scfg, seed);
            let r = run_frame(&model, &cfg, &sc.points, PER_ROW);
            let core = run_core(&sc.points);
            let near = near_rows(&r);
            let approx = core.1.rows_approximated;
            compared += 1;
            near_scenes += usize::from(!near.is_empty());
            approx_scenes += usize::from(approx > 0);
            let tag = format!("{name} seed {seed}");
            match compare(&model, &core, &r) {
                Ok(d) => {
                    matched += 1;
                    fam = fam.max(d);
                    ended += r.counters.ended;
                    merged += r.counters.merged;
                    no_slot += r.counters.no_slot;
                    println!(
                        "{tag}: ok, {} lanes, mean {:.2e} m, cov {:.2e}, near rows {}, approximated rows {approx}",
                        d.lanes,
                        d.mean_abs,
                        d.cov_rel,
                        near.len()
                    );
                    for n in &near {
                        println!("    near (decided alike): {n}");
                    }
                }
                Err(e) if !near.is_empty() || approx > 0 => {
                    excluded.push(format!(
                        "{tag}: {e}; approximated rows {approx}; near: {}",
                        near.join("; ")
                    ));
                }
                Err(e) => failures.push(format!("{tag}: {e} (no decision near a threshold)")),
            }
        }
        println!(
            "== {name}: {} lanes, max mean dev {:.3e} m ({:.3} of tol), max cov dev {:.3e} rel, max existence dev {:.1e}",
            fam.lanes, fam.mean_abs, fam.mean_frac, fam.cov_rel, fam.exist_abs
        );
        total = total.max(fam);
    }
    println!(
        "TOTAL: {compared} scenes, {matched} matched, {} excluded, {} failed; {near_scenes} scenes with a decision within {NEAR:e} of a threshold, {approx_scenes} with approximated rows",
        excluded.len(),
        failures.len()
    );
    println!(
        "TOTAL: {} lanes, max mean dev {:.3e} m ({:.3} of tol), max cov dev {:.3e} rel, max existence dev {:.1e}",
        total.lanes, total.mean_abs, total.mean_frac, total.cov_rel, total.exist_abs
    );
    for e in &excluded {
        println!("excluded: {e}");
    }
    assert!(failures.is_empty(), "{failures:#?}");
    // Exclusions are for rare near-threshold scenes only.
    assert!(excluded.len() * 5 <= compared, "{excluded:#?}");
    // The scenes exercise what they claim to: lanes, ended tracks, merges, the slot limit.
    assert!(total.lanes >= 40, "{} lanes compared", total.lanes);
    assert!(
        ended > 0 && merged > 0 && no_slot > 0,
        "{ended} {merged} {no_slot}"
    );
}

/// The comparison is sharp: the reference with the old workaround (`σ_c² = 1 m²` instead of the
/// tables' 25 m²) or the old `confirm_hits = 4` does not pass it against the core.
#[test]
fn comparison_detects_the_old_reference() {
    let (model, cfg) = reference();
    let sc = Scenario::generate(
        &ScenarioConfig {
            shape: rbf(4.0, 35.0),
            clutter_density: 0.05,
            ..base()
        },
        8,
    );
    let core = run_core(&sc.points);
    let r = run_frame(&model, &cfg, &sc.points, PER_ROW);
    compare(&model, &core, &r).unwrap();
    for bad in [
        Config {
            offset_variance: 1.0,
            ..cfg.clone()
        },
        Config {
            confirm_hits: 4,
            ..cfg.clone()
        },
    ] {
        let r = run_frame(&model, &bad, &sc.points, PER_ROW);
        let e = compare(&model, &core, &r).unwrap_err();
        println!("old reference: {e}");
    }
}

/// The within-frame row-noise scale the tracker sets (docs/design.md §11.12) is the same model
/// in both: the core with the tracker's scale against the reference with it, and not against
/// the reference without it.
#[test]
fn row_noise_scale_matches_reference() {
    let (model, cfg) = reference();
    let s = stjpdacf::persist::PersistConfig::DEFAULT.row_noise_scale;
    let core_cfg = CoreConfig {
        row_noise_scale: s,
        ..CoreConfig::default()
    };
    let scaled = Config {
        row_noise_scale: f64::from(s),
        ..cfg.clone()
    };
    let mut compared = 0;
    for seed in [8, 9, 10] {
        let sc = Scenario::generate(
            &ScenarioConfig {
                shape: rbf(4.0, 35.0),
                clutter_density: 0.05,
                ..base()
            },
            seed,
        );
        let core = run_core_with(&sc.points, &core_cfg);
        let r = run_frame(&model, &scaled, &sc.points, PER_ROW);
        if !near_rows(&r).is_empty() {
            continue;
        }
        compare(&model, &core, &r).unwrap();
        compared += 1;
        if compared == 1 {
            let unscaled = run_frame(&model, &cfg, &sc.points, PER_ROW);
            assert!(compare(&model, &core, &unscaled).is_err());
        }
    }
    assert!(compared >= 2, "{compared} scenes compared");
}
