//! cargo-fuzz target `tracker_step`: the body and its invariants are `stjpdacf_test_support::fuzz::tracker_step`
//! (also run over the committed corpus by `host-tests/tests/fuzz_corpus.rs`).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Err(v) = stjpdacf_test_support::fuzz::tracker_step(data) {
        panic!("invariant violated: {v}");
    }
});
