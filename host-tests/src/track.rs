//! `stjpdacf track`: runs the core `ReferenceTracker` over a file of frames and writes TuSimple
//! predictions.
//!
//! Per frame: image points → BEV through the camera (or BEV points as given with `--space bev`),
//! [`preprocess`] (row binning and lateral clustering, what a front end hands the MCU),
//! `Tracker::step` at the frame's time (a new clip resets the tracker), then, for frames that
//! carry `h_samples`, each lane seen within the last `MAX_REPORT_MISSES` frames is written at
//! those rows: inside the BEV window by the tracker's GP evaluation (`Tracker::lane_at`), beyond
//! the far end by extending the lane linearly from its last two index points (DESIGN 4.0: rows
//! near the horizon are extrapolated, never left out), −2 outside the lane's observed extent
//! (one index interval of margin) and outside the image. `run_time` is the milliseconds spent in
//! `Tracker::step` for that frame.

use std::time::Instant as WallClock;

use anyhow::{bail, Context, Result};

use stjpdacf::kernel::{Matern32, RbfStateSpace};
use stjpdacf::tables::{
    Hyper, ReferenceTables, SpatialTables, Tables, TemporalTables, FORMAT_VERSION,
};
use stjpdacf::tracker::{Instant, LaneEstimate, ReferenceTracker};

use crate::camera::Camera;
use crate::hyper::HyperFile;
use crate::tablegen::ModelTables;
use crate::tusimple::{Frame, TuSimpleRecord};

/// Lanes not seen for more frames than this are not written.
pub const MAX_REPORT_MISSES: u16 = 2;

/// Where the frames' points live.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Space {
    /// Image pixels `[column, row]` of the camera.
    Image,
    /// BEV metres `[x lateral, u ahead]`.
    Bev,
}

/// Counters of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TrackStats {
    /// Frames processed.
    pub frames: usize,
    /// Clips (tracker resets).
    pub clips: usize,
    /// Predictions written.
    pub predictions: usize,
    /// Points that did not map to BEV (at or above the horizon, non-finite).
    pub unmapped_points: usize,
    /// Steps the tracker rejected (non-increasing time within a clip).
    pub rejected_steps: usize,
    /// Mean and largest `Tracker::step` time, ms.
    pub mean_ms: f64,
    /// Largest step time, ms.
    pub max_ms: f64,
}

/// Builds f32 tables for the reference configuration from a hyperparameter file at run time (the
/// same computation as `stjpdacf tables`, without the Rust source round trip), leaked to `'static`.
pub fn tables_from_hyper(h: &HyperFile) -> Result<&'static ReferenceTables> {
    if h.spatial.order != 2 || h.lanes() != 6 || h.index_points != 16 {
        bail!("the reference tracker needs N_T = 2, 6 lane slots and 16 index points");
    }
    let t = ModelTables::from_hyper(h)?;
    let m = |d: &nalgebra::DMatrix<f64>| d.map(|v| v as f32);
    let tables: Tables<2, 6, 16> = Tables {
        version: FORMAT_VERSION,
        hyper: Hyper {
            spatial_order: 2,
            spatial_variance: h.spatial.variance as f32,
            spatial_lengthscale: h.spatial.lengthscale as f32,
            offset_variance: h.spatial.offset_variance as f32,
            temporal_variance: h.temporal.variance as f32,
            temporal_lengthscale: h.temporal.lengthscale as f32,
            meas_noise: h.noise.measurement as f32,
            pseudo_noise: h.noise.pseudo as f32,
            u_min: h.window.u_min as f32,
            u_max: h.window.u_max as f32,
            row_step: h.spatial.row_step as f32,
            frame_step: h.temporal.frame_step as f32,
            gram_variance_fraction: h.temporal.gram_variance_fraction as f32,
        },
        spatial: SpatialTables {
            model: RbfStateSpace {
                A: m(&t.spatial_a).fixed_view::<2, 2>(0, 0).into_owned(),
                qc: t.spatial_qc as f32,
                p_inf: m(&t.spatial_p_inf).fixed_view::<2, 2>(0, 0).into_owned(),
            },
            f: m(&t.spatial_f).fixed_view::<2, 2>(0, 0).into_owned(),
            q: m(&t.spatial_q).fixed_view::<2, 2>(0, 0).into_owned(),
        },
        temporal: TemporalTables {
            kernel: Matern32::new(h.temporal.variance as f32, h.temporal.lengthscale as f32),
            f: m(&t.temporal_f).fixed_view::<2, 2>(0, 0).into_owned(),
            q: m(&t.temporal_q).fixed_view::<2, 2>(0, 0).into_owned(),
            p_inf: m(&t.temporal_p_inf).fixed_view::<2, 2>(0, 0).into_owned(),
        },
        index_u: nalgebra::SVector::from_fn(|i, _| t.index_u[i] as f32),
        gram: m(&t.gram).fixed_view::<16, 16>(0, 0).into_owned(),
        gram_eigvec: m(&t.gram_eigvec).fixed_view::<16, 16>(0, 0).into_owned(),
        gram_eigval: nalgebra::SVector::from_fn(|i, _| t.gram_eigval[i] as f32),
        gram_rank: t.gram_rank as u32,
        coreg: m(&t.coreg).fixed_view::<6, 6>(0, 0).into_owned(),
        coreg_chol: m(&t.coreg_chol).fixed_view::<6, 6>(0, 0).into_owned(),
    };
    tables
        .validate()
        .map_err(|e| anyhow::anyhow!("generated tables are invalid: {e}"))?;
    Ok(Box::leak(Box::new(tables)))
}

