//! Classifies crash inputs of `tracker_step` or `wire_decode`: does a frame the tracker stepped
//! on, up to the failing step, give a spatial pseudo-measurement covariance that is not PSD
//! (finding F1)?
//! `cargo run --release --example classify -- [wire_decode] FILE...`
use stjpdacf::spatial::filter::{Config, LaneObservation, SpatialFilter};
use stjpdacf::tables::DEFAULT;

/// The frames the tracker stepped on up to the failure `msg` describes.
fn frames(wire: bool, data: &[u8], msg: &str) -> Vec<Vec<[f32; 2]>> {
    let index = |rest: &str, word: &str| -> usize {
        rest.strip_prefix(word)
            .and_then(|s| s.split(':').next())
            .and_then(|s| s.parse().ok())
            .unwrap_or(usize::MAX)
    };
    if wire {
        let [raw, structured] = stjpdacf_test_support::fuzz::wire_accepted_frames(data);
        let (part, rest) = match msg.split_once(": ") {
            Some(("raw stream", rest)) => (raw, rest),
            Some((_, rest)) => (structured, rest),
            None => (structured, msg),
        };
        let k = index(rest, "buffer ");
        return part
            .into_iter()
            .filter(|(b, _)| *b <= k)
            .map(|(_, p)| p)
            .collect();
    }
    let step = index(msg, "step ");
    stjpdacf_test_support::fuzz::decode_tracker_input(data)
        .into_iter()
        .take(step.saturating_add(1))
        .map(|(_, p)| p.into_iter().take(256).collect())
        .collect()
}

fn main() {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let wire = args.first().is_some_and(|a| a == "wire_decode");
    if wire {
        args.remove(0);
    }
    let (mut f1, mut other) = (0, 0);
    for path in args {
        let data = std::fs::read(&path).unwrap_or_default();
        let r = if wire {
            stjpdacf_test_support::fuzz::wire_decode(&data)
        } else {
            stjpdacf_test_support::fuzz::tracker_step(&data)
        };
        let Err(msg) = r else {
            println!("{path}: passes");
            continue;
        };
        let mut worst = f64::INFINITY;
        for pts in frames(wire, &data, &msg) {
            let mut sf: Box<SpatialFilter<3, 6, 64, 16>> = Box::new(SpatialFilter::new());
            let empty = LaneObservation::EMPTY;
            let mut out = [empty; 6];
            let (n, _) = sf.run(&DEFAULT, &Config::DEFAULT, &pts, &mut out);
            for o in out.iter().take(n) {
                let idx: Vec<usize> = (0..16).filter(|&i| o.present[i]).collect();
                worst = worst.min(
                    stjpdacf_test_support::invariants::eigen_figures(&o.cov, &idx).min_eig_corr,
                );
            }
        }
        if worst < -1e-3 {
            f1 += 1
        } else {
            other += 1;
            println!("{path}: NOT F1 (spatial min eig {worst:.3e}): {msg}");
        }
    }
    println!("F1: {f1}, other: {other}");
}
