//! Puts the repository's `memory.x` (the reference MCU: 1 MiB flash, 256 KiB RAM) on the linker's
//! search path, where cortex-m-rt's `link.x` includes it: the linker enforces the budget.
//! `STJPDACF_MEMORY_X=<path>` substitutes another memory map (for measurements of code that does
//! not fit the reference MCU yet; never for the budgets).
use std::path::PathBuf;

fn main() {
    let out = PathBuf::from(std::env::var_os("OUT_DIR").expect("OUT_DIR"));
    let manifest =
        PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("CARGO_MANIFEST_DIR"));
    let src = match std::env::var_os("STJPDACF_MEMORY_X") {
        Some(p) => manifest.join(p),
        None => manifest.join("../../memory.x"),
    };
    std::fs::copy(&src, out.join("memory.x")).expect("copy memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", src.display());
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-env-changed=STJPDACF_MEMORY_X");
}
