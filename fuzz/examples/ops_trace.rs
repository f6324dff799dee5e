//! Prints the operations of a `temporal_ops` input and the temporal covariance's health after
//! each: `cargo run --release --example ops_trace -- FILE...`.
use stjpdacf::tables::DEFAULT;
use stjpdacf::temporal::smoother::Temporal;
use stjpdacf_test_support::fuzz::{
    check_temporal, decode_temporal_input, Op, PsdCheck, LANES, NX, POINTS, RANK,
};

fn main() {
    for f in std::env::args().skip(1) {
        let Ok(data) = std::fs::read(&f) else {
            eprintln!("cannot read {f}");
            continue;
        };
        let mut t: Box<Temporal<LANES, POINTS, RANK, NX, 42, 4>> = Box::new(Temporal::new());
        println!("== {f}");
        for (k, op) in decode_temporal_input(&data).iter().enumerate() {
            let (what, res) = op.apply(&mut t);
            println!("op {k}: {what} -> {res:?}");
            if let Op::Update(_, obs) = op {
                println!("   z {:?}", obs.z.as_slice());
            }
            let p = t.filter().covariance();
            for s in 0..LANES {
                if t.filter().is_active(s) {
                    let i0 = s * 2 * RANK;
                    let d: Vec<String> = (i0..i0 + 2 * RANK)
                        .map(|i| format!("{:.2e}", p[(i, i)]))
                        .collect();
                    println!("   slot {s} diag: {}", d.join(" "));
                }
            }
            match check_temporal(&t, &DEFAULT, PsdCheck::Eigen) {
                Ok(h) => println!("   health: min eig (corr) {:.3e}", h.min_eig_corr),
                Err(e) => println!("   VIOLATION: {e}"),
            }
        }
    }
}
