//! The firmware benchmark's host side (`bench/firmware`): scenario files, build, QEMU runs, the
//! JSON summary, the budget check, and the no-panic proof.
//!
//! ```sh
//! # regenerate the scenario files (bench/firmware/scenarios/*.stjf)
//! cargo xtask firmware-scenarios
//! # build, run every binary under QEMU, write the JSON summary, check the committed budget
//! cargo xtask firmware --check
//! # after an intended change of the figures: rewrite bench/firmware/budget.json
//! cargo xtask firmware --update-budget
//! # the no-panic proof (on failure: the call chains that reach a panic)
//! cargo xtask nopanic
//! ```
//!
//! Needs `rustup target add thumbv7em-none-eabihf`, `rustup component add llvm-tools`,
//! `qemu-system-arm` and `flip-link` (`cargo install --locked flip-link`).

use std::collections::BTreeMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context, Result};
use clap::Args;
use serde::{Deserialize, Serialize};
use stjpdacf_tools::{fwscenario, repo_root};

/// The stages as the firmware prints them (`events_stage` is the Events stage).
const STAGES: [&str; 12] = [
    "binning",
    "row_predict",
    "gating",
    "events_stage",
    "update",
    "management",
    "backward",
    "identity",
    "temporal",
    "smoother",
    "output",
    "known",
];
/// The binary that is the no-panic proof (never run).
const NOPANIC: &str = "nopanic";
/// The binary that prints every lane for the C API's comparison (`cargo xtask capi`), not a
/// benchmark.
pub const LANES: &str = "lanes_typical";
/// A count may exceed its budget by this fraction...
const TOLERANCE: f64 = 0.02;
/// ...plus this many instructions (a SysTick reading is quantised to 5 instructions, so a stage
/// entered a few hundred times per frame moves by tens of instructions when unrelated code moves
/// the readings' phase).
const SLACK: u64 = 100;
/// Stack high-water limit, bytes.
const STACK_LIMIT: u64 = 16 * 1024;
/// Flash limit of every running binary (`text + data`), bytes: the issue "Fit the MCU"'s 256 KiB.
const FLASH_LIMIT: u64 = 256 * 1024;
/// Start of RAM in memory.x (and QEMU's mps2-an386).
const RAM_ORIGIN: u64 = 0x2000_0000;
/// The loop `calibration` measures, instructions.
const CALIBRATION: u64 = 2_000_000;

