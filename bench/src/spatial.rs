//! The inputs of the spatial JPDACF benches (`benches/spatial.rs`) and of their callgrind driver
//! (`examples/spatial_icount.rs`), at the reference configuration (docs/design.md §2: D = 6, N = 16,
//! M = 256 with at most 16 per row, R_max = 64, E = 512): the same seeds and the same
//! construction in both, so that their counts tie together.

use nalgebra::{SMatrix, SVector};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use stjpdacf::spatial::filter::{Config, LaneObservation, SpatialFilter};
use stjpdacf::spatial::row::{self, RowParams};
use stjpdacf::spatial::Stacked;
use stjpdacf::tables::DEFAULT;
use stjpdacf_tools::scenario::{Scenario, ScenarioConfig};

/// State entries per lane (offset + order-2 RBF state).
pub const NS: usize = 3;
/// Lane slots D.
pub const LANES: usize = 6;
/// Rows R_max.
pub const ROWS: usize = 64;
/// Points per row.
pub const PER_ROW: usize = 16;
/// Index points N.
pub const POINTS: usize = 16;
/// Measurement budget M of a frame.
pub const MEAS: usize = 256;
/// Event budget E.
pub const EVENTS: usize = 512;
/// Lane spacing of the row benches, m.
pub const SPACING: f32 = 3.6;

/// The spatial filter at the reference configuration.
pub type Filter = SpatialFilter<NS, LANES, ROWS, PER_ROW>;
/// The stacked state of the reference configuration.
pub type State = Stacked<NS, LANES>;
/// The filter's output buffer.
pub type Obs = [LaneObservation<POINTS>; LANES];

/// A standard normal draw (Box–Muller).
pub fn normal(rng: &mut ChaCha8Rng) -> f32 {
    let u1: f32 = 1.0 - rng.random::<f32>();
    let u2: f32 = rng.random::<f32>();
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f32::consts::PI * u2).cos()
}

/// `blockdiag(corner, m)`.
pub fn embed(m: &SMatrix<f32, 2, 2>, corner: f32) -> SMatrix<f32, NS, NS> {
    SMatrix::from_fn(|i, j| match (i, j) {
        (0, 0) => corner,
        (0, _) | (_, 0) => 0.0,
        _ => m[(i - 1, j - 1)],
    })
}

/// The measurement row `h` (offset + GP value).
pub fn h() -> SVector<f32, NS> {
    SVector::from([1.0, 1.0, 0.0])
}

/// Position of lane `t` of `n`, [`SPACING`] apart and centred on x = 0.
pub fn lane_x(t: usize, n: usize) -> f32 {
    (t as f32 - (n as f32 - 1.0) / 2.0) * SPACING
}

/// `n` tracks at the lane positions with the broad prior of a fresh frame: offset variance from
/// the tables, GP part `B ⊗ P∞`.
pub fn broad_state(n: usize) -> State {
    let pinf = &DEFAULT.spatial.model.p_inf;
    let b = &DEFAULT.coreg;
    let mut s = State::new();
    for t in 0..n {
        let p = embed(&(pinf * b[(t, t)]), DEFAULT.hyper.offset_variance);
        s.push(SVector::from([lane_x(t, n), 0.0, 0.0]), &p)
            .expect("fewer than LANES tracks");
    }
    for i in 0..n {
        for j in i + 1..n {
            s.set_cross(i, j, &embed(&(pinf * b[(i, j)]), 0.0));
        }
    }
    s
}

/// The broad state tracked over 12 rows with known associations (exact Kalman updates), then
/// predicted to the next row: the state of a typical row in the middle of a frame.
pub fn tracked_state(n: usize, rng: &mut ChaCha8Rng) -> State {
    let f = embed(&DEFAULT.spatial.f, 1.0);
    let q = embed(&DEFAULT.spatial.q, 0.0);
    let mut s = broad_state(n);
    for r in 0..12 {
        if r > 0 {
            s.predict(&f, &q, &DEFAULT.coreg);
        }
        for t in 0..n {
            let z = lane_x(t, n) + 0.1 * normal(rng);
            assert!(s.update_single(t, &h(), z, DEFAULT.hyper.meas_noise));
        }
    }
    s.predict(&f, &q, &DEFAULT.coreg);
    s
}

/// The row parameters of `Config::DEFAULT` (gated miss model).
pub fn core_params() -> RowParams {
    let c = Config::DEFAULT;
    RowParams {
        pd: c.pd,
        pg: c.pg,
        gamma: c.gamma,
        clutter_density: c.clutter_density,
        r: DEFAULT.hyper.meas_noise,
        miss: row::MissModel::Gated,
    }
}

/// `m` points uniform in `±half_width`.
pub fn clustered(rng: &mut ChaCha8Rng, m: usize, half_width: f32) -> Vec<f32> {
    (0..m)
        .map(|_| (rng.random::<f32>() * 2.0 - 1.0) * half_width)
        .collect()
}

