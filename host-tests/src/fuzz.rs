//! Fuzz harness of `stjpdacf`: each public function takes arbitrary bytes, drives one part of the
//! core with them and checks the core's invariants, returning `Err(description)` for the first
//! one broken. The cargo-fuzz targets (`fuzz/fuzz_targets/*.rs`) panic on `Err`;
//! `host-tests/tests/fuzz_corpus.rs` runs the same bodies over the committed corpora as plain
//! tests. This module needs only the core, `nalgebra`, `arbitrary` and `crc32fast` (the fuzz
//! crate builds this crate without its default `host` feature).
//!
//! Targets:
//! * [`tracker_step`]: `ReferenceTracker::step` on up to [`MAX_STEPS`] frames per input: lane-like
//!   point sets (0–6 lanes, any offset, slope, curvature, noise and detection rate), raw `f32`
//!   bit patterns (NaN, ±inf, subnormals, huge), special values at and beyond the window edges,
//!   any count (up to ~870, beyond `MEAS` = 256), and any timestamps (nominal, repeats,
//!   reversals, microsecond steps, days, any `i64`).
//! * [`temporal_ops`]: the temporal filter and fixed-lag smoother (`Temporal`) alone, under any
//!   sequence of predict (any step), start (any slot and ranks), update (any present mask, any
//!   positions, PSD covariances from 1e-10 to 1e2 m² and injected NaN/inf), remove, re-rank.
//! * [`tables_validate`]: `Tables::validate` on the default tables after arbitrary mutations
//!   (raw values, special values, scaling, symmetric edits and consistent rescalings that the
//!   validator should accept); tables it accepts then run through the spatial and temporal
//!   filters.
//!
//! Invariants (all targets, where they apply): no panic; every published number finite; published
//! variances ≥ 0; existence in [0, 1]; extents inside the window and ordered; ≤ `LANES` lanes;
//! ids and slots unique; counters consistent with the input; a refused step or failed operation
//! leaves the state untouched; the temporal covariance finite, symmetric within [`crate::invariants::ASYM_TOL`] and
//! positive semi-definite within [`crate::invariants::PSD_TOL`] (both in correlation form, see [`cov_health`]).

use arbitrary::Unstructured;
use nalgebra::SMatrix;
use stjpdacf::spatial::filter::{Config as SpatialConfig, LaneObservation, SpatialFilter, Status};
use stjpdacf::tables::{ReferenceTables, DEFAULT};
use stjpdacf::temporal::smoother::Temporal;
use stjpdacf::tracker::{Instant, ReferenceTracker, StepError};
use stjpdacf::wire::{self, FrameInfo, LinkStats, Receiver, WireError};

use crate::invariants::present_indices;
pub use crate::invariants::{
    check_output, check_temporal, check_tracker, cov_health, CovHealth, PsdCheck, LANES, MEAS, NX,
    POINTS, RANK,
};
/// Frames per [`tracker_step`] input.
pub const MAX_STEPS: usize = 16;
/// Operations per [`temporal_ops`] input.
pub const MAX_OPS: usize = 48;

/// A tiny deterministic generator (SplitMix64) for noise inside a decoded frame, so that a few
/// input bytes describe a whole lane.
#[derive(Debug, Clone, Copy)]
struct Mix(u64);

impl Mix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    fn unit(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
    /// Roughly standard normal (sum of 4 uniforms, scaled).
    fn normal(&mut self) -> f32 {
        let s: f32 = (0..4).map(|_| self.unit()).sum();
        (s - 2.0) * 1.732
    }
}

const SPECIAL: [f32; 24] = [
    f32::NAN,
    -f32::NAN,
    f32::INFINITY,
    f32::NEG_INFINITY,
    f32::MAX,
    f32::MIN,
    f32::MIN_POSITIVE,
    1e-42,
    -1e-42,
    0.0,
    -0.0,
    3.0,
    80.0,
    2.358_333,
    80.641_67,
    2.999_999,
    80.000_01,
    1e30,
    -1e30,
    1e7,
    -1e7,
    f32::EPSILON,
    41.5,
    1e-20,
];

fn byte(u: &mut Unstructured<'_>) -> u8 {
    u.arbitrary().unwrap_or(0)
}

fn special(u: &mut Unstructured<'_>) -> f32 {
    SPECIAL[usize::from(byte(u)) % SPECIAL.len()]
}

fn raw_f32(u: &mut Unstructured<'_>) -> f32 {
    f32::from_bits(u.arbitrary().unwrap_or(0))
}

/// A frame step in microseconds: mostly nominal (50 ms ± 32 ms), else a repeat, a reversal, a
/// microsecond, up to 49 days, or any `i64`.
fn decode_dt(u: &mut Unstructured<'_>) -> i64 {
    match byte(u) % 10 {
        0..=4 => 50_000 + i64::from(u.arbitrary::<i16>().unwrap_or(0)),
        5 => 0,
        6 => -i64::from(u.arbitrary::<u16>().unwrap_or(1)),
        7 => i64::from(u.arbitrary::<u32>().unwrap_or(0)) * 1000,
        8 => 1 + i64::from(byte(u)),
        _ => u.arbitrary::<i64>().unwrap_or(0),
    }
}