/// Lateral gap (metres) that separates two feature-point clusters in one BEV row.
pub const CLUSTER_GAP: f64 = 0.25;

/// Preprocessing the core expects (DESIGN 1: "on the MCU the feature points arrive
/// preprocessed"): BEV points are binned to the spatial filter's rows (K = 4 rows per index
/// interval) and, within a row, points closer than [`CLUSTER_GAP`] laterally are merged into their
/// mean. An edge detector returns many points per marking in near rows (one BEV row spans tens of
/// image rows there); without this they would fill the row budget and look like clutter.
/// Points outside the window are dropped (the core would reject them).
pub fn preprocess(points: &[(f64, f64)], tables: &ReferenceTables) -> Vec<[f32; 2]> {
    let h = &tables.hyper;
    let (u0, u1) = (f64::from(h.u_min), f64::from(h.u_max));
    let rows = 15 * 4;
    let du = (u1 - u0) / rows as f64;
    let mut bins: Vec<Vec<f64>> = vec![Vec::new(); rows + 1];
    for &(u, x) in points {
        if !(u.is_finite() && x.is_finite()) {
            continue;
        }
        let r = ((u - u0) / du).round();
        if r >= 0.0 && r <= rows as f64 {
            bins[r as usize].push(x);
        }
    }
    let mut out = Vec::new();
    for (r, xs) in bins.iter_mut().enumerate() {
        xs.sort_by(f64::total_cmp);
        let u = u0 + r as f64 * du;
        let mut start = 0;
        for i in 1..=xs.len() {
            if i == xs.len() || xs[i] - xs[i - 1] > CLUSTER_GAP {
                let c = &xs[start..i];
                out.push([u as f32, (c.iter().sum::<f64>() / c.len() as f64) as f32]);
                start = i;
            }
        }
    }
    out
}

