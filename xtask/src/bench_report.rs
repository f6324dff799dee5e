//! Collects the benches' measurements into `docs/bench/` and draws the scaling plot.
//!
//! ```sh
//! cargo bench -p stjpdacf-bench --bench tracker --bench stages --bench scaling
//! cargo xtask bench-report
//! ```
//!
//! Reads `target/stjpdacf-bench/{tracker,stages,scaling,icount}.json` and criterion's estimates under
//! `target/criterion/`, merges them into `docs/bench/results.json` (what was not measured again
//! keeps its committed value), rewrites the tables between the `bench_report` markers of
//! `docs/bench/README.md`, and writes `docs/bench/scaling.csv` and `docs/bench/scaling.png`.
//! With `--committed` it only redraws the tables, the CSV and the plot from the committed
//! `results.json`.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use stjpdacf_bench::report::{plot_scaling, render_csv, render_markdown, splice, Results};
use stjpdacf_tools::repo_root;

/// `cargo xtask bench-report`: turns the host benches' measurements into docs/bench/.
#[derive(Args, Debug)]
pub struct ReportArgs {
    /// Redraw from the committed results.json only (no new measurements).
    #[arg(long)]
    committed: bool,
    /// Output folder.
    #[arg(long, default_value = "docs/bench")]
    out: PathBuf,
}

/// `cargo xtask bench-report`.
pub fn run(args: ReportArgs) -> Result<()> {
    let out = if args.out.is_absolute() {
        args.out
    } else {
        repo_root().join(args.out)
    };
    std::fs::create_dir_all(&out)?;
    let json = out.join("results.json");
    let old: Option<Results> = if json.exists() {
        Some(
            serde_json::from_str(&std::fs::read_to_string(&json)?)
                .with_context(|| format!("parsing {}", json.display()))?,
        )
    } else {
        None
    };
    let results = if args.committed {
        old.context("no committed results.json")?
    } else {
        let new = Results::collect()?;
        match old {
            Some(old) => new.merged_over(old),
            None => new,
        }
    };
    std::fs::write(&json, serde_json::to_string_pretty(&results)?)?;
    let readme = out.join("README.md");
    let doc = std::fs::read_to_string(&readme)
        .with_context(|| format!("reading {}", readme.display()))?;
    std::fs::write(&readme, splice(&doc, &render_markdown(&results)?)?)?;
    std::fs::write(out.join("scaling.csv"), render_csv(&results))?;
    if results.scaling_points.iter().any(|p| p.time.is_some()) {
        plot_scaling(&results.scaling_points, &out.join("scaling.png"))?;
    }
    println!(
        "wrote {}/{{results.json,README.md (generated part),scaling.csv,scaling.png}}",
        out.display()
    );
    Ok(())
}