/// `cargo xtask firmware`: build the firmware, run every binary under QEMU, write the JSON
/// summary, check or rewrite the budgets.
#[derive(Args, Debug)]
pub struct RunArgs {
    /// Where to write the JSON summary (default bench/firmware/target/report.json, or
    /// report-qemu-ram.json with --qemu-ram).
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Fail when a count exceeds bench/firmware/budget.json by more than 2 % (+100
    /// instructions), when a budgeted binary does not run, or when a stack high-water mark
    /// exceeds 16 KiB.
    #[arg(long)]
    pub check: bool,
    /// Rewrite bench/firmware/budget.json from this run.
    #[arg(long, conflicts_with = "check")]
    pub update_budget: bool,
    /// Link against QEMU's whole memory (bench/firmware/memory-qemu.x: 4 MiB RAM) instead of
    /// the reference MCU's memory.x, to measure code that does not fit it yet. No budgets.
    #[arg(long, conflicts_with_all = ["check", "update_budget"])]
    pub qemu_ram: bool,
    /// Kill a QEMU run after this many seconds.
    #[arg(long, default_value_t = 300)]
    pub timeout: u64,
    /// Skip `cargo build` (use the binaries already built).
    #[arg(long)]
    pub no_build: bool,
    /// The budget file (default bench/firmware/budget.json). A budget records the build-time
    /// model variables it was measured with (`build_env`: `STJPDACF_FW_TABLES`, `_RANK`,
    /// `_ASSOC`, `_PER_LANE`, `_K`, `_RANK_CAP`, `_OWN_PD`): `--check` builds with exactly those, `--update-budget`
    /// records the ones set now.
    #[arg(long)]
    pub budget: Option<PathBuf>,
}

/// The prefix of the firmware's build-time model variables (bench/firmware/src/lib.rs).
const MODEL_ENV: &str = "STJPDACF_FW_";

/// The model variables set in this process's environment.
fn model_env() -> BTreeMap<String, String> {
    std::env::vars()
        .filter(|(k, _)| k.starts_with(MODEL_ENV))
        .collect()
}

/// max and median (the lower median: a value of an actual frame) of per-frame counts.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
struct Stat {
    max: u64,
    median: u64,
}

impl Stat {
    fn of(v: &[u64]) -> Self {
        let mut s = v.to_vec();
        s.sort_unstable();
        Self {
            max: s.last().copied().unwrap_or(0),
            median: s.get(s.len().saturating_sub(1) / 2).copied().unwrap_or(0),
        }
    }
}

/// Per-scenario figures, instructions per frame.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
struct ScenarioFigures {
    frames: usize,
    points_min: u64,
    points_max: u64,
    lanes_max: u64,
    spatial_events_max: u64,
    rows_pruned_max: u64,
    probe_calls_max: u64,
    /// `Tracker::step` (or `SpatialFilter::run`) per frame, all stages.
    total: Stat,
    /// `wire::Receiver::accept` of the frame (CRC and decoding), not part of `total`.
    decode: Stat,
    stages: BTreeMap<String, Stat>,
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub(crate) struct Sizes {
    pub(crate) text: u64,
    pub(crate) data: u64,
    pub(crate) bss: u64,
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
struct BinaryReport {
    /// "ok", or what went wrong ("fault: ...", "timeout", "exit N").
    status: String,
    sizes: Sizes,
    /// Painted-stack high-water mark, bytes (absent when the run did not finish).
    stack_used: Option<u64>,
    /// The stack region's size (the RAM the statics leave), bytes.
    stack_size: u64,
    /// The bytes of the scenario files the binary embeds (`include_bytes!` of
    /// `bench/firmware/scenarios/<scenario>.stjf`): test input in its text, not part of a
    /// product's image; the flash limit applies to the rest.
    #[serde(default)]
    frames_bytes: u64,
    probe_overhead_per_call: Option<u64>,
    scenarios: BTreeMap<String, ScenarioFigures>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct Report {
    schema: String,
    qemu: String,
    machine: String,
    memory_map: String,
    instructions_per_tick: u64,
    binaries: BTreeMap<String, BinaryReport>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct BudgetEntry {
    /// `false`: known not to run on the reference memory map yet (not enforced).
    runs: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    note: Option<String>,
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    scenarios: BTreeMap<String, ScenarioBudget>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct ScenarioBudget {
    total: Stat,
    decode: Stat,
    stages: BTreeMap<String, Stat>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
struct Budget {
    schema: String,
    /// How to check and re-baseline.
    about: String,
    tolerance: f64,
    slack_instructions: u64,
    stack_limit_bytes: u64,
    /// Flash (`text + data`: `data`'s initial image is stored in flash) of every running binary.
    flash_limit_bytes: u64,
    /// The build-time model variables of the measured build (empty: the default model).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    build_env: BTreeMap<String, String>,
    binaries: BTreeMap<String, BudgetEntry>,
}

pub(crate) fn fw_dir() -> PathBuf {
    repo_root().join("bench/firmware")
}

pub(crate) fn cargo() -> Command {
    let mut c = Command::new(std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into()));
    // The firmware is its own workspace with its own target and flags.
    for v in [
        "RUSTFLAGS",
        "CARGO_ENCODED_RUSTFLAGS",
        "CARGO_BUILD_TARGET",
        "CARGO_TARGET_DIR",
    ] {
        c.env_remove(v);
    }
    c.current_dir(fw_dir());
    c
}

pub(crate) fn llvm_tool(name: &str) -> Result<PathBuf> {
    let out = Command::new("rustc")
        .args(["--print", "sysroot"])
        .output()?;
    let sysroot = String::from_utf8(out.stdout)?.trim().to_string();
    let vv = Command::new("rustc").arg("-vV").output()?;
    let host = String::from_utf8(vv.stdout)?
        .lines()
        .find_map(|l| l.strip_prefix("host: ").map(str::to_string))
        .context("rustc -vV: no host line")?;
    let p = Path::new(&sysroot)
        .join("lib/rustlib")
        .join(host)
        .join("bin")
        .join(name);
    ensure!(
        p.exists(),
        "{} not found: rustup component add llvm-tools",
        p.display()
    );
    Ok(p)
}

/// The QEMU command line of `bench/firmware/.cargo/config.toml` (one source of truth).
pub(crate) fn runner() -> Result<Vec<String>> {
    runner_in(&fw_dir())
}

/// The (first, uncommented) runner line of `<dir>/.cargo/config.toml`, split into words.
pub(crate) fn runner_in(dir: &Path) -> Result<Vec<String>> {
    let path = dir.join(".cargo/config.toml");
    let cfg = std::fs::read_to_string(&path)?;
    let line = cfg
        .lines()
        .find_map(|l| l.trim().strip_prefix("runner = \""))
        .and_then(|l| l.strip_suffix('"'))
        .with_context(|| format!("no runner in {}", path.display()))?;
    Ok(line.split_whitespace().map(str::to_string).collect())
}

/// The firmware's binaries, from `src/bin/*.rs`.
fn binaries() -> Result<Vec<String>> {
    let mut v: Vec<String> = std::fs::read_dir(fw_dir().join("src/bin"))?
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let p = e.path();
            (p.extension()? == "rs").then(|| p.file_stem()?.to_str().map(str::to_string))?
        })
        .collect();
    v.sort();
    Ok(v)
}

/// Runs `cmd` with a time limit; returns (exit code or None when killed, stdout, stderr).
pub(crate) fn run_with_timeout(
    mut cmd: Command,
    limit: Duration,
) -> Result<(Option<i32>, String, String)> {
    let mut child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .context("starting qemu-system-arm (apt-get install qemu-system-arm)")?;
    let mut so = child.stdout.take().context("stdout")?;
    let mut se = child.stderr.take().context("stderr")?;
    let t_out = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = so.read_to_string(&mut s);
        s
    });
    let t_err = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = se.read_to_string(&mut s);
        s
    });
    let start = Instant::now();
    let code = loop {
        if let Some(st) = child.try_wait()? {
            break st.code().or(Some(-1));
        }
        if start.elapsed() > limit {
            child.kill()?;
            child.wait()?;
            break None;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let out = t_out.join().unwrap_or_default();
    let err = t_err.join().unwrap_or_default();
    Ok((code, out, err))
}

pub(crate) fn kv(line: &str) -> BTreeMap<&str, u64> {
    line.split_whitespace()
        .filter_map(|t| t.split_once('='))
        .filter_map(|(k, v)| Some((k, v.parse().ok()?)))
        .collect()
}

/// The stack region's size from the linker symbols (`_stack_start` − `_stack_end`; flip-link
/// sets both), bytes.
fn stack_region(elf: &Path) -> Result<u64> {
    let out = Command::new(llvm_tool("llvm-nm")?).arg(elf).output()?;
    ensure!(out.status.success(), "llvm-nm {} failed", elf.display());
    let text = String::from_utf8(out.stdout)?;
    let sym = |name: &str| {
        text.lines()
            .find(|l| l.ends_with(&format!(" {name}")))
            .and_then(|l| u64::from_str_radix(l.split_whitespace().next()?, 16).ok())
            .with_context(|| format!("{name} not in {}", elf.display()))
    };
    Ok(sym("_stack_start")?.saturating_sub(sym("_stack_end")?))
}

pub(crate) fn sizes(elf: &Path) -> Result<Sizes> {
    let out = Command::new(llvm_tool("llvm-size")?).arg(elf).output()?;
    ensure!(out.status.success(), "llvm-size {} failed", elf.display());
    let text = String::from_utf8(out.stdout)?;
    let nums: Vec<u64> = text
        .lines()
        .nth(1)
        .context("llvm-size output")?
        .split_whitespace()
        .take(3)
        .map(str::parse)
        .collect::<Result<_, _>>()?;
    Ok(Sizes {
        text: nums[0],
        data: nums[1],
        bss: nums[2],
    })
}

/// What one binary printed: its scenarios, `(stack used, stack size)` and the probe overhead.
type Parsed = (
    BTreeMap<String, ScenarioFigures>,
    Option<(u64, u64)>,
    Option<u64>,
);

/// Parses one binary's semihosting output.
fn parse(stdout: &str) -> Result<Parsed> {
    let mut frames: Vec<(String, Vec<BTreeMap<&str, u64>>)> = Vec::new();
    let mut stack = None;
    let mut overhead = None;
    for line in stdout.lines() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("SCENARIO") => {
                let name = words.next().context("SCENARIO without a name")?;
                let m = kv(line);
                let cal = m.get("calibration").copied().unwrap_or(0);
                ensure!(
                    cal.abs_diff(CALIBRATION) <= 20,
                    "clock calibration: a {CALIBRATION}-instruction loop measured {cal} \
                     (QEMU's -icount shift or SysTick clock is not what INSTR_PER_TICK assumes)"
                );
                overhead = m.get("probe_overhead").copied();
                frames.push((name.to_string(), Vec::new()));
            }
            Some("FRAME") => {
                let (_, f) = frames.last_mut().context("FRAME before SCENARIO")?;
                f.push(kv(line));
            }
            Some("STACK") => {
                let m = kv(line);
                stack = m.get("used").copied().zip(m.get("size").copied());
            }
            _ => {}
        }
    }
    let mut out = BTreeMap::new();
    for (name, fs) in frames.into_iter().filter(|(_, fs)| !fs.is_empty()) {
        let col = |k: &str| {
            fs.iter()
                .map(|f| f.get(k).copied().unwrap_or(0))
                .collect::<Vec<_>>()
        };
        let max = |k: &str| col(k).into_iter().max().unwrap_or(0);
        let stages = STAGES
            .iter()
            .map(|s| (s.trim_end_matches("_stage").to_string(), Stat::of(&col(s))))
            .collect();
        out.insert(
            name,
            ScenarioFigures {
                frames: fs.len(),
                points_min: col("points").into_iter().min().unwrap_or(0),
                points_max: max("points"),
                lanes_max: max("lanes"),
                spatial_events_max: max("events"),
                rows_pruned_max: max("approx"),
                probe_calls_max: max("calls"),
                total: Stat::of(&col("total")),
                decode: Stat::of(&col("decode")),
                stages,
            },
        );
    }
    Ok((out, stack, overhead))
}