/// A lane's column at image row `row`, or −2.
fn sample(
    tr: &ReferenceTracker,
    tables: &ReferenceTables,
    cam: &Camera,
    lane: &LaneEstimate<16>,
    row: f64,
) -> f64 {
    let h = &tables.hyper;
    let Some((u, _)) = cam.to_bev(cam.vp_col, row) else {
        return -2.0;
    };
    let interval = f64::from(h.u_max - h.u_min) / 15.0;
    if u < f64::from(lane.u_first) - interval {
        return -2.0;
    }
    let x = if u <= f64::from(h.u_max) {
        if u > f64::from(lane.u_last) + interval {
            return -2.0;
        }
        let uc = u.max(f64::from(h.u_min)) as f32;
        match tr.lane_at(usize::from(lane.slot), uc) {
            Some((x, _)) => f64::from(x),
            None => return -2.0,
        }
    } else {
        // Beyond the window: only lanes observed up to its far end, extended linearly.
        if f64::from(lane.u_last) + interval < f64::from(h.u_max) {
            return -2.0;
        }
        let (u1, u2) = (f64::from(tables.index_u[14]), f64::from(tables.index_u[15]));
        let (x1, x2) = (f64::from(lane.z[14]), f64::from(lane.z[15]));
        x2 + (u - u2) * (x2 - x1) / (u2 - u1)
    };
    match cam.to_image(u, x) {
        Some((col, _)) if col >= 0.0 && col < cam.width => col,
        _ => -2.0,
    }
}

/// Runs the tracker over `frames`; returns the predictions for the frames with `h_samples`.
pub fn track(
    frames: &[Frame],
    tables: &'static ReferenceTables,
    cam: &Camera,
    space: Space,
    mut progress: impl FnMut(usize),
) -> Result<(Vec<TuSimpleRecord>, TrackStats)> {
    let mut stats = TrackStats::default();
    let mut out = Vec::new();
    let mut tracker: Option<Box<ReferenceTracker>> = None;
    let mut clip: Option<&str> = None;
    let mut total_ms = 0.0;
    for (k, f) in frames.iter().enumerate() {
        f.check()
            .with_context(|| format!("frame {k} (clip {})", f.clip))?;
        if clip != Some(f.clip.as_str()) {
            tracker = Some(Box::new(ReferenceTracker::new(tables)));
            clip = Some(f.clip.as_str());
            stats.clips += 1;
        }
        let Some(tr) = tracker.as_mut() else { continue };
        let mut bev_pts: Vec<(f64, f64)> = Vec::with_capacity(f.points.len());
        for p in &f.points {
            let bev = match space {
                Space::Image => cam.to_bev(p[0], p[1]),
                Space::Bev => Some((p[1], p[0])),
            };
            match bev {
                Some((u, x)) if u.is_finite() && x.is_finite() => bev_pts.push((u, x)),
                _ => stats.unmapped_points += 1,
            }
        }
        let pts = preprocess(&bev_pts, tables);
        let start = WallClock::now();
        let res = tr.step(Instant::from_micros((f.t * 1e6).round() as i64), &pts);
        let ms = start.elapsed().as_secs_f64() * 1e3;
        total_ms += ms;
        stats.max_ms = stats.max_ms.max(ms);
        stats.frames += 1;
        progress(k);
        let output = match res {
            Ok(o) => o,
            Err(_) => {
                stats.rejected_steps += 1;
                continue;
            }
        };
        let (Some(raw), Some(rows)) = (&f.raw_file, &f.h_samples) else {
            continue;
        };
        let mut lanes: Vec<(f64, Vec<f64>)> = output
            .filtered
            .iter()
            .filter(|l| l.misses <= MAX_REPORT_MISSES)
            .map(|l| {
                (
                    f64::from(l.z[0]),
                    rows.iter()
                        .map(|&r| sample(tr, tables, cam, l, r))
                        .collect::<Vec<f64>>(),
                )
            })
            .filter(|(_, xs)| xs.iter().any(|v| *v >= 0.0))
            .collect();
        lanes.sort_by(|a, b| a.0.total_cmp(&b.0));
        out.push(TuSimpleRecord {
            raw_file: raw.clone(),
            lanes: lanes.into_iter().map(|(_, xs)| xs).collect(),
            h_samples: rows.clone(),
            run_time: Some(ms),
        });
        stats.predictions += 1;
    }
    stats.mean_ms = if stats.frames > 0 {
        total_ms / stats.frames as f64
    } else {
        0.0
    };
    Ok((out, stats))
}
