//! The whole per-frame spatial JPDACF in f64, exactly as `docs/spatial-filter.md` specifies:
//! row binning (§1), the per-lane model with an offset state (§2), the walk over the rows with
//! initiation, update, hits and misses, confirmation, deletion, ending and merging (§3), and the
//! backward pass that turns every confirmed track into pseudo-measurements at the index points with
//! their N×N covariance block (§4).
//!
//! This is the oracle for the core's frame walk (`src/spatial/`). It reuses the single-row f64
//! reference [`super::jpda`] (prediction, gating and the exact mixture update with the
//! `1 − P_D P_G` miss factor) and enumerates **every** joint event: there is no event budget here;
//! a row whose event count exceeds [`Config::max_events`] is only flagged ([`RowDiag::over_budget`])
//! so that a comparison knows where the core approximates.
//!
//! # Units and sizes
//! BEV metres: `u` ahead, `x` lateral. `N` index points over the tables' window, `K` rows per index
//! interval, `Δu = (u_max − u_min)/((N − 1)·K)` computed from the window, so `F_u`, `Q_u` are
//! recomputed at `Δu` from the RBF hyperparameters (with the default file, `K = 4` gives the file's
//! `spatial.row_step` = 77/60 m).
//! The lane state is `[c, g, g', …]` (`NS = NT + 1`), `F = blockdiag(1, F_u)`,
//! `Q = blockdiag(0, Q_u)`, `h = [1, 1, 0, …]`.
//!
//! # Readings of the specification
//! Where `docs/spatial-filter.md` leaves room, this module reads it as the core
//! (`src/spatial/filter/`) does:
//! 1. **Ended tracks in the update** (§3.4): an ended track stays in the stacked state and is
//!    forced to *miss* in every event (it gates no point, carries no miss factor). The event
//!    weights and `β` are those of the active tracks alone (`jpda::row_step` on the active tracks'
//!    marginal); the mixture update is then applied to the **whole** stacked state with the gains
//!    `P̄ H_δᵀ S_δ⁻¹` (so an ended track's state moves only through its cross-covariance with the
//!    active tracks). When tracks exist but none is active, the only event is "all missed" (1
//!    event, the state is unchanged, every point is clutter).
//! 2. **Freedom** (§3.2a) is tested once per row, against the predicted *active* tracks, before
//!    any initiation of the row.
//! 3. "**fewer than LANES tracks exist**" (§3.2c) counts every track in the stacked state,
//!    ended ones included. The rank counts every track (ended ones and tracks started earlier in
//!    the same row), on the current state (after the earlier initiations' point updates).
//! 4. **Consistency** (§3.2b) is inclusive, `|x − x_b| ≤ init_gate`; a buffer entry that made a
//!    point consistent stays in the buffer (entries leave only by age). The buffer at row `r` holds
//!    the entries of rows `r − init_rows ..= r − 1`. Free points are examined by increasing `x`,
//!    ties in input order.
//! 5. **The new track** (§3.2d): prior `E[c] = x`, `Var(c) = offset_variance` (the tables' value,
//!    25 m² in the default file), the GP part conditioned on the others through `B`; then the
//!    whole stacked state gets a Kalman update with the initiating point as a certain association
//!    (`z = x`, `h` on the new track, variance `r`), and the point is removed from the points of
//!    the row's update. Should that update be impossible (`h P h + r ≤ 0`), the track keeps its
//!    prior, as in the core.
//! 6. **Hits** (§3.4): `hits` and `misses` are totals over the track's life (the rows in which it
//!    was active, from its initiation row on); confirmation uses the total hits, deletion and
//!    ending the consecutive misses. A track ended at row `r` is not recorded at row `r` (§3.6
//!    records tracks that are not ended), so its recorded rows end at `r − 1`.
//! 7. **Merge** (§3.5): on the *filtered* positions `h·x` after the row update. One counter per
//!    rank (the pair with its right neighbour); pairs are examined left to right, a pair with an
//!    ended track or a track already deleted in this row (by misses or by an earlier merge of the
//!    same row) is skipped (its counter is left as it is), otherwise its counter is incremented
//!    when `|h·x_a − h·x_b| ≤ merge_distance` and set to 0 when not; at `merge_rows` the loser is
//!    deleted (fewer hits; equal hits: the later start row; then the right one). Every counter is
//!    reset to 0 whenever a track is inserted or removed.
//! 8. **No track** in a row: no update (the filtered state is the prediction, 0 events); all
//!    of the row's points count as clutter.
//! 9. **A numerical failure** of the row update (`row_step` returns `None`) leaves the state
//!    (after initiation) as the filtered one and counts neither hits nor misses; the row is
//!    flagged [`RowDiag::failed`].
//! 10. **Recording** (§3.6): the "predicted" moments of row `r` are taken after initiation, i.e.
//!     after the new tracks' point updates (which also move the other tracks through their
//!     cross-covariances); a track started at row `r` records its prior conditioned on its point.
//! 11. **Pseudo-measurements** (§4): the backward pass runs from the last recorded row down to the
//!     start row; index points `i` with `i·K` inside the *hit extent* `[first_row, last_row]` get
//!     a pseudo-measurement. The output covariance is N×N with zero rows and columns at missing
//!     index points (still PSD). No measurement noise is added: it is `Cov(h·x_a, h·x_b)`.
//! 12. **Clutter points** (counter) are a row's points (after initiation removed its starting
//!     points) valid for no active track in the update's gating.
//!
//! [`RowDiag::margins`] records how close each of the row's discrete decisions came to its
//! threshold, so that a comparison with an f32 implementation can tell a flipped decision from a
//! bug.

