//! Lane boundaries are a lane apart (docs/design.md §11.14): a line-like structure beside the
//! outermost marking, closer than the narrowest lane, is tracked but not published, and a
//! structure inside the outermost lane is the one not published, not that marking.
//! `cargo test -p stjpdacf-test-support --test lane_width -- --nocapture`

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::{Instant, LaneEstimate, ReferenceTracker, TrackerConfig};

const POINTS: usize = 16;

/// The kerb's offset: 1.4 m outside the outermost marking (at 1 m the duplicate and newcomer
/// rules of §11.9 and §11.5 already keep it from publication on most frames).
const KERB: f64 = 6.9;

/// Rows every 1.25 m over the window, a point per row with probability `p` and Gaussian noise
/// σ = 5 cm at lateral offset `x` (a straight line parallel to the road).
fn line(rng: &mut ChaCha8Rng, pts: &mut Vec<[f32; 2]>, x: f64, p: f64) {
    let noise = Normal::new(0.0, 0.05).unwrap();
    let mut u = 3.0;
    while u <= 77.0 {
        if rng.random_bool(p) {
            pts.push([u as f32, (x + noise.sample(rng)) as f32]);
        }
        u += 1.25;
    }
}

/// Whether a published lane lies within 0.4 m of `x` at every index point of its extent
/// between 10 and 70 m (at least 3 of them).
fn published_at(out: &[LaneEstimate<POINTS>], x: f64) -> bool {
    let u = DEFAULT.index_u;
    out.iter().any(|l| {
        let inside: Vec<usize> = (0..POINTS)
            .filter(|&i| u[i] >= l.u_first && u[i] <= l.u_last && u[i] >= 10.0 && u[i] <= 70.0)
            .collect();
        inside.len() >= 3 && inside.iter().all(|&i| (f64::from(l.z[i]) - x).abs() < 0.4)
    })
}

/// 40 frames at 20 Hz of the markings at `markings` (detected on 90 % of rows) and the lines
/// `extra` (offset, detection per row); per line of `watch`, the frames on which a lane is
/// published on it.
fn frames_published(
    cfg: TrackerConfig,
    seed: u64,
    extra: &[(f64, f64)],
    watch: &[f64],
) -> Vec<usize> {
    let mut t = Box::new(ReferenceTracker::with_config(&DEFAULT, cfg));
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut seen = vec![0; watch.len()];
    for k in 0..40i64 {
        let mut pts = Vec::new();
        for x in [-1.8, 1.8, 5.5] {
            line(&mut rng, &mut pts, x, 0.9);
        }
        for &(x, p) in extra {
            line(&mut rng, &mut pts, x, p);
        }
        pts.sort_by(|a, b| a[0].total_cmp(&b[0]));
        let out = t
            .step(Instant::from_micros(50_000 * (k + 1)), &pts)
            .unwrap();
        for (n, &x) in seen.iter_mut().zip(watch) {
            *n += usize::from(published_at(&out.filtered, x));
        }
    }
    seen
}

/// A kerb 1.4 m outside the outermost of three markings (3.7 m lanes), as dense and smooth as
/// paint: without the rule it is published on every frame (measured 40 of 40), with it on none,
/// and the outermost marking is published on as many frames either way (40).
#[test]
fn a_kerb_beside_the_outermost_marking_is_not_published() {
    let mut off = TrackerConfig::DEFAULT;
    off.persist.lane_width = 0.0;
    let kerb = [(KERB, 0.9)];
    let on = frames_published(TrackerConfig::DEFAULT, 5, &kerb, &[KERB, 5.5, 1.8]);
    let without = frames_published(off, 5, &kerb, &[KERB, 5.5, 1.8]);
    println!(
        "frames published (kerb, outer marking, inner marking): rule {on:?}, without {without:?}"
    );
    assert!(
        without[0] >= 35,
        "the kerb must be tracked as a lane: {without:?}"
    );
    assert_eq!(on[0], 0, "{on:?}");
    assert!(on[1] >= 38 && on[1] == without[1], "{on:?} {without:?}");
    assert!(on[2] >= 38, "{on:?}");
}

/// A sparse structure inside the outermost lane (3.65 m from the marking at 1.8 m, 1.85 m from
/// the one at 5.5 m; 35 % of its rows), published as a lane on every frame without the rule (40
/// of 40): it lies inside a lane, close to a lane on either side, so with the rule it is the one
/// not published (0 frames), and the outermost marking keeps every frame it has without the
/// rule (40).
#[test]
fn a_structure_inside_the_outermost_lane_is_hidden_not_its_marking() {
    let mut off = TrackerConfig::DEFAULT;
    off.persist.lane_width = 0.0;
    let seam = [(3.65, 0.35)];
    let on = frames_published(TrackerConfig::DEFAULT, 9, &seam, &[5.5, 3.65]);
    let without = frames_published(off, 9, &seam, &[5.5, 3.65]);
    println!("frames published (outer marking, inner structure): rule {on:?}, without {without:?}");
    assert!(
        without[1] >= 35,
        "the inner structure must be published: {without:?}"
    );
    assert_eq!(on[0], without[0], "{on:?} {without:?}");
    assert!(on[0] >= 38, "{on:?}");
    assert_eq!(on[1], 0, "{on:?}");
}
