//! Instructions per frame on the host (x86-64, callgrind), core `Tracker::step` against the dense
//! f64 reference pipeline (step + fixed-lag output) on the same frames: a load-independent
//! cross-check of the criterion speed-up (instruction counts are not time: the reference's dense
//! f64 linear algebra retires more work per instruction than the core's small f32 loops).
//!
//! ```sh
//! cargo build --release -p stjpdacf-bench --example icount
//! target/release/examples/icount            # runs itself under valgrind, ~5 min
//! cargo xtask bench-report
//! ```
//!
//! For each sequence (`typical`, `worst`) and each side it runs
//! `valgrind --tool=callgrind --toggle-collect=*<side>_frame* <this program> --inner <side> <seq>`:
//! the inner run warms up untimed (one pass), then steps one pass of the sequence inside
//! `core_frame` / `reference_frame` (never inlined), so callgrind's totals are the instructions
//! of those frames only. Writes `target/stjpdacf-bench/icount.json`.

use std::hint::black_box;
use std::path::Path;
use std::process::Command;

use anyhow::{bail, Context, Result};
use stjpdacf::probe::NoProbe;
use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::ReferenceTracker;
use stjpdacf_bench::harness::Driver;
use stjpdacf_bench::inputs::{self, Frame, STEP_US};
use stjpdacf_bench::report::{self, IcountOut, IcountRow, Machine};
use stjpdacf_reference::pipeline::{PipelineConfig, ReferencePipeline};
use stjpdacf_tools::tablegen::ModelTables;

#[inline(never)]
fn core_frame(d: &mut Driver<ReferenceTracker>, frames: &[Frame]) {
    black_box(d.step(frames, &mut NoProbe));
}

#[inline(never)]
fn reference_frame(p: &mut ReferencePipeline, now: f64, points: &[(f64, f64)]) {
    let out = p.step(now, points).expect("reference step");
    black_box((out, p.lagged().expect("reference smoother")));
}

fn frames_of(seq: &str) -> Result<Vec<Frame>> {
    Ok(match seq {
        "typical" => inputs::typical(),
        "worst" => inputs::worst(),
        other => bail!("unknown sequence {other}"),
    })
}

fn inner(side: &str, seq: &str) -> Result<()> {
    let frames = frames_of(seq)?;
    match side {
        "core" => {
            let mut d = Driver::new(Box::new(ReferenceTracker::new(&DEFAULT)));
            d.warm_up(&frames, 1);
            for _ in 0..frames.len() {
                core_frame(&mut d, &frames);
            }
        }
        "reference" => {
            let h = stjpdacf_bench::config::default_hyper()?;
            let t = ModelTables::from_hyper(&h)?;
            let mut p = ReferencePipeline::new(&t, 4, PipelineConfig::from_tables(&t))?;
            let mut now = 0i64;
            for f in &frames {
                now += STEP_US;
                p.step(now as f64 * 1e-6, &f.p64)?;
            }
            for f in &frames {
                now += STEP_US;
                reference_frame(&mut p, now as f64 * 1e-6, &f.p64);
            }
        }
        other => bail!("unknown side {other}"),
    }
    Ok(())
}

/// Collected instructions (`summary:`/`totals:` line of a callgrind output file).
fn totals(path: &Path) -> Result<u64> {
    let text = std::fs::read_to_string(path).with_context(|| format!("{}", path.display()))?;
    text.lines()
        .rev()
        .find_map(|l| {
            l.strip_prefix("totals:")
                .or_else(|| l.strip_prefix("summary:"))
        })
        .and_then(|v| v.split_whitespace().next())
        .context("no totals in the callgrind output")?
        .parse()
        .context("totals")
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    if args.get(1).map(String::as_str) == Some("--inner") {
        let side = args.get(2).context("side")?;
        let seq = args.get(3).context("sequence")?;
        return inner(side, seq);
    }
    let me = std::env::current_exe()?;
    let dir = report::out_dir();
    std::fs::create_dir_all(&dir)?;
    let machine = Machine::now();
    let mut rows = Vec::new();
    for seq in ["typical", "worst"] {
        let n = frames_of(seq)?.len();
        let mut per_frame = [0u64; 2];
        for (i, side) in ["core", "reference"].iter().enumerate() {
            let out = dir.join(format!("callgrind.{side}.{seq}.out"));
            let status = Command::new("valgrind")
                .arg("--tool=callgrind")
                .arg(format!("--callgrind-out-file={}", out.display()))
                .arg(format!("--toggle-collect=*{side}_frame*"))
                .arg(&me)
                .args(["--inner", side, seq])
                .status()
                .context("running valgrind (apt-get install valgrind)")?;
            if !status.success() {
                bail!("valgrind failed on {side} {seq}");
            }
            per_frame[i] = totals(&out)? / n as u64;
            println!("{seq} {side}: {} instructions per frame", per_frame[i]);
        }
        rows.push(IcountRow {
            sequence: seq.to_string(),
            frames: n,
            core_per_frame: per_frame[0],
            reference_per_frame: per_frame[1],
        });
    }
    report::write_side_file("icount.json", &IcountOut { machine, rows })
}