/// Lane-like points (0–6 lanes over the 61 rows) plus raw and special points, in an order the
/// input chooses (it matters for the `MEAS` cut).
fn decode_frame(u: &mut Unstructured<'_>) -> Vec<[f32; 2]> {
    let mut pts = Vec::new();
    let lanes = byte(u) % 7;
    let mut mix = Mix(u64::from(u.arbitrary::<u32>().unwrap_or(0)));
    let noise = [0.0, 0.02, 0.1, 0.5, 3.0][usize::from(byte(u)) % 5];
    let pd = f32::from(byte(u)) / 255.0;
    let row = 77.0f32 / 60.0;
    for _ in 0..lanes {
        let x0 = f32::from(u.arbitrary::<i16>().unwrap_or(0)) / 100.0;
        let slope = f32::from(u.arbitrary::<i8>().unwrap_or(0)) * 1e-3;
        let curv = f32::from(u.arbitrary::<i8>().unwrap_or(0)) * 2e-5;
        for r in 0..61 {
            if mix.unit() >= pd {
                continue;
            }
            let uu = 3.0 + r as f32 * row;
            pts.push([uu, x0 + slope * uu + curv * uu * uu + noise * mix.normal()]);
        }
    }
    let raw = u.arbitrary::<u16>().unwrap_or(0) % 512;
    for _ in 0..raw {
        if u.is_empty() {
            break;
        }
        let p = match byte(u) % 5 {
            0 => [raw_f32(u), raw_f32(u)],
            1 => [special(u), special(u)],
            2 | 3 => [3.0 + 77.0 * mix.unit(), -15.0 + 30.0 * mix.unit()],
            _ => [special(u), -15.0 + 30.0 * mix.unit()],
        };
        pts.push(p);
    }
    if !pts.is_empty() {
        let k = usize::from(byte(u)) % pts.len();
        pts.rotate_left(k);
    }
    pts
}

/// The frames a [`tracker_step`] input describes: `(time in µs, points)` each (times as given,
/// not necessarily increasing). Public so that a crash input can be printed and turned into a
/// named regression test.
pub fn decode_tracker_input(data: &[u8]) -> Vec<(i64, Vec<[f32; 2]>)> {
    let mut u = Unstructured::new(data);
    let mut now = i64::from(u.arbitrary::<i32>().unwrap_or(0));
    let mut frames = Vec::new();
    for _ in 0..MAX_STEPS {
        if u.is_empty() {
            break;
        }
        now = now.saturating_add(decode_dt(&mut u));
        frames.push((now, decode_frame(&mut u)));
    }
    frames
}

/// `ReferenceTracker::step` on up to [`MAX_STEPS`] decoded frames; checks every output, the
/// state after every step, and that refused steps (non-increasing time) change nothing.
///
/// # Errors
/// A description of the first invariant violated.
pub fn tracker_step(data: &[u8]) -> Result<(), String> {
    let mut t = Box::new(ReferenceTracker::new(&DEFAULT));
    let mut last: Option<i64> = None;
    for (k, (at, pts)) in decode_tracker_input(data).into_iter().enumerate() {
        let refuse = last.is_some_and(|l| at <= l);
        let before = if refuse { Some(format!("{t:?}")) } else { None };
        let frames = t.frames();
        match (t.step(Instant::from_micros(at), &pts), before) {
            (Err(StepError::NonIncreasingTime), Some(before)) => {
                if format!("{t:?}") != before {
                    return Err(format!("step {k}: refused step changed the state"));
                }
            }
            (Ok(out), None) => {
                check_output(&out, pts.len()).map_err(|e| format!("step {k}: {e}"))?;
                check_tracker(&t, PsdCheck::Cholesky).map_err(|e| format!("step {k}: {e}"))?;
                if t.frames() != frames + 1 {
                    return Err(format!("step {k}: frames {} after {frames}", t.frames()));
                }
                last = Some(at);
            }
            (r, b) => {
                return Err(format!(
                    "step {k}: at {at} after {last:?}: {:?} (refusal expected: {})",
                    r.err(),
                    b.is_some()
                ))
            }
        }
    }
    Ok(())
}

/// A pseudo-measurement as the spatial filter would give (present mask, positions near a line,
/// PSD covariance `L Lᵀ` with variances from 1e-10 to 1e2 m²), with special values injected
/// into a position, or NaN/±inf into the covariance, at a small rate.
fn decode_obs(u: &mut Unstructured<'_>) -> LaneObservation<POINTS> {
    let mask = u.arbitrary::<u16>().unwrap_or(0);
    let present: [bool; POINTS] = core::array::from_fn(|i| mask & (1 << i) != 0);
    let base = f32::from(u.arbitrary::<i16>().unwrap_or(0)) / 100.0;
    let slope = f32::from(u.arbitrary::<i8>().unwrap_or(0)) * 1e-3;
    let mut mix = Mix(u64::from(u.arbitrary::<u32>().unwrap_or(0)));
    let level = f32::from(byte(u)) / 255.0 * 12.0 - 10.0; // log10 of the variances
    let corr = f32::from(byte(u)) / 255.0;
    let mut z = nalgebra::SVector::<f32, POINTS>::zeros();
    let mut l = SMatrix::<f32, POINTS, POINTS>::zeros();
    for i in 0..POINTS {
        if !present[i] {
            continue;
        }
        let ui = DEFAULT.index_u[i];
        let sd = 10f32.powf(0.5 * (level + mix.unit()));
        z[i] = base + slope * ui + sd * mix.normal();
        l[(i, i)] = sd * (1.0 - corr).max(1e-3);
        for j in 0..i {
            if present[j] {
                l[(i, j)] = sd * corr * (mix.unit() - 0.5);
            }
        }
    }
    let mut cov = l * l.transpose();
    match byte(u) % 16 {
        0 => z[usize::from(byte(u)) % POINTS] = special(u),
        1 => {
            // Only non-finite values: a finite edit could make `R` indefinite, which is outside
            // the update's contract (the spatial filter's covariances are PSD; see finding F1/F2).
            let (i, j) = (usize::from(byte(u)) % POINTS, usize::from(byte(u)) % POINTS);
            let v = [f32::NAN, f32::INFINITY, f32::NEG_INFINITY][usize::from(byte(u)) % 3];
            cov[(i, j)] = v;
            cov[(j, i)] = v;
        }
        _ => {}
    }
    LaneObservation {
        status: Status::Confirmed,
        present,
        z,
        cov,
        u_first: DEFAULT.hyper.u_min,
        u_last: DEFAULT.hyper.u_max,
        existence: 1.0,
        rank: 0,
        llr: 0.0,
    }
}

fn decode_step(u: &mut Unstructured<'_>) -> f32 {
    match byte(u) % 6 {
        0..=2 => 0.05 * (1.0 + f32::from(u.arbitrary::<i8>().unwrap_or(0)) / 128.0),
        3 => special(u),
        4 => raw_f32(u),
        _ => 10f32.powf(f32::from(u.arbitrary::<i8>().unwrap_or(0)) / 16.0),
    }
}

