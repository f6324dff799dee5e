//! `stjpdacf`: the command-line tool of the ST-JPDACF lane tracker.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};

use stjpdacf_host::hyper::HyperFile;
use stjpdacf_host::metric;
use stjpdacf_host::tablegen;
use stjpdacf_host::{camera::Camera, trainrun};

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
    /// Train the spatial kernel, B and the noise (and fit the temporal length-scale) from
    /// TuSimple labels; writes a complete hyperparameter file.
    Train {
        /// TuSimple label files (JSON lines).
        #[arg(long, num_args = 1.., required = true)]
        labels: Vec<PathBuf>,
        /// Output hyperparameter file.
        #[arg(long)]
        out: PathBuf,
        /// Base hyperparameter file (window, D, N and every field not trained).
        #[arg(long, default_value = tablegen::DEFAULT_HYPER)]
        base: PathBuf,
        /// L-BFGS starts (the first from the base values, the others random around them).
        #[arg(long, default_value_t = 4)]
        restarts: usize,
        /// Seed of the frame selection and the random starts.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// At most this many frames, evenly spread over the usable ones.
        #[arg(long, default_value_t = 300)]
        max_frames: usize,
        /// Minimum spacing of the points kept per lane, metres.
        #[arg(long, default_value_t = 3.0)]
        spacing: f64,
        /// L-BFGS iterations per start.
        #[arg(long, default_value_t = 300)]
        max_iters: u64,
        /// Per-lane offset variance σ_c² (m²); default: the base file's.
        #[arg(long)]
        offset_variance: Option<f64>,
        /// Train σ_c² as well.
        #[arg(long)]
        train_offset: bool,
        /// Write the fitted temporal length-scale (default: keep the base value, record the fit).
        #[arg(long)]
        fit_temporal: bool,
        /// Cut temporal series where labelled clips are further apart than this, seconds.
        #[arg(long, default_value_t = 10.0)]
        max_gap: f64,
        /// Camera of the labels, a JSON file with the fields of `Camera` (default: TuSimple).
        #[arg(long)]
        camera: Option<PathBuf>,
        /// Write a report (B heat map PNG, summary.json, summary.md) into this folder.
        #[arg(long)]
        report: Option<PathBuf>,
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
        Command::Train {
            labels,
            out,
            base,
            restarts,
            seed,
            max_frames,
            spacing,
            max_iters,
            offset_variance,
            train_offset,
            fit_temporal,
            max_gap,
            camera,
            report,
        } => {
            let camera = match camera {
                Some(p) => serde_json::from_str(
                    &std::fs::read_to_string(&p)
                        .with_context(|| format!("reading {}", p.display()))?,
                )
                .with_context(|| format!("parsing camera {}", p.display()))?,
                None => Camera::tusimple(),
            };
            let opts = trainrun::TrainOptions {
                labels,
                base,
                camera,
                restarts,
                seed,
                max_frames,
                spacing,
                max_iters,
                offset_variance,
                train_offset,
                use_fitted_temporal: fit_temporal,
                max_gap,
            };
            let bar = indicatif::ProgressBar::new(restarts as u64);
            bar.set_style(
                indicatif::ProgressStyle::with_template(
                    "{spinner} [{elapsed_precise}] start {pos}/{len} {wide_msg}",
                )
                .context("progress template")?,
            );
            let progress = |start: usize, evals: usize, lml: f64| {
                bar.set_position(start as u64);
                bar.set_message(format!("evaluation {evals}, LML {lml:.3}"));
                bar.tick();
            };
            let outcome = trainrun::run(&opts, &progress)?;
            bar.finish_and_clear();
            let text = serde_json::to_string_pretty(&outcome.hyper)? + "\n";
            std::fs::write(&out, text).with_context(|| format!("writing {}", out.display()))?;
            let p = &outcome.fit.params;
            eprintln!(
                "wrote {}: {} frames, LML {:.3}, ℓ_u = {:.3} m, noise = {:.5} m², σ_c² = {:.3} m²",
                out.display(),
                outcome.frames_used,
                outcome.fit.lml,
                p.lengthscale,
                p.noise,
                p.offset_variance
            );
            eprintln!("B =\n{:.3}", p.b());
            eprintln!(
                "stationary B profile (|i−j| = 0..): {:.3?}",
                stjpdacf_host::train::stationary_profile(&p.b())
            );
            if let Some(dir) = report {
                let cmd = std::env::args().collect::<Vec<_>>().join(" ");
                trainrun::write_report(&dir, &outcome, &cmd)?;
                eprintln!("report in {}", dir.display());
            }
        }
    }
    Ok(())
}
