//! Host tools of `stjpdacf`, the library behind the `stjpdacf` command-line program.
//!
//! * [`tablegen`] — hyperparameter file → the core's static tables (`stjpdacf tables`);
//! * [`track`] — runs the core tracker on feature-point frames (`stjpdacf track`);
//! * [`baseline`] — a per-frame sequential-RANSAC baseline on the same points (no tracking);
//! * [`tusimple`], [`metric`] — TuSimple label I/O and the official metric (`stjpdacf eval`);
//! * [`synth`], [`camera`] — the real-geometry replay and the camera model (`stjpdacf synth`);
//! * [`scenario`], [`fwscenario`] — seeded synthetic BEV frames for the spatial filter, and the
//!   firmware scenario files;
//! * [`frontend`] — image → BEV feature points (`stjpdacf frontend`);
//! * [`train`], [`trainrun`] — hyperparameter training (`stjpdacf train`);
//! * [`demo`] — the demo on bundled data (`stjpdacf demo`).
//!
//! This crate uses `std` freely; the no_std core is the `stjpdacf` crate and the f64 reference is
//! `stjpdacf-reference`.

pub mod baseline;
pub mod camera;
pub mod culane;
pub mod demo;
pub mod frontend;
pub mod fwscenario;
pub mod heldout;
pub mod metric;
pub mod rownoise;
pub mod scenario;
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

/// A file the checkout bundles (`rel` under [`repo_root`], e.g. `data/hyper/default.json`): what
/// the tools read when an input is not given, from whatever folder they run in, as the demo
/// does. A path the user gives is relative to the working folder, as usual.
pub fn bundled(rel: &str) -> std::path::PathBuf {
    repo_root().join(rel)
}

/// Create (or replace) the output file `path`, and its folder if it does not exist yet (an
/// output under `out/run1/` needs no `mkdir` first, as the demo's `--out` needs none).
///
/// # Errors
/// The folder or the file cannot be created; the error names the path.
pub fn create_output(path: &std::path::Path) -> anyhow::Result<std::fs::File> {
    use anyhow::Context;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))
}

/// Write `bytes` to the output file `path` ([`create_output`]: its folder created if needed).
///
/// # Errors
/// As [`create_output`], or the write fails; the error names the path.
pub fn write_output(path: &std::path::Path, bytes: impl AsRef<[u8]>) -> anyhow::Result<()> {
    use anyhow::Context;
    std::io::Write::write_all(&mut create_output(path)?, bytes.as_ref())
        .with_context(|| format!("writing {}", path.display()))
}

/// `path` as a record names it (a provenance, a summary): relative to the checkout when it lies
/// in it (a [`bundled`] default reads `data/hyper/default.json`, not the build machine's folder),
/// else as given; `/` as the separator.
pub fn shown_path(path: &std::path::Path) -> String {
    path.strip_prefix(repo_root())
        .unwrap_or(path)
        .to_string_lossy()
        .replace('\\', "/")
}