/// One operation of [`temporal_ops`].
#[derive(Debug, Clone)]
pub enum Op {
    /// `predict(dt)`.
    Predict(f32),
    /// `start_lane(slot, rank, ranks)`.
    Start(usize, u8, [u8; LANES]),
    /// `update(slot, observation)`.
    Update(usize, Box<LaneObservation<POINTS>>),
    /// `remove_lane(slot)`.
    Remove(usize),
    /// `set_ranks(ranks)`.
    SetRanks([u8; LANES]),
}

impl Op {
    /// Applies the operation; returns a description and the result.
    pub fn apply(
        &self,
        t: &mut Temporal<LANES, POINTS, RANK, NX, 42, 4>,
    ) -> (
        String,
        Result<(), stjpdacf::temporal::filter::TemporalError>,
    ) {
        match self {
            Op::Predict(dt) => (format!("predict {dt:e} s"), t.predict(&DEFAULT, *dt)),
            Op::Start(s, rank, ranks) => (
                format!("start slot {s} rank {rank} ranks {ranks:?}"),
                t.start_lane(&DEFAULT, *s, *rank, ranks).map(|_| ()),
            ),
            Op::Update(s, obs) => {
                let n = obs.present.iter().filter(|p| **p).count();
                let (lo, hi) = obs
                    .cov
                    .diagonal()
                    .iter()
                    .zip(obs.present)
                    .filter(|(_, p)| *p)
                    .fold((f32::INFINITY, 0.0f32), |(a, b), (v, _)| {
                        (a.min(*v), b.max(*v))
                    });
                // As the tracker does after its lane updates (here: a frame with one update,
                // the strictest schedule).
                let res = t.update(&DEFAULT, *s, obs).map(|_| ());
                let raised = if res.is_ok() {
                    t.repair_covariance(&DEFAULT)
                } else {
                    0
                };
                (
                    format!(
                        "update slot {s}, {n} points, variances {lo:e}..{hi:e}, {raised} pivots repaired"
                    ),
                    res,
                )
            }
            Op::Remove(s) => {
                t.remove_lane(*s);
                (format!("remove slot {s}"), Ok(()))
            }
            Op::SetRanks(ranks) => (format!("set_ranks {ranks:?}"), t.set_ranks(ranks)),
        }
    }
}

/// The operations a [`temporal_ops`] input describes.
pub fn decode_temporal_input(data: &[u8]) -> Vec<Op> {
    let mut u = Unstructured::new(data);
    let mut ops = Vec::new();
    for _ in 0..MAX_OPS {
        if u.is_empty() {
            break;
        }
        ops.push(match byte(&mut u) % 6 {
            0 => Op::Predict(decode_step(&mut u)),
            1 => {
                let s = usize::from(byte(&mut u)) % (LANES + 1);
                let rank = byte(&mut u) % 8;
                Op::Start(s, rank, core::array::from_fn(|_| byte(&mut u) % 8))
            }
            2 | 3 => {
                let s = usize::from(byte(&mut u)) % (LANES + 1);
                Op::Update(s, Box::new(decode_obs(&mut u)))
            }
            4 => Op::Remove(usize::from(byte(&mut u)) % (LANES + 1)),
            _ => Op::SetRanks(core::array::from_fn(|_| byte(&mut u) % 8)),
        });
    }
    ops
}

/// Any sequence of the temporal stage's operations (up to [`MAX_OPS`]); after each, the state is
/// checked ([`check_temporal`]) and a failed operation must have left it untouched.
///
/// # Errors
/// A description of the first invariant violated.
pub fn temporal_ops(data: &[u8]) -> Result<(), String> {
    let mut t: Box<Temporal<LANES, POINTS, RANK, NX, 42, 4>> = Box::new(Temporal::new());
    for (k, op) in decode_temporal_input(data).iter().enumerate() {
        let before = t.clone();
        let (what, res) = op.apply(&mut t);
        if res.is_err() && *t != *before {
            return Err(format!(
                "op {k} ({what}) failed with {res:?} and changed the state"
            ));
        }
        check_temporal(&t, &DEFAULT, PsdCheck::Cholesky)
            .map_err(|e| format!("op {k} ({what}, {res:?}): {e}"))?;
    }
    Ok(())
}

/// Number of `f32` entries [`table_f32`] can reach.
const TABLE_F32: usize = 16 + 6 * 4 + 16 + 256 + 256 + 16 + 36 + 36;

/// The `k`-th `f32` of the tables (hyper scalars, then every matrix entry).
fn table_f32(t: &mut ReferenceTables, k: usize) -> Option<&mut f32> {
    if k < 16 {
        return scalar_mut(t, k);
    }
    let mut k = k - 16;
    let slices: [&mut [f32]; 11] = [
        t.spatial.model.A.as_mut_slice(),
        t.spatial.model.p_inf.as_mut_slice(),
        t.spatial.f.as_mut_slice(),
        t.spatial.q.as_mut_slice(),
        t.temporal.f.as_mut_slice(),
        t.temporal.q.as_mut_slice(),
        t.index_u.as_mut_slice(),
        t.gram.as_mut_slice(),
        t.gram_eigvec.as_mut_slice(),
        t.gram_eigval.as_mut_slice(),
        t.coreg.as_mut_slice(),
    ];
    for s in slices {
        if k < s.len() {
            return s.get_mut(k);
        }
        k -= s.len();
    }
    t.coreg_chol.as_mut_slice().get_mut(k)
}

fn scalar_mut(t: &mut ReferenceTables, k: usize) -> Option<&mut f32> {
    let h = &mut t.hyper;
    Some(match k {
        0 => &mut h.spatial_variance,
        1 => &mut h.spatial_lengthscale,
        2 => &mut h.offset_variance,
        3 => &mut h.temporal_variance,
        4 => &mut h.temporal_lengthscale,
        5 => &mut h.meas_noise,
        6 => &mut h.pseudo_noise,
        7 => &mut h.u_min,
        8 => &mut h.u_max,
        9 => &mut h.row_step,
        10 => &mut h.frame_step,
        11 => &mut h.gram_variance_fraction,
        12 => &mut t.spatial.model.qc,
        13 => &mut t.temporal.kernel.variance,
        14 => &mut t.temporal.kernel.lengthscale,
        _ => &mut t.temporal.p_inf.m11,
    })
}

