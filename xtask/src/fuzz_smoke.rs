//! `cargo xtask fuzz-smoke`: the bounded, reproducible fuzz run of CI.
//!
//! Builds the cargo-fuzz targets (libFuzzer, no sanitizer: stable Rust), fuzzes each from its
//! committed seed corpus (`fuzz/seeds/<target>/`) for a fixed number of executions from a fixed
//! seed (`-seed=1 -runs=N`: the same inputs on every machine, so a CI failure reproduces locally
//! with this command; exploration is the job of the long runs, `fuzz/README.md`), then replays
//! every crash found and fails on any violation that is not an open, reported finding listed in
//! `fuzz/known-findings.txt` (or on any crash without an invariant message, e.g. a panic inside
//! the core). libFuzzer stops at the first crash. `--cap` is a wall-clock cap per target in
//! seconds: a slow machine runs a prefix of the same sequence.
//!
//! Needs `cargo install cargo-fuzz --locked`.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{bail, ensure, Context, Result};
use clap::Args;
use regex::Regex;
use stjpdacf_tools::repo_root;

/// Targets and their executions: about 10 s each on one core of the CI machines.
const TARGETS: [(&str, u64); 4] = [
    ("tracker_step", 20_000),
    ("temporal_ops", 20_000),
    ("tables_validate", 15_000),
    ("wire_decode", 4_000),
];

/// Options of `cargo xtask fuzz-smoke`.
#[derive(Args, Debug)]
pub struct SmokeArgs {
    /// Wall-clock cap per target, seconds.
    #[arg(long, default_value_t = 60)]
    pub cap: u64,
}

/// The open findings' message patterns (`fuzz/known-findings.txt`, one regular expression a line).
fn known_findings(root: &Path) -> Result<Vec<Regex>> {
    let p = root.join("fuzz/known-findings.txt");
    let text = std::fs::read_to_string(&p).with_context(|| format!("reading {}", p.display()))?;
    text.lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .map(|l| Regex::new(l).with_context(|| format!("{}: pattern {l:?}", p.display())))
        .collect()
}

/// Numbers in a message replaced by `N`, so that messages of one kind count together.
fn message_kind(msg: &str) -> String {
    static NUMBER: std::sync::LazyLock<Option<Regex>> =
        std::sync::LazyLock::new(|| Regex::new(r"-?[0-9][0-9.]*(e-?[0-9]+)?").ok());
    match NUMBER.as_ref() {
        Some(re) => re.replace_all(msg, "N").into_owned(),
        None => msg.to_owned(),
    }
}

/// The executions libFuzzer reports in its log (`Done N runs`, else the last `#N`).
fn executions(log: &str) -> u64 {
    let done = log.lines().find_map(|l| {
        l.strip_prefix("Done ")
            .and_then(|r| r.split_whitespace().next())
            .and_then(|n| n.parse().ok())
    });
    done.or_else(|| {
        log.lines().rev().find_map(|l| {
            l.strip_prefix('#')
                .and_then(|r| r.split(|c: char| !c.is_ascii_digit()).next())
                .and_then(|n| n.parse().ok())
        })
    })
    .unwrap_or(0)
}

