//! Prints what a fuzz input does: `cargo run --release --example show -- TARGET FILE`.
fn main() {
    let mut a = std::env::args().skip(1);
    let (target, path) = (a.next().unwrap_or_default(), a.next().unwrap_or_default());
    let data = std::fs::read(&path).unwrap_or_default();
    let r = match target.as_str() {
        "tracker_step" => {
            for (at, pts) in stjpdacf_fuzz::decode_tracker_input(&data) {
                println!("t = {at} µs, {} points: {pts:?}", pts.len());
            }
            stjpdacf_fuzz::tracker_step(&data)
        }
        "temporal_ops" => stjpdacf_fuzz::temporal_ops(&data),
        "tables_validate" => stjpdacf_fuzz::tables_validate(&data),
        _ => Err(format!("unknown target {target}")),
    };
    println!("{r:?}");
}
