//! Host benchmarks of `stjpdacf`: the inputs, probes and harness the criterion benches in
//! `benches/` share, and the report that turns their measurements into `docs/bench/`.
//!
//! * `cargo bench -p stjpdacf-bench --bench tracker` — the full `Tracker::step` and each stage,
//!   typical and worst case, next to the dense f64 reference (criterion);
//! * `cargo bench -p stjpdacf-bench --bench stages` — the per-stage split of the step from a
//!   timing probe ([`harness::profile`]), with the probe's own overhead;
//! * `cargo bench -p stjpdacf-bench --bench scaling` — time per frame against M, D, N and E;
//! * `cargo xtask bench-report` — collects the three into
//!   `docs/bench/results.json`, the tables of `docs/bench/README.md`, `scaling.csv` and
//!   `scaling.png`;
//! * `cargo bench -p stjpdacf-bench --bench stonesoup` — the 200 Stone Soup JPDA scans through
//!   the core's row JPDA ([`stonesoup`]); `cargo run --release -p stjpdacf-bench --example
//!   stonesoup_report` times Stone Soup on the same scans in the same run (when it is installed)
//!   and prints the per-scan ratio and the state agreement.

pub mod config;
pub mod cputime;
pub mod harness;
pub mod inputs;
pub mod probes;
pub mod report;
pub mod spatial;
pub mod stonesoup;
