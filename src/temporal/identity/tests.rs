use super::*;
use crate::observation::Status;
use nalgebra::SMatrix;

const P: usize = 5;

fn obs(z: [f32; P], present: [bool; P], var: f32) -> LaneObservation<P> {
    LaneObservation {
        status: Status::Confirmed,
        present,
        z: SVector::from(z),
        cov: SMatrix::from_diagonal(&SVector::from(present.map(|p| if p { var } else { 0.0 }))),
        u_first: 3.0,
        u_last: 80.0,
        existence: 1.0,
        rank: 0,
        llr: 0.0,
    }
}

fn flat(x: f32) -> LaneObservation<P> {
    obs([x; P], [true; P], 0.05)
}

fn pred(z: [f32; P], present: [bool; P], var: f32) -> LanePrediction<P> {
    LanePrediction {
        present,
        z: SVector::from(z),
        var: SVector::from([var; P]),
    }
}

#[test]
fn pair_cost_is_mean_normalised_squared_distance_over_common_points() {
    let o = obs(
        [0.0, 1.0, 2.0, 3.0, 9.0],
        [true, true, true, true, false],
        0.5,
    );
    let p = pred(
        [0.0, 0.0, 0.0, 0.0, 0.0],
        [false, true, true, true, true],
        1.5,
    );
    // Common points 1..=3: (1 + 4 + 9) / 2 / 3.
    let c = pair_cost(&o, &p, 3).unwrap();
    assert!((c - 14.0 / 6.0).abs() < 1e-6, "{c}");
    assert_eq!(pair_cost(&o, &p, 4), Err(PairReject::TooFewCommon));
}

#[test]
fn non_finite_or_bad_variance_rejects_the_pair_only_where_common() {
    let p = pred([0.0; P], [true, true, true, true, false], 1.0);
    let mut o = flat(0.5);
    o.z[4] = f32::NAN; // not common: harmless
    assert!(pair_cost(&o, &p, 3).is_ok());
    o.z[2] = f32::INFINITY;
    assert_eq!(pair_cost(&o, &p, 3), Err(PairReject::NonFinite));
    let mut o = flat(0.5);
    o.cov[(1, 1)] = -0.01;
    assert_eq!(pair_cost(&o, &p, 3), Err(PairReject::NonFinite));
    let o = obs([0.5; P], [true; P], 0.0);
    let p0 = pred([0.0; P], [true; P], 0.0);
    assert_eq!(pair_cost(&o, &p0, 3), Err(PairReject::NonFinite));
}

#[test]
fn search_stays_within_the_leaf_bound() {
    // Costs decreasing along the search order keep improving the best, so little prunes.
    let mut cost = [[0.0f32; MAX_LANES]; MAX_LANES];
    for (i, row) in cost.iter_mut().enumerate() {
        for (j, c) in row.iter_mut().enumerate() {
            *c = 0.9 - 0.01 * (i * 6 + j) as f32 * (j % 2) as f32;
        }
    }
    let allowed = [0b11_1111u32; MAX_LANES];
    let s = search(&cost, &allowed, 6, 6, 1.0);
    assert!(s.leaves > 1 && s.leaves <= 13_327, "{}", s.leaves);
    assert_eq!(s.assign[..6].iter().filter(|&&l| l != NONE).count(), 6);
    // With a gate of 1 and costs 0.5 every full matching costs 3, nothing ties below it.
    let cost = [[0.5f32; MAX_LANES]; MAX_LANES];
    let s = search(&cost, &allowed, 6, 6, 1.0);
    assert!((s.total - 3.0).abs() < 1e-6);
    assert!(s.leaves <= 13_327);
    // Identity assignment: the first in slot order.
    assert_eq!(&s.assign[..6], &[0, 1, 2, 3, 4, 5]);
}

