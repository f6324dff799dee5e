//! Lane identity (`stjpdacf::temporal::identity`): the core's assignment against the brute-force
//! f64 reference on seeded random cases, id stability over multi-frame sequences, and properties
//! under arbitrary (non-finite) input.

use nalgebra::{SMatrix, SVector};
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha20Rng;
use stjpdacf::spatial::filter::{LaneObservation, Status};
use stjpdacf::temporal::identity::{
    IdentityConfig, LaneId, LanePrediction, LaneTable, ObsFate, SlotFate,
};
use stjpdacf_reference::identity::{self as reference, Curve, Gate};

const D: usize = 6;
const N: usize = 8;

fn observation(present: [bool; N], z: [f32; N], var: [f32; N]) -> LaneObservation<N> {
    LaneObservation {
        status: Status::Confirmed,
        present,
        z: SVector::from(z),
        cov: SMatrix::from_diagonal(&SVector::from(var)),
        u_first: 3.0,
        u_last: 80.0,
        existence: 1.0,
        rank: 0,
        llr: 0.0,
    }
}

fn flat(x: f32) -> LaneObservation<N> {
    observation([true; N], [x; N], [0.05; N])
}

fn obs_curve(o: &LaneObservation<N>) -> Curve {
    Curve {
        present: o.present.to_vec(),
        z: o.z.iter().map(|&v| f64::from(v)).collect(),
        var: o.cov.diagonal().iter().map(|&v| f64::from(v)).collect(),
    }
}

fn pred_curve(p: &LanePrediction<N>) -> Curve {
    Curve {
        present: p.present.to_vec(),
        z: p.z.iter().map(|&v| f64::from(v)).collect(),
        var: p.var.iter().map(|&v| f64::from(v)).collect(),
    }
}

/// A table whose live slots are exactly `live` (ids 0..6 assigned, then the others removed).
fn table_with(live: [bool; D]) -> LaneTable<D> {
    let mut t = LaneTable::<D>::new();
    let seeds: Vec<LaneObservation<N>> = (0..D).map(|k| flat(100.0 * k as f32)).collect();
    let none = [LanePrediction::EMPTY; D];
    let out = t.associate(&none, &seeds, &IdentityConfig::DEFAULT);
    assert_eq!(out.report.started, D as u32);
    let preds: [LanePrediction<N>; D] =
        core::array::from_fn(|k| LanePrediction::from_observation(&seeds[k], 0.05));
    let keep: Vec<LaneObservation<N>> = (0..D).filter(|&k| live[k]).map(|k| seeds[k]).collect();
    let cfg = IdentityConfig {
        max_misses: 1,
        ..IdentityConfig::DEFAULT
    };
    let _ = t.associate(&preds, &keep, &cfg);
    for (k, &l) in live.iter().enumerate() {
        assert_eq!(t.lane(k).is_some(), l);
    }
    t
}

fn random_mask(rng: &mut ChaCha20Rng, p: f64) -> [bool; N] {
    core::array::from_fn(|_| rng.random_bool(p))
}

