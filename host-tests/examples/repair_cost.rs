//! Cost of `Temporal::repair_covariance` at the reference configuration: six lanes born and
//! updated (an update each: the repair is due), then one repair. Run under callgrind to count
//! instructions: `valgrind --tool=callgrind target/release/examples/repair_cost`.
use nalgebra::{SMatrix, SVector};
use stjpdacf::spatial::filter::{LaneObservation, Status};
use stjpdacf::tables::DEFAULT;
use stjpdacf::temporal::smoother::Temporal;

fn main() {
    let mut t: Box<Temporal<6, 16, 7, 84, 42, 4>> = Box::new(Temporal::new());
    let mut ranks = [0u8; 6];
    for s in 0..6 {
        ranks[s] = s as u8;
        t.start_lane(&DEFAULT, s, s as u8, &ranks).expect("start");
    }
    for s in 0..6 {
        let obs = LaneObservation::<16> {
            status: Status::Confirmed,
            present: [true; 16],
            z: SVector::from_fn(|i, _| -5.5 + 2.0 * s as f32 + 0.01 * i as f32),
            cov: SMatrix::from_fn(|i, j| if i == j { 1e-3 } else { 0.0 }),
            u_first: 3.0,
            u_last: 40.0,
            existence: 1.0,
            rank: s as u8,
            llr: 0.0,
        };
        t.update(&DEFAULT, s, &obs).expect("update");
    }
    let due = t.filter().repair_due();
    let raised = std::hint::black_box(&mut t).repair_covariance(&DEFAULT);
    println!("repair due {due}, {raised} failed factorisations");
}