/// A factor `2^(i/4)` for `i` an `i8`: 2^-32 … 2^31.75.
fn factor(u: &mut Unstructured<'_>) -> f32 {
    2f32.powf(f32::from(u.arbitrary::<i8>().unwrap_or(0)) / 4.0)
}

/// Mutates the default tables as the input says.
/// The tables a [`tables_validate`] input describes (the default tables, mutated).
pub fn mutate_tables(u: &mut Unstructured<'_>) -> ReferenceTables {
    let mut t = DEFAULT;
    let n = byte(u) % 8;
    for _ in 0..n {
        match byte(u) % 9 {
            0 => {
                let k = usize::from(u.arbitrary::<u16>().unwrap_or(0)) % TABLE_F32;
                let v = raw_f32(u);
                if let Some(e) = table_f32(&mut t, k) {
                    *e = v;
                }
            }
            1 => {
                let k = usize::from(u.arbitrary::<u16>().unwrap_or(0)) % TABLE_F32;
                let v = special(u);
                if let Some(e) = table_f32(&mut t, k) {
                    *e = v;
                }
            }
            2 => {
                let k = usize::from(u.arbitrary::<u16>().unwrap_or(0)) % TABLE_F32;
                let f = factor(u);
                if let Some(e) = table_f32(&mut t, k) {
                    *e *= f;
                }
            }
            3 => {
                // A symmetric edit of a symmetric matrix (passes the symmetry checks).
                let (i, j) = (usize::from(byte(u)), usize::from(byte(u)));
                let f = factor(u);
                match byte(u) % 3 {
                    0 => {
                        let (i, j) = (i % POINTS, j % POINTS);
                        let v = t.gram[(i, j)] * f;
                        t.gram[(i, j)] = v;
                        t.gram[(j, i)] = v;
                    }
                    1 => {
                        let (i, j) = (i % 2, j % 2);
                        let v = t.temporal.q[(i, j)] * f;
                        t.temporal.q[(i, j)] = v;
                        t.temporal.q[(j, i)] = v;
                    }
                    _ => {
                        let (i, j) = (i % 2, j % 2);
                        let v = t.spatial.q[(i, j)] * f;
                        t.spatial.q[(i, j)] = v;
                        t.spatial.q[(j, i)] = v;
                    }
                }
            }
            4 => {
                // B scaled consistently: B c², L c.
                let f = factor(u);
                t.coreg *= f * f;
                t.coreg_chol *= f;
            }
            5 => {
                // The Gram matrix and its eigenvalues scaled together.
                let f = factor(u);
                t.gram *= f;
                t.gram_eigval *= f;
            }
            6 => {
                let k = usize::from(byte(u)) % 16;
                let f = factor(u);
                if let Some(e) = scalar_mut(&mut t, k) {
                    *e *= f;
                }
            }
            7 => t.gram_rank = u32::from(byte(u)) % 20,
            _ => match byte(u) % 2 {
                0 => t.version = u.arbitrary().unwrap_or(0),
                _ => t.hyper.spatial_order = u32::from(byte(u)) % 8,
            },
        }
    }
    t
}

/// Checks one spatial observation.
fn check_obs(o: &LaneObservation<POINTS>, tables: &ReferenceTables) -> Result<(), String> {
    for i in (0..POINTS).filter(|&i| o.present[i]) {
        if !o.z[i].is_finite() {
            return Err(format!("observation z[{i}] = {}", o.z[i]));
        }
    }
    let idx = present_indices(o);
    cov_health(&o.cov, &idx, PsdCheck::Cholesky).map_err(|e| format!("observation: {e}"))?;
    let (lo, hi) = (tables.hyper.u_min, tables.hyper.u_max);
    if !(o.u_first <= o.u_last
        && o.u_first >= lo - tables.hyper.row_step
        && o.u_last <= hi + tables.hyper.row_step)
    {
        return Err(format!("observation extent {} .. {}", o.u_first, o.u_last));
    }
    if !(0.0..=1.0).contains(&o.existence) || usize::from(o.rank) >= LANES {
        return Err(format!(
            "observation existence {} rank {}",
            o.existence, o.rank
        ));
    }
    Ok(())
}