#[test]
fn core_matches_brute_force_reference_on_seeded_random_cases() {
    let mut rng = ChaCha20Rng::seed_from_u64(0x1d_e7_17_7e);
    let cfg = IdentityConfig::DEFAULT;
    let g = Gate {
        gate: f64::from(cfg.gate),
        min_common: usize::from(cfg.min_common),
    };
    let (mut accepted, mut tried, mut with_matches, mut nontrivial) = (0, 0, 0, 0);
    while accepted < 600 {
        tried += 1;
        assert!(tried < 20_000, "too many near ties");
        let live: [bool; D] = core::array::from_fn(|_| rng.random_bool(0.7));
        let centres: [f32; D] = core::array::from_fn(|k| -9.0 + 3.6 * k as f32);
        // Lanes bunched more tightly than real ones sometimes, so that gates overlap.
        let squeeze = if rng.random_bool(0.5) { 1.0 } else { 0.15 };
        let preds: [LanePrediction<N>; D] = core::array::from_fn(|k| LanePrediction {
            present: random_mask(&mut rng, 0.75),
            z: SVector::from_fn(|i, _| {
                centres[k] * squeeze + 0.02 * i as f32 + rng.random_range(-0.1..0.1)
            }),
            var: SVector::from_fn(|_, _| rng.random_range(0.02f32..0.4)),
        });
        let n_obs = rng.random_range(0..=D);
        let obs: Vec<LaneObservation<N>> = (0..n_obs)
            .map(|_| {
                let k = rng.random_range(0..D);
                let shift = rng.random_range(-1.5f32..1.5);
                let z: [f32; N] = core::array::from_fn(|i| {
                    centres[k] * squeeze + 0.02 * i as f32 + shift + rng.random_range(-0.2..0.2)
                });
                let var: [f32; N] = core::array::from_fn(|_| rng.random_range(0.02..0.4));
                observation(random_mask(&mut rng, 0.75), z, var)
            })
            .collect();

        let oc: Vec<Curve> = obs.iter().map(obs_curve).collect();
        let lc: Vec<Option<Curve>> = (0..D)
            .map(|k| live[k].then(|| pred_curve(&preds[k])))
            .collect();
        // Exclude pairs whose f64 cost sits at the gate (f32 could fall on the other side).
        let at_gate = oc.iter().any(|o| {
            lc.iter().flatten().any(|p| {
                reference::pair_cost(o, p, g.min_common)
                    .is_some_and(|c| (c - g.gate).abs() <= 1e-3 * g.gate)
            })
        });
        let want = reference::assign(&oc, &lc, g);
        let near_tie = want
            .second_total
            .is_some_and(|s| s - want.best.total <= 1e-3 * want.best.total.abs().max(1.0));
        if at_gate || near_tie {
            continue;
        }
        accepted += 1;

        let mut t = table_with(live);
        let out = t.associate(&preds, &obs, &cfg);
        let got: Vec<Option<usize>> = out
            .obs_fates()
            .iter()
            .map(|f| match *f {
                ObsFate::Matched { slot } => Some(usize::from(slot)),
                _ => None,
            })
            .collect();
        assert_eq!(got, want.best.lane_of, "case {tried}");
        let total = f64::from(out.report.total_cost);
        assert!(
            (total - want.best.total).abs() <= 1e-4 * want.best.total.max(1.0),
            "case {tried}: total {total} vs {}",
            want.best.total
        );
        let m = got.iter().flatten().count();
        if m > 0 {
            with_matches += 1;
        }
        // Cases where some observation had a choice of lanes.
        let choices = oc
            .iter()
            .filter(|o| {
                lc.iter()
                    .flatten()
                    .filter(|p| reference::allowed_cost(o, p, g).is_some())
                    .count()
                    > 1
            })
            .count();
        if choices > 0 {
            nontrivial += 1;
        }
        assert!(out.report.leaves <= 13_327);
    }
    assert!(with_matches > 300, "{with_matches}");
    assert!(nontrivial > 50, "{nontrivial}");
}

/// A minimal per-frame driver: constant-position predictions from each slot's last observation,
/// variance growing with the misses.
struct Driver {
    table: LaneTable<D>,
    last: [Option<LaneObservation<N>>; D],
    cfg: IdentityConfig,
}

impl Driver {
    fn new() -> Self {
        Self {
            table: LaneTable::new(),
            last: [None; D],
            cfg: IdentityConfig::DEFAULT,
        }
    }