fn run_binary(elf: &Path, timeout: u64) -> Result<BinaryReport> {
    let r = runner()?;
    let mut cmd = Command::new(&r[0]);
    cmd.args(&r[1..]).arg(elf);
    let (code, stdout, stderr) = run_with_timeout(cmd, Duration::from_secs(timeout))?;
    let (scenarios, stack, overhead) = parse(&stdout)?;
    let status = match code {
        None => format!("timeout after {timeout} s"),
        Some(c) if c < 0 && stderr.contains("Lockup") => {
            // QEMU's register dump: R13 is the stack pointer at the lockup.
            let sp = stderr
                .split_whitespace()
                .find_map(|w| w.strip_prefix("R13="))
                .and_then(|v| u64::from_str_radix(v, 16).ok());
            match sp {
                Some(sp) if sp < RAM_ORIGIN => format!(
                    "stack overflow: CPU lockup with SP = {sp:#010x}, below RAM ({RAM_ORIGIN:#010x}; \
                     flip-link puts the stack there so that it faults)"
                ),
                _ => format!(
                    "fault: CPU lockup (a fault while taking an exception): {}",
                    stderr.lines().next().unwrap_or("").trim()
                ),
            }
        }
        Some(0) if stdout.contains("DONE ok") => "ok".to_string(),
        Some(c) => {
            let why = stdout
                .lines()
                .chain(stderr.lines())
                .find(|l| {
                    l.starts_with("ERROR") || l.starts_with("HARDFAULT") || l.contains("fatal")
                })
                .unwrap_or("")
                .trim()
                .to_string();
            format!("fault (exit {c}): {why}")
        }
    };
    let frames_bytes = scenarios
        .keys()
        .filter_map(|s| {
            std::fs::metadata(repo_root().join(format!("bench/firmware/scenarios/{s}.stjf"))).ok()
        })
        .map(|m| m.len())
        .sum();
    Ok(BinaryReport {
        status,
        sizes: sizes(elf)?,
        stack_used: stack.map(|s| s.0),
        stack_size: stack_region(elf)?,
        frames_bytes,
        probe_overhead_per_call: overhead,
        scenarios,
    })
}

