//! The fixed-lag coupled smoother (docs/design.md §5), exact, by state augmentation of the lagged lane
//! coefficients only.
//!
//! For each lag `j = 1..=LAG` the window keeps the lagged position coefficients `a_{k−j}` of every
//! lane (`NA = LANES·RANK` numbers), their per-lane `RANK×RANK` covariance blocks (what is
//! published: a lane's smoothed positions and variances at the index points), and the
//! cross-covariance `C_j = Cov(a_{k−j}, x_k)` with the current state (`NA × NX`). A prediction
//! moves the window by one frame (a ring buffer: the oldest lag is overwritten by the current
//! lanes) and maps `C_j ← C_j F̄ᵀ`; a lane update with the filter's gain parts
//! `(G = P Hᵀ-columns, M = V_mᵀ S⁻¹ V_m, w = V_mᵀ S⁻¹ ν)` moves every lag by the same innovation:
//! with `K_j = C_j[:, a_s]`, `a_{k−j} += K_j w`, `Σ_j −= K_j M K_jᵀ`, `C_j −= K_j M Gᵀ`. This is the
//! Kalman filter of the augmented state `[x_k, a_{k−1}, …, a_{k−L}]` restricted to the blocks the
//! output needs, so `a_{k−L|k}` equals the RTS fixed-lag estimate `x_{k−L|k}` exactly, with no
//! inverse of the predicted covariance (the RTS gain `P_{k|k} Fᵀ P_{k+1|k}⁻¹` would need an
//! 84×84 factorisation of a numerically singular matrix).
//!
//! # Invariant
//! In every lag, `C_j` is zero outside (rows of the lanes present at `k − j`) × (columns of the
//! lanes active now): lane starts and removals keep it so. Every loop runs over those blocks only.
//!
//! # RAM
//! `LAG · 4 · (NA + LANES·RANK² + NA·NX)` bytes: 61,824 B (60.4 KiB) at 6 lanes, rank 7,
//! L = 4 — the largest item of the tracker, as docs/design.md §5 expects.
//!
//! # Cost
//! With `p` lanes present in a lag, `n` active now, `r` Gram components: per prediction
//! `LAG · 4·(p r)·(2 n r)` multiply-adds (plus copying the current lanes into the newest lag);
//! per lane update `LAG · (p r)·(2 n r)·r`. No stack copy of the window: updates are checked
//! (bounds on every product) before anything is written, then applied in place.

use nalgebra::{Matrix2, SMatrix, SVector};

use super::filter::{
    dot, project, repair_psd, times_sym, Spans, TemporalError, TemporalFilter, UpdateInfo,
    UpdateParts,
};
use crate::linalg::{get, set};
use crate::observation::LaneObservation;
use crate::probe::{NoProbe, Probe, Stage};
use crate::tables::Tables;

/// The largest smoother lag `LAG` (frames) of [`Temporal`] and of the tracker
/// (`crate::tracker::Tracker`), which keeps `2·LAG + 1` frames of lane extents and `LAG + 1`
/// frames of lane ids for the smoothed output. RAM grows linearly with `LAG` (see the module
/// docs: 15,456 B (15.1 KiB) a frame of lag at 6 lanes and rank 7), so a larger lag is rarely
/// wanted on a microcontroller; raise this constant (and re-measure) if it is.
pub const MAX_LAG: usize = 7;

/// One lag of the window.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Lagged<const LANES: usize, const RANK: usize, const NA: usize, const NX: usize> {
    mean: SVector<f32, NA>,
    blocks: [SMatrix<f32, RANK, RANK>; LANES],
    cross: SMatrix<f32, NA, NX>,
    present: [bool; LANES],
}

impl<const LANES: usize, const RANK: usize, const NA: usize, const NX: usize>
    Lagged<LANES, RANK, NA, NX>
{
    /// Column `j` of `C`.
    fn col_mut(&mut self, j: usize) -> Option<&mut [f32]> {
        self.cross.as_mut_slice().get_mut(j * NA..(j + 1) * NA)
    }
}

/// The temporal filter with its fixed-lag smoother: the per-frame temporal stage of the tracker.
///
/// `NX = 2·LANES·RANK`, `NA = LANES·RANK`, `LAG ≥ 1` frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Temporal<
    const LANES: usize,
    const POINTS: usize,
    const RANK: usize,
    const NX: usize,
    const NA: usize,
    const LAG: usize,
> {
    filter: TemporalFilter<LANES, POINTS, RANK, NX>,
    /// Ring buffer: lag `j` (1..=LAG) is `window[(head + j − 1) % LAG]`.
    window: [Lagged<LANES, RANK, NA, NX>; LAG],
    head: usize,
    frames: u32,
    /// `true`: the per-lane approximation (see [`Temporal::with_per_lane`]); `false` (all-zero,
    /// the default) the exact smoother.
    per_lane: bool,
}