/// `Tables::validate` on mutated default tables (must not panic; the unmutated tables pass);
/// tables it accepts run through the spatial filter (observation invariants) and the temporal
/// stage (start, predict, update: [`check_temporal`]) on three straight lanes plus input points.
///
/// # Errors
/// A description of the first invariant violated.
pub fn tables_validate(data: &[u8]) -> Result<(), String> {
    let mut u = Unstructured::new(data);
    let t = mutate_tables(&mut u);
    let valid = t.validate();
    if t == DEFAULT && valid.is_err() {
        return Err(format!("default tables rejected: {valid:?}"));
    }
    if valid.is_err() {
        return Ok(());
    }
    let mut pts = Vec::new();
    for r in 0..61 {
        let uu = t.hyper.u_min + r as f32 * t.hyper.row_step;
        for x in [-5.4f32, -1.8, 1.8] {
            pts.push([uu, x + 0.01 * (r % 3) as f32]);
        }
    }
    pts.extend(decode_frame(&mut u).into_iter().take(64));
    let mut spatial: Box<SpatialFilter<3, LANES, 64, 16>> = Box::new(SpatialFilter::new());
    let mut temporal: Box<Temporal<LANES, POINTS, RANK, NX, 42, 4>> = Box::new(Temporal::new());
    let empty = LaneObservation::EMPTY;
    let cfg = SpatialConfig::DEFAULT;
    for frame in 0..3 {
        let mut out = [empty; LANES];
        let (n, rep) = spatial.run(&t, &cfg, &pts, &mut out);
        if n > LANES || usize::from(rep.lanes_out) != n {
            return Err(format!("frame {frame}: {n} observations, report {rep:?}"));
        }
        for o in out.iter().take(n) {
            check_obs(o, &t).map_err(|e| format!("frame {frame}: {e}"))?;
        }
        if frame > 0 {
            let before = temporal.clone();
            if temporal.predict(&t, t.hyper.frame_step).is_err() && *temporal != *before {
                return Err(format!("frame {frame}: failed predict changed the state"));
            }
        }
        for (s, o) in out.iter().enumerate().take(n) {
            if !temporal.filter().is_active(s) {
                let lanes = temporal.filter().lanes();
                let mut ranks = [0u8; LANES];
                for (q, r) in ranks.iter_mut().enumerate() {
                    *r = q as u8;
                }
                let before = temporal.clone();
                if temporal.start_lane(&t, s, lanes as u8, &ranks).is_err() && *temporal != *before
                {
                    return Err(format!("frame {frame}: failed start changed the state"));
                }
            }
            if temporal.filter().is_active(s) {
                let before = temporal.clone();
                if temporal.update(&t, s, o).is_err() && *temporal != *before {
                    return Err(format!("frame {frame}: failed update changed the state"));
                }
            }
        }
        check_temporal(&temporal, &t, PsdCheck::Cholesky)
            .map_err(|e| format!("frame {frame}: {e}"))?;
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// wire_decode: the SPI feature-frame decoder (`stjpdacf::wire`) and its receiver.

/// Frames per [`wire_decode`] input the tracker steps on at most.
pub const MAX_FRAMES: usize = 16;
/// Buffers per [`wire_decode`] input offered to the receiver at most (per part).
pub const MAX_OFFERS: usize = 64;
/// Decoded frames per [`wire_decode`] input whose mutations (bit flips, truncations,
/// extensions) are checked.
const MUTATED_FRAMES: usize = 4;
/// Bit flips at pseudo-random positions per mutated frame (besides every bit of the header).
const FLIPS: usize = 32;
/// What a point buffer holds before a call: any write shows (no decodable point is beyond ±128 m).
const SENTINEL: [f32; 2] = [-999.0, 999.0];

/// The outcome the documented layout (`stjpdacf::wire` module docs) gives for `bytes` with
/// capacity `cap`: the checks in their documented order (length of the header, magic, version
/// and flags, count against the capacity, length of the frame, CRC-32/ISO-HDLC computed by
/// `crc32fast`), written independently of the decoder.
fn wire_spec(bytes: &[u8], cap: usize) -> Result<(u32, i64, usize), WireError> {
    if bytes.len() < wire::HEADER_LEN {
        return Err(WireError::Truncated);
    }
    if bytes[..4] != wire::MAGIC {
        return Err(WireError::BadMagic);
    }
    if bytes[4] != wire::VERSION || bytes[5] != 0 {
        return Err(WireError::BadVersion);
    }
    let n = u16::from_le_bytes([bytes[6], bytes[7]]);
    if usize::from(n) > cap {
        return Err(WireError::Oversized { count: n });
    }
    let len = 24 + 4 * usize::from(n);
    if bytes.len() < len {
        return Err(WireError::Truncated);
    }
    let crc = u32::from_le_bytes([
        bytes[len - 4],
        bytes[len - 3],
        bytes[len - 2],
        bytes[len - 1],
    ]);
    if crc32fast::hash(&bytes[..len - 4]) != crc {
        return Err(WireError::BadCrc);
    }
    let seq = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]);
    let mut t = [0u8; 8];
    t.copy_from_slice(&bytes[12..20]);
    Ok((seq, i64::from_le_bytes(t), usize::from(n)))
}

/// A decoded frame: its header and its points.
pub type Decoded = (FrameInfo, Vec<[f32; 2]>);

/// `wire::decode` of `bytes` into a buffer of `cap` sentinel points, checked: the result is the
/// layout's ([`wire_spec`]: same error, or same header); on error no point is written; on
/// success exactly `count ≤ cap` points are written, each finite, within ±128 m and a multiple of
/// `LSB_M`, and the frame re-encodes to the same bytes (round trip).
fn checked_decode(bytes: &[u8], cap: usize) -> Result<Result<Decoded, WireError>, String> {
    let mut buf = vec![SENTINEL; cap];
    let r = wire::decode(bytes, &mut buf);
    let spec = wire_spec(bytes, cap);
    match r {
        Err(e) => {
            if spec != Err(e) {
                return Err(format!("decode gives {e:?}, the layout {spec:?}"));
            }
            if buf.iter().any(|p| *p != SENTINEL) {
                return Err(format!("decode failed with {e:?} and wrote points"));
            }
            Ok(Err(e))
        }
        Ok(info) => {
            let got = (info.seq, info.time.as_micros(), info.count);
            if spec != Ok(got) {
                return Err(format!("decode gives {got:?}, the layout {spec:?}"));
            }
            let n = info.count;
            if buf[n..].iter().any(|p| *p != SENTINEL) {
                return Err(format!("decode of {n} points wrote beyond them"));
            }
            for (i, p) in buf[..n].iter().enumerate() {
                let ok =
                    |v: f32| v.is_finite() && v.abs() <= 128.0 && (v / wire::LSB_M).fract() == 0.0;
                if !(ok(p[0]) && ok(p[1])) {
                    return Err(format!("decoded point {i} is {p:?}"));
                }
            }
            let len = wire::frame_len(n);
            let mut again = vec![0u8; len];
            match wire::encode(info.seq, info.time, &buf[..n], &mut again) {
                Ok(l) if l == len && again[..] == bytes[..len] => {}
                r => {
                    let at = again.iter().zip(bytes).position(|(a, b)| a != b);
                    return Err(format!(
                        "round trip: re-encoding gives {r:?}, first differing byte {at:?}"
                    ));
                }
            }
            buf.truncate(n);
            Ok(Ok((info, buf)))
        }
    }
}