fn print_report(r: &Report) {
    println!("{} — {} — {}", r.machine, r.qemu, r.memory_map);
    for (b, br) in &r.binaries {
        println!(
            "\n{b}: {} | text {} data {} bss {} | flash without the {} B of scenario frames {} \
             | stack {} of {} B",
            br.status,
            br.sizes.text,
            br.sizes.data,
            br.sizes.bss,
            br.frames_bytes,
            (br.sizes.text + br.sizes.data).saturating_sub(br.frames_bytes),
            br.stack_used.map_or("?".into(), |v| v.to_string()),
            br.stack_size,
        );
        for (s, f) in &br.scenarios {
            println!(
                "  {s}: {} frames, {}–{} points, ≤ {} lanes, ≤ {} events, ≤ {} rows pruned; \
                 instructions per frame max {} median {} (decode max {})",
                f.frames,
                f.points_min,
                f.points_max,
                f.lanes_max,
                f.spatial_events_max,
                f.rows_pruned_max,
                f.total.max,
                f.total.median,
                f.decode.max
            );
            for (st, v) in &f.stages {
                if v.max > 0 {
                    println!("    {st:<12} max {:>10} median {:>10}", v.max, v.median);
                }
            }
        }
    }
}

fn check(report: &Report, budget: &Budget) -> Vec<String> {
    let mut fails = Vec::new();
    let over = |have: u64, want: u64| {
        have as f64 > want as f64 * (1.0 + budget.tolerance) + budget.slack_instructions as f64
    };
    for (b, be) in &budget.binaries {
        if be.runs && !report.binaries.contains_key(b) {
            fails.push(format!("{b}: budgeted, but not in the run"));
        }
    }
    for (b, br) in &report.binaries {
        let Some(be) = budget.binaries.get(b) else {
            fails.push(format!("{b}: no budget (run with --update-budget)"));
            continue;
        };
        if !be.runs {
            if br.status == "ok" {
                println!("note: {b} runs now but its budget says it does not: re-baseline with --update-budget");
            } else {
                println!("known: {b} does not run yet ({})", br.status);
            }
            continue;
        }
        if br.status != "ok" {
            fails.push(format!("{b}: {}", br.status));
            continue;
        }
        match br.stack_used {
            Some(s) if s > budget.stack_limit_bytes => fails.push(format!(
                "{b}: stack high-water {s} B exceeds {} B",
                budget.stack_limit_bytes
            )),
            None => fails.push(format!("{b}: no stack figure")),
            _ => {}
        }
        let flash = (br.sizes.text + br.sizes.data).saturating_sub(br.frames_bytes);
        if flash > budget.flash_limit_bytes {
            fails.push(format!(
                "{b}: flash (text + data without the {} B of scenario frames) {flash} B exceeds \
                 {} B",
                br.frames_bytes, budget.flash_limit_bytes
            ));
        }
        for s in br.scenarios.keys() {
            if !be.scenarios.contains_key(s) {
                fails.push(format!("{b}/{s}: no budget (run with --update-budget)"));
            }
        }
        for (s, sb) in &be.scenarios {
            let Some(f) = br.scenarios.get(s) else {
                fails.push(format!("{b}/{s}: scenario missing from the run"));
                continue;
            };
            let mut pairs = vec![
                ("total".to_string(), f.total, sb.total),
                ("decode".to_string(), f.decode, sb.decode),
            ];
            for (st, want) in &sb.stages {
                let have = f
                    .stages
                    .get(st)
                    .copied()
                    .unwrap_or(Stat { max: 0, median: 0 });
                pairs.push((st.clone(), have, *want));
            }
            for (what, have, want) in pairs {
                // A count the budget has but the run does not (its key missing from the FRAME
                // lines, or its probe never called) reads 0, which no budget can exceed.
                if want.max > 0 && have.max == 0 {
                    fails.push(format!(
                        "{b}/{s}: {what} not measured (0 on every frame; the budget has max {})",
                        want.max
                    ));
                }
                for (kind, h, w) in [
                    ("max", have.max, want.max),
                    ("median", have.median, want.median),
                ] {
                    if over(h, w) {
                        fails.push(format!(
                            "{b}/{s}: {what} {kind} {h} exceeds the budget {w} by {:+.2} %",
                            (h as f64 / w.max(1) as f64 - 1.0) * 100.0
                        ));
                    }
                }
            }
        }
    }
    fails
}

