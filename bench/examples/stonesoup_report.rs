//! The Stone Soup JPDA scans through the core's row JPDA and, when `stonesoup` imports, through
//! Stone Soup 1.9.1 in the same run: per-scan times, their ratio, and the tracked-state and
//! association agreement.
//!
//! ```text
//! cargo run --release -p stjpdacf-bench --example stonesoup_report
//! cargo run --release -p stjpdacf-bench --example stonesoup_report -- --python .venv/bin/python
//! ```
//!
//! The Python interpreter is `--python`, else `$STONESOUP_PYTHON`, else `python3`; it runs
//! `bench/data/stonesoup/stonesoup_time.py` (Stone Soup's loop of the generating script, on the
//! stored scans), which prints its per-scan times as JSON. Without `stonesoup` the core side is
//! printed and compared with the states stored in the JSON. No figure here is asserted.

use std::process::Command;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::Parser;
use serde::Deserialize;
use stjpdacf_bench::cputime::thread_cpu;
use stjpdacf_bench::stonesoup::{
    agreement, beta_agreement, data_dir, replay, Agreement, BetaAgreement, Core, Scans,
    StoneSoupBeta,
};

#[derive(Parser)]
#[command(about = "Stone Soup JPDA scans: the core's row JPDA against Stone Soup, same run")]
struct Args {
    /// Replays of the 200 scans timed on the core side.
    #[arg(long, default_value_t = 300)]
    repeats: usize,
    /// Replays timed on the Stone Soup side (the generating script used 3).
    #[arg(long, default_value_t = 3)]
    stonesoup_repeats: usize,
    /// Python interpreter with stonesoup (default: $STONESOUP_PYTHON, else python3).
    #[arg(long)]
    python: Option<String>,
    /// Do not run Stone Soup.
    #[arg(long)]
    skip_stonesoup: bool,
}

/// Output of `stonesoup_time.py`.
#[derive(Deserialize)]
struct SsRun {
    versions: serde_json::Value,
    per_scan_s: Vec<Vec<f64>>,
    replay_cpu_s: Vec<f64>,
    associate_only_s: Vec<Vec<f64>>,
    means: Vec<Vec<[f64; 2]>>,
    beta: Vec<Vec<Vec<(i64, f64)>>>,
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    let i = ((v.len().saturating_sub(1)) as f64 * p).round() as usize;
    v.get(i).copied().unwrap_or(f64::NAN)
}

/// Per-scan times `t[r][k]` (seconds) → (median over all, mean over all, p90 over all,
/// per-scan medians over the repeats).
fn stats(t: &[Vec<f64>]) -> (f64, f64, f64, Vec<f64>) {
    let mut all: Vec<f64> = t.iter().flatten().copied().collect();
    let mean = all.iter().sum::<f64>() / all.len().max(1) as f64;
    let p90 = percentile(&mut all, 0.9);
    let med = median(&mut all);
    let n = t.first().map_or(0, Vec::len);
    let per_scan = (0..n)
        .map(|k| {
            median(
                &mut t
                    .iter()
                    .filter_map(|r| r.get(k).copied())
                    .collect::<Vec<_>>(),
            )
        })
        .collect();
    (med, mean, p90, per_scan)
}

/// Times every scan of `repeats` replays of the core, one `Instant` pair per scan, and the
/// thread CPU time of each whole replay: (per-scan wall times `t[r][k]`, CPU time per replay),
/// seconds.
fn time_core(scans: &Scans, repeats: usize) -> (Vec<Vec<f64>>, Vec<f64>) {
    let start = Core::new(scans);
    let mut out = Vec::with_capacity(repeats);
    let mut cpu = Vec::with_capacity(repeats);
    // One untimed replay to warm the caches.
    for r in 0..=repeats {
        let mut core = start.clone();
        let mut row = Vec::with_capacity(scans.points.len());
        let c0 = thread_cpu();
        for pts in &scans.points {
            let t0 = Instant::now();
            let o = core.step(std::hint::black_box(pts));
            std::hint::black_box(&o);
            row.push(t0.elapsed().as_secs_f64());
        }
        let c = (thread_cpu() - c0).as_secs_f64();
        if r > 0 {
            out.push(row);
            cpu.push(c);
        }
    }
    (out, cpu)
}