use anyhow::{ensure, Context, Result};
use nalgebra::{DMatrix, DVector};

use super::jpda::{self, Estimate, MissConvention, RowParams};
use super::statespace::RbfTaylor;
use crate::model::ModelTables;

mod backward;
mod stacked;

use backward::backward;
pub use stacked::{condition_on_point, insert_track, mixture_update_full};
use stacked::{indices, marginal, remove_track};

/// The parameters of the frame walk (`spatial::Config` of the core; defaults of §6).
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    /// Number of lane slots D (at most the size of B).
    pub lanes: usize,
    /// Detection probability of a lane in a row.
    pub pd: f64,
    /// Gate probability `P_G`.
    pub pg: f64,
    /// χ²(1) gate threshold `γ` (inclusive).
    pub gamma: f64,
    /// Poisson clutter density per metre of lateral extent per row.
    pub clutter_density: f64,
    /// Lateral variance of a point, m².
    pub r: f64,
    /// Event budget `E` of the core (only flagged here; the reference enumerates everything).
    pub max_events: usize,
    /// Rows the initiation buffer remembers.
    pub init_rows: usize,
    /// Lateral distance (m) that makes two free points consistent.
    pub init_gate: f64,
    /// Tentative tracks at once.
    pub max_tentative: usize,
    /// Hits that confirm a tentative track.
    pub confirm_hits: usize,
    /// Consecutive misses that delete a tentative track with no hit yet.
    pub tentative_misses: usize,
    /// Consecutive misses that delete a tentative track with at least one hit (the longest dash
    /// gap it bridges).
    pub tentative_gap_misses: usize,
    /// Scale of the row-to-row process noise `Q_u` (1: the tables' model).
    pub row_noise_scale: f64,
    /// Consecutive misses that end a confirmed track.
    pub max_misses: usize,
    /// Lateral distance (m) under which two adjacent tracks are near-duplicates.
    pub merge_distance: f64,
    /// Consecutive near rows that trigger a merge.
    pub merge_rows: usize,
    /// Prior variance `σ_c²` of a new track's offset, m².
    pub offset_variance: f64,
}

impl Config {
    /// The §6 defaults, with `r` = the tables' measurement noise, `offset_variance` = the tables'
    /// `spatial.offset_variance` and `lanes` = the size of the tables' B.
    pub fn from_tables(t: &ModelTables) -> Self {
        Self {
            lanes: t.coreg.nrows(),
            pd: 0.9,
            pg: 0.99,
            gamma: 6.634897,
            clutter_density: 0.05,
            r: t.hyper.noise.measurement,
            max_events: 512,
            init_rows: 3,
            init_gate: 0.5,
            max_tentative: 3,
            confirm_hits: 6,
            tentative_misses: 8,
            tentative_gap_misses: 8,
            row_noise_scale: 1.0,
            max_misses: 12,
            merge_distance: 0.3,
            merge_rows: 3,
            offset_variance: t.hyper.spatial.offset_variance,
        }
    }