/// Bit flips, truncations and extensions of a decoded frame `frame` (exactly its bytes):
/// every truncation is `Truncated`; an extension (bytes after the frame) decodes to the same
/// frame; a single bit flip (every bit of the header, [`FLIPS`] pseudo-random bits anywhere) is
/// an error or the same frame.
fn check_mutations(frame: &[u8], want: &Decoded) -> Result<(), String> {
    let same = |r: &Result<Decoded, WireError>| matches!(r, Ok(d) if d == want);
    for cut in 0..frame.len() {
        let r = checked_decode(&frame[..cut], MEAS)?;
        if r.as_ref().err() != Some(&WireError::Truncated) {
            return Err(format!(
                "frame of {} bytes cut at {cut}: {:?}",
                frame.len(),
                r.err()
            ));
        }
    }
    let mut longer = frame.to_vec();
    for tail in [&[0u8][..], &[0xFF, 0x5A, 0x00], frame] {
        longer.truncate(frame.len());
        longer.extend_from_slice(tail);
        let r = checked_decode(&longer, MEAS)?;
        if !same(&r) {
            return Err(format!(
                "frame extended by {} bytes: {:?}",
                tail.len(),
                r.err()
            ));
        }
    }
    let mut mix = Mix(u64::from(wire::crc32(frame)));
    let header_bits = 8 * wire::HEADER_LEN.min(frame.len());
    let random = (0..FLIPS).map(|_| (mix.next() % (8 * frame.len() as u64)) as usize);
    let mut flipped = frame.to_vec();
    for bit in (0..header_bits).chain(random) {
        flipped[bit / 8] ^= 1 << (bit % 8);
        let r = checked_decode(&flipped, MEAS)?;
        flipped[bit / 8] ^= 1 << (bit % 8);
        if r.is_ok() && !same(&r) {
            let d = r.as_ref().map(|d| d.0);
            return Err(format!("bit {bit} flipped: decoded as another frame {d:?}"));
        }
    }
    Ok(())
}

/// A receiver, the independent model of what it must do, and the tracker it feeds.
struct Link {
    rx: Receiver,
    /// The model: sequence number and time of the last frame that must have been accepted.
    last: Option<(u32, Instant)>,
    /// The model's counters.
    stats: LinkStats,
    tracker: Box<ReferenceTracker>,
    /// Frames the tracker stepped on.
    stepped: usize,
    /// Frames whose mutations were checked.
    mutated: usize,
    /// Buffers offered.
    offers: usize,
}

/// What [`Link::offer`] saw: the stateless decode and the receiver's verdict.
struct Offered {
    decoded: Result<Decoded, WireError>,
    accepted: Result<FrameInfo, WireError>,
}

impl Link {
    fn new() -> Self {
        Self {
            rx: Receiver::new(),
            last: None,
            stats: LinkStats::default(),
            tracker: Box::new(ReferenceTracker::new(&DEFAULT)),
            stepped: 0,
            mutated: 0,
            offers: 0,
        }
    }

    /// One buffer: the checked stateless decode (and, for the first few frames, its
    /// mutations), then `Receiver::accept` against the model (same verdict, same points, point
    /// buffer untouched on refusal, same counters), then, when accepted, `Tracker::step` on the
    /// frame (up to [`MAX_FRAMES`]): it must accept the frame (its time increases) and keep
    /// every invariant (`check_output`, `check_tracker`). A refused buffer never reaches the
    /// tracker; the next acceptable frame is accepted and stepped on.
    fn offer(&mut self, bytes: &[u8]) -> Result<Offered, String> {
        let k = self.offers;
        self.offers += 1;
        let decoded = checked_decode(bytes, MEAS).map_err(|e| format!("buffer {k}: {e}"))?;
        if let Ok(d) = &decoded {
            if self.mutated < MUTATED_FRAMES {
                self.mutated += 1;
                check_mutations(&bytes[..wire::frame_len(d.0.count)], d)
                    .map_err(|e| format!("buffer {k}: {e}"))?;
            }
        }
        let model = match &decoded {
            Err(e) => Err(*e),
            Ok((info, _)) => match self.last {
                Some((seq, _)) if info.seq <= seq => Err(WireError::NonIncreasingSequence),
                Some((_, time)) if info.time <= time => Err(WireError::NonIncreasingTime),
                _ => Ok(*info),
            },
        };
        let mut pts = vec![SENTINEL; MEAS];
        let accepted = self.rx.accept(bytes, &mut pts);
        if accepted != model {
            return Err(format!(
                "buffer {k}: receiver gives {accepted:?}, expected {model:?}"
            ));
        }
        match (&accepted, &decoded) {
            (Ok(info), Ok((_, want))) => {
                let n = info.count;
                if pts[..n] != want[..] || pts[n..].iter().any(|p| *p != SENTINEL) {
                    return Err(format!(
                        "buffer {k}: receiver wrote other points than decode"
                    ));
                }
                if let Some((seq, _)) = self.last {
                    self.stats.skipped = self.stats.skipped.saturating_add(info.seq - seq - 1);
                }
                self.stats.frames += 1;
                self.last = Some((info.seq, info.time));
            }
            (Err(e), _) => {
                if pts.iter().any(|p| *p != SENTINEL) {
                    return Err(format!("buffer {k}: refused ({e:?}) but points written"));
                }
                let c = match e {
                    WireError::Truncated => &mut self.stats.truncated,
                    WireError::BadMagic => &mut self.stats.bad_magic,
                    WireError::BadVersion => &mut self.stats.bad_version,
                    WireError::Oversized { .. } => &mut self.stats.oversized,
                    WireError::BadCrc => &mut self.stats.bad_crc,
                    WireError::NonIncreasingSequence => &mut self.stats.non_increasing_seq,
                    WireError::NonIncreasingTime => &mut self.stats.non_increasing_time,
                    _ => return Err(format!("buffer {k}: unknown error {e:?}")),
                };
                *c += 1;
            }
            (Ok(_), Err(_)) => {
                return Err(format!("buffer {k}: model accepted an undecodable frame"))
            }
        }
        if *self.rx.stats() != self.stats {
            return Err(format!(
                "buffer {k}: counters {:?}, expected {:?}",
                self.rx.stats(),
                self.stats
            ));
        }
        if let Ok(info) = &accepted {
            if self.stepped < MAX_FRAMES {
                self.stepped += 1;
                let frames = self.tracker.frames();
                let n = info.count;
                let out = self.tracker.step(info.time, &pts[..n]).map_err(|e| {
                    format!("buffer {k}: accepted frame refused by the tracker: {e}")
                })?;
                check_output(&out, n).map_err(|e| format!("buffer {k}: {e}"))?;
                check_tracker(&self.tracker, PsdCheck::Cholesky)
                    .map_err(|e| format!("buffer {k}: {e}"))?;
                if self.tracker.frames() != frames + 1 {
                    return Err(format!("buffer {k}: tracker did not count the frame"));
                }
            }
        }
        Ok(Offered { decoded, accepted })
    }
}

