//! The whole per-frame pipeline in dense f64: the oracle of the core's `Tracker::step`
//! (`src/tracker/`), built from the other references and following the core step by step.
//!
//! One frame (`ReferencePipeline::step`):
//! 1. spatial frame: [`spatial::run_frame`] on the first `max_points` points; its confirmed and
//!    ended tracks (rank order) are the observations;
//! 2. temporal prediction over the frame step `T` (not on the first frame) of the dense coupled
//!    state ([`CoupledTemporalModel`] over the current lanes in rank order, all `N` index points,
//!    full `K_u`);
//! 3. lane identity: [`identity::assign`] of the observations (curve: pseudo-measurements and the
//!    diagonal of their covariance) against the predictions of the live slots (mean and variance of
//!    `f` at every index point, all points present); matched lanes reset their misses, unmatched
//!    lanes coast or are removed at `max_misses`, unmatched observations with at least
//!    `min_common` valid points start lanes in the lowest free slot, in input order;
//! 4. removed lanes leave the dense state (their rows and columns are deleted);
//! 5. new lanes start in slot order, each at its rank from the left among the lanes present
//!    (positions: the new lane's first present pseudo-measurement, the others' current mean at
//!    index point 0; ties by slot); the others are re-ordered to their new ranks and the new lane's
//!    block is the conditional of the prior `(B_n ⊗ K_u) ⊗ P∞_t` given the other lanes' states,
//!    `x_new = Σ_t a_t x_t + w`, `a_t = −Λ_{k,ρ(t)}/Λ_kk`, `Λ = B_n⁻¹`,
//!    `w ~ N(0, (K_u ⊗ P∞_t)/Λ_kk)`, applied to the current moments (as the core does);
//! 6. the seen lanes are updated (one stacked update, which equals the core's sequential per-lane
//!    updates: the lanes' measurement noises are independent);
//! 7. re-rank by the filtered mean at index point 0 (ties by slot): the state's blocks are
//!    permuted;
//! 8. fixed-lag output: `x_{k−L|k}` by RTS ([`rts_step`]) over the stored dense steps, when the
//!    lane set and order did not change in the window (otherwise not comparable: counted).
//!
//! # Choices where the core's contract leaves room (read from `src/tracker/` and mirrored)
//! * No prediction on the first frame; afterwards every frame predicts by its own `T`, also with
//!   no lanes and in blackout frames (empty frames: all lanes coast, filtered = predicted).
//! * Points beyond `max_points` are dropped before the spatial frame (the core's `MEAS`); all the
//!   spatial frame's confirmed and ended tracks are observations, in rank order, at most `D`.
//! * Identity predictions are the moments right after the prediction, before removals and starts.
//! * A lane removed and a lane started in the same slot in one frame: the old block is deleted
//!   first, the new lane starts after (the core's `SlotFate::New { replaced }`).
//! * The rank position of a lane is its mean at index point 0 (every index point is present in
//!   a temporal lane), of a new lane its first present pseudo-measurement; ties go to the lower
//!   slot, NaN positions last. Lanes already started this frame are ranked by their (conditional)
//!   mean, as the core does.
//! * After a removal the remaining lanes keep their order until the next start or the re-rank at
//!   the end of the frame (the core's ranks keep their gaps until then; B is only read by a start
//!   and by the next prediction, when they are a permutation again).
//! * Pseudo-measurement covariance: the spatial reference's `pseudo_cov` (+ `r₀² I`, added by
//!   [`CoupledTemporalModel::measurement`]); a non-finite pseudo-measurement counts as missing.
//! * Existence: the spatial existence when seen, multiplied by `existence_decay` when not; the
//!   smoothed lanes carry the newest frame's existence and the ids of frame `k − L`, as the core.
//! * Variances are the dense marginals of `f` at the index points (the core's are those of its
//!   truncated basis: see `tests/tracker_equivalence.rs` for the effect).
//! * The fixed-lag output is computed on demand ([`ReferencePipeline::lagged`]): four RTS steps
//!   with an SVD each are the costliest part of the reference.

use std::collections::VecDeque;

use anyhow::{bail, ensure, Context, Result};
use nalgebra::{DMatrix, DVector};

use crate::identity::{self, Curve, Gate};
use crate::model::ModelTables;
use crate::spatial::{self, FrameResult, Model};
use crate::temporal::{
    predict, rts_step, update, CoupledTemporalModel, FilterStep, Gaussian, LaneMeasurement,
};