impl<
        const LANES: usize,
        const POINTS: usize,
        const RANK: usize,
        const NX: usize,
        const NA: usize,
        const LAG: usize,
    > Default for Temporal<LANES, POINTS, RANK, NX, NA, LAG>
{
    fn default() -> Self {
        Self::new()
    }
}

/// A product of finite factors stays far from overflow below this bound.
const SAFE: f32 = 1e30;

/// `sqrt(Σ v²)`, a bound on every `|v|` (infinite or NaN when some value is not finite).
fn norm_bound(v: &[f32]) -> f32 {
    crate::math::sqrt(v.iter().map(|x| x * x).sum::<f32>())
}

impl<
        const LANES: usize,
        const POINTS: usize,
        const RANK: usize,
        const NX: usize,
        const NA: usize,
        const LAG: usize,
    > Temporal<LANES, POINTS, RANK, NX, NA, LAG>
{
    const EMPTY: Lagged<LANES, RANK, NA, NX> = Lagged {
        mean: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; NA]; 1])),
        blocks: [SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; RANK]; RANK])); LANES],
        cross: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; NA]; NX])),
        present: [false; LANES],
    };

    /// No lanes, empty window (`const`).
    pub const fn new() -> Self {
        const { assert!(NA == LANES * RANK, "NA must be LANES·RANK") };
        const { assert!(LAG >= 1 && LAG <= MAX_LAG, "LAG must be 1..=MAX_LAG") };
        Self {
            filter: TemporalFilter::new(),
            window: [Self::EMPTY; LAG],
            head: 0,
            frames: 0,
            per_lane: false,
        }
    }

    /// [`Temporal::new`] with the chosen smoother (`const`). Exact (the default,
    /// `per_lane = false`): every lane's lagged coefficients move with every lane's innovation through the full
    /// cross-covariances `C_j = Cov(a_{k−j}, x_k)`. Per lane (`true`): `C_j` is kept block-diagonal
    /// (lane `t`'s lagged coefficients against lane `t`'s current state only), so a lane's lagged
    /// estimate moves with its own innovations only: a lane update costs `LAG·2r³` multiply-adds
    /// instead of `LAG·(p r)(2 n r) r`, and a prediction `LAG·n·4r²` instead of
    /// `LAG·4(p r)(2 n r)`. The filtered lanes are the same either way; the smoothed ones lose what other lanes'
    /// innovations say about a lane's past (docs/design.md §5.1, measured in docs/measurements.md
    /// "Fitting the MCU").
    ///
    /// Experimental: with coupled lanes the projection can make the lagged covariance indefinite,
    /// so the smoothed variances are then only their floor; the smoothed means are what the option
    /// is for.
    pub const fn with_per_lane(per_lane: bool) -> Self {
        let mut t = Self::new();
        t.per_lane = per_lane;
        t
    }

    /// Chooses the smoother of [`Temporal::with_per_lane`] on an empty window (the tracker's
    /// in-place `init`).
    pub(crate) const fn set_per_lane(&mut self, per_lane: bool) {
        self.per_lane = per_lane;
    }

    /// The window's loops run on each lane's own blocks: the per-lane smoother, or an
    /// [`uncoupled`](TemporalFilter::uncoupled) filter, whose cross-covariances `C_j` are then
    /// block-diagonal too (every lag was copied from a block-diagonal `P` and moved by gains
    /// that vanish outside their lane), so the per-lane loops are the exact smoother.
    fn own_blocks(&self) -> bool {
        self.per_lane || self.filter.uncoupled()
    }

    /// The filter (filtered lanes at the current frame).
    pub fn filter(&self) -> &TemporalFilter<LANES, POINTS, RANK, NX> {
        &self.filter
    }

    /// Frames predicted so far (the window is full once this reaches `LAG`).
    pub fn frames(&self) -> u32 {
        self.frames
    }

    /// Index in `window` of lag `j` (1..=LAG).
    fn slot_of(&self, j: usize) -> usize {
        (self.head + j.saturating_sub(1)) % LAG
    }

    /// See [`TemporalFilter::set_ranks`].
    ///
    /// # Errors
    /// As [`TemporalFilter::set_ranks`].
    pub fn set_ranks(&mut self, ranks: &[u8; LANES]) -> Result<(), TemporalError> {
        self.filter.set_ranks(ranks)
    }

    /// Starts a lane (see [`TemporalFilter::start_lane`]); the window's cross-covariances gain the
    /// new lane's columns `Σ_t a_t C_j[:, x_t]`; its lagged rows stay absent (it did not exist).
    ///
    /// # Errors
    /// As [`TemporalFilter::start_lane`]; the state is unchanged.
    // Not inlined: its stack frame must not add to its caller's (stack budget).
    #[inline(never)]
    pub fn start_lane<const NT: usize>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        s: usize,
        rank: u8,
        ranks: &[u8; LANES],
    ) -> Result<(), TemporalError> {
        let active_before = core::array::from_fn::<bool, LANES, _>(|t| self.filter.is_active(t));
        let a = self.filter.start_lane(tables, s, rank, ranks)?;
        let r = TemporalFilter::<LANES, POINTS, RANK, NX>::r_used(tables);
        let base = |t: usize| TemporalFilter::<LANES, POINTS, RANK, NX>::index(t, 0, 0);
        if self.own_blocks() {
            // Per lane, or uncoupled (then `a = 0` and this is exact): the new lane's state is
            // not related to any lagged lane.
            for lag in &mut self.window {
                if let Some(cols) = lag
                    .cross
                    .as_mut_slice()
                    .get_mut(base(s) * NA..(base(s) + 2 * RANK) * NA)
                {
                    cols.fill(0.0);
                }
            }
            return Ok(());
        }
        for lag in &mut self.window {
            for off in 0..2 * r {
                let mut col = [0.0f32; NA];
                for t in (0..LANES).filter(|&t| get(&active_before, t)) {
                    let at = get(&a, t);
                    let src = lag
                        .cross
                        .as_slice()
                        .get((base(t) + off) * NA..(base(t) + off + 1) * NA);
                    if let Some(src) = src {
                        for (d, v) in col.iter_mut().zip(src) {
                            *d += at * v;
                        }
                    }
                }
                if let Some(dst) = lag.col_mut(base(s) + off) {
                    dst.copy_from_slice(&col);
                }
            }
        }
        Ok(())
    }

    /// Removes a lane from the filter (its lagged history stays in the window until it ages out;
    /// its columns of the cross-covariances are zeroed).
    pub fn remove_lane(&mut self, s: usize) {
        if !self.filter.is_active(s) {
            return;
        }
        self.filter.remove_lane(s);
        let lo = TemporalFilter::<LANES, POINTS, RANK, NX>::index(s, 0, 0);
        for lag in &mut self.window {
            if let Some(cols) = lag
                .cross
                .as_mut_slice()
                .get_mut(lo * NA..(lo + 2 * RANK) * NA)
            {
                cols.fill(0.0);
            }
        }
    }

    /// Predicts over `t` seconds: the current lanes' coefficients enter the window as lag 1 (the
    /// oldest lag leaves), then `C_j ← C_j F̄ᵀ`.
    ///
    /// # Errors
    /// [`TemporalError::BadStep`]; the state is unchanged.
    pub fn predict<const NT: usize>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        t: f32,
    ) -> Result<(), TemporalError> {
        self.predict_probed(tables, t, &mut NoProbe)
    }

    /// [`Temporal::predict`] reporting [`Stage::Temporal`] and [`Stage::Smoother`] to `probe`.
    ///
    /// # Errors
    /// As [`Temporal::predict`].
    // Not inlined: its stack frame must not add to its caller's (stack budget).
    #[inline(never)]
    pub fn predict_probed<const NT: usize, P: Probe>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        t: f32,
        probe: &mut P,
    ) -> Result<(), TemporalError> {
        self.predict_scaled_probed(tables, t, 1.0, probe)
    }

    /// [`Temporal::predict_probed`] with the process noise `Q_t(T)` multiplied by `q_scale`
    /// (≥ 1: the adaptive scale of [`crate::persist`], docs/design.md §11; a scale that is not
    /// finite or below 1 counts as 1).
    ///
    /// # Errors
    /// As [`Temporal::predict`].
    #[inline(never)]
    pub fn predict_scaled_probed<const NT: usize, P: Probe>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        t: f32,
        q_scale: f32,
        probe: &mut P,
    ) -> Result<(), TemporalError> {
        probe.enter(Stage::Temporal);
        let (f, q) = tables
            .temporal
            .kernel
            .transition(t)
            .ok_or(TemporalError::BadStep)?;
        let q = if q_scale.is_finite() && q_scale > 1.0 {
            q * q_scale
        } else {
            q
        };
        probe.enter(Stage::Smoother);
        let r = TemporalFilter::<LANES, POINTS, RANK, NX>::r_used(tables);
        let sp = self.filter.spans(r);
        // The oldest lag becomes lag 1 and takes the current lanes (x_k, P_k before predicting).
        self.head = (self.head + LAG - 1) % LAG;
        let coupled = !self.own_blocks();
        let filter = &self.filter;
        if let Some(fresh) = self.window.get_mut(self.head) {
            let old = fresh.present;
            for s in 0..LANES {
                let on = filter.is_active(s);
                set(&mut fresh.present, s, on);
                let rows = s * RANK..s * RANK + RANK;
                if !on {
                    if get(&old, s) {
                        // Rows of a lane gone since: zero them on every column.
                        for j in sp.indices() {
                            if let Some(c) = fresh.col_mut(j).and_then(|c| c.get_mut(rows.clone()))
                            {
                                c.fill(0.0);
                            }
                        }
                    }
                    continue;
                }
                let ia = |j: usize| TemporalFilter::<LANES, POINTS, RANK, NX>::index(s, j, 0);
                let x = filter.mean().as_slice();
                let p = filter.covariance().as_slice();
                for j in 0..RANK {
                    if let Some(m) = fresh.mean.get_mut(s * RANK + j) {
                        *m = if j < r {
                            x.get(ia(j)).copied().unwrap_or(0.0)
                        } else {
                            0.0
                        };
                    }
                }
                for col in sp.indices() {
                    // Per lane: only lane s's own columns.
                    let keep = coupled || col / (2 * RANK) == s;
                    if let Some(c) = fresh.col_mut(col).and_then(|c| c.get_mut(rows.clone())) {
                        for (j, e) in c.iter_mut().enumerate() {
                            // P is symmetric: row ia(j) of column col = entry (col, ia(j)).
                            *e = if j < r && keep {
                                p.get(col + NX * ia(j)).copied().unwrap_or(0.0)
                            } else {
                                0.0
                            };
                        }
                    }
                }
                if let Some(b) = fresh.blocks.get_mut(s) {
                    *b = SMatrix::from_fn(|j, j2| {
                        if j < r && j2 < r {
                            p.get(ia(j) + NX * ia(j2)).copied().unwrap_or(0.0)
                        } else {
                            0.0
                        }
                    });
                }
            }
        }
        for lag in &mut self.window {
            times_transition(lag, &sp, &f, r, coupled);
        }
        probe.enter(Stage::Temporal);
        self.filter.predict_with(tables, &f, &q);
        self.frames = self.frames.saturating_add(1);
        Ok(())
    }

    /// Updates lane `s` with its pseudo-measurements: the filter and every lag of the window.
    ///
    /// # Errors
    /// As [`TemporalFilter::update`]; the state is unchanged.
    pub fn update<const NT: usize>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        s: usize,
        obs: &LaneObservation<POINTS>,
    ) -> Result<UpdateInfo, TemporalError> {
        self.update_probed(tables, s, obs, &mut NoProbe)
    }

    /// [`Temporal::update`] reporting [`Stage::Temporal`] and [`Stage::Smoother`] to `probe`.
    ///
    /// # Errors
    /// As [`Temporal::update`].
    // Not inlined: its stack frame must not add to its caller's (stack budget).
    #[inline(never)]
    pub fn update_probed<const NT: usize, P: Probe>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        s: usize,
        obs: &LaneObservation<POINTS>,
        probe: &mut P,
    ) -> Result<UpdateInfo, TemporalError> {
        probe.enter(Stage::Temporal);
        let mut g = UpdateParts::EMPTY;
        self.filter.prepare_update(tables, s, obs, &mut g)?;
        self.apply_parts(&g, probe)
    }

    /// Update of lane `s` by row evidence in information form (`J`, `i` on the Gram
    /// components; `TemporalFilter::prepare_info_update`, docs/design.md §11.3), the lags
    /// moved by the same innovation as in [`Temporal::update`].
    ///
    /// # Errors
    /// As [`Temporal::update`]; the state is unchanged.
    #[inline(never)]
    pub fn update_info_probed<const NT: usize, P: Probe>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        s: usize,
        jm: &SMatrix<f32, RANK, RANK>,
        iv: &SVector<f32, RANK>,
        probe: &mut P,
    ) -> Result<UpdateInfo, TemporalError> {
        probe.enter(Stage::Temporal);
        let mut g = UpdateParts::EMPTY;
        self.filter.prepare_info_update(tables, s, jm, iv, &mut g)?;
        self.apply_parts(&g, probe)
    }

    /// Checks gain parts against the filter and every lag, then applies them to both.
    #[inline(always)]
    fn apply_parts<P: Probe>(
        &mut self,
        g: &UpdateParts<RANK, NX>,
        probe: &mut P,
    ) -> Result<UpdateInfo, TemporalError> {
        self.filter.check_update(g)?;
        probe.enter(Stage::Smoother);
        // Check every lag before writing anything.
        let r = g.r as f32;
        let gmax = self.filter.g_max(g);
        let mmax = norm_bound(g.m.as_slice());
        let wmax = norm_bound(g.w.as_slice());
        let a0 = TemporalFilter::<LANES, POINTS, RANK, NX>::index(g.slot, 0, 0);
        let only = self.own_blocks().then_some(g.slot);
        for lag in &self.window {
            let kmax = gain_bound(lag, a0, g.r, only);
            let ok = r * kmax * wmax < SAFE && r * r * kmax * mmax * kmax.max(gmax) < SAFE;
            let finite =
                kmax.is_finite() && mmax.is_finite() && wmax.is_finite() && gmax.is_finite();
            if !(ok && finite) {
                return Err(TemporalError::Numerical);
            }
        }
        let sp = self.filter.spans(g.r);
        for lag in &mut self.window {
            lag_update(lag, g, &sp, a0, only);
        }
        probe.enter(Stage::Temporal);
        self.filter.apply_update(g);
        Ok(UpdateInfo {
            repaired_pivots: g.repaired,
            nis: g.nis,
        })
    }

    /// Repairs the filter's covariance and every lagged lane's covariance block where f32
    /// rounding made them indefinite ([`TemporalFilter::repair_covariance`]: the lag blocks
    /// `Σ_j −= K_j M K_jᵀ` cancel as the filter's covariance does); returns the factorisations
    /// that failed. Call it once per frame after the lane updates (the tracker does). Like the
    /// filter's, it runs when a lane was updated since the last call (the same updates move the
    /// lag blocks).
    ///
    /// # Complexity
    /// `n³/6` multiply-adds for the filter (`n = 2r·lanes`) plus `LAG·lanes·r³/6` for the
    /// window, per factorisation: one each on a healthy covariance, at most
    /// [`crate::temporal::filter::REPAIR_ATTEMPTS`] each.
    pub fn repair_covariance<const NT: usize>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
    ) -> u32 {
        if !self.filter.repair_due() {
            return 0;
        }
        let mut raised = u32::from(self.filter.repair_covariance(tables));
        let r = (tables.gram_rank as usize).min(RANK);
        let runs = 0..r;
        for lag in &mut self.window {
            for (block, present) in lag.blocks.iter_mut().zip(lag.present) {
                if present {
                    raised += u32::from(repair_psd::<RANK>(
                        block.as_mut_slice(),
                        RANK,
                        core::slice::from_ref(&runs),
                    ));
                }
            }
        }
        raised
    }

    /// The smoothed lane in slot `s` `lag` frames back (`1..=LAG`): positions at the index points
    /// and their variances, `None` if the lane was absent then or the window is not that deep yet.
    pub fn lagged<const NT: usize>(
        &self,
        tables: &Tables<NT, LANES, POINTS>,
        s: usize,
        lag: usize,
    ) -> Option<(SVector<f32, POINTS>, SVector<f32, POINTS>)> {
        if lag == 0 || lag > LAG || (self.frames as usize) < lag {
            return None;
        }
        let l = self.window.get(self.slot_of(lag))?;
        if !get(&l.present, s) {
            return None;
        }
        let r = (tables.gram_rank as usize).min(RANK);
        let blk = l.blocks.get(s)?;
        let a: [f32; RANK] = core::array::from_fn(|j| {
            if j < r {
                l.mean.get(s * RANK + j).copied().unwrap_or(0.0)
            } else {
                0.0
            }
        });
        let p: [[f32; RANK]; RANK] = core::array::from_fn(|j| {
            core::array::from_fn(|j2| {
                if j < r && j2 < r {
                    blk.get((j, j2)).copied().unwrap_or(0.0)
                } else {
                    0.0
                }
            })
        });
        Some(project(&tables.gram_eigvec, r, &a, &p))
    }
}