/// What the harness did to a frame of a structured [`wire_decode`] input before sending it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// Sent as encoded.
    None,
    /// 1–3 bits flipped.
    Flip,
    /// Cut short.
    Truncate,
    /// Bytes appended.
    Extend,
    /// Arbitrary bytes instead of the frame.
    Garbage,
    /// The last good frame sent again (its sequence number replayed).
    Replay,
    /// A new sequence number with a timestamp at or before the last good frame's.
    StaleTime,
    /// A count above the budget `MEAS`, under a correct CRC.
    Oversized,
    /// Magic, version or flags changed, under a correct CRC.
    BadHeader,
}

/// One buffer of a structured [`wire_decode`] input.
#[derive(Debug, Clone)]
pub struct Sent {
    /// The bytes sent.
    pub bytes: Vec<u8>,
    /// What was done to the frame.
    pub fault: Fault,
    /// The frame before the fault (for `Flip`, `Truncate`, `Extend`).
    pub original: Option<Vec<u8>>,
}

/// Rewrites the CRC of a frame (all of `f`) after an edit.
fn reseal(f: &mut [u8]) {
    let body = f.len() - wire::CRC_LEN;
    let crc = wire::crc32(&f[..body]);
    f[body..].copy_from_slice(&crc.to_le_bytes());
}

/// The buffers a structured [`wire_decode`] input describes: up to [`MAX_FRAMES`] frames
/// encoded with `wire::encode` (lane-like and raw points as in [`tracker_step`], those the format
/// can carry, cut to `MEAS`; sequence numbers increasing with gaps, wrapping at `u32::MAX`;
/// times increasing), each sent as is or with a [`Fault`] (the faulty copy alone, or followed by
/// the good frame).
pub fn decode_wire_input(data: &[u8]) -> Vec<Sent> {
    let mut u = Unstructured::new(data);
    let mut seq = u.arbitrary::<u32>().unwrap_or(0);
    let mut t = i64::from(u.arbitrary::<i32>().unwrap_or(0));
    let mut last_good: Option<(Vec<u8>, i64)> = None;
    let mut sent = Vec::new();
    for _ in 0..MAX_FRAMES {
        if u.is_empty() {
            break;
        }
        seq = seq.wrapping_add(1 + u32::from(byte(&mut u) % 8).saturating_sub(5));
        t = t.saturating_add(1 + 1000 * i64::from(u.arbitrary::<u8>().unwrap_or(50)));
        let mut pts = decode_frame(&mut u);
        pts.retain(|p| p.iter().all(|v| v.is_finite() && v.abs() < 127.0));
        let fault = match byte(&mut u) % 16 {
            0..=6 => Fault::None,
            7 => Fault::Flip,
            8 => Fault::Truncate,
            9 => Fault::Extend,
            10 => Fault::Garbage,
            11 => Fault::Replay,
            12 => Fault::StaleTime,
            13 => Fault::Oversized,
            _ => Fault::BadHeader,
        };
        let all = pts.clone();
        pts.truncate(MEAS);
        let mut good = vec![0u8; wire::frame_len(pts.len())];
        if wire::encode(seq, Instant::from_micros(t), &pts, &mut good).is_err() {
            continue;
        }
        let len = good.len();
        let (bytes, original) = match fault {
            Fault::None => (good.clone(), None),
            Fault::Flip => {
                let mut f = good.clone();
                for _ in 0..1 + byte(&mut u) % 3 {
                    let bit = usize::from(u.arbitrary::<u16>().unwrap_or(0)) % (8 * len);
                    f[bit / 8] ^= 1 << (bit % 8);
                }
                (f, Some(good.clone()))
            }
            Fault::Truncate => {
                let cut = usize::from(u.arbitrary::<u16>().unwrap_or(0)) % len;
                (good[..cut].to_vec(), Some(good.clone()))
            }
            Fault::Extend => {
                let mut f = good.clone();
                let n = usize::from(byte(&mut u));
                f.extend((0..n).map(|_| byte(&mut u)));
                (f, Some(good.clone()))
            }
            Fault::Garbage => {
                let n = usize::from(u.arbitrary::<u16>().unwrap_or(0)) % 1200;
                ((0..n).map(|_| byte(&mut u)).collect(), None)
            }
            Fault::Replay => match &last_good {
                Some((f, _)) => (f.clone(), None),
                None => (good.clone(), None),
            },
            Fault::StaleTime => {
                let back = i64::from(u.arbitrary::<u16>().unwrap_or(0));
                let at = last_good
                    .as_ref()
                    .map_or(t, |(_, lt)| lt.saturating_sub(back));
                let mut f = vec![0u8; len];
                let _ = wire::encode(seq, Instant::from_micros(at), &pts, &mut f);
                (f, None)
            }
            Fault::Oversized => {
                let mut f = good.clone();
                if all.len() > MEAS {
                    // The frame with every point (encodable: `all` holds at most ~870).
                    f = vec![0u8; wire::frame_len(all.len())];
                    let _ = wire::encode(seq, Instant::from_micros(t), &all, &mut f);
                } else {
                    let n = (MEAS + 1 + usize::from(u.arbitrary::<u16>().unwrap_or(0)))
                        .min(usize::from(u16::MAX)) as u16;
                    f[6..8].copy_from_slice(&n.to_le_bytes());
                    reseal(&mut f);
                }
                (f, None)
            }
            Fault::BadHeader => {
                let mut f = good.clone();
                let at = usize::from(byte(&mut u)) % 6;
                f[at] ^= byte(&mut u).max(1);
                reseal(&mut f);
                (f, None)
            }
        };
        let resend = fault != Fault::None && byte(&mut u) & 1 == 0;
        sent.push(Sent {
            bytes,
            fault,
            original,
        });
        if resend {
            sent.push(Sent {
                bytes: good.clone(),
                fault: Fault::None,
                original: None,
            });
        }
        if fault == Fault::None || resend {
            last_good = Some((good, t));
        }
    }
    sent
}

