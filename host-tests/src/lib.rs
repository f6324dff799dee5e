//! Host side of `stjpdacf`: the f64 reference implementation, the offline table generator, the
//! hyperparameter file format, and the tools behind the `stjpdacf` command-line program.
//!
//! This crate uses `std` freely; the no_std core is the `stjpdacf` crate.

pub mod camera;
pub mod demo;
pub mod frontend;
pub mod fwscenario;
pub mod hyper;
pub mod invariants;
pub mod metric;
pub mod reference;
pub mod scenario;
pub mod soak;
pub mod synth;
pub mod tablegen;
pub mod track;
pub mod train;
pub mod trainrun;
pub mod tusimple;

/// The repository root (this crate's parent folder), for tools and tests that read bundled data.
pub fn repo_root() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map(std::path::Path::to_path_buf)
        .unwrap_or_default()
}