/// Row ranges of the lanes present in a lag, `[t·RANK, t·RANK + r)`, adjacent ones merged.
fn rows_of<const LANES: usize, const RANK: usize>(
    present: [bool; LANES],
    r: usize,
) -> Spans<LANES> {
    let mut sp = Spans::new();
    for t in (0..LANES).filter(|&t| get(&present, t)) {
        sp.push(t * RANK, t * RANK + r);
    }
    sp
}

/// The bound `Σ_k ‖K_j[:, k]‖` of a lag's gain `K_j = C_j[:, a_s]` (`a0` = lane `s`'s first
/// column, `r` components) over the rows the update moves: the present lanes' rows, or with
/// `only = Some(s)` (own blocks) lane `s`'s own. Not inlined: both update paths share it.
#[inline(never)]
fn gain_bound<const LANES: usize, const RANK: usize, const NA: usize, const NX: usize>(
    lag: &Lagged<LANES, RANK, NA, NX>,
    a0: usize,
    r: usize,
    only: Option<usize>,
) -> f32 {
    let runs = match only {
        Some(s) => own_rows::<LANES, RANK>(lag.present, r, s),
        None => rows_of::<LANES, RANK>(lag.present, r),
    };
    (0..r)
        .flat_map(|k| runs.iter().map(move |rg| (k, rg)))
        .filter_map(|(k, rg)| {
            let c0 = (a0 + 2 * k) * NA;
            lag.cross.as_slice().get(c0 + rg.start..c0 + rg.end)
        })
        .map(norm_bound)
        .sum::<f32>()
}