/// A row input: the predicted state, the points and the event budget.
#[derive(Debug, Clone)]
pub struct RowInput {
    /// The predicted state.
    pub state: State,
    /// The row's points.
    pub points: Vec<f32>,
    /// The event budget.
    pub budget: usize,
}

/// The rows of the row benches, drawn from seed 2024, with their names:
/// * `row_typical` — 6 tracked lanes ([`tracked_state`]), one point per lane (truth + 0.1 m
///   noise) and 2 clutter points uniform in ±12 m;
/// * `row_worst` — 6 tracks with the broad prior ([`broad_state`]), 16 points clustered in
///   [−3, 3] m: all inside every gate;
/// * `row_maxwork` — the typical state, 2 points inside each of the first 5 gates and 1 inside
///   the sixth, none shared: 3⁵ · 2 = 486 events, all 2⁶ = 64 patterns;
/// * `row_dense512`, `row_dense_exact` — 4 broad tracks, 8 points clustered in [−2, 2] m (all
///   inside every gate), with E = 512 and E = 4096.
pub fn row_inputs() -> [(&'static str, RowInput); 5] {
    let mut rng = ChaCha8Rng::seed_from_u64(2024);
    let typical = tracked_state(LANES, &mut rng);
    let mut pts: Vec<f32> = (0..LANES)
        .map(|t| lane_x(t, LANES) + 0.1 * normal(&mut rng))
        .collect();
    pts.extend((0..2).map(|_| (rng.random::<f32>() * 2.0 - 1.0) * 12.0));
    let broad = broad_state(LANES);
    let worst = clustered(&mut rng, PER_ROW, 3.0);
    let mut heavy: Vec<f32> = (0..LANES - 1)
        .flat_map(|t| [lane_x(t, LANES) - 0.15, lane_x(t, LANES) + 0.15])
        .collect();
    heavy.push(lane_x(LANES - 1, LANES) + 0.05);
    let dense_state = broad_state(4);
    let dense = clustered(&mut rng, 8, 2.0);
    let input = |state: State, points: Vec<f32>, budget: usize| RowInput {
        state,
        points,
        budget,
    };
    [
        ("row_typical", input(typical, pts, EVENTS)),
        ("row_worst", input(broad, worst, EVENTS)),
        ("row_maxwork", input(typical, heavy, EVENTS)),
        ("row_dense512", input(dense_state, dense.clone(), EVENTS)),
        ("row_dense_exact", input(dense_state, dense, 4096)),
    ]
}

/// Rows of the worst-case frame that hold only the 6 lane points (they let all 6 tracks start:
/// at most `max_tentative = 2` tentative tracks at once, confirmed after `confirm_hits = 6`).
pub const LEAD_IN_ROWS: usize = 16;

/// M = 256 points: [`LEAD_IN_ROWS`] rows with one point per lane (6 straight lanes 3.6 m apart),
/// then `(256 − 6·LEAD_IN_ROWS)/16 = 10` consecutive full rows of 16 points: the 6 lane points
/// plus 10 clutter points each within ±0.4 m of a random lane (inside its gate).
pub fn worst_frame(rng: &mut ChaCha8Rng) -> Vec<[f32; 2]> {
    let du = (DEFAULT.hyper.u_max - DEFAULT.hyper.u_min) / 60.0;
    let mut pts = Vec::with_capacity(MEAS);
    let full_rows = (MEAS - LANES * LEAD_IN_ROWS) / PER_ROW;
    for r in 0..LEAD_IN_ROWS + full_rows {
        let u = DEFAULT.hyper.u_min + r as f32 * du;
        for t in 0..LANES {
            pts.push([u, lane_x(t, LANES) + 0.1 * normal(rng)]);
        }
        if r < LEAD_IN_ROWS {
            continue;
        }
        for _ in LANES..PER_ROW {
            let t = rng.random_range(0..LANES);
            pts.push([
                u,
                lane_x(t, LANES) + (rng.random::<f32>() * 2.0 - 1.0) * 0.4,
            ]);
        }
    }
    pts
}

/// The typical frame: 3 curved lanes (RBF shape, σ² = 4 m², ℓ = 35 m), clutter 0.05 /m over
/// ±12 m, 61 rows (≈ 240 points), seed 4.
pub fn typical_scenario() -> Scenario {
    Scenario::generate(&ScenarioConfig::curved(), 4)
}

/// A scenario's points in f32, `[u, x]`.
pub fn to_f32(sc: &Scenario) -> Vec<[f32; 2]> {
    sc.points
        .iter()
        .map(|&(u, x)| [u as f32, x as f32])
        .collect()
}

/// An empty output buffer.
pub fn empty_out() -> Obs {
    [LaneObservation::EMPTY; LANES]
}
