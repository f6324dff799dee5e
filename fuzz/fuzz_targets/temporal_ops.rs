//! cargo-fuzz target `temporal_ops`: the body and its invariants are `stjpdacf_test_support::fuzz::temporal_ops`
//! (also run over the committed corpus by `host-tests/tests/fuzz_corpus.rs`).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Err(v) = stjpdacf_test_support::fuzz::temporal_ops(data) {
        panic!("invariant violated: {v}");
    }
});
