//! One replay clip frame by frame: the demo's replay (bundled labels, seed 1, mid preset,
//! default tracker), and for each frame of the clip whose label file name contains the first
//! argument, the true lanes' and the published lanes' columns at image rows 300 / 450 / 600 /
//! 700 (720p; `-` where a lane has no point), the published ids, their existence, the ray test's
//! offset at the camera's foot point on each published estimate (`a â±sd`, design §11.10; from
//! the estimate's marginal variances over its published extent `u`, an approximation of the
//! core's, which uses the full covariance over the frame's observed extent) with the core's own
//! verdict (`Tracker::ray_diagnosis`: `Paint` / `Ray` / `Aligned` / `Undecided`, and `moving`
//! where the motion rule reads its offset as moving), and the step report's removals (deleted, of which by the ray test and as connectors; merged as
//! duplicates; observations refused as rays). How a lane was lost or replaced, frame by frame.
//!
//! `cargo run --release -p stjpdacf-tools --example clip_trace -- 0313-1/1560/`
//! (`CLIP_TRACE_DISTRACTORS=3`: the robustness curve's 3 distractor segments per frame).
use stjpdacf::tracker::TrackerConfig;
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::synth::{self, NoiseLevel, SynthParams};
use stjpdacf_tools::track::{self, Space};

/// The image rows (720p) at which the lanes' columns are printed.
const ROWS: [f64; 4] = [300.0, 450.0, 600.0, 700.0];

fn main() -> anyhow::Result<()> {
    let want = std::env::args()
        .nth(1)
        .ok_or_else(|| anyhow::anyhow!("usage: clip_trace <part of a label's raw_file>"))?;
    let labels = stjpdacf_tools::demo::replay_labels()?;
    let cam = Camera::tusimple();
    let mut params = SynthParams::preset(NoiseLevel::Mid);
    if let Some(k) = std::env::var("CLIP_TRACE_DISTRACTORS")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        params.distractors = k;
    }
    let o = synth::synthesize(&labels, &params, &cam, 1)?;
    let gt_index = o.gt_index();
    track::track_with(
        &o.frames,
        &stjpdacf::tables::DEFAULT,
        &cam,
        Space::Image,
        TrackerConfig::DEFAULT,
        |v| {
            // Clips are named `synthNNNN` after the label's index, the last frame's record.
            let clip = v.frame.clip.trim_start_matches("synth").parse::<usize>();
            if !clip.is_ok_and(|c| o.gt_last.get(c).is_some_and(|g| g.raw_file.contains(&want))) {
                return;
            }
            let Some(p) = v.prediction else { return };
            let Some(g) = gt_index
                .get(p.raw_file.as_str())
                .and_then(|&j| o.gt_all.get(j))
            else {
                return;
            };
            let at = |lane: &Vec<f64>| -> String {
                ROWS.iter()
                    .map(|r| {
                        g.h_samples
                            .iter()
                            .position(|h| (h - r).abs() < 1.0)
                            .and_then(|i| lane.get(i))
                            .filter(|x| **x >= 0.0)
                            .map_or("-".to_string(), |x| format!("{x:.0}"))
                    })
                    .collect::<Vec<_>>()
                    .join("/")
            };
            let gts: Vec<String> = g.lanes.iter().map(at).collect();
            let preds: Vec<String> = p
                .lanes
                .iter()
                .zip(v.prediction_ids)
                .map(|(l, id)| format!("#{id} {}", at(l)))
                .collect();
            let existence: Vec<String> = v
                .output
                .map(|out| {
                    out.filtered
                        .iter()
                        .map(|l| {
                            // The ray test's offset at the foot point on the published estimate
                            // (its marginal variances only, plus the point variance).
                            let t = &stjpdacf::tables::DEFAULT;
                            let r = t.hyper.meas_noise;
                            let present: [bool; 16] = std::array::from_fn(|i| {
                                t.index_u[i] >= l.u_first && t.index_u[i] <= l.u_last
                            });
                            let w: [f32; 16] = std::array::from_fn(|i| 1.0 / (l.var[i] + r));
                            let cov = |a: &[f32; 16], b: &[f32; 16]| -> f32 {
                                (0..16).map(|i| a[i] * b[i] * (l.var[i] + r)).sum()
                            };
                            let ray =
                                stjpdacf::persist::ray_stat(&t.index_u, &l.z, &present, &w, &cov)
                                    .map_or("-".to_string(), |st| {
                                        format!("a {:.2}±{:.2}", st.a, st.sd_a)
                                    });
                            let (verdict, moving) = v.tracker.ray_diagnosis(usize::from(l.slot));
                            let moving = if moving { " moving" } else { "" };
                            format!(
                                "{:?} {:.2} ({ray}, u {:.0}–{:.0}; core {verdict:?}{moving})",
                                l.id, l.existence, l.u_first, l.u_last
                            )
                        })
                        .collect()
                })
                .unwrap_or_default();
            let removed = v.output.map_or(String::new(), |out| {
                let k = &out.report.known;
                format!(
                    "deleted {} (rays {}, connectors {}), merged {}, rays refused {}",
                    k.deleted, k.ray_deleted, k.connectors_deleted, k.merged, k.ray_refused
                )
            });
            println!(
                "{}: true [{}] published [{}] points {} existence [{}] {removed}",
                p.raw_file,
                gts.join(", "),
                preds.join(", "),
                v.points.len(),
                existence.join(", ")
            );
        },
    )?;
    Ok(())
}
