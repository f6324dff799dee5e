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
use super::{get, set, Stacked};
use crate::probe::{NoProbe, Probe, Stage};
use crate::tables::Tables;

/// Largest `init_rows` (rows the initiation buffer remembers).
pub const MAX_INIT_ROWS: usize = 4;

/// A point within this lateral distance (metres) of a point already kept in its row is a
/// duplicate and is rejected (DESIGN 7).
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
    /// Consecutive misses that delete a tentative track.
    pub tentative_misses: u16,
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

/// Life stage of a spatial track.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Status {
    /// Started from consistent points, not yet confirmed.
    Tentative,
    /// Confirmed by `confirm_hits` hits.
    Confirmed,
    /// Confirmed, then `max_misses` consecutive misses: takes no more points.
    Ended,
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
}

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

/// One confirmed lane of this frame, ready for the temporal filter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaneObservation<const POINTS: usize> {
    /// `Confirmed` or `Ended` (tentative tracks are not reported).
    pub status: Status,
    /// Index point `i` has a pseudo-measurement (inside the lane's observed extent).
    pub present: [bool; POINTS],
    /// Smoothed lateral position at each present index point, metres.
    pub z: SVector<f32, POINTS>,
    /// Covariance of the present pseudo-measurements (zero rows/columns for absent ones), m².
    pub cov: SMatrix<f32, POINTS, POINTS>,
    /// First row with support, metres ahead.
    pub u_first: f32,
    /// Last row with support, metres ahead.
    pub u_last: f32,
    /// Hits over the track's life divided by its rows (hits + misses).
    pub existence: f32,
    /// Rank from the left among this frame's tracks (B's slot at the end of the walk).
    pub rank: u8,
}

impl<const POINTS: usize> LaneObservation<POINTS> {
    /// A blank observation (tentative, no point present, all zero): the filler of output arrays.
    pub const EMPTY: Self = Self {
        status: Status::Tentative,
        present: [false; POINTS],
        z: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; POINTS]; 1])),
        cov: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; POINTS]; POINTS])),
        u_first: 0.0,
        u_last: 0.0,
        existence: 0.0,
        rank: 0,
    };
}