/// Tuning of the reference pipeline (the core's `TrackerConfig::DEFAULT` and capacities).
#[derive(Debug, Clone, PartialEq)]
pub struct PipelineConfig {
    /// The spatial reference's configuration.
    pub spatial: spatial::Config,
    /// Points kept per BEV row (the core's `PER_ROW`).
    pub per_row: usize,
    /// Points used per frame (the core's `MEAS`); the rest are ignored.
    pub max_points: usize,
    /// Identity gate (mean normalised squared distance per common point).
    pub gate: f64,
    /// Fewest common points of a pair, and fewest valid points to start a lane.
    pub min_common: usize,
    /// A lane is removed at this many consecutive misses.
    pub max_misses: usize,
    /// Existence factor per frame without an observation.
    pub existence_decay: f64,
    /// Fixed lag `L`.
    pub lag: usize,
}

impl PipelineConfig {
    /// The core's defaults at the reference configuration: spatial `Config::from_tables`, 16
    /// points per row, 256 points per frame, gate 9, `min_common` 3, `max_misses` 10, existence
    /// decay 0.8, lag 4.
    pub fn from_tables(t: &ModelTables) -> Self {
        Self {
            spatial: spatial::Config::from_tables(t),
            per_row: 16,
            max_points: 256,
            gate: 9.0,
            min_common: 3,
            max_misses: 10,
            existence_decay: 0.8,
            lag: 4,
        }
    }
}

/// One lane as published by the reference.
#[derive(Debug, Clone, PartialEq)]
pub struct RefLane {
    /// Reference id (its own counter from 0; compare with the core's ids as a bijection).
    pub id: u32,
    /// Slot (lowest free slot at the start, as in the core).
    pub slot: usize,
    /// Mean of `f` at the index points.
    pub z: Vec<f64>,
    /// Variance of `f` at the index points.
    pub var: Vec<f64>,
    /// Existence (spatial existence when seen, decaying while coasting).
    pub existence: f64,
    /// Consecutive misses.
    pub misses: usize,
}

/// What one reference frame produced.
#[derive(Debug, Clone)]
pub struct RefStepOutput {
    /// The spatial frame.
    pub spatial: FrameResult,
    /// Filtered lanes, in slot order.
    pub filtered: Vec<RefLane>,
    /// Lanes started this frame.
    pub started: usize,
    /// Lanes removed this frame.
    pub removed: usize,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Meta {
    id: u32,
    misses: usize,
    existence: f64,
}

#[derive(Debug, Clone)]
struct Hist {
    step: FilterStep,
    /// Slots of the dense blocks during the update (rank order before the re-rank).
    order_filtered: Vec<usize>,
    /// Slots after the re-rank.
    order_after: Vec<usize>,
    /// A lane started or was removed this frame.
    structural: bool,
    /// Ids by slot at the end of the frame.
    ids: Vec<Option<u32>>,
    /// Existence by slot at the end of the frame.
    existence: Vec<f64>,
}

/// The dense f64 pipeline (see the module docs).
#[derive(Debug, Clone)]
pub struct ReferencePipeline {
    model: Model,
    temporal: CoupledTemporalModel,
    cfg: PipelineConfig,
    slots: Vec<Option<Meta>>,
    /// Slots in rank order (the dense state's lane blocks).
    order: Vec<usize>,
    state: Gaussian,
    next_id: u32,
    last: Option<f64>,
    history: VecDeque<Hist>,
}

fn first_present(z: &[Option<f64>]) -> Option<f64> {
    z.iter().flatten().copied().find(|v| v.is_finite())
}

/// Rank order of `slots` by position, ties by slot (NaN positions last).
fn rank_order(mut items: Vec<(usize, f64)>) -> Vec<usize> {
    items.sort_by(|a, b| {
        let (pa, pb) = (a.1, b.1);
        match (pa.is_nan(), pb.is_nan()) {
            (false, true) => std::cmp::Ordering::Less,
            (true, false) => std::cmp::Ordering::Greater,
            (true, true) => a.0.cmp(&b.0),
            (false, false) => pa.total_cmp(&pb).then(a.0.cmp(&b.0)),
        }
    });
    items.into_iter().map(|(s, _)| s).collect()
}

impl ReferencePipeline {
    /// A pipeline on `tables` (spatial model with `k` rows between index points).
    pub fn new(tables: &ModelTables, k: usize, cfg: PipelineConfig) -> Result<Self> {
        let model = Model::new(tables, k)?;
        let temporal = CoupledTemporalModel::from_tables(tables)?;
        ensure!(
            model.points == temporal.points(),
            "spatial model has {} index points, temporal {}",
            model.points,
            temporal.points()
        );
        let d = temporal.max_lanes();
        Ok(Self {
            model,
            temporal,
            cfg,
            slots: vec![None; d],
            order: Vec::new(),
            state: Gaussian::new(DVector::zeros(0), DMatrix::zeros(0, 0))?,
            next_id: 0,
            last: None,
            history: VecDeque::new(),
        })
    }