/// Lane `s`'s rows `[s·RANK, s·RANK + r)` if it is present in the lag, else none.
fn own_rows<const LANES: usize, const RANK: usize>(
    present: [bool; LANES],
    r: usize,
    s: usize,
) -> Spans<LANES> {
    let mut sp = Spans::new();
    if s < LANES && get(&present, s) {
        sp.push(s * RANK, s * RANK + r);
    }
    sp
}

/// `C ← C F̄ᵀ` on the present rows and the active column pairs (`coupled = false`: on each
/// column's own lane's rows only, the per-lane smoother's diagonal blocks).
fn times_transition<const LANES: usize, const RANK: usize, const NA: usize, const NX: usize>(
    lag: &mut Lagged<LANES, RANK, NA, NX>,
    sp: &Spans<LANES>,
    f: &Matrix2<f32>,
    r: usize,
    coupled: bool,
) {
    let (f00, f01, f10, f11) = (f.m11, f.m12, f.m21, f.m22);
    let present = lag.present;
    let all = rows_of::<LANES, RANK>(present, r);
    let cs = lag.cross.as_mut_slice();
    for c0 in sp.indices().step_by(2) {
        let Some(pair) = cs.get_mut(c0 * NA..(c0 + 2) * NA) else {
            continue;
        };
        let (a, b) = pair.split_at_mut(NA);
        let rows = if coupled {
            all
        } else {
            own_rows::<LANES, RANK>(present, r, c0 / (2 * RANK))
        };
        for rows in rows.iter() {
            if let (Some(ca), Some(cb)) = (a.get_mut(rows.clone()), b.get_mut(rows)) {
                for (va, vb) in ca.iter_mut().zip(cb.iter_mut()) {
                    let (x0, x1) = (*va, *vb);
                    *va = f00 * x0 + f01 * x1;
                    *vb = f10 * x0 + f11 * x1;
                }
            }
        }
    }
}