fn budget_from(report: &Report) -> Budget {
    let binaries = report
        .binaries
        .iter()
        .map(|(b, br)| {
            let runs = br.status == "ok";
            let entry = BudgetEntry {
                runs,
                note: (!runs).then(|| br.status.clone()),
                scenarios: if runs {
                    br.scenarios
                        .iter()
                        .map(|(s, f)| {
                            (
                                s.clone(),
                                ScenarioBudget {
                                    total: f.total,
                                    decode: f.decode,
                                    stages: f.stages.clone(),
                                },
                            )
                        })
                        .collect()
                } else {
                    BTreeMap::new()
                },
            };
            (b.clone(), entry)
        })
        .collect();
    Budget {
        schema: "stjpdacf-firmware-budget/v1".into(),
        about:
            "Instructions per frame (max and median over each scenario's frames) under QEMU \
                mps2-an386 -icount shift=3. Checked by `cargo xtask firmware --check`: a count may exceed its budget by `tolerance` \
                plus `slack_instructions`; every running binary's stack high-water mark must stay \
                under `stack_limit_bytes` and its flash (text + data, without the scenario frames it embeds) \
                under `flash_limit_bytes`; `runs: false` marks a binary that does not run on the \
                reference memory map yet (not enforced). Re-baseline with `cargo xtask firmware --update-budget`."
                .into(),
        tolerance: TOLERANCE,
        slack_instructions: SLACK,
        stack_limit_bytes: STACK_LIMIT,
        flash_limit_bytes: FLASH_LIMIT,
        build_env: model_env(),
        binaries,
    }
}