    fn n(&self) -> usize {
        self.temporal.points()
    }

    /// Mean and variance of slot `s`'s `f` at the index points in `g` with lane order `order`.
    fn lane_moments(
        &self,
        g: &Gaussian,
        order: &[usize],
        s: usize,
    ) -> Option<(Vec<f64>, Vec<f64>)> {
        let pos = order.iter().position(|&t| t == s)?;
        let n = self.n();
        let ix = |i: usize| (pos * n + i) * 2;
        Some((
            (0..n).map(|i| g.mean[ix(i)]).collect(),
            (0..n).map(|i| g.cov[(ix(i), ix(i))]).collect(),
        ))
    }

    /// Permutes the state's lane blocks from `self.order` to `new_order` (same slots).
    fn permute(&mut self, new_order: &[usize]) {
        let b = 2 * self.n();
        let src: Vec<usize> = new_order
            .iter()
            .flat_map(|s| {
                let p = self.order.iter().position(|t| t == s).unwrap_or(0);
                (p * b..(p + 1) * b).collect::<Vec<_>>()
            })
            .collect();
        let mean = DVector::from_iterator(src.len(), src.iter().map(|&i| self.state.mean[i]));
        let cov = DMatrix::from_fn(src.len(), src.len(), |i, j| {
            self.state.cov[(src[i], src[j])]
        });
        self.state = Gaussian { mean, cov };
        self.order = new_order.to_vec();
    }

    /// Deletes slot `s`'s block from the state.
    fn remove(&mut self, s: usize) {
        let Some(p) = self.order.iter().position(|&t| t == s) else {
            return;
        };
        let b = 2 * self.n();
        let keep: Vec<usize> = (0..self.state.dim())
            .filter(|i| !(p * b..(p + 1) * b).contains(i))
            .collect();
        let mean = DVector::from_iterator(keep.len(), keep.iter().map(|&i| self.state.mean[i]));
        let cov = DMatrix::from_fn(keep.len(), keep.len(), |i, j| {
            self.state.cov[(keep[i], keep[j])]
        });
        self.state = Gaussian { mean, cov };
        self.order.remove(p);
    }

    /// Starts slot `s` at lateral position `x` (step 5 of the module docs).
    fn start(&mut self, s: usize, x: f64) -> Result<()> {
        let n = self.n();
        let b = 2 * n;
        let mut items: Vec<(usize, f64)> = self
            .order
            .iter()
            .enumerate()
            .map(|(p, &t)| (t, self.state.mean[p * b]))
            .collect();
        items.push((s, x));
        let full = rank_order(items);
        let k = full
            .iter()
            .position(|&t| t == s)
            .context("new lane not ranked")?;
        let others: Vec<usize> = full.iter().copied().filter(|&t| t != s).collect();
        self.permute(&others);
        let m = full.len();
        ensure!(m <= self.temporal.max_lanes(), "too many lanes");
        let bm = self.temporal.coreg.view((0, 0), (m, m)).clone_owned();
        let lam = bm
            .cholesky()
            .context("B block is not positive definite")?
            .inverse();
        let lkk = lam[(k, k)];
        ensure!(lkk.is_finite() && lkk > 0.0, "Λ_kk = {lkk}");
        // a over the others' blocks (positions in `others`, ranks in `full`).
        let a: Vec<f64> = others
            .iter()
            .map(|t| {
                let r = full.iter().position(|u| u == t).unwrap_or(0);
                -lam[(k, r)] / lkk
            })
            .collect();
        let old_dim = self.state.dim();
        // T maps the old state to the new lane's mean part: x_new = T x_old + w.
        let mut t = DMatrix::<f64>::zeros(b, old_dim);
        for (q, &aq) in a.iter().enumerate() {
            for i in 0..b {
                t[(i, q * b + i)] = aq;
            }
        }
        let w = self
            .temporal
            .gram
            .kronecker(&self.temporal.temporal.p_inf_closed())
            / lkk;
        let new_mean = &t * &self.state.mean;
        let cross = &t * &self.state.cov; // b × old
        let own = &cross * t.transpose() + w;
        // Insert at block position k.
        let dim = old_dim + b;
        let at = k * b;
        let map_old = |i: usize| if i < at { i } else { i + b };
        let mut mean = DVector::zeros(dim);
        let mut cov = DMatrix::zeros(dim, dim);
        for i in 0..old_dim {
            mean[map_old(i)] = self.state.mean[i];
            for j in 0..old_dim {
                cov[(map_old(i), map_old(j))] = self.state.cov[(i, j)];
            }
        }
        for i in 0..b {
            mean[at + i] = new_mean[i];
            for j in 0..old_dim {
                cov[(at + i, map_old(j))] = cross[(i, j)];
                cov[(map_old(j), at + i)] = cross[(i, j)];
            }
            for j in 0..b {
                cov[(at + i, at + j)] = own[(i, j)];
            }
        }
        self.state = Gaussian { mean, cov };
        self.order = full;
        Ok(())
    }

