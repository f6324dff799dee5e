//! Test support of `stjpdacf`: the helpers the host tests (`host-tests/tests/`), the fuzz targets
//! (`fuzz/`) and the benches share.
//!
//! * [`invariants`] — the reliability invariants of the core's outputs and temporal covariance;
//! * [`fuzz`] — the fuzz harness bodies: arbitrary bytes → one part of the core → its invariants
//!   (run by cargo-fuzz in `fuzz/` and over the committed corpora by `tests/fuzz_corpus.rs`);
//! * [`soak`] (feature `host`, on by default) — long runs of the core against the f64 reference;
//! * [`strategies`] (feature `host`) — proptest strategies of the property tests;
//! * [`golden`] (feature `host`) — reading the golden JSON files under `data/golden/`.
//!
//! Nothing outside tests, fuzzing and benches depends on this crate.

pub mod fuzz;
#[cfg(feature = "host")]
pub mod golden;
pub mod invariants;
#[cfg(feature = "host")]
pub mod soak;
#[cfg(feature = "host")]
pub mod strategies;
