//! Where the replay's lane ids come from: the demo's replay (40 bundled labels × 20 frames,
//! seed 1, coupled B, default configuration) at one noise level; every id the tracker publishes
//! in a clip (as the demo's identity table counts them: lanes seen within `MAX_REPORT_MISSES`
//! frames) is "true" when the official metric matched it to a labelled lane on some frame and
//! "false" (never a true lane) otherwise. Per class: the number of frames it was published on,
//! the clip frame and the lane's age at its first publication, and its existence then.
//! `ID_DIAG_LIST=1` prints every false id with its frames, existence, age and hits, and the
//! step report of the frame after its last publication (what removed it: the ray test,
//! connectors, merges, a yielded slot). `ID_DIAG_OFF=cars,road_edge,shadows,clutter,merges`
//! switches synth sources off (which source makes the never-true ids).
//!
//! `cargo run --release -p stjpdacf-tools --example id_diag [-- low|mid|high] [seed=N]` (default mid,
//! seed 1;
//! `newcomer_wait=0` for the publication rule of before stop 44, `newcomer_wait=1` for stop 44's;
//! `ray_motion=0` for the ray test of before stop 62; `lane_width=0` for the publication of
//! before stop 63).
//!
//! `-- heldout [clutter=K] [noise=K] [segments=S]`: the same count on the second generator
//! ([`heldout`]: held-out label geometry, no road edges and no vehicles; clutter density × K,
//! column noise × K, S fixed segments a clip: the demo's held-out conditions are clutter=1, 2,
//! 4, 8, segments=8, noise=2, 4), which gives ground truth for each clip's last frame only: lane ids
//! per clip against the label's lanes, and how many of them the last frame matched to a label.
use std::collections::{BTreeMap, HashMap};
use stjpdacf::tracker::TrackerConfig;
use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::heldout::{self, HeldoutParams};
use stjpdacf_tools::metric;
use stjpdacf_tools::synth::{self, NoiseLevel, SynthParams};
use stjpdacf_tools::track::{self, Space, MAX_REPORT_MISSES};

#[derive(Default, Debug)]
struct Life {
    frames: Vec<usize>,
    ex: Vec<f32>,
    age: Vec<u32>,
    hits: Vec<u32>,
    matched: usize,
}