    /// One frame at time `now` (seconds) with points `(u, x)`.
    ///
    /// # Errors
    /// A non-increasing time, or a numerical failure of a reference stage.
    #[allow(clippy::too_many_lines)]
    pub fn step(&mut self, now: f64, points: &[(f64, f64)]) -> Result<RefStepOutput> {
        let dt = match self.last {
            Some(last) if now <= last => bail!("time does not increase: {now} after {last}"),
            Some(last) => Some(now - last),
            None => None,
        };
        let n = self.n();
        let used = points.len().min(self.cfg.max_points);
        // 1. Spatial frame.
        let frame = spatial::run_frame(
            &self.model,
            &self.cfg.spatial,
            &points[..used],
            self.cfg.per_row,
        );
        let obs: Vec<&spatial::TrackOutput> = frame.tracks.iter().take(self.slots.len()).collect();
        // 2. Prediction.
        let mut transition = None;
        if let Some(dt) = dt {
            if !self.order.is_empty() {
                let lanes = self.order.len();
                let f = self.temporal.transition(lanes, dt)?;
                let q = self.temporal.process_noise(lanes, dt)?;
                self.state = predict(&self.state, &f, &q)?;
                transition = Some(f);
            }
        }
        // 3. Identity.
        let curves: Vec<Curve> = obs
            .iter()
            .map(|t| Curve {
                present: t.pseudo.iter().map(Option::is_some).collect(),
                z: t.pseudo.iter().map(|p| p.unwrap_or(0.0)).collect(),
                var: (0..n).map(|i| t.pseudo_cov[(i, i)]).collect(),
            })
            .collect();
        let preds: Vec<Option<Curve>> = (0..self.slots.len())
            .map(|s| {
                self.slots[s]?;
                let (z, var) = self.lane_moments(&self.state, &self.order, s)?;
                Some(Curve {
                    present: vec![true; n],
                    z,
                    var,
                })
            })
            .collect();
        let gate = Gate {
            gate: self.cfg.gate,
            min_common: self.cfg.min_common,
        };
        let lane_of = identity::assign(&curves, &preds, gate).best.lane_of;
        let mut seen: Vec<Option<usize>> = vec![None; self.slots.len()];
        for (o, l) in lane_of.iter().enumerate() {
            if let Some(l) = *l {
                seen[l] = Some(o);
            }
        }
        let mut removed = Vec::new();
        for (s, (slot, seen_s)) in self.slots.iter_mut().zip(&seen).enumerate() {
            if let Some(meta) = slot.as_mut() {
                if seen_s.is_some() {
                    meta.misses = 0;
                } else {
                    meta.misses += 1;
                    if meta.misses >= self.cfg.max_misses {
                        *slot = None;
                        removed.push(s);
                    }
                }
            }
        }
        let mut started = Vec::new();
        for (o, l) in lane_of.iter().enumerate() {
            if l.is_some() {
                continue;
            }
            let c = &curves[o];
            let valid = (0..n)
                .filter(|&i| {
                    c.present[i] && c.z[i].is_finite() && c.var[i].is_finite() && c.var[i] >= 0.0
                })
                .count();
            if valid < self.cfg.min_common {
                continue;
            }
            let Some(free) = self.slots.iter().position(Option::is_none) else {
                continue;
            };
            self.slots[free] = Some(Meta {
                id: self.next_id,
                misses: 0,
                existence: 0.0,
            });
            self.next_id += 1;
            seen[free] = Some(o);
            started.push(free);
        }
        // 4. Removed lanes leave the state.
        for &s in &removed {
            self.remove(s);
        }
        // 5. New lanes start in slot order.
        started.sort_unstable();
        for &s in &started {
            let o = seen[s].context("started lane without observation")?;
            let x = first_present(&obs[o].pseudo).unwrap_or(0.0);
            self.start(s, x)?;
        }
        // 6. Update the seen lanes.
        let predicted = self.state.clone();
        if !self.order.is_empty() {
            let meas: Vec<Option<LaneMeasurement>> = self
                .order
                .iter()
                .map(|&s| {
                    let o = obs[seen[s]?];
                    Some(LaneMeasurement {
                        z: o.pseudo
                            .iter()
                            .map(|p| p.filter(|v| v.is_finite()))
                            .collect(),
                        cov: o.pseudo_cov.clone(),
                    })
                })
                .collect();
            let sm = self.temporal.measurement(&meas)?;
            self.state = update(&self.state, &sm.h, &sm.r, &sm.z)?;
        }
        for (slot, seen_s) in self.slots.iter_mut().zip(&seen) {
            if let Some(meta) = slot.as_mut() {
                match *seen_s {
                    Some(o) => meta.existence = obs[o].existence,
                    None => meta.existence *= self.cfg.existence_decay,
                }
            }
        }
        let filtered_state = self.state.clone();
        let order_filtered = self.order.clone();
        // 7. Re-rank.
        let items: Vec<(usize, f64)> = self
            .order
            .iter()
            .enumerate()
            .map(|(p, &t)| (t, self.state.mean[p * 2 * n]))
            .collect();
        let new_order = rank_order(items);
        self.permute(&new_order);
        // Output.
        let filtered: Vec<RefLane> = (0..self.slots.len())
            .filter_map(|s| {
                let meta = self.slots[s]?;
                let (z, var) = self.lane_moments(&self.state, &self.order, s)?;
                Some(RefLane {
                    id: meta.id,
                    slot: s,
                    z,
                    var,
                    existence: meta.existence,
                    misses: meta.misses,
                })
            })
            .collect();
        // 8. History and the fixed-lag output.
        let lag = self.cfg.lag;
        self.history.push_back(Hist {
            step: FilterStep {
                transition,
                predicted,
                filtered: filtered_state,
            },
            order_filtered,
            order_after: self.order.clone(),
            structural: !(started.is_empty() && removed.is_empty()),
            ids: self.slots.iter().map(|m| m.map(|m| m.id)).collect(),
            existence: self
                .slots
                .iter()
                .map(|m| m.map_or(0.0, |m| m.existence))
                .collect(),
        });
        while self.history.len() > lag + 1 {
            self.history.pop_front();
        }
        self.last = Some(now);
        Ok(RefStepOutput {
            spatial: frame,
            filtered,
            started: started.len(),
            removed: removed.len(),
        })
    }

