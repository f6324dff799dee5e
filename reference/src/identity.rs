//! Lane identity in f64 (docs/design.md §4.3), straight from the definition: the normalised squared
//! curve-space distance over the common index points, the gate, and the optimal assignment found by
//! brute force over every injective partial map from observations to live lanes. Unbounded and
//! plain on purpose; it shares no code with the core.
//!
//! Definitions (the same contract as the core's `temporal::identity`):
//! * `cost(o, p) = mean over points present in both of (z_o − z_p)² / (v_o + v_p)`;
//! * a pair is allowed iff it has at least `min_common` common points, every value read at them is
//!   finite, both variances are `≥ 0` with a positive sum, and `cost ≤ gate`;
//! * the total of an assignment is `Σ matched costs + gate · (unmatched observations + unmatched
//!   live lanes)`; the least total wins, ties to the first map in the order "observation by
//!   observation, lanes in slot order, then unmatched".

/// One curve at the index points: an observation (with the diagonal of its covariance) or a
/// lane's prediction.
#[derive(Debug, Clone, PartialEq)]
pub struct Curve {
    /// Point `i` is present.
    pub present: Vec<bool>,
    /// Lateral positions, metres.
    pub z: Vec<f64>,
    /// Variances, m².
    pub var: Vec<f64>,
}

/// Gate parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Gate {
    /// Largest allowed cost; also the price of an unmatched observation or lane.
    pub gate: f64,
    /// Fewest common points.
    pub min_common: usize,
}

/// The cost of a pair before the gate, `None` when it cannot be compared (too few common points
/// or a bad value at a common point).
pub fn pair_cost(obs: &Curve, pred: &Curve, min_common: usize) -> Option<f64> {
    let n = obs.present.len().min(pred.present.len());
    let mut terms = Vec::new();
    for i in 0..n {
        if !(obs.present[i] && pred.present[i]) {
            continue;
        }
        let (zo, zp, vo, vp) = (obs.z[i], pred.z[i], obs.var[i], pred.var[i]);
        let fine = [zo, zp, vo, vp].iter().all(|v| v.is_finite()) && vo >= 0.0 && vp >= 0.0;
        if !fine || vo + vp <= 0.0 {
            return None;
        }
        terms.push((zo - zp).powi(2) / (vo + vp));
    }
    if terms.len() < min_common.max(1) {
        return None;
    }
    let mean = terms.iter().sum::<f64>() / terms.len() as f64;
    mean.is_finite().then_some(mean)
}

/// The gated cost: `Some` only for an allowed pair.
pub fn allowed_cost(obs: &Curve, pred: &Curve, g: Gate) -> Option<f64> {
    pair_cost(obs, pred, g.min_common).filter(|&c| c <= g.gate)
}

/// One assignment and its total.
#[derive(Debug, Clone, PartialEq)]
pub struct Assignment {
    /// Lane slot of each observation, `None` when unmatched.
    pub lane_of: Vec<Option<usize>>,
    /// The total cost.
    pub total: f64,
}

/// The optimal assignment and the total of the runner-up (another map), for tie checks.
#[derive(Debug, Clone, PartialEq)]
pub struct Ranked {
    /// The optimum (first in enumeration order among equal totals).
    pub best: Assignment,
    /// The least total among all other maps, `None` when there is no other map.
    pub second_total: Option<f64>,
}

/// Every injective partial map from `obs` into the live lanes (`lanes[slot]` is `None` for a free
/// slot) using allowed pairs only, in enumeration order, with its total.
pub fn all_assignments(obs: &[Curve], lanes: &[Option<Curve>], g: Gate) -> Vec<Assignment> {
    let cost: Vec<Vec<Option<f64>>> = obs
        .iter()
        .map(|o| {
            lanes
                .iter()
                .map(|l| l.as_ref().and_then(|p| allowed_cost(o, p, g)))
                .collect()
        })
        .collect();
    let live = lanes.iter().filter(|l| l.is_some()).count();
    let mut out = Vec::new();
    let mut cur = Vec::new();
    fn rec(
        i: usize,
        cost: &[Vec<Option<f64>>],
        cur: &mut Vec<Option<usize>>,
        live: usize,
        gate: f64,
        out: &mut Vec<Assignment>,
    ) {
        if i == cost.len() {
            let matched: Vec<(usize, usize)> = cur
                .iter()
                .enumerate()
                .filter_map(|(o, l)| l.map(|l| (o, l)))
                .collect();
            let sum: f64 = matched.iter().map(|&(o, l)| cost[o][l].unwrap()).sum();
            let unmatched = (cost.len() - matched.len()) + (live - matched.len());
            out.push(Assignment {
                lane_of: cur.clone(),
                total: sum + gate * unmatched as f64,
            });
            return;
        }
        for l in 0..cost[i].len() {
            if cost[i][l].is_some() && !cur.contains(&Some(l)) {
                cur.push(Some(l));
                rec(i + 1, cost, cur, live, gate, out);
                cur.pop();
            }
        }
        cur.push(None);
        rec(i + 1, cost, cur, live, gate, out);
        cur.pop();
    }
    rec(0, &cost, &mut cur, live, g.gate, &mut out);
    out
}

/// The optimal assignment by brute force.
pub fn assign(obs: &[Curve], lanes: &[Option<Curve>], g: Gate) -> Ranked {
    let all = all_assignments(obs, lanes, g);
    let mut best = 0;
    for (k, a) in all.iter().enumerate() {
        if a.total < all[best].total {
            best = k;
        }
    }
    let second_total = all
        .iter()
        .enumerate()
        .filter(|&(k, _)| k != best)
        .map(|(_, a)| a.total)
        .min_by(f64::total_cmp);
    Ranked {
        best: all[best].clone(),
        second_total,
    }
}