/// Counters of one frame of the spatial filter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
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
        Self {
            state: Stacked::new(),
            meta: [Meta::EMPTY; LANES],
            hist: [[Rec::EMPTY; ROWS]; LANES],
            bin_n: [0; ROWS],
            bins: [[0.0; PER_ROW]; ROWS],
            buf: [[0.0; PER_ROW]; MAX_INIT_ROWS],
            buf_n: [0; MAX_INIT_ROWS],
        }
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
    #[allow(non_snake_case, clippy::too_many_lines)]
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
        const { assert!(NS == NT + 1, "NS must be NT + 1 (offset + RBF state)") };
        let mut rep = SpatialReport {
            points_in: points.len().min(u32::MAX as usize) as u32,
            ..SpatialReport::default()
        };
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
        let F = embed(&fu, 1.0);
        let Q = embed(&qu, 0.0);
        let hv = SVector::<f32, NS>::from_fn(|i, _| if i <= 1 { 1.0 } else { 0.0 });
        let params = RowParams {
            pd: cfg.pd,
            pg: cfg.pg,
            gamma: cfg.gamma,
            clutter_density: cfg.clutter_density,
            r: h.meas_noise,
            miss: cfg.miss,
        };

        // Bin the points (§1).
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
            let rf = libm::rintf((u - h.u_min) / du);
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

        for r in 0..rows {
            if r > 0 {
                probe.enter(Stage::RowPredict);
                self.state.predict(&F, &Q, &tables.coreg);
            }
            probe.enter(Stage::Management);
            let row_pts = self.bins.get(r).copied().unwrap_or([0.0; PER_ROW]);
            let m = usize::from(get(&self.bin_n, r)).min(PER_ROW);
            let used = self.initiate(
                r, &row_pts, m, init_rows, cfg, &params, &hv, tables, &mut rep,
            );
            // The points that started tracks have been used (§3.2d); the rest go to the update.
            let mut rest = [0.0f32; PER_ROW];
            let mut nr = 0usize;
            for (j, x) in row_pts.iter().enumerate().take(m) {
                if used & (1 << j) == 0 {
                    set(&mut rest, nr, *x);
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
            let o = row::update_probed(
                &mut self.state,
                &hv,
                rest.get(..nr).unwrap_or(&[]),
                &params,
                cfg.max_events,
                skip,
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

    /// §3.2: start tentative tracks from consistent free points; returns the mask of the row's
    /// points that started a track.
    #[allow(clippy::too_many_arguments)]
    #[inline(never)]
    fn initiate<const NT: usize, const POINTS: usize>(
        &mut self,
        r: usize,
        pts: &[f32; PER_ROW],
        m: usize,
        init_rows: usize,
        cfg: &Config,
        params: &RowParams,
        hv: &SVector<f32, NS>,
        tables: &Tables<NT, LANES, POINTS>,
        rep: &mut SpatialReport,
    ) -> u32 {
        // Free points (valid for no active track), sorted by x. Each active track's predicted
        // measurement and its variance, once.
        let mut pred = [(0.0f32, f32::INFINITY); LANES];
        let mut np = 0usize;
        for (t, mt) in self.meta.iter().enumerate().take(self.state.len()) {
            if mt.status != Status::Ended {
                set(&mut pred, np, self.predicted_z(t, hv, params.r));
                np += 1;
            }
        }
        let pred = pred.get(..np).unwrap_or(&[]);
        let mut free = [(0.0f32, 0u8); PER_ROW];
        let mut nf = 0usize;
        for (j, x) in pts.iter().enumerate().take(m) {
            let valid_for_some = pred.iter().any(|(z, s)| {
                let e = x - z;
                e * e / s <= params.gamma
            });
            if !valid_for_some {
                set(&mut free, nf, (*x, j as u8));
                nf += 1;
            }
        }
        if let Some(f) = free.get_mut(..nf) {
            // By x; ties keep input order (a stable sort).
            super::sort_by(f, |a, b| a.0.total_cmp(&b.0).is_lt());
        }
        let mut used = 0u32;
        let slot = r % MAX_INIT_ROWS;
        let mut keep = [0.0f32; PER_ROW];
        let mut nk = 0usize;
        for (x, j) in free.iter().take(nf).copied() {
            let consistent = (1..=init_rows).any(|back| {
                if back > r {
                    return false;
                }
                let b = (r - back) % MAX_INIT_ROWS;
                let n = usize::from(get(&self.buf_n, b));
                self.buf
                    .get(b)
                    .is_some_and(|row| row.iter().take(n).any(|y| (x - y).abs() <= cfg.init_gate))
            });
            let tentative = self
                .meta
                .iter()
                .take(self.state.len())
                .filter(|mt| mt.status == Status::Tentative)
                .count();
            if consistent && tentative < usize::from(cfg.max_tentative) && self.state.len() < LANES
            {
                if self.start_track(r, x, hv, params.r, tables) {
                    rep.started += 1;
                    used |= 1 << j;
                    continue;
                }
            } else if consistent {
                rep.no_slot += 1;
            }
            set(&mut keep, nk, x);
            nk += 1;
        }
        if let Some(b) = self.buf.get_mut(slot) {
            *b = keep;
        }
        set(&mut self.buf_n, slot, nk as u8);
        used
    }

    /// §3.2d: the B-conditioned prior of a new track at lateral position `x`, inserted at its rank.
    fn start_track<const NT: usize, const POINTS: usize>(
        &mut self,
        r: usize,
        x: f32,
        hv: &SVector<f32, NS>,
        meas_var: f32,
        tables: &Tables<NT, LANES, POINTS>,
    ) -> bool {
        let n = self.state.len();
        let k = (0..n)
            .filter(|&t| self.predicted_z(t, hv, 0.0).0 < x)
            .count();
        // Row k of Λ = B_{n+1}⁻¹ from the stored Cholesky factor: L v = e_k, Lᵀ y = v.
        let m = n + 1;
        let l = &tables.coreg_chol;
        let lg = |i: usize, j: usize| l.get((i, j)).copied().unwrap_or(0.0);
        let mut v = [0.0f32; LANES];
        for i in 0..m {
            let mut s = if i == k { 1.0 } else { 0.0 };
            for j in 0..i {
                s -= lg(i, j) * get(&v, j);
            }
            set(&mut v, i, s / lg(i, i));
        }
        let mut y = [0.0f32; LANES];
        for i in (0..m).rev() {
            let mut s = get(&v, i);
            for j in i + 1..m {
                s -= lg(j, i) * get(&y, j);
            }
            set(&mut y, i, s / lg(i, i));
        }
        let lkk = get(&y, k);
        if !(lkk.is_finite() && lkk > 0.0) {
            return false;
        }
        // a_i over the existing ranks (old rank i ↔ new slot i or i + 1).
        let mut a = [0.0f32; LANES];
        for i in 0..n {
            let slot = if i < k { i } else { i + 1 };
            set(&mut a, i, -get(&y, slot) / lkk);
        }
        // S zeroes the offset row: x_new = [c; Σ a_i g_i + w].
        let sel = SMatrix::<f32, NS, NS>::from_fn(|i, j| if i == j && i > 0 { 1.0 } else { 0.0 });
        let mut mean = SVector::<f32, NS>::zeros();
        let mut cross = [SMatrix::<f32, NS, NS>::zeros(); LANES];
        for i in 0..n {
            let ai = get(&a, i);
            if let Some(xi) = self.state.mean(i) {
                mean += sel * xi * ai;
            }
            for (j, c) in cross.iter_mut().enumerate().take(n) {
                if let Some(pij) = self.state.cov(i, j) {
                    *c += sel * pij * ai;
                }
            }
        }
        let mut var = SMatrix::<f32, NS, NS>::zeros();
        for i in 0..n {
            for j in 0..n {
                if let Some(pij) = self.state.cov(i, j) {
                    var += sel * pij * sel * (get(&a, i) * get(&a, j));
                }
            }
        }
        let pinf = &tables.spatial.model.p_inf;
        var += SMatrix::<f32, NS, NS>::from_fn(|i, j| match (i, j) {
            (0, 0) => tables.hyper.offset_variance,
            (0, _) | (_, 0) => 0.0,
            _ => pinf.get((i - 1, j - 1)).copied().unwrap_or(0.0) / lkk,
        });
        if let Some(c0) = mean.get_mut(0) {
            *c0 = x;
        }
        let used = self
            .meta
            .iter()
            .take(n)
            .fold(0u32, |acc, mt| acc | (1 << mt.store));
        let store = (0..LANES as u32)
            .find(|s| used & (1 << s) == 0)
            .unwrap_or(0) as u8;
        if self.state.insert(k, mean, &var, &cross).is_err() {
            return false;
        }
        // Shift metadata right of k.
        for i in (k + 1..=n).rev() {
            let prev = get(&self.meta, i - 1);
            set(&mut self.meta, i, prev);
        }
        set(
            &mut self.meta,
            k,
            Meta {
                store,
                start_row: r as u16,
                last_rec: r as u16,
                ..Meta::EMPTY
            },
        );
        for mt in self.meta.iter_mut().take(n + 1) {
            mt.near = 0;
        }
        // Condition on the initiating point (a certain association).
        self.state.update_single(k, hv, x, meas_var);
        true
    }

    /// §3.4–3.5: hits and misses, confirm / delete / end, merge.
    #[inline(never)]
    fn manage(
        &mut self,
        r: usize,
        o: &row::RowOutcome<LANES>,
        cfg: &Config,
        hv: &SVector<f32, NS>,
        params: &RowParams,
        rep: &mut SpatialReport,
    ) {
        let n = self.state.len();
        let mut delete = 0u32;
        for t in 0..n {
            let Some(mt) = self.meta.get_mut(t) else {
                continue;
            };
            if mt.status == Status::Ended || o.failed {
                continue;
            }
            if 1.0 - get(&o.beta_miss, t) >= 0.5 {
                mt.hits = mt.hits.saturating_add(1);
                mt.miss_run = 0;
                if mt.first_row == NO_ROW {
                    mt.first_row = r as u16;
                }
                mt.last_row = r as u16;
                if mt.status == Status::Tentative && mt.hits >= cfg.confirm_hits {
                    mt.status = Status::Confirmed;
                    rep.confirmed += 1;
                }
            } else {
                mt.misses = mt.misses.saturating_add(1);
                mt.miss_run = mt.miss_run.saturating_add(1);
                match mt.status {
                    Status::Tentative if mt.miss_run >= cfg.tentative_misses => delete |= 1 << t,
                    Status::Confirmed if mt.miss_run >= cfg.max_misses => {
                        mt.status = Status::Ended;
                        rep.ended += 1;
                    }
                    _ => {}
                }
            }
        }
        // Merge adjacent near-duplicates.
        for t in 0..n.saturating_sub(1) {
            let (ma, mb) = (get(&self.meta, t), get(&self.meta, t + 1));
            if ma.status == Status::Ended || mb.status == Status::Ended || delete & (3 << t) != 0 {
                continue;
            }
            let (za, _) = self.predicted_z(t, hv, params.r);
            let (zb, _) = self.predicted_z(t + 1, hv, params.r);
            let near = if (za - zb).abs() <= cfg.merge_distance {
                ma.near.saturating_add(1)
            } else {
                0
            };
            if let Some(mt) = self.meta.get_mut(t) {
                mt.near = near;
            }
            if near >= cfg.merge_rows {
                let loser =
                    if ma.hits < mb.hits || (ma.hits == mb.hits && ma.start_row > mb.start_row) {
                        t
                    } else {
                        t + 1
                    };
                delete |= 1 << loser;
                rep.merged += 1;
            }
        }
        for t in (0..n).rev() {
            if delete & (1 << t) != 0 {
                if get(&self.meta, t).status == Status::Tentative {
                    rep.deleted += 1;
                }
                self.remove_track(t);
            }
        }
    }

    fn remove_track(&mut self, t: usize) {
        let n = self.state.len();
        self.state.remove(t);
        for i in t..n.saturating_sub(1) {
            let next = get(&self.meta, i + 1);
            set(&mut self.meta, i, next);
        }
        for mt in self.meta.iter_mut() {
            mt.near = 0;
        }
    }

    /// §4: backward RTS pass per confirmed track and pseudo-measurements at the index points.
    ///
    /// Per row one `NS×NS` `LDLᵀ` solve for the gain `G_r = P_{r|r} Fᵀ P_{r+1|r}⁻¹`. The
    /// cross-covariances with the index points already passed are only needed through `h`, so
    /// each is kept as the vector `Cov(x_r, x_b) h` and the gains of an index interval are
    /// composed once (`Γ = G_r Γ`) and applied to those vectors at the next index row:
    /// `O(NS³)` per row plus `O(NS²)` per (index point, index interval).
    #[allow(non_snake_case, clippy::too_many_arguments)]
    #[inline(never)]
    fn smooth<const NT: usize, const POINTS: usize>(
        &self,
        tables: &Tables<NT, LANES, POINTS>,
        F: &SMatrix<f32, NS, NS>,
        hv: &SVector<f32, NS>,
        k_rows: usize,
        du: f32,
        out: &mut [LaneObservation<POINTS>; LANES],
        rep: &mut SpatialReport,
    ) -> usize {
        let f = F.data.0;
        let [h] = hv.data.0;
        let mut n_out = 0usize;
        for (rank, mt) in self.meta.iter().enumerate().take(self.state.len()) {
            if mt.status == Status::Tentative || mt.first_row == NO_ROW {
                continue;
            }
            let Some(hist) = self.hist.get(usize::from(mt.store)) else {
                continue;
            };
            let (a, b) = (usize::from(mt.start_row), usize::from(mt.last_rec));
            let (first, last) = (usize::from(mt.first_row), usize::from(mt.last_row));
            let mut obs = LaneObservation {
                status: mt.status,
                present: [false; POINTS],
                z: SVector::zeros(),
                cov: SMatrix::zeros(),
                u_first: tables.hyper.u_min + du * f32::from(mt.first_row),
                u_last: tables.hyper.u_min + du * f32::from(mt.last_row),
                existence: f32::from(mt.hits) / f32::from(mt.hits.saturating_add(mt.misses).max(1)),
                rank: rank as u8,
            };
            // v[i] = Cov(x_{r'}, x_{iK}) h for the registered index points, at the last index row
            // r' passed; gam = G_r ⋯ G_{r'−1} since then.
            let mut v = [[0.0f32; NS]; POINTS];
            let mut registered = 0u64;
            let mut gam = ident::<NS>();
            let mut compose = false;
            let mut xs = [0.0f32; NS];
            let mut ps = [[0.0f32; NS]; NS];
            let mut ok = true;
            for r in (a..=b).rev() {
                let Some(rec) = hist.get(r) else { continue };
                let [xf] = rec.xf.data.0;
                let pf = rec.pf.data.0;
                if r == b {
                    xs = xf;
                    ps = pf;
                } else {
                    let Some(next) = hist.get(r + 1) else {
                        continue;
                    };
                    // Gᵀ = P_{r+1|r}⁻¹ F P_{r|r}.
                    let Some(gt) = spd_solve(&next.pp.data.0, &mat_mul(&f, &pf)) else {
                        ok = false;
                        break;
                    };
                    let g = transpose(&gt);
                    let [xp] = next.xp.data.0;
                    // xs ← x_f + G (xs − x_p);  ps ← P_f + G (ps − P_p) Gᵀ (symmetric).
                    let mut dxs = xs;
                    for (d, p) in dxs.iter_mut().zip(xp.iter()) {
                        *d -= p;
                    }
                    let gd = mat_vec(&g, &dxs);
                    for ((x, f0), d) in xs.iter_mut().zip(xf.iter()).zip(gd.iter()) {
                        *x = f0 + d;
                    }
                    let mut dp = ps;
                    for (dc, pc) in dp.iter_mut().zip(next.pp.data.0.iter()) {
                        for (dv, pv) in dc.iter_mut().zip(pc.iter()) {
                            *dv -= pv;
                        }
                    }
                    let t = mat_mul(&g, &dp);
                    ps = pf;
                    for c in 0..NS {
                        for rr in 0..=c {
                            // (T Gᵀ)[rr][c] = Σ_k T[rr][k] G[c][k]
                            let mut acc = 0.0f32;
                            for k in 0..NS {
                                acc += m_at(&t, rr, k) * m_at(&g, c, k);
                            }
                            let s = 0.5 * (m_at(&ps, rr, c) + m_at(&ps, c, rr)) + acc;
                            m_set(&mut ps, rr, c, s);
                            m_set(&mut ps, c, rr, s);
                        }
                    }
                    if compose {
                        gam = mat_mul(&g, &gam);
                    } else {
                        let mut m = registered;
                        while m != 0 {
                            if let Some(vj) = v.get_mut(m.trailing_zeros() as usize) {
                                *vj = mat_vec(&g, vj);
                            }
                            m &= m - 1;
                        }
                    }
                }
                if r % k_rows == 0 {
                    let i = r / k_rows;
                    let inside = r >= first && r <= last;
                    if i < POINTS && i < 64 && inside {
                        // Bring the registered vectors to this row, then add this point.
                        for (j, vj) in v.iter_mut().enumerate() {
                            if registered & (1 << j) != 0 {
                                if compose {
                                    *vj = mat_vec(&gam, vj);
                                }
                                let e = dot(&h, vj);
                                if let Some(c) = obs.cov.get_mut((i, j)) {
                                    *c = e;
                                }
                                if let Some(c) = obs.cov.get_mut((j, i)) {
                                    *c = e;
                                }
                            }
                        }
                        gam = ident::<NS>();
                        // Composing the gains costs NS³ per row, propagating NS² per vector.
                        compose = (registered | 1 << i).count_ones() as usize >= NS;
                        let vi = mat_vec(&ps, &h);
                        if let Some(c) = obs.cov.get_mut((i, i)) {
                            *c = dot(&h, &vi);
                        }
                        set(&mut v, i, vi);
                        registered |= 1 << i;
                        set(&mut obs.present, i, true);
                        if let Some(z) = obs.z.get_mut(i) {
                            *z = dot(&h, &xs);
                        }
                    }
                }
            }
            // NaN-propagating sum: 0 exactly when every entry is finite.
            let probe = obs.z.iter().fold(0.0f32, |acc, v| acc + v * 0.0)
                + obs.cov.iter().fold(0.0f32, |acc, v| acc + v * 0.0);
            let finite = probe == 0.0;
            if !(ok && finite) {
                rep.smoother_failed += 1;
                continue;
            }
            if repair_psd(&mut obs) {
                rep.cov_repaired += 1;
            }
            if let Some(o) = out.get_mut(n_out) {
                *o = obs;
                n_out += 1;
            }
        }
        n_out
    }
}

/// Entry `(r, c)` of a column-major `N×N` array (`m[c][r]`), 0 past its end.
#[inline(always)]
fn m_at<const N: usize>(m: &[[f32; N]; N], r: usize, c: usize) -> f32 {
    m.get(c).and_then(|col| col.get(r)).copied().unwrap_or(0.0)
}

/// Sets entry `(r, c)` of a column-major `N×N` array (no-op past its end).
#[inline(always)]
fn m_set<const N: usize>(m: &mut [[f32; N]; N], r: usize, c: usize, v: f32) {
    if let Some(e) = m.get_mut(c).and_then(|col| col.get_mut(r)) {
        *e = v;
    }
}

/// The `N×N` identity (column-major).
#[inline(always)]
fn ident<const N: usize>() -> [[f32; N]; N] {
    let mut m = [[0.0f32; N]; N];
    for (c, col) in m.iter_mut().enumerate() {
        set(col, c, 1.0);
    }
    m
}

/// `a · b`.
#[inline(always)]
fn dot<const N: usize>(a: &[f32; N], b: &[f32; N]) -> f32 {
    a.iter().zip(b.iter()).map(|(x, y)| x * y).sum()
}

/// `M v` (column-major `M`).
#[inline(always)]
fn mat_vec<const N: usize>(m: &[[f32; N]; N], v: &[f32; N]) -> [f32; N] {
    let mut out = [0.0f32; N];
    for (col, vc) in m.iter().zip(v.iter()) {
        for (o, e) in out.iter_mut().zip(col.iter()) {
            *o += e * vc;
        }
    }
    out
}

/// `A B` (column-major): column `c` of the product is `A` times column `c` of `B`.
#[inline(always)]
fn mat_mul<const N: usize>(a: &[[f32; N]; N], b: &[[f32; N]; N]) -> [[f32; N]; N] {
    let mut out = [[0.0f32; N]; N];
    for (oc, bc) in out.iter_mut().zip(b.iter()) {
        *oc = mat_vec(a, bc);
    }
    out
}

/// `Mᵀ` (column-major).
#[inline(always)]
fn transpose<const N: usize>(m: &[[f32; N]; N]) -> [[f32; N]; N] {
    let mut out = [[0.0f32; N]; N];
    for (c, col) in m.iter().enumerate() {
        for (r, v) in col.iter().enumerate() {
            m_set(&mut out, c, r, *v);
        }
    }
    out
}

/// Solves `A X = B` for a symmetric positive definite `A` (column-major `N×N` arrays) by
/// `A = L D Lᵀ`; `None` when a pivot is not positive and finite (`A` not positive definite).
///
/// # Complexity
/// `N³/6` for the factor and `N³` for the `N` right-hand sides; no square root.
#[inline(always)]
fn spd_solve<const N: usize>(a: &[[f32; N]; N], b: &[[f32; N]; N]) -> Option<[[f32; N]; N]> {
    let mut l = [[0.0f32; N]; N]; // l[c][r] = L_rc, unit diagonal implied
    let mut d = [0.0f32; N];
    let mut invd = [0.0f32; N];
    for j in 0..N {
        let mut dj = m_at(a, j, j);
        for k in 0..j {
            let ljk = m_at(&l, j, k);
            dj -= ljk * ljk * get(&d, k);
        }
        if !(dj.is_finite() && dj > 0.0) {
            return None;
        }
        let ij = 1.0 / dj;
        set(&mut d, j, dj);
        set(&mut invd, j, ij);
        for i in j + 1..N {
            // L_ij d_j = A_ij − Σ_{k<j} L_ik L_jk d_k
            let mut s = m_at(a, i, j);
            for k in 0..j {
                s -= m_at(&l, i, k) * m_at(&l, j, k) * get(&d, k);
            }
            m_set(&mut l, i, j, s * ij);
        }
    }
    let mut x = *b;
    for col in x.iter_mut() {
        for i in 0..N {
            let mut s = get(col, i);
            for k in 0..i {
                s -= m_at(&l, i, k) * get(col, k);
            }
            set(col, i, s);
        }
        for (v, id) in col.iter_mut().zip(invd.iter()) {
            *v *= id;
        }
        for i in (0..N).rev() {
            let mut s = get(col, i);
            for k in i + 1..N {
                s -= m_at(&l, k, i) * get(col, k);
            }
            set(col, i, s);
        }
    }
    Some(x)
}

impl Default for Meta {
    fn default() -> Self {
        Self::EMPTY
    }
}

/// Makes a lane's pseudo-measurement covariance positive definite over its present points
/// (`docs/spatial-filter.md` §4): a modified Cholesky in index order raises every pivot below
/// `1e-6 ×` the largest present variance to `max(|d|, that floor)` and adds the difference to
/// that point's variance. A positive definite block is left as it is. Returns whether anything
/// was added. `O(m³/6)` for `m` present points.
fn repair_psd<const POINTS: usize>(obs: &mut LaneObservation<POINTS>) -> bool {
    let mut idx = [0u8; POINTS];
    let mut m = 0usize;
    for (i, &p) in obs.present.iter().enumerate() {
        if p {
            set(&mut idx, m, i as u8);
            m += 1;
        }
    }
    let at = |a: usize| usize::from(get(&idx, a));
    let mut c = SMatrix::<f32, POINTS, POINTS>::zeros();
    let mut top = 0.0f32;
    for b in 0..m {
        for a in b..m {
            let v = 0.5
                * (obs.cov.get((at(a), at(b))).copied().unwrap_or(0.0)
                    + obs.cov.get((at(b), at(a))).copied().unwrap_or(0.0));
            if let Some(e) = c.get_mut((a, b)) {
                *e = v;
            }
            if a == b {
                top = top.max(v.abs());
            }
        }
    }
    let floor = 1e-6 * top;
    if !(floor.is_finite() && floor > 0.0) {
        return false;
    }
    let mut load = [0.0f32; POINTS];
    let raised = crate::math::cholesky_loaded(&mut c, m, floor, floor, &mut load);
    if raised == 0 || raised == u8::MAX {
        return false;
    }
    for (a, l) in load.iter().enumerate().take(m) {
        if let Some(e) = obs.cov.get_mut((at(a), at(a))) {
            *e += l;
        }
    }
    true
}
