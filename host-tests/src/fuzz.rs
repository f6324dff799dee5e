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
//!   positions, PSD covariances with variances from 1e-16 to 1e3 m² and injected NaN/inf), remove, re-rank.
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
use stjpdacf::tables::{ReferenceTables, DEFAULT, UNCOUPLED};
use stjpdacf::temporal::smoother::Temporal;
use stjpdacf::tracker::{Instant, ReferenceTracker, StepError};

use crate::invariants::present_indices;

mod wire_link;

pub use crate::invariants::{
    check_output, check_temporal, check_tracker, cov_health, CovHealth, PsdCheck, LANES, MEAS, NX,
    POINTS, RANK,
};
pub use wire_link::{
    decode_wire_input, wire_accepted_frames, wire_decode, Fault, Sent, MAX_FRAMES, MAX_OFFERS,
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

/// `ReferenceTracker::step` on up to [`MAX_STEPS`] decoded frames, on the default and on the
/// uncoupled tables; checks every output, the state after every step, and that refused steps
/// (non-increasing time) change nothing.
///
/// # Errors
/// A description of the first invariant violated.
pub fn tracker_step(data: &[u8]) -> Result<(), String> {
    tracker_step_with(data, &DEFAULT).map_err(|e| format!("default tables: {e}"))?;
    // The uncoupled tables (B diagonal): own-block temporal loops and rows split into clusters.
    tracker_step_with(data, &UNCOUPLED).map_err(|e| format!("uncoupled tables: {e}"))
}

/// [`tracker_step`] on one set of tables.
///
/// # Errors
/// A description of the first invariant violated.
pub fn tracker_step_with(data: &[u8], tables: &'static ReferenceTables) -> Result<(), String> {
    let mut t = Box::new(ReferenceTracker::new(tables));
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
/// PSD covariance `L Lᵀ` with variances from 1e-16 to 1e3 m²), with special values injected
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
    /// Applies the operation with the default tables; returns a description and the result.
    pub fn apply(
        &self,
        t: &mut Temporal<LANES, POINTS, RANK, NX, 42, 4>,
    ) -> (
        String,
        Result<(), stjpdacf::temporal::filter::TemporalError>,
    ) {
        self.apply_with(t, &DEFAULT)
    }

    /// Applies the operation with `tables`; returns a description and the result.
    pub fn apply_with(
        &self,
        t: &mut Temporal<LANES, POINTS, RANK, NX, 42, 4>,
        tables: &ReferenceTables,
    ) -> (
        String,
        Result<(), stjpdacf::temporal::filter::TemporalError>,
    ) {
        match self {
            Op::Predict(dt) => (format!("predict {dt:e} s"), t.predict(tables, *dt)),
            Op::Start(s, rank, ranks) => (
                format!("start slot {s} rank {rank} ranks {ranks:?}"),
                t.start_lane(tables, *s, *rank, ranks).map(|_| ()),
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
                let res = t.update(tables, *s, obs).map(|_| ());
                let raised = if res.is_ok() {
                    t.repair_covariance(tables)
                } else {
                    0
                };
                (
                    format!(
                        "update slot {s}, {n} points, variances {lo:e}..{hi:e}, {raised} failed factorisations repaired"
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
    // The same operations on the coupled default model and on the uncoupled one, whose
    // filter runs its own-block loops (docs/design.md §4.2.6).
    for (name, tables) in [("default", &DEFAULT), ("uncoupled", &UNCOUPLED)] {
        temporal_ops_with(data, tables).map_err(|e| format!("{name} tables: {e}"))?;
    }
    Ok(())
}

/// [`temporal_ops`] on one model; while the filter says it is uncoupled, every cross-lane entry
/// of its covariance must be exactly zero (the own-block loops rely on it).
fn temporal_ops_with(data: &[u8], tables: &ReferenceTables) -> Result<(), String> {
    let mut t: Box<Temporal<LANES, POINTS, RANK, NX, 42, 4>> = Box::new(Temporal::new());
    for (k, op) in decode_temporal_input(data).iter().enumerate() {
        let before = t.clone();
        let (what, res) = op.apply_with(&mut t, tables);
        if res.is_err() && *t != *before {
            return Err(format!(
                "op {k} ({what}) failed with {res:?} and changed the state"
            ));
        }
        check_temporal(&t, tables, PsdCheck::Cholesky)
            .map_err(|e| format!("op {k} ({what}, {res:?}): {e}"))?;
        if t.filter().uncoupled() {
            let p = t.filter().covariance();
            let lane = |i: usize| i / (2 * RANK);
            for j in 0..NX {
                for i in 0..NX {
                    if lane(i) != lane(j) && p[(i, j)] != 0.0 {
                        return Err(format!(
                            "op {k} ({what}): uncoupled, but P[{i}, {j}] = {:e}",
                            p[(i, j)]
                        ));
                    }
                }
            }
        }
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
/// stage (start, predict, update and the per-frame covariance repair, as the tracker runs it:
/// [`check_temporal`]) on three straight lanes plus input points.
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
        // As the tracker does after every frame's lane updates (docs/design.md §4.2.4): the f32
        // update may lose positive definiteness to rounding (F5, F7); the stage is update +
        // repair, and the repaired state is what must be healthy.
        temporal.repair_covariance(&t);
        check_temporal(&temporal, &t, PsdCheck::Cholesky)
            .map_err(|e| format!("frame {frame}: {e}"))?;
    }
    Ok(())
}
