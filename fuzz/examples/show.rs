//! Prints what a fuzz input does: `cargo run --release --example show -- TARGET FILE`.
fn main() {
    let mut a = std::env::args().skip(1);
    let (target, path) = (a.next().unwrap_or_default(), a.next().unwrap_or_default());
    let data = std::fs::read(&path).unwrap_or_default();
    let r = match target.as_str() {
        "tracker_step" => {
            for (at, pts) in stjpdacf_test_support::fuzz::decode_tracker_input(&data) {
                println!("t = {at} µs, {} points: {pts:?}", pts.len());
            }
            stjpdacf_test_support::fuzz::tracker_step(&data)
        }
        "temporal_ops" => stjpdacf_test_support::fuzz::temporal_ops(&data),
        "tables_validate" => {
            which_differ(&data);
            stjpdacf_test_support::fuzz::tables_validate(&data)
        }
        _ => Err(format!("unknown target {target}")),
    };
    println!("{r:?}");
}

/// Which matrices differ from the default.
pub fn which_differ(data: &[u8]) {
    let t = stjpdacf_test_support::fuzz::mutate_tables(&mut arbitrary::Unstructured::new(data));
    let d = stjpdacf::tables::DEFAULT;
    let m = |a: &[f32], b: &[f32]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max)
    };
    println!(
        "eigvec {} gram {} eigval {} coreg {} chol {} A {} p_inf {} sf {} sq {} tf {} tq {} tp {} index_u {}",
        m(t.gram_eigvec.as_slice(), d.gram_eigvec.as_slice()),
        m(t.gram.as_slice(), d.gram.as_slice()),
        m(t.gram_eigval.as_slice(), d.gram_eigval.as_slice()),
        m(t.coreg.as_slice(), d.coreg.as_slice()),
        m(t.coreg_chol.as_slice(), d.coreg_chol.as_slice()),
        m(t.spatial.model.A.as_slice(), d.spatial.model.A.as_slice()),
        m(t.spatial.model.p_inf.as_slice(), d.spatial.model.p_inf.as_slice()),
        m(t.spatial.f.as_slice(), d.spatial.f.as_slice()),
        m(t.spatial.q.as_slice(), d.spatial.q.as_slice()),
        m(t.temporal.f.as_slice(), d.temporal.f.as_slice()),
        m(t.temporal.q.as_slice(), d.temporal.q.as_slice()),
        m(t.temporal.p_inf.as_slice(), d.temporal.p_inf.as_slice()),
        m(t.index_u.as_slice(), d.index_u.as_slice()),
    );
}
