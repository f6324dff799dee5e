//! Criterion benches for `stjpdacf` (host). The benches live in `benches/`; this library is empty
//! and only exists so the package has a target besides them.