/// One target: fuzz, then classify every crash input. Returns the crashes not known.
fn smoke_target(
    bin: &Path,
    work: &Path,
    target: &str,
    runs: u64,
    cap: u64,
    known: &[Regex],
) -> Result<usize> {
    let root = repo_root();
    let corpus = work.join(target).join("corpus");
    let crashes = work.join(target).join("crashes");
    std::fs::create_dir_all(&corpus)?;
    std::fs::create_dir_all(&crashes)?;
    for e in std::fs::read_dir(root.join("fuzz/seeds").join(target))? {
        let p = e?.path();
        if let Some(name) = p.file_name() {
            std::fs::copy(&p, corpus.join(name))?;
        }
    }
    let exe = bin.join(target);
    let start = Instant::now();
    let out = Command::new(&exe)
        .arg("-seed=1")
        .arg(format!("-runs={runs}"))
        .arg(format!("-max_total_time={cap}"))
        .arg("-rss_limit_mb=4096")
        .arg(format!("-artifact_prefix={}/", crashes.display()))
        .arg(&corpus)
        .output()
        .with_context(|| format!("running {}", exe.display()))?;
    let secs = start.elapsed().as_secs();
    let log =
        String::from_utf8_lossy(&out.stderr).into_owned() + &String::from_utf8_lossy(&out.stdout);
    let mut inputs: Vec<PathBuf> = std::fs::read_dir(&crashes)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .collect();
    inputs.sort();
    let mut kinds = std::collections::BTreeMap::<String, usize>::new();
    let mut unknown = 0;
    for c in &inputs {
        let replay = Command::new(&exe).arg(c).output()?;
        let text = String::from_utf8_lossy(&replay.stderr).into_owned()
            + &String::from_utf8_lossy(&replay.stdout);
        let msg = text
            .lines()
            .find(|l| l.contains("invariant violated"))
            .map(str::to_owned);
        *kinds
            .entry(message_kind(
                msg.as_deref().unwrap_or("no invariant message"),
            ))
            .or_default() += 1;
        let is_known = msg
            .as_deref()
            .is_some_and(|m| known.iter().any(|k| k.is_match(m)));
        if !is_known {
            unknown += 1;
            let bytes = std::fs::read(c)?;
            println!(
                "NEW FINDING in {target}: {}: {}\ninput (hex): {}",
                msg.as_deref()
                    .unwrap_or("no invariant message (panic in the core?)"),
                c.display(),
                bytes.iter().map(|b| format!("{b:02x}")).collect::<String>()
            );
        }
    }
    println!(
        "fuzz smoke {target}: {} of {runs} executions (seed 1) in {secs} s, {} crash inputs, {unknown} not known findings",
        executions(&log),
        inputs.len()
    );
    for (k, n) in kinds {
        println!("    {n} {k}");
    }
    // A run without a crash input must have ended as libFuzzer ends a clean run (exit 0) after
    // executing inputs: a target that fails at start or exits at once has tested nothing.
    if inputs.is_empty() {
        let lines: Vec<&str> = log.lines().collect();
        ensure!(
            out.status.success() && executions(&log) > 0,
            "fuzz smoke {target}: libFuzzer ended ({}) after {} executions without a crash \
             input:\n{}",
            out.status,
            executions(&log),
            lines[lines.len().saturating_sub(20)..].join("\n")
        );
    }
    Ok(unknown)
}

/// `cargo xtask fuzz-smoke`.
pub fn run(a: &SmokeArgs) -> Result<()> {
    let root = repo_root();
    let st = Command::new("cargo")
        .current_dir(&root)
        .args(["fuzz", "build", "--sanitizer", "none", "-O"])
        .status()
        .context("cargo fuzz build (is cargo-fuzz installed? cargo install cargo-fuzz --locked)")?;
    ensure!(st.success(), "cargo fuzz build failed");
    let bin = root.join("fuzz/target/x86_64-unknown-linux-gnu/release");
    let known = known_findings(&root)?;
    let work = std::env::temp_dir().join(format!("stjpdacf-fuzz-smoke-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&work);
    let mut unknown = 0;
    for (t, runs) in TARGETS {
        unknown += smoke_target(&bin, &work, t, runs, a.cap, &known)?;
    }
    std::fs::remove_dir_all(&work).with_context(|| format!("removing {}", work.display()))?;
    if unknown > 0 {
        bail!("{unknown} crash inputs that are not known findings");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_of_one_kind_count_together() {
        assert_eq!(
            message_kind("invariant violated: variance -1.5e-3 at 12"),
            "invariant violated: variance N at N"
        );
    }

    #[test]
    fn executions_from_done_line_or_last_status() {
        assert_eq!(
            executions("#2 INITED\n#4096 pulse\nDone 20000 runs in 9 second(s)"),
            20000
        );
        assert_eq!(executions("#2 INITED\n#4096 pulse  cov: 1"), 4096);
        assert_eq!(executions("nothing"), 0);
    }
}

#[cfg(test)]
mod stub_targets {
    use super::*;
    use std::os::unix::fs::PermissionsExt;

    /// `smoke_target` on a stand-in for the libFuzzer binary (a shell script).
    fn smoke_stub(name: &str, body: &str) -> Result<usize> {
        let d = std::env::temp_dir().join(format!("fuzz-smoke-stub-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        let bin = d.join("bin");
        std::fs::create_dir_all(&bin)?;
        let exe = bin.join("wire_decode");
        std::fs::write(&exe, format!("#!/bin/sh\n{body}\n"))?;
        std::fs::set_permissions(&exe, std::fs::Permissions::from_mode(0o755))?;
        let r = smoke_target(&bin, &d.join("work"), "wire_decode", 4000, 60, &[]);
        std::fs::remove_dir_all(&d)?;
        r
    }

    #[test]
    fn a_target_that_runs_nothing_fails() {
        assert!(smoke_stub("silent", "exit 0").is_err());
        assert!(smoke_stub("error", "echo 'ERROR: libFuzzer: x' >&2; exit 1").is_err());
        assert_eq!(
            smoke_stub("clean", "echo 'Done 4000 runs in 1 second(s)' >&2; exit 0").ok(),
            Some(0)
        );
    }
}
