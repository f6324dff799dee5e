//! The spatial JPDACF over one frame (`docs/spatial-filter.md` is the exact procedure): bins the
//! frame's feature points into BEV rows, walks the rows near to far with the coupled row step,
//! manages tracks (consistent-points initiation with a B-conditioned prior, confirmation, ending,
//! merging), and turns every confirmed track into pseudo-measurements at the index points by a
//! backward RTS pass along `u`.
//!
//! # Capacities and RAM
//! `SpatialFilter<NS, LANES, ROWS, PER_ROW>`: `NS = NT + 1` state entries per lane, `LANES` tracks,
//! `ROWS ≥ (POINTS − 1)·K + 1` rows, `PER_ROW` points per row (≤ 32). The row history for the
//! backward pass dominates: `LANES · ROWS · (2 NS + 2 NS²) · 4` bytes (36.9 KiB at NS = 3,
//! LANES = 6, ROWS = 64); the row bins `ROWS · (PER_ROW · 4 + 1)` bytes.
//!
//! # Cost per frame
//! `R` rows, each: one prediction (`n(n+1)/2` blocks, `2 NS³` each at most), at most
//! `max_tentative` initiations (`O(n² NS²)` plus two triangular solves of order `n`), one row
//! update (see [`super::row`]), and O(n · PER_ROW) bookkeeping; then per confirmed track `R` RTS
//! steps (one `NS×NS` `LDLᵀ` solve and `O(NS³)` products each) and, per index interval, `NS²`
//! per index point already passed (`O(POINTS² NS² / 2)` per track). No recursion, no allocation.
//! Instruction counts per stage: `python3 bench/icount.py` (`docs/benchmarks.md`).

use nalgebra::{SMatrix, SVector};

use super::row::{self, MissModel, RowParams, MAX_ROW_POINTS};
use super::Stacked;
use crate::linalg::{dot, get, set};
pub use crate::observation::{LaneObservation, Status};
use crate::probe::{NoProbe, Probe, Stage};
use crate::tables::Tables;

mod smooth;
mod tracks;

/// Largest `init_rows` (rows the initiation buffer remembers).
pub const MAX_INIT_ROWS: usize = 4;

/// A point within this lateral distance (metres) of a point already kept in its row is a
/// duplicate and is rejected (docs/design.md §7.1).
pub const DUPLICATE_DISTANCE: f32 = 1e-3;

/// Tuning of the spatial filter (`docs/spatial-filter.md` §6).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Config {
    /// Detection probability of a lane in a row.
    pub pd: f32,
    /// Gate probability.
    pub pg: f32,
    /// Gate threshold on `d²` (inclusive).
    pub gamma: f32,
    /// Poisson clutter per metre of lateral extent per row.
    pub clutter_density: f32,
    /// Miss weighting.
    pub miss: MissModel,
    /// Events scored per row (E).
    pub max_events: usize,
    /// Rows per index interval (K).
    pub rows_per_interval: u8,
    /// Rows the initiation buffer remembers (≤ [`MAX_INIT_ROWS`]).
    pub init_rows: u8,
    /// Lateral distance that makes two free points consistent, metres.
    pub init_gate: f32,
    /// Tentative tracks at once.
    pub max_tentative: u8,
    /// Hits that confirm a tentative track.
    pub confirm_hits: u16,
    /// Consecutive misses that delete a tentative track with no hit since its initiation.
    pub tentative_misses: u16,
    /// Consecutive misses that delete a tentative track with at least one hit since its
    /// initiation (a dash behind it, the next one ahead): the rows of the longest dash gap it
    /// bridges. The default keeps it at `tentative_misses` (8): while hits confirm a lane, a
    /// longer tentative life lets clutter confirm one. The [`crate::tracker::Tracker`] sets
    /// [`crate::persist::PersistConfig::gap_misses`] (11) here, where existence confirms.
    pub tentative_gap_misses: u16,
    /// Scale of the row-to-row process noise `Q_u` (docs/design.md §11.12): 1 is the table's
    /// model, whose `N_T = 2` approximation of the RBF bends far more freely from row to row
    /// than a painted lane does. The [`crate::tracker::Tracker`] sets
    /// [`crate::persist::PersistConfig::row_noise_scale`] here. Finite and positive, else
    /// `bad_config`.
    pub row_noise_scale: f32,
    /// Consecutive misses that end a confirmed track.
    pub max_misses: u16,
    /// Lateral distance under which adjacent tracks are near-duplicates, metres.
    pub merge_distance: f32,
    /// Consecutive rows of near-duplication that merge two tracks.
    pub merge_rows: u16,
}