#[test]
fn search_prefers_optimal_total_over_greedy() {
    // Greedy (obs 0 takes lane 0 at 1.0) would force obs 1 to lane 1 at 8.0: total 9.
    // Optimal: obs 0 → lane 1 (2.0), obs 1 → lane 0 (1.5): 3.5.
    let mut cost = [[f32::INFINITY; MAX_LANES]; MAX_LANES];
    cost[0][0] = 1.0;
    cost[0][1] = 2.0;
    cost[1][0] = 1.5;
    cost[1][1] = 8.0;
    let allowed = [0b11u32; MAX_LANES];
    let s = search(&cost, &allowed, 2, 2, 9.0);
    assert_eq!(&s.assign[..2], &[1, 0]);
    assert!((s.total - 3.5).abs() < 1e-6);
}

#[test]
fn lanes_start_match_coast_and_are_removed_with_fresh_ids() {
    let cfg = IdentityConfig {
        max_misses: 3,
        ..IdentityConfig::DEFAULT
    };
    let mut t: LaneTable<3> = LaneTable::new();
    let none = [LanePrediction::EMPTY; 3];
    let a = flat(-1.8);
    let b = flat(1.8);
    let out = t.associate(&none, &[a, b], &cfg);
    assert_eq!(
        out.obs_fates(),
        &[ObsFate::New { slot: 0 }, ObsFate::New { slot: 1 }]
    );
    assert_eq!(t.lane(0).unwrap().id, LaneId(0));
    assert_eq!(t.lane(1).unwrap().id, LaneId(1));
    let preds = [
        LanePrediction::from_observation(&a, 0.1),
        LanePrediction::from_observation(&b, 0.1),
        LanePrediction::EMPTY,
    ];
    // Only b is seen: a coasts twice, then is removed at its third miss.
    for miss in 1..=2u16 {
        let out = t.associate(&preds, &[b], &cfg);
        assert_eq!(out.obs_fates(), &[ObsFate::Matched { slot: 1 }]);
        assert_eq!(out.slots[0], SlotFate::Coasting { misses: miss });
        assert_eq!(t.lane(0).unwrap().misses, miss);
    }
    let out = t.associate(&preds, &[b], &cfg);
    assert_eq!(out.slots[0], SlotFate::Removed { id: LaneId(0) });
    assert!(t.lane(0).is_none());
    // a comes back: a new lane with a fresh id in the lowest free slot.
    let out = t.associate(&preds, &[a, b], &cfg);
    assert_eq!(out.obs_fates()[0], ObsFate::New { slot: 0 });
    assert_eq!(t.lane(0).unwrap().id, LaneId(2));
    assert_eq!(t.lane(1).unwrap().age, 4);
}

#[test]
fn full_table_drops_and_freed_slot_is_reused_with_replaced() {
    let cfg = IdentityConfig {
        max_misses: 1,
        ..IdentityConfig::DEFAULT
    };
    let mut t: LaneTable<1> = LaneTable::new();
    let none = [LanePrediction::EMPTY; 1];
    let out = t.associate(&none, &[flat(0.0), flat(3.6)], &cfg);
    assert_eq!(
        out.obs_fates(),
        &[ObsFate::New { slot: 0 }],
        "only LANES observations considered"
    );
    assert_eq!(out.report.excess_observations, 1);
    let preds = [LanePrediction::from_observation(&flat(0.0), 0.1)];
    // Far away: lane 0 misses (max_misses 1: removed) and the observation takes its slot.
    let out = t.associate(&preds, &[flat(10.0)], &cfg);
    assert_eq!(
        out.slots[0],
        SlotFate::New {
            obs: 0,
            replaced: Some(LaneId(0))
        }
    );
    assert_eq!(out.report.gated_out, 1);
    assert_eq!(t.lane(0).unwrap().id, LaneId(1));
    // Full with a matched lane: a second, far observation is dropped.
    let cfg = IdentityConfig::DEFAULT;
    let preds = [LanePrediction::from_observation(&flat(10.0), 0.1)];
    let out = t.associate(&preds, &[flat(10.0), flat(-5.0)], &cfg);
    assert_eq!(
        out.obs_fates(),
        &[ObsFate::Matched { slot: 0 }],
        "the second observation is beyond LANES"
    );
    let mut t: LaneTable<2> = LaneTable::new();
    let _ = t.associate(&[LanePrediction::EMPTY; 2], &[flat(0.0), flat(3.6)], &cfg);
    let preds = [
        LanePrediction::from_observation(&flat(0.0), 0.1),
        LanePrediction::from_observation(&flat(3.6), 0.1),
    ];
    let out = t.associate(&preds, &[flat(20.0), flat(3.6)], &cfg);
    assert_eq!(
        out.obs_fates(),
        &[
            ObsFate::Dropped(DropReason::NoSlot),
            ObsFate::Matched { slot: 1 }
        ]
    );
    assert_eq!(out.slots[0], SlotFate::Coasting { misses: 1 });
    assert_eq!(out.report.dropped_no_slot, 1);
}