fn python(args: &Args) -> String {
    args.python
        .clone()
        .or_else(|| std::env::var("STONESOUP_PYTHON").ok())
        .unwrap_or_else(|| "python3".to_owned())
}

fn run_stonesoup(py: &str, repeats: usize) -> Result<Option<SsRun>> {
    let probe = Command::new(py)
        .args(["-c", "import stonesoup"])
        .output()
        .with_context(|| format!("run {py}"));
    match probe {
        Ok(o) if o.status.success() => {}
        _ => return Ok(None),
    }
    let script = data_dir().join("stonesoup_time.py");
    let out = Command::new(py)
        .env("PYTHONDONTWRITEBYTECODE", "1")
        // One thread, as in the generating run (the 1×1 and 2×2 products never need more).
        .env("OPENBLAS_NUM_THREADS", "1")
        .env("OMP_NUM_THREADS", "1")
        .arg(&script)
        .args(["--repeats", &repeats.to_string()])
        .output()
        .with_context(|| format!("run {py} {}", script.display()))?;
    if !out.status.success() {
        bail!(
            "{} failed: {}",
            script.display(),
            String::from_utf8_lossy(&out.stderr)
        );
    }
    Ok(Some(
        serde_json::from_slice(&out.stdout).context("parse stonesoup_time.py output")?,
    ))
}

/// Prints the state agreement; the covariances only when `cov` (the live run outputs means only).
fn print_agreement(what: &str, a: &Agreement, cov: bool) {
    println!(
        "  {what}: position RMS {:.2e} m, max {:.2e} m (scan {}); velocity RMS {:.2e}, max {:.2e} \
         m/scan (scan {})",
        a.pos.rms, a.pos.max, a.pos.at_scan, a.vel.rms, a.vel.max, a.vel.at_scan
    );
    if cov {
        println!(
            "  {what}: covariance entries RMS {:.2e}, max {:.2e} (scan {})",
            a.cov.rms, a.cov.max, a.cov.at_scan
        );
    }
}

fn print_beta(what: &str, b: &BetaAgreement) {
    println!(
        "  {what}: β RMS {:.2e}, max {:.2e} (scan {}); gates differing in {} of {} (scan, track)",
        b.beta.rms, b.beta.max, b.beta.at_scan, b.gate_mismatches, b.pairs
    );
}