    fn row_params(&self) -> RowParams {
        RowParams {
            pd: self.pd,
            pg: self.pg,
            gamma: self.gamma,
            clutter_density: self.clutter_density,
            r: self.r,
            miss: MissConvention::Pg,
        }
    }
}

/// The per-lane model and the row grid of one frame (§1, §2).
#[derive(Debug, Clone, PartialEq)]
pub struct Model {
    /// Window start `u_min`, m.
    pub u_min: f64,
    /// Window end `u_max`, m.
    pub u_max: f64,
    /// Index points N.
    pub points: usize,
    /// Rows per index interval K.
    pub k: usize,
    /// Row spacing `Δu = (u_max − u_min)/((N − 1)·K)`.
    pub du: f64,
    /// Rows R = (N − 1)·K + 1.
    pub rows: usize,
    /// `F = blockdiag(1, F_u(Δu))` (`NS × NS`).
    pub f: DMatrix<f64>,
    /// `Q = blockdiag(0, Q_u(Δu))`.
    pub q: DMatrix<f64>,
    /// `P∞_u` of the GP part (`NT × NT`).
    pub p_inf_u: DMatrix<f64>,
    /// `h = [1, 1, 0, …]` (`1 × NS`).
    pub h: DMatrix<f64>,
    /// Coregionalisation `B` (D×D).
    pub b: DMatrix<f64>,
}

impl Model {
    /// The model of the tables' hyperparameters with `k` rows per index interval; `F_u` and `Q_u`
    /// are computed at `Δu` from the window (not at the file's `row_step`).
    pub fn new(t: &ModelTables, k: usize) -> Result<Self> {
        ensure!(k >= 1, "K must be at least 1");
        let hp = &t.hyper;
        let n = hp.index_points;
        ensure!(n >= 2, "need at least two index points");
        let (u_min, u_max) = (hp.window.u_min, hp.window.u_max);
        let du = (u_max - u_min) / ((n - 1) * k) as f64;
        let rbf = RbfTaylor {
            variance: hp.spatial.variance,
            lengthscale: hp.spatial.lengthscale,
            order: hp.spatial.order,
        };
        let p_inf_u = rbf.p_inf().context("spatial Lyapunov equation")?;
        let (fu, qu) = rbf.transition(du).context("spatial transition")?;
        let nt = fu.nrows();
        let ns = nt + 1;
        let mut f = DMatrix::zeros(ns, ns);
        f[(0, 0)] = 1.0;
        f.view_mut((1, 1), (nt, nt)).copy_from(&fu);
        let mut q = DMatrix::zeros(ns, ns);
        q.view_mut((1, 1), (nt, nt)).copy_from(&qu);
        let mut h = DMatrix::zeros(1, ns);
        h[(0, 0)] = 1.0;
        h[(0, 1)] = 1.0;
        Ok(Self {
            u_min,
            u_max,
            points: n,
            k,
            du,
            rows: (n - 1) * k + 1,
            f,
            q,
            p_inf_u,
            h,
            b: t.coreg.clone(),
        })
    }

    /// State size NS = NT + 1.
    pub fn ns(&self) -> usize {
        self.f.nrows()
    }

    /// Longitudinal position `u_r` of row `r`.
    pub fn row_u(&self, r: usize) -> f64 {
        self.u_min + r as f64 * self.du
    }

    /// Index point `u^f_i`.
    pub fn index_u(&self, i: usize) -> f64 {
        self.u_min + i as f64 * (self.u_max - self.u_min) / (self.points - 1) as f64
    }

    /// The row of a point at `u` (§1: `round((u − u_min)/Δu)`, ties to even), `None` when it is
    /// outside `0..R` or `u` is not finite.
    pub fn row_of(&self, u: f64) -> Option<usize> {
        let v = ((u - self.u_min) / self.du).round_ties_even();
        if v.is_finite() && v >= 0.0 && v <= (self.rows - 1) as f64 {
            Some(v as usize)
        } else {
            None
        }
    }
}

/// Why input points were not used.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Rejected {
    /// A non-finite coordinate.
    pub non_finite: usize,
    /// A row outside `0..R`.
    pub out_of_window: usize,
    /// Within [`DUPLICATE_DISTANCE`] of a point already kept in its row.
    pub duplicate: usize,
    /// The row already held `PER_ROW` points.
    pub row_full: usize,
}