fn qemu_version() -> String {
    Command::new("qemu-system-arm")
        .arg("--version")
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .and_then(|s| s.lines().next().map(str::to_string))
        .unwrap_or_else(|| "qemu-system-arm (version unknown)".into())
}

fn cmd_run(
    json: Option<PathBuf>,
    do_check: bool,
    update: bool,
    qemu_ram: bool,
    timeout: u64,
    no_build: bool,
    budget_path: Option<PathBuf>,
) -> Result<()> {
    let budget_path = budget_path.unwrap_or_else(|| fw_dir().join("budget.json"));
    // A check builds the model its budget was measured with, whatever this shell has set.
    let budget: Option<Budget> = if do_check {
        Some(serde_json::from_str(
            &std::fs::read_to_string(&budget_path)
                .with_context(|| format!("reading {}", budget_path.display()))?,
        )?)
    } else {
        None
    };
    let bins: Vec<String> = binaries()?
        .into_iter()
        .filter(|b| b != NOPANIC && b != LANES)
        .collect();
    let target = if qemu_ram {
        fw_dir().join("target/qemu-ram")
    } else {
        fw_dir().join("target")
    };
    if !no_build {
        let mut c = cargo();
        c.args(["build", "--release"]);
        for b in &bins {
            c.args(["--bin", b]);
        }
        c.env("CARGO_TARGET_DIR", &target);
        if qemu_ram {
            c.env("STJPDACF_MEMORY_X", "memory-qemu.x");
        }
        if let Some(b) = &budget {
            for k in model_env().keys() {
                c.env_remove(k);
            }
            c.envs(&b.build_env);
            if !b.build_env.is_empty() {
                println!("model of {}: {:?}", budget_path.display(), b.build_env);
            }
        }
        let st = c.status().context("cargo build (firmware)")?;
        ensure!(st.success(), "the firmware build failed");
    }
    let mut binaries = BTreeMap::new();
    for b in &bins {
        let elf = target.join("thumbv7em-none-eabihf/release").join(b);
        eprintln!("running {b} under QEMU...");
        binaries.insert(b.clone(), run_binary(&elf, timeout)?);
    }
    let report = Report {
        schema: "stjpdacf-firmware-report/v1".into(),
        qemu: qemu_version(),
        machine: "QEMU mps2-an386, Cortex-M4F, -icount shift=3 (instructions counted by SysTick)"
            .into(),
        memory_map: if qemu_ram {
            "bench/firmware/memory-qemu.x: 4 MiB flash, 4 MiB RAM (NOT the reference MCU)".into()
        } else {
            "memory.x: 1 MiB flash, 256 KiB RAM (the reference MCU)".into()
        },
        instructions_per_tick: 5,
        binaries,
    };
    print_report(&report);
    let json = json.unwrap_or_else(|| {
        fw_dir().join("target").join(if qemu_ram {
            "report-qemu-ram.json"
        } else {
            "report.json"
        })
    });
    if let Some(d) = json.parent() {
        std::fs::create_dir_all(d)?;
    }
    std::fs::write(&json, serde_json::to_string_pretty(&report)? + "\n")?;
    println!("\nwrote {}", json.display());
    if update {
        let b = budget_from(&report);
        std::fs::write(&budget_path, serde_json::to_string_pretty(&b)? + "\n")?;
        println!("wrote {}", budget_path.display());
    }
    if let Some(b) = budget {
        let fails = check(&report, &b);
        if !fails.is_empty() {
            for f in &fails {
                eprintln!("BUDGET: {f}");
            }
            bail!("{} budget violation(s)", fails.len());
        }
        println!("budget check passed ({})", budget_path.display());
    }
    Ok(())
}