fn main() -> Result<()> {
    let args = Args::parse();
    let scans = Scans::load()?;
    let rep = replay(&scans);
    let n = scans.points.len();
    let counts: Vec<usize> = scans.points.iter().map(Vec::len).collect();
    println!(
        "Stone Soup JPDA scans: {n} scans, {} tracks, {}–{} points/scan; core: γ = {:.6}, \
         E = {}, events/scan {}–{} (median {}), {} approximated, {} failed",
        stjpdacf_bench::stonesoup::TRACKS,
        counts.iter().min().unwrap_or(&0),
        counts.iter().max().unwrap_or(&0),
        scans.gamma,
        stjpdacf_bench::stonesoup::MAX_EVENTS,
        rep.events.iter().min().unwrap_or(&0),
        rep.events.iter().max().unwrap_or(&0),
        median(&mut rep.events.iter().map(|&e| f64::from(e)).collect::<Vec<_>>()),
        rep.approximated,
        rep.failed
    );

    println!("\nAgreement of the core (f32) with Stone Soup 1.9.1 (f64):");
    let a = agreement(&scans, &rep);
    print_agreement("states stored in the JSON", &a, true);
    match StoneSoupBeta::load() {
        Ok(b) => print_beta("β of stonesoup_beta.json", &beta_agreement(&rep, &b)),
        Err(e) => println!("  (no stored β: {e:#})"),
    }
    println!(
        "  position RMSE against the truth: core {:.5} m, Stone Soup {:.5} m",
        a.core_rmse_truth, a.stonesoup_rmse_truth
    );

    let (core_t, core_cpu) = time_core(&scans, args.repeats);
    let n_scans = n as f64;
    let c_cpu = median(&mut core_cpu.clone()) / n_scans;
    let (c_med, c_mean, c_p90, c_scan) = stats(&core_t);
    // The replay's typical time per scan (what criterion's `--bench stonesoup` measures / 200):
    // the mean over the scans of each scan's median, robust to preemption spikes.
    let c_replay = c_scan.iter().sum::<f64>() / c_scan.len().max(1) as f64;
    println!(
        "\nCore (predict + spatial::row::associate + PDA update), {} replays: per scan median \
         {:.2} µs, mean {:.2} µs, p90 {:.2} µs; mean of the per-scan medians {:.2} µs",
        args.repeats,
        c_med * 1e6,
        c_mean * 1e6,
        c_p90 * 1e6,
        c_replay * 1e6
    );
    println!(
        "  thread CPU time per replay / {n}: median {:.2} µs per scan",
        c_cpu * 1e6
    );

    let py = python(&args);
    let ss = if args.skip_stonesoup {
        None
    } else {
        run_stonesoup(&py, args.stonesoup_repeats)?
    };
    let Some(ss) = ss else {
        let t = &scans.file.timing_stonesoup_per_scan;
        println!(
            "\nStone Soup skipped ({}): the JSON's recorded run (another time, maybe another \
             machine) had median {:.2} ms, mean {:.2} ms per scan, i.e. {:.0}× the core's median \
             here (indicative only).",
            if args.skip_stonesoup {
                "--skip-stonesoup".to_owned()
            } else {
                format!("`{py} -c 'import stonesoup'` failed")
            },
            t.median_s * 1e3,
            t.mean_s * 1e3,
            t.median_s / c_med
        );
        return Ok(());
    };
    let (s_med, s_mean, s_p90, s_scan) = stats(&ss.per_scan_s);
    let s_replay = s_scan.iter().sum::<f64>() / s_scan.len().max(1) as f64;
    let s_cpu = median(&mut ss.replay_cpu_s.clone()) / n_scans;
    let (a_med, _, _, _) = stats(&ss.associate_only_s);
    let mut ratios: Vec<f64> = s_scan.iter().zip(&c_scan).map(|(s, c)| s / c).collect();
    let r_med = median(&mut ratios);
    let (r_min, r_max) = (ratios[0], ratios[ratios.len() - 1]);
    println!(
        "Stone Soup {} ({}), same run, {} replays: per scan median {:.3} ms, mean {:.3} ms, \
         p90 {:.3} ms; mean of the per-scan medians {:.3} ms (associate only: median {:.3} ms)",
        ss.versions
            .get("stonesoup")
            .and_then(|v| v.as_str())
            .unwrap_or("?"),
        py,
        ss.per_scan_s.len(),
        s_med * 1e3,
        s_mean * 1e3,
        s_p90 * 1e3,
        s_replay * 1e3,
        a_med * 1e3
    );
    println!(
        "Ratio Stone Soup / core: {:.0}× (medians), {:.0}× (means of the per-scan medians); per \
         scan (ratio of each scan's medians): median {:.0}×, min {:.0}×, max {:.0}×",
        s_med / c_med,
        s_replay / c_replay,
        r_med,
        r_min,
        r_max
    );
    println!(
        "  thread CPU time per replay / {n} (includes building Stone Soup's Detection objects): \
         Stone Soup {:.3} ms, core {:.2} µs per scan: {:.0}×",
        s_cpu * 1e3,
        c_cpu * 1e6,
        s_cpu / c_cpu
    );
    let live = StoneSoupBeta {
        means: ss.means,
        beta: ss.beta,
    };
    let mut live_file = scans.file.clone();
    live_file.stonesoup_track_means = live.means.clone();
    let live_scans = Scans::new(live_file)?;
    println!("Agreement with this run's Stone Soup:");
    print_agreement("states", &agreement(&live_scans, &rep), false);
    print_beta("β", &beta_agreement(&rep, &live));
    Ok(())
}