/// Slots by existence: with every slot taken, an observation with positive evidence takes the
/// slot of the coasting lane of lowest finite hold; matched lanes, lanes that hold (`∞`) and
/// observations with negative evidence change nothing; without holds the table is
/// [`LaneTable::associate_births`].
#[test]
fn full_table_yields_the_weakest_coasting_slot_to_positive_evidence() {
    let cfg = IdentityConfig::DEFAULT;
    let start = |t: &mut LaneTable<3>| {
        let _ = t.associate(
            &[LanePrediction::EMPTY; 3],
            &[flat(-3.6), flat(0.0), flat(3.6)],
            &cfg,
        );
    };
    let preds = [
        LanePrediction::from_observation(&flat(-3.6), 0.1),
        LanePrediction::from_observation(&flat(0.0), 0.1),
        LanePrediction::from_observation(&flat(3.6), 0.1),
    ];
    let strong = LaneObservation {
        llr: 2.0,
        ..flat(7.2)
    };
    let weak = LaneObservation {
        llr: -0.5,
        ..flat(7.2)
    };
    // Lane 0 is matched (held low all the same), lanes 1 and 2 coast; 2 is the weakest.
    let hold = [0.01, 0.05, 0.02];
    let seen = flat(-3.6);
    let may = [true; 3];

    let mut t: LaneTable<3> = LaneTable::new();
    start(&mut t);
    let out = t.associate_claims(&preds, &[seen, strong], &cfg, &may, Some(&hold), 0);
    assert_eq!(
        out.obs_fates(),
        &[ObsFate::Matched { slot: 0 }, ObsFate::New { slot: 2 }]
    );
    assert_eq!(
        out.slots[2],
        SlotFate::New {
            obs: 1,
            replaced: Some(LaneId(2))
        }
    );
    assert_eq!(out.slots[1], SlotFate::Coasting { misses: 1 });
    assert_eq!((out.report.evicted, out.report.removed), (1, 1));
    assert_eq!((out.report.coasting, out.report.started), (1, 1));
    assert_eq!(t.lane(2).unwrap().id, LaneId(3));

    // Negative evidence, every lane holding, a refused start, no holds: dropped for want of a slot.
    for (o, hold, may) in [
        (weak, Some([0.01, 0.05, 0.02]), [true; 3]),
        (
            strong,
            Some([0.01, f32::INFINITY, f32::INFINITY]),
            [true; 3],
        ),
        (strong, Some([0.01, 0.05, 0.02]), [true, false, true]),
        (strong, None, [true; 3]),
    ] {
        let mut t: LaneTable<3> = LaneTable::new();
        start(&mut t);
        let out = t.associate_claims(&preds, &[seen, o], &cfg, &may, hold.as_ref(), 0);
        assert_eq!(out.obs_fates()[0], ObsFate::Matched { slot: 0 });
        assert!(matches!(out.obs_fates()[1], ObsFate::Dropped(_)));
        assert_eq!((out.report.evicted, out.report.removed), (0, 0));
        assert!((0..3).all(|s| t.lane(s).unwrap().id == LaneId(s as u32)));
    }

    // Two claims in one frame take the two weakest slots, in input order.
    let mut t: LaneTable<3> = LaneTable::new();
    start(&mut t);
    let far = LaneObservation {
        llr: 0.0,
        ..flat(-7.2)
    };
    let out = t.associate_claims(&preds, &[seen, strong, far], &cfg, &may, Some(&hold), 0);
    assert_eq!(
        out.obs_fates(),
        &[
            ObsFate::Matched { slot: 0 },
            ObsFate::New { slot: 2 },
            ObsFate::New { slot: 1 }
        ]
    );
    assert_eq!(out.report.evicted, 2);
}