    /// One frame; returns the id of each observation's lane (None when dropped).
    fn frame(&mut self, obs: &[LaneObservation<N>]) -> Vec<Option<LaneId>> {
        let preds: [LanePrediction<N>; D] =
            core::array::from_fn(|k| match (&self.last[k], self.table.lane(k)) {
                (Some(o), Some(l)) => {
                    LanePrediction::from_observation(o, 0.05 * (1.0 + f32::from(l.misses)))
                }
                _ => LanePrediction::EMPTY,
            });
        let out = self.table.associate(&preds, obs, &self.cfg);
        for (k, f) in out.slots.iter().enumerate() {
            match *f {
                SlotFate::Matched { obs: i } | SlotFate::New { obs: i, .. } => {
                    self.last[k] = Some(obs[usize::from(i)]);
                }
                SlotFate::Removed { .. } | SlotFate::Free => self.last[k] = None,
                SlotFate::Coasting { .. } => {}
            }
        }
        out.obs_fates()
            .iter()
            .map(|f| match *f {
                ObsFate::Matched { slot } | ObsFate::New { slot } => {
                    self.table.lane(usize::from(slot)).map(|l| l.id)
                }
                ObsFate::Dropped(_) => None,
            })
            .collect()
    }
}

fn lane_at(x: f32) -> LaneObservation<N> {
    // A gently curving lane, offset x.
    let z: [f32; N] = core::array::from_fn(|i| x + 0.002 * (i as f32 * 10.0).powi(2) / 10.0);
    observation([true; N], z, [0.05; N])
}

#[test]
fn ids_are_stable_under_drift_short_gaps_and_new_after_removal() {
    let mut d = Driver::new();
    let xs = [-5.4f32, -1.8, 1.8, 5.4];
    let ids0 = d.frame(&xs.map(lane_at));
    assert!(ids0.iter().all(Option::is_some));
    let max_misses = usize::from(d.cfg.max_misses);
    let mut f = 1;
    // Drift 0.1 m/frame for 20 frames: ids unchanged.
    while f <= 20 {
        let ids = d.frame(&xs.map(|x| lane_at(x + 0.1 * f as f32)));
        assert_eq!(ids, ids0, "frame {f}");
        f += 1;
    }
    // Lane 2 disappears for max_misses − 1 frames, then comes back with its id.
    for _ in 0..max_misses - 1 {
        let obs: Vec<_> = [0, 1, 3]
            .iter()
            .map(|&k| lane_at(xs[k] + 0.1 * f as f32))
            .collect();
        let ids = d.frame(&obs);
        assert_eq!(ids, vec![ids0[0], ids0[1], ids0[3]], "frame {f}");
        f += 1;
    }
    let ids = d.frame(&xs.map(|x| lane_at(x + 0.1 * f as f32)));
    assert_eq!(ids, ids0, "back after a short gap");
    f += 1;
    // Now it disappears for max_misses frames: removed, and back with a fresh id.
    for _ in 0..max_misses {
        let obs: Vec<_> = [0, 1, 3]
            .iter()
            .map(|&k| lane_at(xs[k] + 0.1 * f as f32))
            .collect();
        let _ = d.frame(&obs);
        f += 1;
    }
    assert_eq!(d.table.len(), 3);
    let ids = d.frame(&xs.map(|x| lane_at(x + 0.1 * f as f32)));
    assert_eq!(ids[0], ids0[0]);
    assert_eq!(ids[1], ids0[1]);
    assert_eq!(ids[3], ids0[3]);
    let fresh = ids[2].unwrap();
    assert!(ids0.iter().flatten().all(|&id| id != fresh), "id reused");
    assert!(fresh.0 > ids0.iter().flatten().map(|i| i.0).max().unwrap());
}

#[test]
fn a_lane_change_keeps_ids() {
    let mut d = Driver::new();
    let xs = [-5.4f32, -1.8, 1.8, 5.4];
    let ids0 = d.frame(&xs.map(lane_at));
    // The car changes lane to the left: every lane moves 3.6 m right over 10 frames.
    for f in 1..=10 {
        let ids = d.frame(&xs.map(|x| lane_at(x + 0.36 * f as f32)));
        assert_eq!(ids, ids0, "frame {f}");
    }
    // A new lane appears on the left, the right one leaves the view: the rest keep their ids.
    let obs: Vec<_> = [-5.4f32, -1.8, 1.8, 5.4]
        .iter()
        .map(|&x| lane_at(x))
        .collect();
    let ids = d.frame(&obs);
    assert_eq!(&ids[1..], &ids0[..3]);
    assert!(ids0.iter().all(|&i| i != ids[0]));
}

