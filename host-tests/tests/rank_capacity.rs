//! The tracker's Gram-rank capacity (its const `RANK`, with `NX = 2·D·RANK`, `NA = D·RANK`)
//! changes its size and cost, not its numbers: a tracker compiled for rank `r` and the reference
//! capacity (rank 7) running tables truncated to `r` publish the same lanes, bit for bit.
//!
//! Every quantity of the core is computed over `r = min(gram_rank, RANK)` components, and the
//! loops over the first `r` of `RANK` entries add the same terms in the same order as loops over
//! exactly `r`. This is what lets an integrator compile the smallest model at its own rank
//! (`STJPDACF_FW_RANK_CAP=1` in the firmware benchmark: 40 % less static RAM and 9 % fewer
//! instructions a typical frame at rank 4, docs/measurements.md "Fitting the MCU") and keep every
//! figure measured with the reference capacity. The firmware's published lanes are compared
//! the same way under QEMU (docs/measurements.md).
//!
//! Inputs: the firmware benchmark's three scenarios (typical, worst, worst_patterns), on the
//! uncoupled tables with LBP on every row (the smallest model) at ranks 4 and 3, and on the
//! default (coupled) tables with the default configuration at ranks 5 and 4. Compared per frame: the
//! filtered and smoothed lanes (every field, floats by their bits) and the step report.

use stjpdacf::persist::PersistConfig;
use stjpdacf::spatial::row::Association;
use stjpdacf::tables::{ReferenceTables, DEFAULT, UNCOUPLED};
use stjpdacf::tracker::{
    Instant, LaneEstimate, Rank3Tracker, Rank4Tracker, Rank5Tracker, ReferenceTracker,
    TrackerConfig,
};
use stjpdacf_tools::fwscenario::{scenarios, STEP_US};

/// A lane as its exact bits: every float by `to_bits`.
fn lane_bits(l: &LaneEstimate<16>) -> String {
    let b = |v: f32| format!("{:08x}", v.to_bits());
    let z: Vec<String> = l.z.iter().map(|v| b(*v)).collect();
    let var: Vec<String> = l.var.iter().map(|v| b(*v)).collect();
    format!(
        "{:?} {} {} {} {} {} {} {} [{}] [{}]",
        l.id,
        l.slot,
        l.misses,
        l.age,
        l.hits,
        b(l.u_first),
        b(l.u_last),
        b(l.existence),
        z.join(" "),
        var.join(" ")
    )
}

/// Each frame's output of a tracker on `frames`: filtered lanes, smoothed lanes, report.
macro_rules! run {
    ($tracker:ty, $tables:expr, $cfg:expr, $frames:expr) => {{
        let mut t: Box<$tracker> = Box::new(<$tracker>::with_config($tables, $cfg));
        let mut out = Vec::new();
        for (k, pts) in $frames.iter().enumerate() {
            let at = Instant::from_micros((k as i64 + 1) * STEP_US);
            let o = t.step(at, pts).expect("the scenarios' times increase");
            let f: Vec<String> = o.filtered.iter().map(lane_bits).collect();
            let s: Vec<String> = o.smoothed.iter().map(lane_bits).collect();
            out.push((f, s, format!("{:?}", o.report)));
        }
        out
    }};
}

fn truncated(base: &ReferenceTables, rank: u32) -> &'static ReferenceTables {
    Box::leak(Box::new(ReferenceTables {
        gram_rank: rank,
        ..*base
    }))
}

fn lbp() -> TrackerConfig {
    TrackerConfig {
        persist: PersistConfig {
            association: Association::Lbp,
            ..PersistConfig::DEFAULT
        },
        ..TrackerConfig::DEFAULT
    }
}

/// Compares two runs frame by frame; returns the lanes compared.
fn same(
    label: &str,
    a: &[(Vec<String>, Vec<String>, String)],
    b: &[(Vec<String>, Vec<String>, String)],
) -> usize {
    assert_eq!(a.len(), b.len(), "{label}: frames");
    let mut lanes = 0;
    for (k, (x, y)) in a.iter().zip(b).enumerate() {
        assert_eq!(x.0, y.0, "{label}: frame {k}: filtered lanes differ");
        assert_eq!(x.1, y.1, "{label}: frame {k}: smoothed lanes differ");
        assert_eq!(x.2, y.2, "{label}: frame {k}: step reports differ");
        lanes += x.0.len() + x.1.len();
    }
    lanes
}

#[test]
fn rank_capacity_changes_no_published_bit() {
    let cases: [(&str, &'static ReferenceTables, TrackerConfig, u32); 4] = [
        ("uncoupled, LBP, rank 4", truncated(&UNCOUPLED, 4), lbp(), 4),
        ("uncoupled, LBP, rank 3", truncated(&UNCOUPLED, 3), lbp(), 3),
        (
            "coupled, default, rank 5",
            truncated(&DEFAULT, 5),
            TrackerConfig::DEFAULT,
            5,
        ),
        (
            "coupled, default, rank 4",
            truncated(&DEFAULT, 4),
            TrackerConfig::DEFAULT,
            4,
        ),
    ];
    println!(
        "size_of: ReferenceTracker {} B, Rank5Tracker {} B, Rank4Tracker {} B, rank 3 {} B",
        std::mem::size_of::<ReferenceTracker>(),
        std::mem::size_of::<Rank5Tracker>(),
        std::mem::size_of::<Rank4Tracker>(),
        std::mem::size_of::<Rank3Tracker>()
    );
    for s in scenarios().unwrap() {
        for (name, tables, cfg, rank) in cases {
            let label = format!("{} / {name}", s.name);
            let reference = run!(ReferenceTracker, tables, cfg, s.frames);
            let compact = match rank {
                5 => run!(Rank5Tracker, tables, cfg, s.frames),
                4 => run!(Rank4Tracker, tables, cfg, s.frames),
                _ => run!(Rank3Tracker, tables, cfg, s.frames),
            };
            let lanes = same(&label, &reference, &compact);
            // The comparison has something to compare: lanes are published in these scenes.
            assert!(lanes > 0, "{label}: no lane published");
            println!(
                "{label}: {} frames, {lanes} lanes bit for bit",
                s.frames.len()
            );
        }
    }
}

/// The compact tracker on the full-rank tables is the truncated model: `r = min(gram_rank,
/// RANK)` everywhere, so rank capacity 4 with rank-7 tables equals rank-4 tables.
#[test]
fn rank_capacity_below_the_tables_rank_truncates() {
    let s = scenarios().unwrap().into_iter().next().unwrap();
    let full = run!(Rank4Tracker, &UNCOUPLED, lbp(), s.frames);
    let cut = run!(ReferenceTracker, truncated(&UNCOUPLED, 4), lbp(), s.frames);
    assert!(same("typical / capacity 4 on rank-7 tables", &full, &cut) > 0);
    let full = run!(Rank5Tracker, &DEFAULT, TrackerConfig::DEFAULT, s.frames);
    let cut = run!(
        ReferenceTracker,
        truncated(&DEFAULT, 5),
        TrackerConfig::DEFAULT,
        s.frames
    );
    assert!(same("typical / capacity 5 on rank-7 tables", &full, &cut) > 0);
}