#[test]
fn unusable_and_non_finite_observations_do_not_start_or_match_lanes() {
    let cfg = IdentityConfig::DEFAULT;
    let mut t: LaneTable<2> = LaneTable::new();
    let mut bad = flat(0.0);
    bad.z = SVector::from([f32::NAN; P]);
    let few = obs([0.0; P], [true, true, false, false, false], 0.05);
    let out = t.associate(&[LanePrediction::EMPTY; 2], &[bad, few], &cfg);
    assert_eq!(
        out.obs_fates(),
        &[
            ObsFate::Dropped(DropReason::Unusable),
            ObsFate::Dropped(DropReason::Unusable)
        ]
    );
    assert!(t.is_empty());
    let _ = t.associate(&[LanePrediction::EMPTY; 2], &[flat(0.0)], &cfg);
    let mut preds = [LanePrediction::from_observation(&flat(0.0), 0.1); 2];
    preds[0].var[0] = f32::NAN;
    let out = t.associate(&preds, &[flat(0.0)], &cfg);
    assert_eq!(out.report.non_finite_pairs, 1);
    // The pair is gated out, so the observation starts a second lane.
    assert_eq!(out.obs_fates(), &[ObsFate::New { slot: 1 }]);
    // A NaN gate admits nothing and still terminates.
    let cfg = IdentityConfig {
        gate: f32::NAN,
        ..IdentityConfig::DEFAULT
    };
    let preds = [LanePrediction::from_observation(&flat(0.0), 0.1); 2];
    let out = t.associate(&preds, &[flat(0.1)], &cfg);
    assert_eq!(out.report.gated_out, 2);
    assert_eq!(out.report.allowed_pairs, 0);
    assert_eq!(out.report.total_cost, 0.0);
}

#[test]
fn ids_skip_live_ids_after_wrapping() {
    let cfg = IdentityConfig::DEFAULT;
    let mut t: LaneTable<3> = LaneTable::starting_at(u32::MAX);
    let none = [LanePrediction::EMPTY; 3];
    let _ = t.associate(&none, &[flat(0.0), flat(3.6)], &cfg);
    assert_eq!(t.lane(0).unwrap().id, LaneId(u32::MAX));
    assert_eq!(t.lane(1).unwrap().id, LaneId(0));
    // Force the counter back onto a live id: it must be skipped.
    t.next_id = 0;
    let preds = [
        LanePrediction::from_observation(&flat(0.0), 0.1),
        LanePrediction::from_observation(&flat(3.6), 0.1),
        LanePrediction::EMPTY,
    ];
    let _ = t.associate(&preds, &[flat(0.0), flat(3.6), flat(7.2)], &cfg);
    assert_eq!(t.lane(2).unwrap().id, LaneId(1));
    assert_eq!(t.next_id(), 2);
}

/// Observations beyond the first `LANES` are ignored (counted in `excess_observations` only):
/// their pairs must not enter the pair counters.
#[test]
fn excess_observations_do_not_enter_the_pair_counters() {
    let cfg = IdentityConfig::DEFAULT;
    let mut t: LaneTable<2> = LaneTable::new();
    let _ = t.associate(&[LanePrediction::EMPTY; 2], &[flat(0.0)], &cfg);
    let preds = [
        LanePrediction::from_observation(&flat(0.0), 0.1),
        LanePrediction::EMPTY,
    ];
    // Three observations, all matching lane 0's prediction; only the first two are considered.
    let out = t.associate(&preds, &[flat(0.0), flat(0.01), flat(0.02)], &cfg);
    assert_eq!(out.report.observations, 2);
    assert_eq!(out.report.excess_observations, 1);
    assert_eq!(out.report.allowed_pairs, 2, "{:?}", out.report);
}