/// A point within this lateral distance (metres) of a point already kept in its row is a
/// duplicate (docs/spatial-filter.md §1).
pub const DUPLICATE_DISTANCE: f64 = 1e-3;

/// Frame counters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    /// Points rejected by binning, by reason.
    pub rejected: Rejected,
    /// Consistent free points that could not start a track (tentative or slot budget full).
    pub no_slot: usize,
    /// Points valid for no active track in the update (summed over rows).
    pub clutter_points: usize,
    /// Tracks started.
    pub initiated: usize,
    /// Tentative tracks confirmed.
    pub confirmed: usize,
    /// Tentative tracks deleted by misses.
    pub deleted: usize,
    /// Tracks deleted by the merge rule.
    pub merged: usize,
    /// Of those, tracks that were still tentative (the core's `deleted` counter includes them).
    pub merged_tentative: usize,
    /// Confirmed tracks ended by misses.
    pub ended: usize,
    /// Rows whose event count exceeded `max_events`.
    pub over_budget_rows: usize,
}

/// A track's life stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Status {
    /// Started, not yet confirmed.
    Tentative,
    /// Confirmed and still updated.
    Confirmed,
    /// Confirmed, then ended by `max_misses` consecutive misses: keeps its slot, takes no points.
    Ended,
}

/// How close a row's discrete decisions came to their thresholds (`f64::INFINITY` when the row
/// made no such decision). An f32 implementation may decide the other way when a margin is tiny.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Margins {
    /// `min |d² − γ|` over the freedom test (§3.2a) and the update's gating (§3.3).
    pub gate: f64,
    /// `min |(1 − β_miss) − 0.5|` over the active tracks (§3.4).
    pub hit: f64,
    /// `min ||x − x_b| − init_gate|` over the free points and the buffer entries (§3.2b).
    pub init_gate: f64,
    /// `min |h·x_t − x|` over the rank counts of the row's initiations (§3.2c).
    pub rank: f64,
    /// `min ||h·x_a − h·x_b| − merge_distance|` over the pairs tested for a merge (§3.5).
    pub merge: f64,
}

impl Default for Margins {
    fn default() -> Self {
        Self {
            gate: f64::INFINITY,
            hit: f64::INFINITY,
            init_gate: f64::INFINITY,
            rank: f64::INFINITY,
            merge: f64::INFINITY,
        }
    }
}

/// What happened in one row.
#[derive(Debug, Clone, PartialEq)]
pub struct RowDiag {
    /// Row index r.
    pub row: usize,
    /// The row's points (lateral positions, input order).
    pub points: Vec<f64>,
    /// The points of the update: the row's points without those that started a track.
    pub update_points: Vec<f64>,
    /// Identities of the tracks in rank order as the update saw them (after initiation).
    pub tracks: Vec<usize>,
    /// Status of each of those tracks during the update (before step 4).
    pub status: Vec<Status>,
    /// Tracks started in this row.
    pub initiated: Vec<usize>,
    /// Predicted stacked state after initiation (new tracks carry their prior conditioned on
    /// their point, and that point update has moved the others too), rank order.
    pub predicted: Estimate,
    /// Filtered stacked state after the update, rank order (same tracks as [`Self::tracks`]).
    pub filtered: Estimate,
    /// Joint events enumerated (0 when nothing was updated).
    pub events: usize,
    /// `events > max_events`: the core approximates this row.
    pub over_budget: bool,
    /// `P(missed)` per track (`None` for an ended track).
    pub beta_miss: Vec<Option<f64>>,
    /// Whether each track hit (`1 − β_miss ≥ 0.5`; `false` for ended tracks and in a failed row).
    pub hit: Vec<bool>,
    /// The row update failed numerically.
    pub failed: bool,
    /// Closest approach of the row's decisions to their thresholds.
    pub margins: Margins,
}