/// The frames of a raw [`wire_decode`] input taken as a byte stream: a frame at the start, then
/// frames back to back; after bytes that do not decode, the stream resumes at the next `MAGIC`
/// (at most [`MAX_OFFERS`] buffers; each is offered from its start to the end of the input).
fn raw_stream(data: &[u8], link: &mut Link) -> Result<(), String> {
    let mut p = 0;
    while p < data.len() && link.offers < MAX_OFFERS {
        let o = link.offer(&data[p..])?;
        p += match o.decoded {
            Ok((info, _)) => wire::frame_len(info.count),
            Err(_) => {
                1 + data[p + 1..]
                    .windows(4)
                    .position(|w| w == wire::MAGIC)
                    .unwrap_or(data.len() - p - 1)
            }
        };
    }
    Ok(())
}

/// The SPI frame decoder and receiver on arbitrary bytes, with the invariants of `fuzz/README.md`:
/// no panic; every buffer decodes as the documented layout says or gives its typed error, never a
/// partial frame ([`checked_decode`]); a decoded frame re-encodes to the same bytes and holds at
/// most `MEAS` points; its bit flips, truncations and extensions give an error or the same
/// frame ([`check_mutations`]); the receiver accepts exactly the frames that decode with an
/// increasing sequence number and time, counts every outcome, and feeds only those to
/// `Tracker::step`, which keeps every invariant and resumes on the next good frame
/// ([`Link::offer`]).
///
/// Two parts, each with its own receiver and tracker: the input as a raw byte stream (frames
/// back to back, corrupted frames mid-stream: what the seed corpus of real frames turns into
/// under mutation), and, unless the input starts with `MAGIC`, the input as a description of
/// frames and the faults applied to them ([`decode_wire_input`]: bit flips, truncation,
/// extension, garbage, a replayed sequence number, a stale timestamp, an oversized count, a bad
/// header), with the effect each fault must have.
///
/// # Errors
/// A description of the first invariant violated.
pub fn wire_decode(data: &[u8]) -> Result<(), String> {
    let mut raw = Link::new();
    raw_stream(data, &mut raw).map_err(|e| format!("raw stream: {e}"))?;
    if data.starts_with(&wire::MAGIC) {
        return Ok(());
    }
    let mut link = Link::new();
    let mut accepted: Vec<Vec<u8>> = Vec::new();
    for (k, s) in decode_wire_input(data).into_iter().enumerate() {
        let last = link.last;
        let o = link
            .offer(&s.bytes)
            .map_err(|e| format!("structured: {e}"))?;
        let orig = s
            .original
            .as_deref()
            .map(|f| checked_decode(f, MEAS).map_err(|e| format!("structured {k}: {e}")))
            .transpose()?;
        let ok = match s.fault {
            Fault::None => o.decoded.is_ok(),
            Fault::Flip => o.decoded.is_err() || orig.as_ref() == Some(&o.decoded),
            Fault::Truncate => o.decoded.as_ref().err() == Some(&WireError::Truncated),
            Fault::Extend => orig.as_ref() == Some(&o.decoded),
            Fault::Garbage => true,
            Fault::Replay => {
                !accepted.contains(&s.bytes) || o.accepted == Err(WireError::NonIncreasingSequence)
            }
            Fault::StaleTime => {
                let stale = match (&o.decoded, last) {
                    (Ok((info, _)), Some((_, lt))) => info.time <= lt,
                    _ => false,
                };
                !stale
                    || matches!(
                        o.accepted,
                        Err(WireError::NonIncreasingTime | WireError::NonIncreasingSequence)
                    )
            }
            Fault::Oversized => matches!(
                o.decoded,
                Err(WireError::Oversized { count }) if usize::from(count) > MEAS
            ),
            Fault::BadHeader => {
                matches!(o.decoded, Err(WireError::BadMagic | WireError::BadVersion))
            }
        };
        if !ok {
            return Err(format!(
                "structured {k}: fault {:?} gave decode {:?}, receiver {:?}",
                s.fault,
                o.decoded.as_ref().map(|d| d.0),
                o.accepted
            ));
        }
        if let Ok(info) = o.accepted {
            accepted.push(s.bytes[..wire::frame_len(info.count)].to_vec());
        }
    }
    Ok(())
}

/// The frames a [`wire_decode`] input makes its two receivers accept, as `(buffer index,
/// points)`: the raw stream's, then the structured part's (empty when the input starts with
/// `MAGIC`). Public so that a crash input can be classified (`examples/classify.rs`).
pub fn wire_accepted_frames(data: &[u8]) -> [Vec<(usize, Vec<[f32; 2]>)>; 2] {
    let mut pts = vec![[0.0f32; 2]; MEAS];
    let mut raw = Vec::new();
    let mut rx = Receiver::new();
    let mut p = 0;
    let mut k = 0;
    while p < data.len() && k < MAX_OFFERS {
        if let Ok(i) = rx.accept(&data[p..], &mut pts) {
            raw.push((k, pts[..i.count].to_vec()));
        }
        p += match wire::decode(&data[p..], &mut pts) {
            Ok(i) => wire::frame_len(i.count),
            Err(_) => {
                1 + data[p + 1..]
                    .windows(4)
                    .position(|w| w == wire::MAGIC)
                    .unwrap_or(data.len() - p - 1)
            }
        };
        k += 1;
    }
    let mut structured = Vec::new();
    if !data.starts_with(&wire::MAGIC) {
        let mut rx = Receiver::new();
        for (k, s) in decode_wire_input(data).iter().enumerate() {
            if let Ok(i) = rx.accept(&s.bytes, &mut pts) {
                structured.push((k, pts[..i.count].to_vec()));
            }
        }
    }
    [raw, structured]
}
