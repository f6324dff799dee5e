//! The second replay generator (`stjpdacf_tools::heldout`) on the bundled held-out labels:
//! reproducibility, clip independence, the last frame shows the label's road, and each effect
//! does what its parameter says.

use stjpdacf_tools::camera::Camera;
use stjpdacf_tools::heldout::{self, HeldoutParams};
use stjpdacf_tools::repo_root;
use stjpdacf_tools::tusimple::{read_labels, TuSimpleRecord};

fn labels() -> Vec<TuSimpleRecord> {
    read_labels(&repo_root().join("data").join(heldout::LABELS)).unwrap()
}

/// Nothing but the lanes, every row detected, no noise, no motion, solid paint.
fn clean() -> HeldoutParams {
    HeldoutParams {
        pixel_noise: 0.0,
        marking_width: 0.0,
        detect_good: 1.0,
        detect_bad: 1.0,
        dashed_prob: 0.0,
        lateral_sd: 0.0,
        heading_rw: 0.0,
        clutter_density: 0.0,
        ..HeldoutParams::default()
    }
}

#[test]
fn the_bundled_labels_are_forty_held_out_frames() {
    let l = labels();
    assert_eq!(l.len(), 40);
    assert!(l
        .iter()
        .all(|r| r.raw_file.contains("/0531/") || r.raw_file.contains("/0601/")));
    for r in &l {
        r.check_shape().unwrap();
    }
}

#[test]
fn output_is_reproducible_and_clips_are_independent() {
    let l = labels();
    let cam = Camera::tusimple();
    let p = HeldoutParams {
        segments: 4.0,
        ..HeldoutParams::default()
    };
    let a = heldout::generate(&l[..4], &p, &cam, 7).unwrap();
    let b = heldout::generate(&l[..4], &p, &cam, 7).unwrap();
    assert_eq!(a, b);
    // Clip 1 does not depend on how many clips follow it.
    let c = heldout::generate(&l[..2], &p, &cam, 7).unwrap();
    let clip1 = |o: &heldout::HeldoutOutput| {
        o.frames
            .iter()
            .filter(|f| f.clip == "heldout0001")
            .cloned()
            .collect::<Vec<_>>()
    };
    assert_eq!(clip1(&a), clip1(&c));
    let d = heldout::generate(&l[..4], &p, &cam, 8).unwrap();
    assert_ne!(a.frames, d.frames);
    // Frames per clip, increasing times, the label on the last frame only.
    assert_eq!(a.frames.len(), 4 * p.frames_per_clip);
    assert_eq!(a.gt_last, l[..4].to_vec());
    for (i, clip) in a.frames.chunks(p.frames_per_clip).enumerate() {
        assert!(clip
            .windows(2)
            .all(|w| w[0].t < w[1].t && w[0].clip == w[1].clip));
        let (last, rest) = clip.split_last().unwrap();
        assert_eq!(last.raw_file.as_deref(), Some(l[i].raw_file.as_str()));
        assert_eq!(last.h_samples.as_ref(), Some(&l[i].h_samples));
        assert!(rest
            .iter()
            .all(|f| f.raw_file.is_none() && f.h_samples.is_none()));
    }
}

#[test]
fn the_last_frame_shows_the_labelled_lanes() {
    let l = labels();
    let cam = Camera::tusimple();
    let p = clean();
    let o = heldout::generate(&l, &p, &cam, 1).unwrap();
    let mut checked = 0;
    for (g, clip) in o.gt_last.iter().zip(o.frames.chunks(p.frames_per_clip)) {
        let last = clip.last().unwrap();
        // The generator's first feature row: the first labelled row below the horizon.
        let first = *g.h_samples.iter().find(|&&r| r > cam.vp_row + 1.0).unwrap();
        for lane in &g.lanes {
            for (col, row) in g.points_of(lane) {
                // Feature rows are every `row_step` rows from there; where one is a labelled
                // row, a point sits on the label (up to the BEV round trip).
                let k = (row - first) / p.row_step as f64;
                if k < 0.0 || k.fract() != 0.0 || !(0.0..cam.width).contains(&col) {
                    continue;
                }
                let near = last
                    .points
                    .iter()
                    .any(|q| (q[1] - row).abs() < 1e-9 && (q[0] - col).abs() < 1e-6);
                assert!(near, "{}: no point at ({col}, {row})", g.raw_file);
                checked += 1;
            }
        }
        // Nothing else: every point is on a labelled lane's row set.
        assert!(last
            .points
            .iter()
            .all(|q| q[1] >= first && q[1] < cam.height));
    }
    assert!(checked > 400, "{checked}");
    assert_eq!((o.clutter_points, o.segment_points), (0, 0));
}