/// The output of one confirmed track (§4).
#[derive(Debug, Clone, PartialEq)]
pub struct TrackOutput {
    /// Identity (order of initiation within the frame).
    pub id: usize,
    /// Rank (slot) at the end of the frame.
    pub rank: usize,
    /// `Confirmed` or `Ended`.
    pub status: Status,
    /// Row where the track was started.
    pub start_row: usize,
    /// Row of its first hit.
    pub first_row: usize,
    /// Row of its last hit.
    pub last_row: usize,
    /// Last recorded row (the backward pass runs from here down to `start_row`).
    pub last_recorded_row: usize,
    /// Hits over its life.
    pub hits: usize,
    /// Misses over its life.
    pub misses: usize,
    /// `hits / (hits + misses)`.
    pub existence: f64,
    /// Observed extent `[u_first_row, u_last_row]`.
    pub extent: (f64, f64),
    /// Smoothed lateral position `h·x_{iK|R}` at each index point, `None` outside the hit extent
    /// `[first_row, last_row]`.
    pub pseudo: Vec<Option<f64>>,
    /// `Cov(h·x_a, h·x_b)` over the index points (N×N, zero at missing points).
    pub pseudo_cov: DMatrix<f64>,
    /// Smoothed marginal state of every recorded row, `start_row ..= last_recorded_row`.
    pub smoothed: Vec<Estimate>,
}

/// Everything one frame produces.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameResult {
    /// Per-row diagnostics, rows `0..R`.
    pub rows: Vec<RowDiag>,
    /// Confirmed tracks (ended or not) in rank order.
    pub tracks: Vec<TrackOutput>,
    /// Tracks still tentative at the end of the frame.
    pub tentative_left: usize,
    /// Counters.
    pub counters: Counters,
}

/// Filtered and predicted marginal moments of one row of a track.
#[derive(Debug, Clone)]
struct Rec {
    pred: Estimate,
    filt: Estimate,
}

#[derive(Debug, Clone)]
struct Track {
    id: usize,
    status: Status,
    start_row: usize,
    first_row: Option<usize>,
    last_row: Option<usize>,
    hits: usize,
    misses: usize,
    consecutive_misses: usize,
    recs: Vec<Rec>,
}

/// Bins a frame's points into rows (§1): returns the rows' lateral positions and the rejections.
pub fn bin_points(
    model: &Model,
    points: &[(f64, f64)],
    per_row: usize,
) -> (Vec<Vec<f64>>, Rejected) {
    let mut rows = vec![Vec::new(); model.rows];
    let mut rej = Rejected::default();
    for &(u, x) in points {
        if !u.is_finite() || !x.is_finite() {
            rej.non_finite += 1;
            continue;
        }
        match model.row_of(u) {
            None => rej.out_of_window += 1,
            Some(r) => {
                let row: &mut Vec<f64> = &mut rows[r];
                if row.iter().any(|y| (x - y).abs() <= DUPLICATE_DISTANCE) {
                    rej.duplicate += 1;
                } else if row.len() >= per_row {
                    rej.row_full += 1;
                } else {
                    row.push(x);
                }
            }
        }
    }
    (rows, rej)
}

