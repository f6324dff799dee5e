//! The fixed-lag coupled smoother (DESIGN 5), exact, by state augmentation of the lagged lane
//! coefficients only.
//!
//! For each lag `j = 1..=LAG` the window keeps the lagged position coefficients `a_{k−j}` of every
//! lane (`NA = LANES·RANK` numbers), their per-lane `RANK×RANK` covariance blocks (what is
//! published: a lane's smoothed positions and variances at the index points), and the
//! cross-covariance `C_j = Cov(a_{k−j}, x_k)` with the current state (`NA × NX`). A prediction
//! shifts the window and maps `C_j ← C_j F̄ᵀ`; a lane update with gain parts
//! `(P Hᵀ, S⁻¹, S⁻¹ν, S⁻¹ H P)` moves every lag by the same innovation:
//! `a_{k−j} += C_j Hᵀ S⁻¹ ν`, `Σ_j −= C_j Hᵀ S⁻¹ H C_jᵀ`, `C_j −= C_j Hᵀ S⁻¹ H P`. This is the
//! Kalman filter of the augmented state `[x_k, a_{k−1}, …, a_{k−L}]` restricted to the blocks the
//! output needs, so `a_{k−L|k}` equals the RTS fixed-lag estimate `x_{k−L|k}` exactly, with no
//! inverse of the predicted covariance (the RTS gain `P_{k|k} Fᵀ P_{k+1|k}⁻¹` would need an
//! 84×84 factorisation of a numerically singular matrix).
//!
//! # RAM
//! `LAG · 4 · (NA + LANES·RANK² + NA·NX)` bytes: 62 KiB at 6 lanes, rank 7, L = 4 — the largest
//! item of the tracker, as DESIGN 5 expects.
//!
//! # Cost
//! Per prediction `LAG · 4·NA·NX`; per lane update `LAG · (NA·RANK·m + NA·m·NX + m²·NA)` with
//! `m ≤ POINTS` present points.

use nalgebra::{SMatrix, SVector};

use super::filter::{times_blockdiag_t, TemporalError, TemporalFilter, UpdateParts};
use crate::probe::{NoProbe, Probe, Stage};
use crate::spatial::filter::LaneObservation;
use crate::spatial::{get, set};
use crate::tables::Tables;