    /// Whether the fixed-lag output of the newest frame can be computed: `None` before the window
    /// holds `L + 1` frames, `Some(false)` when a lane started or was removed in the last `L`
    /// frames or a re-rank permuted the lanes inside the window (not comparable), else
    /// `Some(true)`.
    pub fn window_comparable(&self) -> Option<bool> {
        let lag = self.cfg.lag;
        let h = &self.history;
        if h.len() != lag + 1 {
            return None;
        }
        Some(
            !h[0].order_filtered.is_empty()
                && (1..=lag).all(|j| {
                    !h[j].structural
                        && h[j].step.transition.is_some()
                        && h[j - 1].order_after == h[j - 1].order_filtered
                        && h[j].order_filtered == h[j - 1].order_after
                }),
        )
    }

    /// The smoothed lanes `L` frames back, `x_{k−L|k}`, by `L` RTS steps ([`rts_step`], SVD
    /// pseudo-inverse where `P_{k+1|k}` is singular) back from the newest filtered state over the
    /// stored dense steps, in slot order (ids of frame `k − L`, existence of frame `k`); `None`
    /// unless [`ReferencePipeline::window_comparable`].
    ///
    /// # Errors
    /// A failed RTS step.
    pub fn lagged(&self) -> Result<Option<Vec<RefLane>>> {
        if self.window_comparable() != Some(true) {
            return Ok(None);
        }
        let lag = self.cfg.lag;
        let h = &self.history;
        let mut sm = h[lag].step.filtered.clone();
        for j in (0..lag).rev() {
            sm = rts_step(&h[j].step, &h[j + 1].step, &sm)
                .with_context(|| format!("fixed-lag RTS step {j}"))?
                .0;
        }
        let order = &h[0].order_filtered;
        let mut slots = order.clone();
        slots.sort_unstable();
        Ok(Some(
            slots
                .into_iter()
                .filter_map(|s| {
                    let (z, var) = self.lane_moments(&sm, order, s)?;
                    Some(RefLane {
                        id: h[0].ids[s]?,
                        slot: s,
                        z,
                        var,
                        existence: h[lag].existence[s],
                        misses: 0,
                    })
                })
                .collect(),
        ))
    }
}