fn main() -> anyhow::Result<()> {
    let mut level = NoiseLevel::Mid;
    let mut config = TrackerConfig::DEFAULT;
    let mut heldout: Option<HeldoutParams> = None;
    let mut seed = 1u64;
    for a in std::env::args().skip(1) {
        match a.as_str() {
            "low" => level = NoiseLevel::Low,
            "mid" => level = NoiseLevel::Mid,
            "high" => level = NoiseLevel::High,
            "heldout" => {
                heldout.get_or_insert_with(HeldoutParams::default);
            }
            w if w.starts_with("ray_motion=") => {
                config.persist.ray_motion = &w["ray_motion=".len()..] != "0";
            }
            w if w.starts_with("lane_width=") => {
                config.persist.lane_width = w["lane_width=".len()..].parse()?;
            }
            w if w.starts_with("newcomer_wait=") => {
                config.persist.newcomer_wait = w["newcomer_wait=".len()..].parse()?;
            }
            w if w.starts_with("clutter=") => {
                let h = heldout.get_or_insert_with(HeldoutParams::default);
                h.clutter_density *= w["clutter=".len()..].parse::<f64>()?;
            }
            w if w.starts_with("seed=") => seed = w["seed=".len()..].parse()?,
            w if w.starts_with("noise=") => {
                let h = heldout.get_or_insert_with(HeldoutParams::default);
                h.pixel_noise *= w["noise=".len()..].parse::<f64>()?;
            }
            w if w.starts_with("segments=") => {
                heldout.get_or_insert_with(HeldoutParams::default).segments =
                    w["segments=".len()..].parse()?;
            }
            _ => anyhow::bail!(
                "unknown argument {a} (low|mid|high, newcomer_wait=FRAMES, seed=N, heldout, clutter=K, noise=K, segments=S)"
            ),
        }
    }
    if let Some(params) = heldout {
        return heldout_ids(&params, config, seed);
    }
    let labels = stjpdacf_tools::demo::replay_labels()?;
    let cam = Camera::tusimple();
    let mut params = SynthParams::preset(level);
    // ID_DIAG_OFF=cars,road_edge,shadows,clutter,merges: switch sources off (which source makes
    // the never-true ids; the synth's random stream changes with the sources, so the clips differ).
    params.switch_off(&std::env::var("ID_DIAG_OFF").unwrap_or_default())?;
    let o = synth::synthesize(&labels, &params, &cam, seed)?;
    let gt_index = o.gt_index();
    let mut lives: BTreeMap<(String, u32), Life> = BTreeMap::new();
    let mut k_in_clip = 0usize;
    let mut reps: HashMap<(String, usize), String> = HashMap::new();
    track::track_with(
        &o.frames,
        &stjpdacf::tables::DEFAULT,
        &cam,
        Space::Image,
        config,
        |v| {
            let new_clip =
                v.index == 0 || o.frames.get(v.index - 1).map(|f| &f.clip) != Some(&v.frame.clip);
            if new_clip {
                k_in_clip = 0
            } else {
                k_in_clip += 1
            }
            let Some(out) = v.output else { return };
            let r = &out.report;
            reps.insert(
                (v.frame.clip.clone(), k_in_clip),
                format!(
                    "del {} (ray {}, conn {}) merged {} evicted {} removed {}",
                    r.known.deleted,
                    r.known.ray_deleted,
                    r.known.connectors_deleted,
                    r.known.merged,
                    r.identity.evicted,
                    r.identity.removed
                ),
            );
            let mut matched_ids = Vec::new();
            if let Some(p) = v.prediction {
                if let Some(&j) = gt_index.get(p.raw_file.as_str()) {
                    let g = &o.gt_all[j];
                    let lanes: Vec<Vec<f64>> = g.lanes_with_points().cloned().collect();
                    let m = metric::match_lanes(&p.lanes, &lanes, &g.h_samples);
                    for gm in m.gt_match.iter().flatten() {
                        if let Some(id) = v.prediction_ids.get(*gm) {
                            matched_ids.push(*id)
                        }
                    }
                }
            }
            for l in out
                .filtered
                .iter()
                .filter(|l| l.misses <= MAX_REPORT_MISSES)
            {
                let e = lives.entry((v.frame.clip.clone(), l.id.0)).or_default();
                e.frames.push(k_in_clip);
                e.ex.push(l.existence);
                e.age.push(l.age);
                e.hits.push(l.hits);
                if matched_ids.contains(&l.id.0) {
                    e.matched += 1
                }
            }
        },
    )?;
    let clips = lives
        .keys()
        .map(|k| k.0.clone())
        .collect::<std::collections::HashSet<_>>()
        .len();
    let (t, f): (Vec<_>, Vec<_>) = lives.iter().partition(|(_, l)| l.matched > 0);
    println!(
        "{level:?}: clips {clips}, ids {} (true {}, never true {})",
        lives.len(),
        t.len(),
        f.len()
    );
    for (name, set) in [("true", &t), ("false", &f)] {
        let mut by_len = BTreeMap::new();
        let mut by_first = BTreeMap::new();
        let mut by_age = BTreeMap::new();
        let mut ex_bins = [0usize; 5];
        for (_, l) in set.iter() {
            *by_len.entry(l.frames.len().min(11)).or_insert(0) += 1;
            *by_first.entry(l.frames[0].min(3)).or_insert(0) += 1;
            *by_age.entry(l.age[0].min(4)).or_insert(0) += 1;
            let e = l.ex[0];
            let b = if e < 0.6 {
                0
            } else if e < 0.8 {
                1
            } else if e < 0.95 {
                2
            } else if e < 0.99 {
                3
            } else {
                4
            };
            ex_bins[b] += 1;
        }
        println!("{name}: frames published {by_len:?}; first clip frame {by_first:?}; age at first pub {by_age:?}; existence at first pub <.6/.6-.8/.8-.95/.95-.99/>=.99 {ex_bins:?}");
    }
    if std::env::var("ID_DIAG_LIST").is_ok() {
        for ((c, id), l) in f.iter() {
            let last = *l.frames.last().unwrap_or(&0);
            let nxt = reps
                .get(&(c.clone(), last + 1))
                .cloned()
                .unwrap_or_default();
            println!(
                "{c} id {id}: next [{nxt}] frames {:?} ex {:?} age {:?} hits {:?}",
                l.frames,
                l.ex.iter()
                    .map(|e| (e * 100.0).round() / 100.0)
                    .collect::<Vec<_>>(),
                l.age,
                l.hits
            );
        }
    }
    Ok(())
}

/// Lane ids per clip on the held-out generator: every id published in a clip (seen within
/// `MAX_REPORT_MISSES` frames), the label's lanes, and the ids the last frame's prediction
/// matched to a labelled lane (the metric's matching).
fn heldout_ids(params: &HeldoutParams, config: TrackerConfig, seed: u64) -> anyhow::Result<()> {
    let labels = heldout::bundled_labels()?;
    let cam = Camera::tusimple();
    let o = heldout::generate(&labels, params, &cam, seed)?;
    let gt: HashMap<&str, &stjpdacf_tools::tusimple::TuSimpleRecord> =
        o.gt_last.iter().map(|g| (g.raw_file.as_str(), g)).collect();
    // The labelled lanes of the clips' last frames, and how many of them each matched.
    let (mut true_lanes, mut matched) = (0usize, 0usize);
    let (_, stats) = track::track_with(
        &o.frames,
        &stjpdacf::tables::DEFAULT,
        &cam,
        Space::Image,
        config,
        |v| {
            let Some(p) = v.prediction else { return };
            let Some(g) = gt.get(p.raw_file.as_str()) else {
                return;
            };
            let lanes: Vec<Vec<f64>> = g.lanes_with_points().cloned().collect();
            true_lanes += lanes.len();
            let m = metric::match_lanes(&p.lanes, &lanes, &g.h_samples);
            matched += m.gt_match.iter().flatten().count();
        },
    )?;
    let clips = stats.clips.max(1) as f64;
    println!(
        "held-out (clutter {:.3} /m², {} segments a clip, column noise {} px): clips {}, lane ids per clip {:.2} \
         against {:.2} labelled lanes ({:.2} ×); labelled lanes matched on the last frame {:.2} a clip",
        params.clutter_density,
        params.segments,
        params.pixel_noise,
        stats.clips,
        stats.lane_ids as f64 / clips,
        true_lanes as f64 / clips,
        stats.lane_ids as f64 / true_lanes.max(1) as f64,
        matched as f64 / clips,
    );
    Ok(())
}
