//! Precision and recall of the image front end on the tuning and held-out halves of the bundled
//! 512×288 TuSimple frames (`frontend::TUNING_SET`, `frontend::HELD_OUT_SET`), with the default
//! parameters, or with `name=value` overrides given as arguments (for tuning on the tuning set).
//!
//! `cargo run --release -p stjpdacf-tools --example frontend_eval [name=value …]`

use std::time::Instant;

use stjpdacf_tools::frontend::{self, FrontendParams, HELD_OUT_SET, TUNING_SET};
use stjpdacf_tools::tusimple::read_labels;

fn main() -> anyhow::Result<()> {
    let dir = stjpdacf_tools::repo_root().join("data/tusimple/sample_512x288");
    let labels = read_labels(&dir.join("label_data.json"))?;
    let mut p = FrontendParams::default();
    for a in std::env::args().skip(1) {
        let (k, v) = a
            .split_once('=')
            .ok_or_else(|| anyhow::anyhow!("expected name=value: {a}"))?;
        p.set(k, v.parse()?)?;
    }
    for (name, set) in [("tuning", TUNING_SET), ("held-out", HELD_OUT_SET)] {
        let (mut tp, mut n, mut rec, mut ms) = (0, 0, Vec::new(), 0.0);
        for raw in set {
            let img = frontend::load_rgb(&dir.join(raw))?;
            let cam = frontend::camera_for(&img, None)?;
            let t0 = Instant::now();
            let pts = frontend::detect(&img, &cam, &p)?;
            ms += t0.elapsed().as_secs_f64() * 1e3;
            let l = labels.iter().find(|l| l.raw_file == raw).expect("label");
            let (a, b, r) = frontend::score(&pts, l, 1.0, 6.0);
            println!(
                "  {raw}: {b} points, precision {:.3}, lane recall {r:.2?}",
                a as f64 / b as f64
            );
            tp += a;
            n += b;
            rec.extend(r);
        }
        let mr = rec.iter().sum::<f64>() / rec.len() as f64;
        let cov = rec.iter().filter(|&&r| r >= 0.25).count();
        println!(
            "{name}: precision {:.3} ({tp}/{n}), mean lane recall {mr:.3}, {cov} of {} lanes ≥ 0.25, {:.1} ms per image",
            tp as f64 / n as f64,
            rec.len(),
            ms / set.len() as f64
        );
    }
    Ok(())
}