impl Config {
    /// The defaults of `docs/spatial-filter.md` §6.
    pub const DEFAULT: Self = Self {
        pd: 0.9,
        pg: 0.99,
        gamma: 6.634_897,
        clutter_density: 0.05,
        miss: MissModel::Gated,
        max_events: 512,
        rows_per_interval: 4,
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
    };
}

impl Default for Config {
    fn default() -> Self {
        Self::DEFAULT
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Meta {
    store: u8,
    status: Status,
    hits: u16,
    misses: u16,
    miss_run: u16,
    first_row: u16,
    last_row: u16,
    start_row: u16,
    last_rec: u16,
    near: u16,
    /// `Σ ln Λ_r` over the track's rows after its start (one-step-ahead, [`BIRTH_PD`]).
    llr: f32,
    /// `llr` at the track's last hit (its observed extent's evidence).
    llr_last: f32,
}

/// The detection probability used for a new track's existence evidence: the prior mean of a
/// lane's per-band detection probability (Beta(1, 1), docs/design.md §11.5), nothing being
/// known about the lane yet.
pub const BIRTH_PD: f32 = 0.5;

const NO_ROW: u16 = u16::MAX;

impl Meta {
    const EMPTY: Self = Self {
        store: 0,
        status: Status::Tentative,
        hits: 0,
        misses: 0,
        miss_run: 0,
        first_row: NO_ROW,
        last_row: NO_ROW,
        start_row: 0,
        last_rec: 0,
        near: 0,
        llr: 0.0,
        llr_last: 0.0,
    };
}

/// Which moments [`SpatialFilter::record`] stores.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Moment {
    Predicted,
    Filtered,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Rec<const NS: usize> {
    xp: SVector<f32, NS>,
    pp: SMatrix<f32, NS, NS>,
    xf: SVector<f32, NS>,
    pf: SMatrix<f32, NS, NS>,
}

impl<const NS: usize> Rec<NS> {
    const EMPTY: Self = Self {
        xp: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; NS]; 1])),
        pp: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; NS]; NS])),
        xf: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; NS]; 1])),
        pf: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; NS]; NS])),
    };
}

/// Counters of one frame of the spatial filter (`repr(C)`: the C API hands it to C as is).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(C)]
pub struct SpatialReport {
    /// Points given.
    pub points_in: u32,
    /// Rejected: non-finite coordinate.
    pub rejected_non_finite: u32,
    /// Rejected: outside the BEV window.
    pub rejected_window: u32,
    /// Rejected: within [`DUPLICATE_DISTANCE`] of a point already kept in its row.
    pub rejected_duplicate: u32,
    /// Rejected: the row already held `PER_ROW` points.
    pub rejected_row_full: u32,
    /// (track, point) pairs inside the gate, summed over rows (after any pruning).
    pub gated: u32,
    /// Points valid for no track when their row was updated.
    pub clutter_points: u32,
    /// Consistent free points that could not start a track (no slot or tentative budget spent).
    pub no_slot: u32,
    /// Joint events scored over all rows.
    pub events: u32,
    /// Rows whose events were pruned to fit `max_events`.
    pub rows_approximated: u32,
    /// Row updates that failed numerically (state kept).
    pub rows_failed: u32,
    /// Tentative tracks started.
    pub started: u16,
    /// Tracks confirmed.
    pub confirmed: u16,
    /// Tentative tracks deleted (by misses, or as near-duplicates: those are in `merged` too).
    pub deleted: u16,
    /// Confirmed tracks ended.
    pub ended: u16,
    /// Tracks removed as near-duplicates.
    pub merged: u16,
    /// Confirmed lanes reported.
    pub lanes_out: u16,
    /// Confirmed lanes whose backward pass failed numerically (not reported).
    pub smoother_failed: u16,
    /// Reported lanes whose pseudo-measurement covariance was not positive definite and was
    /// repaired (see `docs/spatial-filter.md` §4).
    pub cov_repaired: u16,
    /// The configuration or tables do not fit the capacities (nothing was done).
    pub bad_config: bool,
}

/// The per-frame spatial filter with its working memory.
#[derive(Debug, Clone, Copy)]
pub struct SpatialFilter<
    const NS: usize,
    const LANES: usize,
    const ROWS: usize,
    const PER_ROW: usize,
> {
    state: Stacked<NS, LANES>,
    meta: [Meta; LANES],
    hist: [[Rec<NS>; ROWS]; LANES],
    bin_n: [u8; ROWS],
    bins: [[f32; PER_ROW]; ROWS],
    buf: [[f32; PER_ROW]; MAX_INIT_ROWS],
    buf_n: [u8; MAX_INIT_ROWS],
}