/// One frame of the spatial JPDACF (§3, §4) on the BEV points `(u, x)`, with at most `per_row`
/// points per row.
pub fn run_frame(
    model: &Model,
    cfg: &Config,
    points: &[(f64, f64)],
    per_row: usize,
) -> FrameResult {
    let ns = model.ns();
    let lanes = cfg.lanes.min(model.b.nrows());
    let params = cfg.row_params();
    let (rows, rejected) = bin_points(model, points, per_row);
    let mut counters = Counters {
        rejected,
        ..Counters::default()
    };
    let mut tracks: Vec<Track> = Vec::new();
    let mut state = Estimate {
        x: DVector::zeros(0),
        p: DMatrix::zeros(0, 0),
    };
    let mut buffer: Vec<(usize, f64)> = Vec::new();
    // Merge counters, one per rank (the pair with its right neighbour).
    let mut near: Vec<usize> = Vec::new();
    let mut next_id = 0usize;
    let mut diags = Vec::with_capacity(model.rows);
    let hx = |e: &Estimate, i: usize| e.x[i * ns] + e.x[i * ns + 1];
    let q_row = &model.q * cfg.row_noise_scale;

    for (r, zs) in rows.iter().enumerate() {
        let mut margins = Margins::default();
        // 1. Predict.
        if r > 0 && !tracks.is_empty() {
            let n = tracks.len();
            let bn = model.b.view((0, 0), (n, n)).into_owned();
            state = jpda::predict(&state.x, &state.p, &model.f, &q_row, &bn);
        }

        // 2. Initiation: freedom once, against the predicted active tracks.
        buffer.retain(|&(br, _)| br + cfg.init_rows >= r);
        let gating = jpda::gate(&state.x, &state.p, &model.h, cfg.r, zs, cfg.gamma);
        let mut free: Vec<(f64, usize)> = Vec::new();
        for (j, &x) in zs.iter().enumerate() {
            let mut valid = false;
            for (t, tr) in tracks.iter().enumerate() {
                if tr.status != Status::Ended {
                    margins.gate = margins.gate.min((gating.d2[t][j] - cfg.gamma).abs());
                    valid |= gating.valid[t][j];
                }
            }
            if !valid {
                free.push((x, j));
            }
        }
        free.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut used = vec![false; zs.len()];
        let mut initiated = Vec::new();
        let mut new_buffer = Vec::new();
        for &(x, j) in &free {
            let mut consistent = false;
            for &(_, bx) in &buffer {
                let d = (x - bx).abs();
                margins.init_gate = margins.init_gate.min((d - cfg.init_gate).abs());
                consistent |= d <= cfg.init_gate;
            }
            let mut started = false;
            if consistent {
                let tentative = tracks
                    .iter()
                    .filter(|t| t.status == Status::Tentative)
                    .count();
                if tentative < cfg.max_tentative && tracks.len() < lanes {
                    for i in 0..tracks.len() {
                        margins.rank = margins.rank.min((hx(&state, i) - x).abs());
                    }
                    let k = (0..tracks.len()).filter(|&i| hx(&state, i) < x).count();
                    if let Some(s) = insert_track(&state, model, k, x, cfg.offset_variance) {
                        state = condition_on_point(&s, &model.h, k, x, cfg.r).unwrap_or(s);
                        tracks.insert(
                            k,
                            Track {
                                id: next_id,
                                status: Status::Tentative,
                                start_row: r,
                                first_row: None,
                                last_row: None,
                                hits: 0,
                                misses: 0,
                                consecutive_misses: 0,
                                recs: Vec::new(),
                            },
                        );
                        near = vec![0; tracks.len()];
                        used[j] = true;
                        initiated.push(next_id);
                        next_id += 1;
                        counters.initiated += 1;
                        started = true;
                    }
                } else {
                    counters.no_slot += 1;
                }
            }
            if !started {
                new_buffer.push((r, x));
            }
        }
        buffer.extend(new_buffer);
        let predicted = state.clone();
        let rest: Vec<f64> = zs
            .iter()
            .zip(&used)
            .filter(|(_, u)| !**u)
            .map(|(x, _)| *x)
            .collect();

        // 3. Update with the remaining points.
        let active: Vec<usize> = (0..tracks.len())
            .filter(|&i| tracks[i].status != Status::Ended)
            .collect();
        let mut beta_miss: Vec<Option<f64>> = tracks
            .iter()
            .map(|t| (t.status != Status::Ended).then_some(1.0))
            .collect();
        let mut events = 0;
        let mut failed = false;
        if tracks.is_empty() {
            counters.clutter_points += rest.len();
        } else if active.is_empty() {
            // Only the "all missed" event: nothing moves.
            events = 1;
            counters.clutter_points += rest.len();
        } else {
            let idx = indices(&active, ns);
            let sub_x = predicted.x.select_rows(&idx);
            let sub_p = predicted.p.select_rows(&idx).select_columns(&idx);
            let res = jpda::row_step(&sub_x, &sub_p, &model.h, &rest, &params);
            let upd = res.as_ref().and_then(|rs| {
                if active.len() == tracks.len() {
                    Some(rs.mixture.clone())
                } else {
                    mixture_update_full(&predicted, &model.h, cfg.r, &rest, &active, rs)
                }
            });
            match (res, upd) {
                (Some(rs), Some(u)) => {
                    state = u;
                    events = rs.events.len();
                    for (a, &t) in active.iter().enumerate() {
                        beta_miss[t] = Some(rs.beta[a][0]);
                        margins.hit = margins.hit.min((0.5 - rs.beta[a][0]).abs());
                    }
                    for d2 in rs.gating.d2.iter().flatten() {
                        margins.gate = margins.gate.min((d2 - cfg.gamma).abs());
                    }
                    counters.clutter_points += (0..rest.len())
                        .filter(|&j| !rs.gating.valid.iter().any(|v| v[j]))
                        .count();
                }
                _ => {
                    failed = true;
                    counters.clutter_points += rest.len();
                }
            }
        }
        let over_budget = events > cfg.max_events;
        if over_budget {
            counters.over_budget_rows += 1;
        }
        let filtered = state.clone();
        let hit: Vec<bool> = beta_miss
            .iter()
            .map(|b| !failed && b.is_some_and(|b| 1.0 - b >= 0.5))
            .collect();
        let diag_tracks: Vec<usize> = tracks.iter().map(|t| t.id).collect();
        let diag_status: Vec<Status> = tracks.iter().map(|t| t.status).collect();

        // 4. Hits and misses (none counted when the update failed).
        let mut delete = vec![false; tracks.len()];
        for (i, t) in tracks.iter_mut().enumerate() {
            if t.status == Status::Ended || failed {
                continue;
            }
            if hit[i] {
                t.hits += 1;
                t.consecutive_misses = 0;
                t.last_row = Some(r);
                if t.first_row.is_none() {
                    t.first_row = Some(r);
                }
                if t.status == Status::Tentative && t.hits >= cfg.confirm_hits {
                    t.status = Status::Confirmed;
                    counters.confirmed += 1;
                }
            } else {
                t.misses += 1;
                t.consecutive_misses += 1;
                let limit = if t.hits > 0 {
                    cfg.tentative_gap_misses
                } else {
                    cfg.tentative_misses
                };
                if t.status == Status::Tentative && t.consecutive_misses >= limit {
                    delete[i] = true;
                    counters.deleted += 1;
                } else if t.status == Status::Confirmed && t.consecutive_misses >= cfg.max_misses {
                    t.status = Status::Ended;
                    counters.ended += 1;
                }
            }
        }

        // 5. Merge, on the filtered positions, left to right.
        for i in 0..tracks.len().saturating_sub(1) {
            let live = |k: usize| !delete[k] && tracks[k].status != Status::Ended;
            if !live(i) || !live(i + 1) {
                continue;
            }
            let d = (hx(&filtered, i) - hx(&filtered, i + 1)).abs();
            margins.merge = margins.merge.min((d - cfg.merge_distance).abs());
            near[i] = if d <= cfg.merge_distance {
                near[i] + 1
            } else {
                0
            };
            if near[i] >= cfg.merge_rows {
                let (a, b) = (&tracks[i], &tracks[i + 1]);
                let loser = if a.hits < b.hits || (a.hits == b.hits && a.start_row > b.start_row) {
                    i
                } else {
                    i + 1
                };
                delete[loser] = true;
                counters.merged += 1;
                if tracks[loser].status == Status::Tentative {
                    counters.merged_tentative += 1;
                }
            }
        }

        // Remove deleted tracks (highest rank first); any removal restarts every merge counter.
        for i in (0..tracks.len()).rev() {
            if delete[i] {
                state = remove_track(&state, ns, i);
                tracks.remove(i);
                near = vec![0; tracks.len()];
            }
        }

        // 6. Record the moments of the tracks that are not ended (by identity in the row's ranks).
        for t in tracks.iter_mut() {
            if t.status == Status::Ended {
                continue;
            }
            let Some(k) = diag_tracks.iter().position(|&id| id == t.id) else {
                continue;
            };
            t.recs.push(Rec {
                pred: marginal(&predicted, ns, k),
                filt: marginal(&filtered, ns, k),
            });
        }

        diags.push(RowDiag {
            row: r,
            points: zs.clone(),
            update_points: rest,
            tracks: diag_tracks,
            status: diag_status,
            initiated,
            predicted,
            filtered,
            events,
            over_budget,
            beta_miss,
            hit,
            failed,
            margins,
        });
    }

    let tentative_left = tracks
        .iter()
        .filter(|t| t.status == Status::Tentative)
        .count();
    let outputs = tracks
        .iter()
        .enumerate()
        .filter(|(_, t)| t.status != Status::Tentative)
        .filter_map(|(rank, t)| backward(model, t, rank))
        .collect();
    FrameResult {
        rows: diags,
        tracks: outputs,
        tentative_left,
        counters,
    }
}