/// With `K = C[:, a_s]` (before the update): `a += K w`, `Σ_t −= K_t M K_tᵀ` (per present lane),
/// `C −= K M Gᵀ` on the active columns.
// Not inlined: its stack frame must not add to its caller's (stack budget).
#[inline(never)]
fn lag_update<const LANES: usize, const RANK: usize, const NA: usize, const NX: usize>(
    lag: &mut Lagged<LANES, RANK, NA, NX>,
    g: &UpdateParts<RANK, NX>,
    sp: &Spans<LANES>,
    a0: usize,
    only: Option<usize>,
) {
    let r = g.r;
    let runs = match only {
        None => rows_of::<LANES, RANK>(lag.present, r),
        Some(s) => return lag_update_own(lag, g, a0, s),
    };
    // K = C[:, a_s] and KM = K M, row-major, on the present rows.
    let mut k = [[0.0f32; RANK]; NA];
    for j in 0..r {
        let src = lag
            .cross
            .as_slice()
            .get((a0 + 2 * j) * NA..(a0 + 2 * j + 1) * NA)
            .unwrap_or(&[]);
        for i in runs.indices() {
            if let (Some(row), Some(v)) = (k.get_mut(i), src.get(i)) {
                set(row, j, *v);
            }
        }
    }
    let mut km = [[0.0f32; RANK]; NA];
    let w: [f32; RANK] = core::array::from_fn(|j| g.w.get(j).copied().unwrap_or(0.0));
    for i in runs.indices() {
        if let (Some(kmi), Some(ki)) = (km.get_mut(i), k.get(i)) {
            *kmi = times_sym(ki, &g.m);
            if let Some(m) = lag.mean.get_mut(i) {
                *m += dot(ki, &w);
            }
        }
    }
    // Σ_t −= KM_t K_tᵀ (symmetric: one triangle computed, mirrored).
    for t in 0..LANES {
        if !get(&lag.present, t) {
            continue;
        }
        let (Some(kmt), Some(kt), Some(blk)) = (
            km.get(t * RANK..t * RANK + r),
            k.get(t * RANK..t * RANK + r),
            lag.blocks.get_mut(t),
        ) else {
            continue;
        };
        for (j, kmj) in kmt.iter().enumerate() {
            for (j2, kj2) in kt.iter().enumerate().skip(j) {
                let v = blk.get((j, j2)).copied().unwrap_or(0.0) - dot(kmj, kj2);
                if let Some(e) = blk.get_mut((j, j2)) {
                    *e = v;
                }
                if let Some(e) = blk.get_mut((j2, j)) {
                    *e = v;
                }
            }
        }
    }
    // C[i, col] −= KM_i · G_col on the present rows and the active columns, two columns (a
    // component's position and rate) at a time so that each row of KM is loaded once for both.
    let cs = lag.cross.as_mut_slice();
    for c0 in sp.indices().step_by(2) {
        let (Some(g0), Some(g1)) = (g.g.get(c0), g.g.get(c0 + 1)) else {
            continue;
        };
        let Some(pair) = cs.get_mut(c0 * NA..(c0 + 2) * NA) else {
            continue;
        };
        let (a, b) = pair.split_at_mut(NA);
        for rows in runs.iter() {
            if let (Some(da), Some(db), Some(kr)) = (
                a.get_mut(rows.clone()),
                b.get_mut(rows.clone()),
                km.get(rows),
            ) {
                for ((va, vb), kmi) in da.iter_mut().zip(db.iter_mut()).zip(kr) {
                    *va -= dot(kmi, g0);
                    *vb -= dot(kmi, g1);
                }
            }
        }
    }
}