/// Call chains (callee first) from the functions of the `stjpdacf` crates to a panic, read from
/// the disassembly of a binary built with an ordinary panic handler.
fn panic_chains(elf: &Path) -> Result<Vec<Vec<String>>> {
    let out = Command::new(llvm_tool("llvm-objdump")?)
        .args(["-d", "--no-show-raw-insn", "-C"])
        .arg(elf)
        .output()?;
    let text = String::from_utf8_lossy(&out.stdout);
    let mut callers: BTreeMap<String, Vec<String>> = BTreeMap::new();
    let mut cur = String::new();
    for line in text.lines() {
        if let Some(name) = line
            .split_once(" <")
            .filter(|(a, _)| a.chars().all(|c| c.is_ascii_hexdigit()) && !a.is_empty())
            .and_then(|(_, b)| b.strip_suffix(">:"))
        {
            cur = name.to_string();
            continue;
        }
        let is_branch = line
            .split('\t')
            .nth(1)
            .is_some_and(|op| op.starts_with('b'));
        if !is_branch {
            continue;
        }
        if let Some(target) = line
            .rsplit_once('<')
            .and_then(|(_, t)| t.split(['+', '>']).next())
        {
            if target != cur {
                let v = callers.entry(target.to_string()).or_default();
                if !v.contains(&cur) {
                    v.push(cur.clone());
                }
            }
        }
    }
    let roots: Vec<String> = callers
        .keys()
        .filter(|k| k.starts_with("core::panicking::") || k.contains("panic_on_ord_violation"))
        .cloned()
        .collect();
    let mut chains = Vec::new();
    let mut queue: Vec<Vec<String>> = roots.into_iter().map(|r| vec![r]).collect();
    let mut seen = std::collections::BTreeSet::new();
    while let Some(chain) = queue.pop() {
        let last = chain.last().cloned().unwrap_or_default();
        if last.starts_with("stjpdacf::") {
            chains.push(chain);
            continue;
        }
        if chain.len() > 12 {
            continue;
        }
        for c in callers.get(&last).into_iter().flatten() {
            if seen.insert((last.clone(), c.clone())) {
                let mut next = chain.clone();
                next.push(c.clone());
                queue.push(next);
            }
        }
    }
    Ok(chains)
}