/// One lag of the window.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Lagged<const LANES: usize, const RANK: usize, const NA: usize, const NX: usize> {
    mean: SVector<f32, NA>,
    blocks: [SMatrix<f32, RANK, RANK>; LANES],
    cross: SMatrix<f32, NA, NX>,
    present: [bool; LANES],
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
    window: [Lagged<LANES, RANK, NA, NX>; LAG],
    frames: u32,
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
        const { assert!(LAG >= 1 && LAG <= 16, "LAG must be 1..=16") };
        Self {
            filter: TemporalFilter::new(),
            window: [Self::EMPTY; LAG],
            frames: 0,
        }
    }

    /// The filter (filtered lanes at the current frame).
    pub fn filter(&self) -> &TemporalFilter<LANES, POINTS, RANK, NX> {
        &self.filter
    }

    /// Frames predicted so far (the window is full once this reaches `LAG`).
    pub fn frames(&self) -> u32 {
        self.frames
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
    pub fn start_lane<const NT: usize>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        s: usize,
        rank: u8,
        ranks: &[u8; LANES],
    ) -> Result<(), TemporalError> {
        let active_before = core::array::from_fn::<bool, LANES, _>(|t| self.filter.is_active(t));
        let a = self.filter.start_lane(tables, s, rank, ranks)?;
        let r = (tables.gram_rank as usize).min(RANK);
        for lag in self.window.iter_mut() {
            for j in 0..RANK {
                for c in 0..2 {
                    let col = TemporalFilter::<LANES, POINTS, RANK, NX>::index(s, j, c);
                    for row in 0..NA {
                        let mut v = 0.0;
                        if j < r {
                            for t in (0..LANES).filter(|&t| get(&active_before, t)) {
                                let ct = TemporalFilter::<LANES, POINTS, RANK, NX>::index(t, j, c);
                                v += get(&a, t) * lag.cross.get((row, ct)).copied().unwrap_or(0.0);
                            }
                        }
                        if let Some(e) = lag.cross.get_mut((row, col)) {
                            *e = v;
                        }
                    }
                }
            }
        }
        Ok(())
    }

    /// Removes a lane from the filter (its lagged history stays in the window until it ages out).
    pub fn remove_lane(&mut self, s: usize) {
        self.filter.remove_lane(s);
        for lag in self.window.iter_mut() {
            for j in 0..RANK {
                for c in 0..2 {
                    let col = TemporalFilter::<LANES, POINTS, RANK, NX>::index(s, j, c);
                    for row in 0..NA {
                        if let Some(e) = lag.cross.get_mut((row, col)) {
                            *e = 0.0;
                        }
                    }
                }
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
    pub fn predict_probed<const NT: usize, P: Probe>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        t: f32,
        probe: &mut P,
    ) -> Result<(), TemporalError> {
        probe.enter(Stage::Temporal);
        let (f, _) = tables
            .temporal
            .kernel
            .transition(t)
            .ok_or(TemporalError::BadStep)?;
        // Snapshot of x_k, P_k for the new lag 1.
        let x = *self.filter.mean();
        let p = *self.filter.covariance();
        self.filter.predict(tables, t)?;
        probe.enter(Stage::Smoother);
        for j in (1..LAG).rev() {
            if let Some(prev) = self.window.get(j - 1).copied() {
                if let Some(w) = self.window.get_mut(j) {
                    *w = prev;
                }
            }
        }
        let mut fresh = Self::EMPTY;
        let ia = |s: usize, j: usize| TemporalFilter::<LANES, POINTS, RANK, NX>::index(s, j, 0);
        for s in 0..LANES {
            let on = self.filter.is_active(s);
            set(&mut fresh.present, s, on);
            if !on {
                continue;
            }
            for j in 0..RANK {
                if let Some(m) = fresh.mean.get_mut(s * RANK + j) {
                    *m = x.get(ia(s, j)).copied().unwrap_or(0.0);
                }
                for col in 0..NX {
                    if let Some(e) = fresh.cross.get_mut((s * RANK + j, col)) {
                        *e = p.get((ia(s, j), col)).copied().unwrap_or(0.0);
                    }
                }
            }
            if let Some(b) = fresh.blocks.get_mut(s) {
                *b = SMatrix::from_fn(|j, j2| p.get((ia(s, j), ia(s, j2))).copied().unwrap_or(0.0));
            }
        }
        if let Some(w) = self.window.get_mut(0) {
            *w = fresh;
        }
        for lag in self.window.iter_mut() {
            times_blockdiag_t(&mut lag.cross, &f);
        }
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
    ) -> Result<(), TemporalError> {
        self.update_probed(tables, s, obs, &mut NoProbe)
    }

    /// [`Temporal::update`] reporting [`Stage::Temporal`] and [`Stage::Smoother`] to `probe`.
    ///
    /// # Errors
    /// As [`Temporal::update`].
    pub fn update_probed<const NT: usize, P: Probe>(
        &mut self,
        tables: &Tables<NT, LANES, POINTS>,
        s: usize,
        obs: &LaneObservation<POINTS>,
        probe: &mut P,
    ) -> Result<(), TemporalError> {
        probe.enter(Stage::Temporal);
        let g = self.filter.prepare_update(tables, s, obs)?;
        probe.enter(Stage::Smoother);
        let mut window = self.window;
        for lag in window.iter_mut() {
            lag_update(lag, &g, tables);
        }
        let finite = window.iter().all(|l| {
            l.mean.iter().chain(l.cross.iter()).all(|v| v.is_finite())
                && l.blocks.iter().all(|b| b.iter().all(|v| v.is_finite()))
        });
        if !finite {
            return Err(TemporalError::Numerical);
        }
        probe.enter(Stage::Temporal);
        self.filter.commit_update(&g)?;
        self.window = window;
        Ok(())
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
        let l = self.window.get(lag - 1)?;
        if !get(&l.present, s) {
            return None;
        }
        let r = (tables.gram_rank as usize).min(RANK);
        let v = &tables.gram_eigvec;
        let vg = |i: usize, j: usize| v.get((i, j)).copied().unwrap_or(0.0);
        let blk = l.blocks.get(s)?;
        let mean = SVector::<f32, POINTS>::from_fn(|i, _| {
            (0..r)
                .map(|j| vg(i, j) * l.mean.get(s * RANK + j).copied().unwrap_or(0.0))
                .sum()
        });
        let var = SVector::<f32, POINTS>::from_fn(|i, _| {
            let mut acc = 0.0;
            for j in 0..r {
                for j2 in 0..r {
                    acc += vg(i, j) * vg(i, j2) * blk.get((j, j2)).copied().unwrap_or(0.0);
                }
            }
            acc
        });
        Some((mean, var))
    }
}

/// `a += C Hᵀ S⁻¹ν`, `Σ −= C Hᵀ S⁻¹ H Cᵀ` (per-lane blocks), `C −= C Hᵀ S⁻¹ H P`.
fn lag_update<
    const LANES: usize,
    const POINTS: usize,
    const RANK: usize,
    const NA: usize,
    const NX: usize,
    const NT: usize,
>(
    lag: &mut Lagged<LANES, RANK, NA, NX>,
    g: &UpdateParts<POINTS, NX>,
    tables: &Tables<NT, LANES, POINTS>,
) {
    let v = &tables.gram_eigvec;
    let vg = |i: usize, j: usize| v.get((i, j)).copied().unwrap_or(0.0);
    // CH = C Hᵀ (NA × POINTS), columns of the updated slot's position coefficients.
    let mut ch = SMatrix::<f32, NA, POINTS>::zeros();
    for i in (0..POINTS).filter(|&i| get(&g.used, i)) {
        for row in 0..NA {
            let mut acc = 0.0;
            for j in 0..g.rank_used {
                let col = (g.slot * RANK + j) * 2;
                acc += lag.cross.get((row, col)).copied().unwrap_or(0.0) * vg(i, j);
            }
            if let Some(e) = ch.get_mut((row, i)) {
                *e = acc;
            }
        }
    }
    lag.mean += ch * g.w;
    let y = g.chol.solve(&ch.transpose()); // S⁻¹ H Cᵀ (POINTS × NA)
    for (s, blk) in lag.blocks.iter_mut().enumerate() {
        if !get(&lag.present, s) {
            continue;
        }
        for j in 0..RANK {
            for j2 in 0..RANK {
                let mut acc = 0.0;
                for i in 0..POINTS {
                    acc += ch.get((s * RANK + j, i)).copied().unwrap_or(0.0)
                        * y.get((i, s * RANK + j2)).copied().unwrap_or(0.0);
                }
                if let Some(e) = blk.get_mut((j, j2)) {
                    *e -= acc;
                }
            }
        }
        *blk = (*blk + blk.transpose()) * 0.5;
    }
    lag.cross -= ch * g.kt;
}