/// [`lag_update`] on lane `s`'s own block (the per-lane smoother, or the uncoupled model,
/// docs/design.md §4.2.6 and §5.1): `K` and `KM` have only lane `s`'s `r` rows, so they are
/// `RANK × RANK` instead of `NA × RANK` (the dense arrays cleared 2·NA·RANK·4 B per lag and
/// update). The same products in the same order as the dense loops on those rows. Not inlined:
/// inlined into [`lag_update`] it ran the coupled default 0.1 % slower (measured).
#[inline(never)]
fn lag_update_own<const LANES: usize, const RANK: usize, const NA: usize, const NX: usize>(
    lag: &mut Lagged<LANES, RANK, NA, NX>,
    g: &UpdateParts<RANK, NX>,
    a0: usize,
    s: usize,
) {
    let r = g.r.min(RANK);
    if !(s < LANES && get(&lag.present, s)) {
        return;
    }
    let base = s * RANK;
    // K = C[s's rows, a_s] and KM = K M, row-major.
    let mut k = [[0.0f32; RANK]; RANK];
    for j in 0..r {
        let src = lag
            .cross
            .as_slice()
            .get((a0 + 2 * j) * NA + base..(a0 + 2 * j) * NA + base + r)
            .unwrap_or(&[]);
        for (row, v) in k.iter_mut().zip(src) {
            set(row, j, *v);
        }
    }
    let mut km = [[0.0f32; RANK]; RANK];
    let w: [f32; RANK] = core::array::from_fn(|j| g.w.get(j).copied().unwrap_or(0.0));
    let means = lag
        .mean
        .as_mut_slice()
        .get_mut(base..base + r)
        .unwrap_or(&mut []);
    for ((kmi, ki), m) in km.iter_mut().zip(k.iter()).zip(means) {
        *kmi = times_sym(ki, &g.m);
        *m += dot(ki, &w);
    }
    // Σ_s −= KM K_sᵀ (one triangle, mirrored).
    if let Some(blk) = lag.blocks.get_mut(s) {
        for (j, kmj) in km.iter().enumerate().take(r) {
            for (j2, kj2) in k.iter().enumerate().take(r).skip(j) {
                let v = blk.get((j, j2)).copied().unwrap_or(0.0) - dot(kmj, kj2);
                if let Some(e) = blk.get_mut((j, j2)) {
                    *e = v;
                }
                if let Some(e) = blk.get_mut((j2, j)) {
                    *e = v;
                }
            }
        }
    }
    // C[i, col] −= KM_i · G_col on s's rows and s's columns, a component's two at a time.
    let cs = lag.cross.as_mut_slice();
    for c0 in (a0..a0 + 2 * r).step_by(2) {
        let (Some(g0), Some(g1)) = (g.g.get(c0), g.g.get(c0 + 1)) else {
            continue;
        };
        let Some(pair) = cs.get_mut(c0 * NA..(c0 + 2) * NA) else {
            continue;
        };
        let (a, b) = pair.split_at_mut(NA);
        if let (Some(da), Some(db)) = (a.get_mut(base..base + r), b.get_mut(base..base + r)) {
            for ((va, vb), kmi) in da.iter_mut().zip(db.iter_mut()).zip(km.iter()) {
                *va -= dot(kmi, g0);
                *vb -= dot(kmi, g1);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::observation::Status;
    use crate::tables::{DEFAULT, UNCOUPLED};

    type T = Temporal<6, 16, 7, 84, 42, 4>;

    /// A lane near `x0 + slope·u` seen at the index points `present(i)`, noise 0.05² m².
    fn obs(x0: f32, slope: f32, present: impl Fn(usize) -> bool) -> LaneObservation<16> {
        let mut o = LaneObservation::EMPTY;
        o.status = Status::Confirmed;
        for i in 0..16 {
            if present(i) {
                let u = DEFAULT.index_u[i];
                o.present[i] = true;
                o.z[i] = x0 + slope * u + 0.01 * (i as f32 * 1.7).sin();
                o.cov[(i, i)] = 0.0025;
                if i > 0 && o.present[i - 1] {
                    o.cov[(i, i - 1)] = 0.001;
                    o.cov[(i - 1, i)] = 0.001;
                }
            }
        }
        o
    }

    /// Starts, updates (point and information form), dropped frames, a removal and a restart
    /// in the same slot, the per-frame repair, with `dense` forcing the coupled loops.
    fn run(dense: bool) -> (T, [bool; 24]) {
        let mut t = T::new();
        let mut was_uncoupled = [false; 24];
        let mut ranks = [0u8; 6];
        for (s, r) in [(0usize, 0u8), (2, 1), (4, 2)] {
            ranks[s] = r;
            t.start_lane(&UNCOUPLED, s, r, &ranks).unwrap();
        }
        for (k, seen) in was_uncoupled.iter_mut().enumerate() {
            if dense {
                t.filter.force_coupled_loops();
            }
            let dt = if k % 7 == 3 { 0.15 } else { 0.05 };
            t.predict(&UNCOUPLED, dt).unwrap();
            for (n, s) in [0usize, 2, 4].into_iter().enumerate() {
                if !t.filter().is_active(s) || (s == 2 && (5..8).contains(&k)) {
                    continue;
                }
                let x0 = -3.6 + 3.6 * n as f32;
                let o = obs(x0, 0.01, |i| (i + k + n) % 5 != 0 && i < 14 - n);
                t.update(&UNCOUPLED, s, &o).unwrap();
            }
            if k == 10 {
                let jm = SMatrix::<f32, 7, 7>::from_fn(|i, j| {
                    if i == j {
                        4.0 / (1.0 + i as f32)
                    } else {
                        0.0
                    }
                });
                let iv = SVector::<f32, 7>::from_fn(|i, _| 0.3 / (1.0 + i as f32));
                t.update_info_probed(&UNCOUPLED, 4, &jm, &iv, &mut NoProbe)
                    .unwrap();
            }
            t.repair_covariance(&UNCOUPLED);
            if k == 12 {
                t.remove_lane(2);
                t.set_ranks(&[0, 0, 0, 0, 1, 0]).unwrap();
            }
            if k == 15 {
                t.start_lane(&UNCOUPLED, 2, 1, &[0, 0, 1, 0, 2, 0]).unwrap();
            }
            *seen = t.filter().uncoupled();
        }
        (t, was_uncoupled)
    }

    /// With `B` diagonal the own-block loops give exactly the numbers of the coupled loops: the
    /// same filtered state and covariance, the same lagged lanes, bit for bit.
    #[test]
    fn own_block_loops_equal_the_coupled_loops_for_diagonal_b() {
        let (fast, seen) = run(false);
        let (dense, _) = run(true);
        assert!(
            seen.iter().all(|&u| u),
            "B diagonal keeps the filter uncoupled"
        );
        assert_eq!(fast.filter().mean(), dense.filter().mean());
        assert_eq!(fast.filter().covariance(), dense.filter().covariance());
        for s in 0..6 {
            for lag in 1..=4 {
                assert_eq!(
                    fast.lagged(&UNCOUPLED, s, lag),
                    dense.lagged(&UNCOUPLED, s, lag)
                );
            }
        }
        assert!(fast.lagged(&UNCOUPLED, 4, 4).is_some());
        // The sequence moved things: the cross-lane blocks are zero, the own ones are not.
        let p = fast.filter().covariance();
        assert!(p[(0, 0)] > 0.0 && p[(28, 28)] > 0.0);
        assert_eq!(p[(0, 28)], 0.0);
    }

    /// The coupled model leaves the own-block loops at its first conditioned start or
    /// cross-lane noise, and an emptied filter returns to them.
    #[test]
    fn coupling_switches_the_own_block_loops_off_and_emptiness_back_on() {
        let mut t = T::new();
        assert!(t.filter().uncoupled());
        t.start_lane(&DEFAULT, 0, 0, &[0; 6]).unwrap();
        assert!(
            t.filter().uncoupled(),
            "one lane has nothing to be coupled to"
        );
        t.predict(&DEFAULT, 0.05).unwrap();
        assert!(t.filter().uncoupled());
        t.start_lane(&DEFAULT, 1, 1, &[0, 1, 0, 0, 0, 0]).unwrap();
        assert!(!t.filter().uncoupled(), "conditioned on lane 0");
        t.remove_lane(0);
        assert!(!t.filter().uncoupled());
        t.remove_lane(1);
        assert!(t.filter().uncoupled(), "empty");
        // Two unconditioned starts under coupled B: the next prediction's noise couples them.
        let mut u = T::new();
        u.start_lane(&UNCOUPLED, 0, 0, &[0; 6]).unwrap();
        u.start_lane(&UNCOUPLED, 1, 1, &[0, 1, 0, 0, 0, 0]).unwrap();
        assert!(u.filter().uncoupled());
        u.predict(&DEFAULT, 0.05).unwrap();
        assert!(!u.filter().uncoupled(), "cross-lane process noise");
        assert_ne!(u.filter().covariance()[(0, 14)], 0.0);
    }
}