impl<const NS: usize, const LANES: usize, const ROWS: usize, const PER_ROW: usize> Default
    for SpatialFilter<NS, LANES, ROWS, PER_ROW>
{
    fn default() -> Self {
        Self::new()
    }
}

impl<const NS: usize, const LANES: usize, const ROWS: usize, const PER_ROW: usize>
    SpatialFilter<NS, LANES, ROWS, PER_ROW>
{
    /// An empty filter (`const`: it can live in a `static`).
    pub const fn new() -> Self {
        const {
            assert!(
                PER_ROW >= 1 && PER_ROW <= MAX_ROW_POINTS,
                "PER_ROW must be 1..=32"
            )
        };
        const { assert!(ROWS >= 2 && ROWS <= 1024, "ROWS must be 2..=1024") };
        let mut f = Self::ZEROED;
        f.clear_meta();
        f
    }

    /// Every byte zero (the tracker's all-zero constant, which lives in `.bss`): [`SpatialFilter::new`]
    /// with its tracks' row markers zero; every frame resets them (`walk`), and the tracker's
    /// `init` does too.
    pub(crate) const ZEROED: Self = {
        const ZERO_META: Meta = Meta {
            first_row: 0,
            last_row: 0,
            ..Meta::EMPTY
        };
        Self {
            state: Stacked::new(),
            meta: [ZERO_META; LANES],
            hist: [[Rec::EMPTY; ROWS]; LANES],
            bin_n: [0; ROWS],
            bins: [[0.0; PER_ROW]; ROWS],
            buf: [[0.0; PER_ROW]; MAX_INIT_ROWS],
            buf_n: [0; MAX_INIT_ROWS],
        }
    };

    /// The tracks' row markers reset to "no row" (what [`SpatialFilter::new`] adds to
    /// [`SpatialFilter::ZEROED`]). O(LANES).
    pub(crate) const fn clear_meta(&mut self) {
        self.meta = [Meta::EMPTY; LANES];
    }

    /// Runs the filter on one frame's BEV points `(u, x)` and writes one [`LaneObservation`] per
    /// confirmed lane into `out` (in rank order); returns the number written and the counters.
    ///
    /// # Complexity
    /// See the module docs. Bounded by `ROWS`, `PER_ROW`, `LANES` and `cfg.max_events`.
    pub fn run<const NT: usize, const POINTS: usize>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        cfg: &Config,
        points: &[[f32; 2]],
        out: &mut [LaneObservation<POINTS>; LANES],
    ) -> (usize, SpatialReport) {
        self.run_probed(tables, cfg, points, out, &mut NoProbe)
    }

    /// [`SpatialFilter::run`] reporting its stages to `probe` (from [`Stage::Binning`] to
    /// [`Stage::Backward`]).
    ///
    /// # Complexity
    /// As [`SpatialFilter::run`].
    #[allow(non_snake_case)]
    // Not inlined: its stack frame must not add to its caller's (stack budget).
    #[inline(never)]
    pub fn run_probed<const NT: usize, const POINTS: usize, P: Probe>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        cfg: &Config,
        points: &[[f32; 2]],
        out: &mut [LaneObservation<POINTS>; LANES],
        probe: &mut P,
    ) -> (usize, SpatialReport) {
        probe.enter(Stage::Binning);
        let rep = self.bin(tables, cfg, points);
        self.walk_probed(tables, cfg, rep, out, probe)
    }

    /// The row geometry: `(rows, Δu)`, `None` when `ROWS` cannot hold the rows or `Δu` is not
    /// positive and finite.
    pub fn geometry<const NT: usize, const POINTS: usize>(
        tables: &Tables<NT, LANES, POINTS>,
        cfg: &Config,
    ) -> Option<(usize, f32)> {
        let h = &tables.hyper;
        let k_rows = usize::from(cfg.rows_per_interval.max(1));
        let rows = (POINTS - 1) * k_rows + 1;
        let du = (h.u_max - h.u_min) / ((POINTS - 1) * k_rows) as f32;
        (rows <= ROWS && du.is_finite() && du > 0.0).then_some((rows, du))
    }

    /// First half of [`SpatialFilter::run`]: empties the state and bins the frame's points into
    /// the rows (docs/design.md §4.1); returns the counters so far (`bad_config` when the
    /// geometry does not fit).
    pub fn bin<const NT: usize, const POINTS: usize>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        cfg: &Config,
        points: &[[f32; 2]],
    ) -> SpatialReport {
        let mut rep = SpatialReport {
            points_in: points.len().min(u32::MAX as usize) as u32,
            ..SpatialReport::default()
        };
        match Self::geometry(tables, cfg) {
            Some((rows, du)) => self.bin_points(points, tables.hyper.u_min, du, rows, &mut rep),
            None => {
                self.bin_n = [0; ROWS];
                rep.bad_config = true;
            }
        }
        rep
    }

    /// The binned points of row `r` (lateral positions, metres; empty past the rows).
    pub fn row_points(&self, r: usize) -> &[f32] {
        let m = usize::from(get(&self.bin_n, r)).min(PER_ROW);
        self.bins.get(r).and_then(|b| b.get(..m)).unwrap_or(&[])
    }

    /// Removes the points of row `r` whose bit is set in `mask` (the order of the others kept).
    pub fn remove_points(&mut self, r: usize, mask: u32) {
        let m = usize::from(get(&self.bin_n, r)).min(PER_ROW);
        let Some(b) = self.bins.get_mut(r) else {
            return;
        };
        let mut k = 0usize;
        for j in 0..m {
            if mask & (1u32.wrapping_shl(j as u32)) == 0 {
                let v = b.get(j).copied().unwrap_or(0.0);
                if let Some(e) = b.get_mut(k) {
                    *e = v;
                }
                k += 1;
            }
        }
        set(&mut self.bin_n, r, k as u8);
    }

    /// Second half of [`SpatialFilter::run`]: walks the binned rows near to far (tracks,
    /// events, management) and writes the confirmed lanes into `out`; `rep` comes from
    /// [`SpatialFilter::bin`].
    #[allow(non_snake_case)]
    #[inline(never)]
    pub fn walk_probed<const NT: usize, const POINTS: usize, P: Probe>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        cfg: &Config,
        mut rep: SpatialReport,
        out: &mut [LaneObservation<POINTS>; LANES],
        probe: &mut P,
    ) -> (usize, SpatialReport) {
        const { assert!(NS == NT + 1, "NS must be NT + 1 (offset + RBF state)") };
        if rep.bad_config {
            return (0, rep);
        }
        let h = &tables.hyper;
        let k_rows = usize::from(cfg.rows_per_interval.max(1));
        let rows = (POINTS - 1) * k_rows + 1;
        let init_rows = usize::from(cfg.init_rows).min(MAX_INIT_ROWS);
        let du = (h.u_max - h.u_min) / ((POINTS - 1) * k_rows) as f32;
        if rows > ROWS || !(du.is_finite() && du > 0.0) {
            rep.bad_config = true;
            return (0, rep);
        }
        // F = blockdiag(1, F_u), Q = blockdiag(0, Q_u), P∞_g, h = [1, 1, 0, …].
        let (fu, qu) = if (du - h.row_step).abs() <= 1e-5 * du {
            (tables.spatial.f, tables.spatial.q)
        } else {
            match tables.spatial.model.transition(du) {
                Some(fq) => fq,
                None => {
                    rep.bad_config = true;
                    return (0, rep);
                }
            }
        };
        let embed = |m: &SMatrix<f32, NT, NT>, corner: f32| {
            SMatrix::<f32, NS, NS>::from_fn(|i, j| match (i, j) {
                (0, 0) => corner,
                (0, _) | (_, 0) => 0.0,
                _ => m.get((i - 1, j - 1)).copied().unwrap_or(0.0),
            })
        };
        let s = cfg.row_noise_scale;
        if !(s.is_finite() && s > 0.0) {
            rep.bad_config = true;
            return (0, rep);
        }
        let F = embed(&fu, 1.0);
        let Q = embed(&(qu * s), 0.0);
        let hv = SVector::<f32, NS>::from_fn(|i, _| if i <= 1 { 1.0 } else { 0.0 });
        let params = RowParams {
            pd: cfg.pd,
            pg: cfg.pg,
            gamma: cfg.gamma,
            clutter_density: cfg.clutter_density,
            r: h.meas_noise,
            miss: cfg.miss,
        };

        // One row outcome and one set of event arrays for every row.
        let mut o = row::RowOutcome::<LANES>::default();
        let mut scratch = row::Scratch::<LANES>::new();
        for r in 0..rows {
            if r > 0 {
                probe.enter(Stage::RowPredict);
                self.state.predict(&F, &Q, &tables.coreg);
            }
            probe.enter(Stage::Management);
            let mut row_pts = self.bins.get(r).copied().unwrap_or([0.0; PER_ROW]);
            let m = usize::from(get(&self.bin_n, r)).min(PER_ROW);
            let used = self.initiate(
                r, &row_pts, m, init_rows, cfg, &params, &hv, tables, &mut rep,
            );
            // The points that started tracks have been used (§3.2d); the rest go to the update,
            // compacted in place (`nr ≤ j`: no second array to clear every row).
            let mut nr = 0usize;
            for j in 0..m {
                if used & (1 << j) == 0 {
                    let x = get(&row_pts, j);
                    set(&mut row_pts, nr, x);
                    nr += 1;
                }
            }
            // Record the predicted moments (priors for tracks started at this row).
            self.record(r, Moment::Predicted);
            let skip =
                self.meta
                    .iter()
                    .take(self.state.len())
                    .enumerate()
                    .fold(0u32, |acc, (t, m)| {
                        if m.status == Status::Ended {
                            acc | (1 << t)
                        } else {
                            acc
                        }
                    });
            row::update_into(
                (&mut o, &mut scratch),
                &mut self.state,
                &hv,
                row_pts.get(..nr).unwrap_or(&[]),
                &params,
                (cfg.max_events, skip),
                probe,
            );
            probe.enter(Stage::Management);
            rep.events = rep.events.saturating_add(o.events);
            rep.clutter_points += o.clutter_points;
            rep.gated = rep
                .gated
                .saturating_add(o.valid.iter().map(|v| v.count_ones()).sum::<u32>());
            rep.rows_approximated += u32::from(o.approximated);
            rep.rows_failed += u32::from(o.failed);
            self.manage(r, &o, cfg, &hv, &params, &mut rep);
            self.record(r, Moment::Filtered);
        }
        probe.enter(Stage::Backward);
        let n_out = self.smooth(tables, &F, &hv, k_rows, du, out, &mut rep);
        rep.lanes_out = n_out as u16;
        (n_out, rep)
    }

    /// Bins the frame's points into the `rows` BEV rows `u_min + r·du` (§1), empties the state,
    /// and counts the rejected points in `rep`.
    #[inline(always)]
    fn bin_points(
        &mut self,
        points: &[[f32; 2]],
        u_min: f32,
        du: f32,
        rows: usize,
        rep: &mut SpatialReport,
    ) {
        self.state = Stacked::new();
        self.meta = [Meta::EMPTY; LANES];
        self.bin_n = [0; ROWS];
        self.buf_n = [0; MAX_INIT_ROWS];
        for p in points {
            let [u, x] = *p;
            if !(u.is_finite() && x.is_finite()) {
                rep.rejected_non_finite += 1;
                continue;
            }
            let rf = libm::rintf((u - u_min) / du);
            if !(rf >= 0.0 && rf < rows as f32) {
                rep.rejected_window += 1;
                continue;
            }
            let r = rf as usize;
            let c = usize::from(get(&self.bin_n, r));
            let dup = self.bins.get(r).is_some_and(|b| {
                b.iter()
                    .take(c)
                    .any(|y| (x - y).abs() <= DUPLICATE_DISTANCE)
            });
            if dup {
                rep.rejected_duplicate += 1;
                continue;
            }
            if c >= PER_ROW {
                rep.rejected_row_full += 1;
                continue;
            }
            if let Some(v) = self.bins.get_mut(r).and_then(|b| b.get_mut(c)) {
                *v = x;
            }
            set(&mut self.bin_n, r, (c + 1) as u8);
        }
    }

    /// Stores each track's current marginal as its predicted or filtered moments for row `r`
    /// (§3.6); filtered moments are not recorded for ended tracks, and mark the last recorded row.
    #[inline(never)]
    fn record(&mut self, r: usize, which: Moment) {
        for (t, meta) in self.meta.iter_mut().enumerate().take(self.state.len()) {
            if which == Moment::Filtered {
                if meta.status == Status::Ended {
                    continue;
                }
                meta.last_rec = r as u16;
            }
            let rec = self
                .hist
                .get_mut(usize::from(meta.store))
                .and_then(|h| h.get_mut(r));
            if let (Some(x), Some(p), Some(rec)) = (self.state.mean(t), self.state.cov(t, t), rec) {
                match which {
                    Moment::Predicted => {
                        rec.xp = *x;
                        rec.pp = *p;
                    }
                    Moment::Filtered => {
                        rec.xf = *x;
                        rec.pf = *p;
                    }
                }
            }
        }
    }

    fn predicted_z(&self, t: usize, hv: &SVector<f32, NS>, r: f32) -> (f32, f32) {
        let z = self.state.mean(t).map_or(0.0, |x| hv.dot(x));
        let s = self
            .state
            .cov(t, t)
            .map_or(f32::INFINITY, |p| hv.dot(&(p * hv)) + r);
        (z, s)
    }
}

impl Default for Meta {
    fn default() -> Self {
        Self::EMPTY
    }
}