fn cmd_nopanic() -> Result<()> {
    let st = cargo()
        .args(["build", "--release", "--bin", NOPANIC])
        .env("CARGO_TARGET_DIR", fw_dir().join("target"))
        .status()?;
    if st.success() {
        println!(
            "no-panic proof: `{NOPANIC}` links with panic-never: no panicking branch survives"
        );
        return Ok(());
    }
    eprintln!(
        "\nno-panic proof FAILED; rebuilding with a plain panic handler to find the paths..."
    );
    // Same target directory: only the firmware crate itself is rebuilt with the feature.
    let dir = fw_dir().join("target");
    let st = cargo()
        .args([
            "build",
            "--release",
            "--bin",
            NOPANIC,
            "--features",
            "trace-panics",
        ])
        .env("CARGO_TARGET_DIR", &dir)
        .status()?;
    ensure!(st.success(), "the trace build failed too");
    let chains = panic_chains(&dir.join("thumbv7em-none-eabihf/release").join(NOPANIC))?;
    for c in &chains {
        eprintln!(
            "  {}",
            c.iter().rev().cloned().collect::<Vec<_>>().join("\n    → ")
        );
    }
    bail!(
        "the core has {} call chain(s) to a panic (printed above)",
        chains.len()
    )
}

/// `cargo xtask firmware-scenarios`: regenerates the scenario files in bench/firmware/scenarios.
pub fn scenarios() -> Result<()> {
    for p in fwscenario::write_all(&repo_root().join(fwscenario::SCENARIO_DIR))? {
        println!("wrote {}", p.display());
    }
    Ok(())
}

/// `cargo xtask firmware`.
pub fn run(a: RunArgs) -> Result<()> {
    cmd_run(
        a.json,
        a.check,
        a.update_budget,
        a.qemu_ram,
        a.timeout,
        a.no_build,
        a.budget,
    )
}

/// `cargo xtask nopanic`: build the no-panic proof; on failure, rebuild it with a plain panic
/// handler and print the call chains from the core to the panic.
pub fn nopanic() -> Result<()> {
    cmd_nopanic()
}
