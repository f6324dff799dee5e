//! Developer commands of `stjpdacf` (`cargo xtask <command>`, an alias in `.cargo/config.toml`).
//!
//! | command | what it does |
//! |---|---|
//! | `firmware [--check \| --update-budget]` | builds `bench/firmware` for the Cortex-M4F, runs every binary under QEMU, writes the JSON summary and checks (or rewrites) `bench/firmware/budget.json` |
//! | `firmware-profile [--bin B] [--top N] [--lines N]` | where a firmware binary's instructions go, per function and per source line, under QEMU |
//! | `firmware-scenarios` | regenerates the firmware's scenario files |
//! | `nopanic` | the no-panic proof: links only if no panicking branch survives in the core |
//! | `fuzz-smoke [--cap S]` | the seeded, bounded cargo-fuzz run CI does |
//! | `bench-report [--committed]` | turns the criterion benches' measurements into `docs/bench/` |
//! | `deps` | checks the crates' dependency graph (no test crate under a non-test crate; the reference shares no code with the core) |
//! | `capi` | the C API: header up to date, staticlibs (host, Cortex-M4F, Cortex-R5F with nightly), the host and Cortex-M4F C examples against the Rust output, sizes and stack; the board example under QEMU |
//! | `ci` | every check CI runs, in order (tools must be installed: `.ci/run` does that first) |

mod bench_report;
mod board;
mod capi;
mod ci;
mod deps;
mod firmware;
mod fuzz_smoke;
mod profile;

use anyhow::Result;
use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "cargo xtask", about = "Developer commands of stjpdacf")]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Build the firmware, run every binary under QEMU, write the JSON summary, check budgets.
    Firmware(firmware::RunArgs),
    /// Where a firmware binary's instructions go, per function (QEMU's block log).
    FirmwareProfile(profile::ProfileArgs),
    /// Regenerate the scenario files in bench/firmware/scenarios.
    FirmwareScenarios,
    /// The no-panic proof (on failure: the call chains that reach a panic).
    Nopanic,
    /// The seeded, bounded fuzz smoke run of CI.
    FuzzSmoke(fuzz_smoke::SmokeArgs),
    /// Turn the host benches' measurements into docs/bench/.
    BenchReport(bench_report::ReportArgs),
    /// Check the crates' dependency graph.
    Deps,
    /// The C API's checks: header, staticlibs, the C examples against the Rust output.
    Capi,
    /// Every check CI runs, in order.
    Ci,
}

fn main() -> Result<()> {
    match Cli::parse().cmd {
        Cmd::Firmware(a) => firmware::run(a),
        Cmd::FirmwareProfile(a) => profile::run(&a),
        Cmd::FirmwareScenarios => firmware::scenarios(),
        Cmd::Nopanic => firmware::nopanic(),
        Cmd::FuzzSmoke(a) => fuzz_smoke::run(&a),
        Cmd::BenchReport(a) => bench_report::run(a),
        Cmd::Deps => deps::check(),
        Cmd::Capi => capi::run_all(),
        Cmd::Ci => ci::run(),
    }
}
