//! Scratch: the budget policy on denser held-out data.
use stjpdacf::tracker::TrackerConfig;
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::demo::score_on;
use stjpdacf_tools::heldout::{self, HeldoutParams};
use stjpdacf_tools::track::{track_with, Space};

fn main() -> anyhow::Result<()> {
    let hl = heldout::bundled_labels()?;
    let cam = Camera::tusimple();
    let conds: Vec<(&str, HeldoutParams)> = vec![
        (
            "x8",
            HeldoutParams {
                clutter_density: 0.16,
                ..Default::default()
            },
        ),
        (
            "x16",
            HeldoutParams {
                clutter_density: 0.32,
                ..Default::default()
            },
        ),
        (
            "rows1 x1",
            HeldoutParams {
                row_step: 1,
                ..Default::default()
            },
        ),
        (
            "rows1 x4",
            HeldoutParams {
                row_step: 1,
                clutter_density: 0.08,
                ..Default::default()
            },
        ),
        (
            "wide box x4",
            HeldoutParams {
                clutter_density: 0.08,
                clutter_box: (5.0, 70.0, 30.0),
                ..Default::default()
            },
        ),
    ];
    for (name, p) in conds {
        let mut acc = [0.0; 2];
        let mut left = 0usize;
        for seed in 1..=3u64 {
            let o = heldout::generate(&hl, &p, &cam, seed)?;
            for (k, off) in [false, true].iter().enumerate() {
                if *off {
                    std::env::set_var("ZZ_NO_FIT", "1")
                } else {
                    std::env::remove_var("ZZ_NO_FIT")
                }
                let (preds, st) = track_with(
                    &o.frames,
                    &stjpdacf::tables::DEFAULT,
                    &cam,
                    Space::Image,
                    TrackerConfig::DEFAULT,
                    |_| {},
                )?;
                if !*off {
                    left += st.over_budget_points;
                }
                acc[k] += score_on(&preds, &o.gt_last, false)?.accuracy / 3.0;
            }
        }
        println!(
            "{name}: fit {:.3}  core-only {:.3}  (left out {left})",
            acc[0], acc[1]
        );
    }
    Ok(())
}
