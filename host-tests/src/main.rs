//! `stjpdacf`: the command-line tool of the ST-JPDACF lane tracker.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};

use stjpdacf_host::hyper::HyperFile;
use stjpdacf_host::metric;
use stjpdacf_host::tablegen;

#[derive(Parser)]
#[command(name = "stjpdacf", version, about = "ST-JPDACF lane tracker: tools")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Generate the static model tables (a Rust source file) from a hyperparameter file.
    Tables {
        /// Hyperparameter file (JSON, schema stjpdacf-hyper/v1).
        #[arg(long, default_value = tablegen::DEFAULT_HYPER)]
        hyper: PathBuf,
        /// Output Rust file (`-` for standard output).
        #[arg(long, default_value = "-")]
        out: PathBuf,
        /// Name of the generated `static`.
        #[arg(long, default_value = "DEFAULT")]
        name: String,
    },
    /// Print how well the RBF state-space approximation of each Taylor order matches the true
    /// kernel (a Markdown table, as in the README).
    Kernels,
    /// Score TuSimple predictions against ground truth with the official TuSimple metric.
    Eval {
        /// Predictions (TuSimple JSON lines with `raw_file`, `lanes`, `run_time`).
        #[arg(long)]
        pred: PathBuf,
        /// Ground truth (TuSimple JSON lines with `raw_file`, `lanes`, `h_samples`).
        #[arg(long)]
        gt: PathBuf,
        /// Print `{"Accuracy": .., "FP": .., "FN": .., "frames": ..}` instead of a table.
        #[arg(long)]
        json: bool,
    },
}

fn main() -> Result<()> {
    match Cli::parse().command {
        Command::Tables { hyper, out, name } => {
            let h = HyperFile::load(&hyper)?;
            let t = tablegen::ModelTables::from_hyper(&h)?;
            let origin = hyper.to_string_lossy().replace('\\', "/");
            let src = tablegen::render(&t, &name, &origin)?;
            if out.as_os_str() == "-" {
                print!("{src}");
            } else {
                std::fs::write(&out, &src).with_context(|| format!("writing {}", out.display()))?;
                eprintln!(
                    "wrote {} (NT = {}, LANES = {}, POINTS = {}, Gram rank {} of {})",
                    out.display(),
                    h.spatial.order,
                    h.lanes(),
                    h.index_points,
                    t.gram_rank,
                    h.index_points
                );
            }
        }
        Command::Kernels => {
            print!(
                "{}",
                stjpdacf_host::reference::statespace::approximation_table(2..=6)
            );
        }
        Command::Eval { pred, gt, json } => {
            let s = metric::evaluate_files(&pred, &gt)?;
            if json {
                println!(
                    "{}",
                    serde_json::to_string(&s).context("serialising the score")?
                );
            } else {
                println!("TuSimple metric ({} frames)", s.frames);
                println!("  Accuracy  {:.6}", s.accuracy);
                println!("  FP        {:.6}", s.fp);
                println!("  FN        {:.6}", s.fn_);
            }
        }
    }
    Ok(())
}
