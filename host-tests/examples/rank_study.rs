//! How much the Gram truncation rank costs in accuracy: trackers with RANK = 4…7 (the tables keep
//! 7 components) against the full dense f64 pipeline on the seeded sequences of
//! `tests/tracker_equivalence.rs` (filtered lanes, every frame).
//!
//! `cargo run --release -p stjpdacf-test-support --example rank_study`

use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::{Instant, StepOutput, Tracker};
use stjpdacf_reference::hyper::HyperFile;
use stjpdacf_reference::pipeline::{PipelineConfig, ReferencePipeline};
use stjpdacf_tools::repo_root;
use stjpdacf_tools::scenario::equivalence_sequence;
use stjpdacf_tools::tablegen::{ModelTables, DEFAULT_HYPER};

trait Step {
    fn step(&mut self, us: i64, pts: &[[f32; 2]]) -> StepOutput<6, 16>;
}

impl<const R: usize, const NX: usize, const NA: usize> Step
    for Tracker<2, 3, 6, 16, 64, 16, 256, R, NX, NA, 4>
{
    fn step(&mut self, us: i64, pts: &[[f32; 2]]) -> StepOutput<6, 16> {
        Tracker::step(self, Instant::from_micros(us), pts).expect("time increases")
    }
}

fn tracker(rank: usize) -> Box<dyn Step> {
    match rank {
        4 => Box::new(Tracker::<2, 3, 6, 16, 64, 16, 256, 4, 48, 24, 4>::new(
            &DEFAULT,
        )),
        5 => Box::new(Tracker::<2, 3, 6, 16, 64, 16, 256, 5, 60, 30, 4>::new(
            &DEFAULT,
        )),
        6 => Box::new(Tracker::<2, 3, 6, 16, 64, 16, 256, 6, 72, 36, 4>::new(
            &DEFAULT,
        )),
        _ => Box::new(Tracker::<2, 3, 6, 16, 64, 16, 256, 7, 84, 42, 4>::new(
            &DEFAULT,
        )),
    }
}

fn main() {
    let h = HyperFile::load(&repo_root().join(DEFAULT_HYPER)).expect("hyper");
    let tables = ModelTables::from_hyper(&h).expect("tables");
    let seqs = [
        equivalence_sequence(1, 0.0, 8),
        equivalence_sequence(2, 0.005, 5),
    ];
    println!("| rank | lanes compared | max |Δmean| (m) | max |Δmean| points 1–15 (m) | max rel |Δvar| | slot mismatches |");
    println!("|---|---|---|---|---|---|");
    for rank in [4usize, 5, 6, 7] {
        let (mut n, mut dm, mut dm15, mut dv, mut mism) = (0usize, 0f64, 0f64, 0f64, 0usize);
        for seq in &seqs {
            let mut core = tracker(rank);
            let mut reference =
                ReferencePipeline::new(&tables, 4, PipelineConfig::from_tables(&tables))
                    .expect("reference");
            for (us, pts) in seq {
                let co = core.step(*us, pts);
                let p64: Vec<(f64, f64)> = pts
                    .iter()
                    .map(|p| (f64::from(p[0]), f64::from(p[1])))
                    .collect();
                let ro = reference.step(*us as f64 * 1e-6, &p64).expect("reference");
                let cs: Vec<usize> = co.filtered.iter().map(|l| usize::from(l.slot)).collect();
                let rs: Vec<usize> = ro.filtered.iter().map(|l| l.slot).collect();
                if cs != rs {
                    mism += 1;
                    continue;
                }
                for (c, r) in co.filtered.iter().zip(&ro.filtered) {
                    n += 1;
                    for i in 0..16 {
                        let d = (f64::from(c.z[i]) - r.z[i]).abs();
                        dm = dm.max(d);
                        if i > 0 {
                            dm15 = dm15.max(d);
                        }
                        dv = dv.max((f64::from(c.var[i]) - r.var[i]).abs() / r.var[i].max(1e-12));
                    }
                }
            }
        }
        println!("| {rank} | {n} | {dm:.2e} | {dm15:.2e} | {dv:.2e} | {mism} |");
    }
}