#[test]
fn each_effect_does_what_its_parameter_says() {
    let l = labels();
    let cam = Camera::tusimple();
    let run = |p: &HeldoutParams| heldout::generate(&l, p, &cam, 3).unwrap();
    let base = run(&clean());
    // Clutter grows with its density (Poisson counts; ×4 gives well over twice as many).
    let c1 = run(&HeldoutParams {
        clutter_density: 0.02,
        ..clean()
    });
    let c4 = run(&HeldoutParams {
        clutter_density: 0.08,
        ..clean()
    });
    assert_eq!(c1.lane_points, base.lane_points);
    assert!(c1.clutter_points > 1000, "{}", c1.clutter_points);
    assert!(c4.clutter_points > 3 * c1.clutter_points);
    // Dashes and misses remove lane points; segments add points of their own.
    let dashed = run(&HeldoutParams {
        dashed_prob: 1.0,
        ..clean()
    });
    assert!(dashed.lane_points * 2 < base.lane_points);
    let missed = run(&HeldoutParams {
        detect_good: 0.9,
        detect_bad: 0.15,
        ..clean()
    });
    assert!(missed.lane_points < base.lane_points && missed.lane_points * 2 > base.lane_points);
    let seg = run(&HeldoutParams {
        segments: 8.0,
        ..clean()
    });
    assert!(seg.segment_points > 0 && seg.lane_points == base.lane_points);
    // Motion moves the earlier frames' points, never the last frame's.
    let moved = run(&HeldoutParams {
        lateral_sd: 0.4,
        heading_rw: 0.01,
        ..clean()
    });
    let k = clean().frames_per_clip;
    let last_frames = |o: &heldout::HeldoutOutput| {
        o.frames
            .iter()
            .skip(k - 1)
            .step_by(k)
            .cloned()
            .collect::<Vec<_>>()
    };
    assert_eq!(last_frames(&moved), last_frames(&base));
    assert_ne!(moved.frames, base.frames);
    // Pitch jitter moves the earlier frames' points in the image (the rows stay the detector's:
    // the columns move), never the last frame's; a few points leave the image or fall above a
    // pitched horizon (under 2 %).
    let pitched = run(&HeldoutParams {
        pitch_jitter: 0.5f64.to_radians(),
        ..clean()
    });
    assert_eq!(last_frames(&pitched), last_frames(&base));
    assert!(
        pitched.lane_points.abs_diff(base.lane_points) * 50 < base.lane_points,
        "{} {}",
        pitched.lane_points,
        base.lane_points
    );
    let moved_points = pitched
        .frames
        .iter()
        .zip(&base.frames)
        .filter(|(a, b)| a.points != b.points)
        .count();
    assert!(moved_points > base.frames.len() / 2, "{moved_points}");
    // Off by default: the reference parameters are what they were.
    assert_eq!(HeldoutParams::default().pitch_jitter, 0.0);
}

#[test]
fn bad_parameters_are_refused() {
    let l = labels();
    let cam = Camera::tusimple();
    for p in [
        HeldoutParams {
            detect_good: 1.5,
            ..HeldoutParams::default()
        },
        HeldoutParams {
            frame_step: 0.0,
            ..HeldoutParams::default()
        },
        HeldoutParams {
            dash_gap: (9.0, 6.0),
            ..HeldoutParams::default()
        },
        HeldoutParams {
            clutter_density: f64::NAN,
            ..HeldoutParams::default()
        },
        HeldoutParams {
            frames_per_clip: 0,
            ..HeldoutParams::default()
        },
    ] {
        assert!(heldout::generate(&l[..1], &p, &cam, 1).is_err(), "{p:?}");
    }
    let twice = vec![l[0].clone(), l[0].clone()];
    assert!(heldout::generate(&twice, &HeldoutParams::default(), &cam, 1).is_err());
}