fn value() -> impl Strategy<Value = f32> {
    prop_oneof![
        8 => -10.0f32..10.0,
        1 => Just(f32::NAN),
        1 => Just(f32::INFINITY),
        1 => Just(f32::NEG_INFINITY),
        1 => Just(f32::MAX),
        1 => Just(0.0f32),
        1 => Just(-1e-3f32),
    ]
}

type Raw = (Vec<bool>, Vec<f32>, Vec<f32>);

fn curve() -> impl Strategy<Value = Raw> {
    (
        proptest::collection::vec(any::<bool>(), N),
        proptest::collection::vec(value(), N),
        proptest::collection::vec(prop_oneof![3 => 0.01f32..1.0, 1 => value()], N),
    )
}

fn arr<T: Copy + Default>(v: &[T]) -> [T; N] {
    core::array::from_fn(|i| v.get(i).copied().unwrap_or_default())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]
    #[test]
    fn any_input_keeps_the_table_consistent(
        frames in proptest::collection::vec(
            (proptest::collection::vec(curve(), 0..9), proptest::collection::vec(curve(), D)),
            1..8,
        ),
        gate in prop_oneof![3 => 0.5f32..20.0, 1 => value()],
        min_common in 0u8..5,
        max_misses in 0u16..4,
    ) {
        let cfg = IdentityConfig { gate, min_common, max_misses };
        let mut t = LaneTable::<D>::new();
        for (obs, preds) in &frames {
            let obs: Vec<_> = obs.iter().map(|(p, z, v)| observation(arr(p), arr(z), arr(v))).collect();
            let preds: [LanePrediction<N>; D] = core::array::from_fn(|k| {
                let (present, z, v) = &preds[k];
                LanePrediction {
                    present: arr(present),
                    z: SVector::from(arr(z)),
                    var: SVector::from(arr(v)),
                }
            });
            let before: Vec<_> = t.lanes().collect();
            let out = t.associate(&preds, &obs, &cfg);
            prop_assert!(t.len() <= D);
            let ids: Vec<u32> = t.lanes().map(|(_, l)| l.id.0).collect();
            let mut sorted = ids.clone();
            sorted.sort_unstable();
            sorted.dedup();
            prop_assert_eq!(sorted.len(), ids.len(), "duplicate ids");
            prop_assert_eq!(out.obs_fates().len(), obs.len().min(D));
            prop_assert!(out.report.leaves <= 13_327);
            // Each slot serves at most one observation, and the fates agree both ways.
            let mut seen = [false; D];
            for (i, f) in out.obs_fates().iter().enumerate() {
                match *f {
                    ObsFate::Matched { slot } => {
                        let s = usize::from(slot);
                        prop_assert!(!seen[s]);
                        seen[s] = true;
                        prop_assert_eq!(out.slots[s], SlotFate::Matched { obs: i as u8 });
                        prop_assert!(before.iter().any(|&(k, _)| k == s));
                    }
                    ObsFate::New { slot } => {
                        let s = usize::from(slot);
                        prop_assert!(!seen[s]);
                        seen[s] = true;
                        let new_here = matches!(out.slots[s], SlotFate::New { obs, .. } if usize::from(obs) == i);
                        prop_assert!(new_here);
                        prop_assert_eq!(t.lane(s).map(|l| l.age), Some(0));
                    }
                    ObsFate::Dropped(_) => {}
                }
            }
            let r = out.report;
            prop_assert_eq!(
                r.matched + r.started + r.dropped_no_slot + r.dropped_unusable,
                r.observations
            );
            prop_assert_eq!(r.excess_observations as usize, obs.len().saturating_sub(D));
        }
    }
}
