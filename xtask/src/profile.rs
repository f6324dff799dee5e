//! `cargo xtask firmware-profile`: where a firmware binary's instructions go, per function, on
//! the Cortex-M4F under QEMU.
//!
//! QEMU runs the binary as `cargo xtask firmware` does (same runner line, same `-icount`), with
//! `-d in_asm,exec,nochain`: every translated block is printed once with its instructions
//! (`in_asm`), and every execution of a block is logged (`exec`; `nochain` makes QEMU return to
//! its loop after each block, so that no execution goes unlogged). The log streams through a
//! named pipe (a whole run logs several GB) into a parser that counts executions per block and
//! weighs each by its instruction count: a block translated with an instruction limit (QEMU does
//! so to stop exactly at a timer deadline under `-icount`; the limit is in the low 9 bits of its
//! `cflags`) counts `min(limit, size)`. Blocks are attributed to the ELF symbol QEMU names in the
//! log, demangled without its hash. Inlined code counts in the function it was inlined into.
//!
//! The total is checked against the SysTick counts the firmware prints (`FRAME … total=`): the
//! profile covers the whole run (start-up, decoding, every frame), so it is at least their sum.
//!
//! ```sh
//! cargo xtask firmware-profile --bin tracker_typical --top 40
//! STJPDACF_FW_TABLES=uncoupled cargo xtask firmware-profile --bin tracker_worst_patterns
//! cargo xtask firmware-profile --top 20 --lines 40   # and per source line (addr2line -i)
//! ```
//!
//! Needs what `cargo xtask firmware` needs, and `mkfifo` (coreutils). About 1–2 min for a binary
//! of ~200 M instructions.

use std::collections::HashMap;
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

use anyhow::{ensure, Context, Result};
use clap::Args;

use crate::firmware::{cargo, fw_dir, run_with_timeout, runner};

/// `cargo xtask firmware-profile`.
#[derive(Args, Debug)]
pub struct ProfileArgs {
    /// The firmware binary (`bench/firmware/src/bin/<name>.rs`).
    #[arg(long, default_value = "tracker_typical")]
    pub bin: String,
    /// Functions to print.
    #[arg(long, default_value_t = 40)]
    pub top: usize,
    /// Also print the source lines with the most instructions (0 = none): every executed
    /// instruction's address weighed by its block's executions, mapped to `file:line` by
    /// `arm-none-eabi-addr2line -i`: the innermost inlined location in this workspace's own
    /// sources (else the innermost one), so that library code (`core` iterators, nalgebra)
    /// counts at the tracker line that calls it; and the helpers (`memclr`, `memcpy`, `sqrtf`,
    /// …) by the line that calls them.
    #[arg(long, default_value_t = 0)]
    pub lines: usize,
    /// Skip `cargo build` (use the binary already built).
    #[arg(long)]
    pub no_build: bool,
    /// Kill the QEMU run after this many seconds.
    #[arg(long, default_value_t = 900)]
    pub timeout: u64,
}

/// Helpers whose instructions are also charged to their caller (the block executed just before
/// the helper was entered): memory clears and copies, and the float functions the Cortex-M4F
/// has no instruction for.
const HELPERS: [&str; 6] = [
    "__aeabi_mem",
    "compiler_builtins",
    "fmaxf",
    "fminf",
    "sqrtf",
    "memcpy",
];

fn is_helper(name: &str) -> bool {
    HELPERS.iter().any(|h| name.contains(h))
}

/// Counts from one QEMU log.
#[derive(Debug, Default)]
struct Counts {
    /// Instructions per translated block start (largest translation seen).
    size: HashMap<u32, u32>,
    /// Instructions per symbol as QEMU names it.
    per: HashMap<String, u64>,
    /// Instructions of helpers per (caller, helper).
    helpers: HashMap<(String, String), u64>,
    /// Executions per (block start, instruction limit; 0 = none).
    execs: HashMap<(u32, u32), u64>,
    /// Instruction addresses per translated block start (the largest translation seen).
    insns: HashMap<u32, Vec<u32>>,
    /// Instructions of helpers per (the calling block's start, helper): the call site.
    helper_sites: HashMap<(u32, String), u64>,
}

impl Counts {
    /// Parses a QEMU `-d in_asm,exec,nochain` log.
    fn parse(r: impl BufRead) -> Result<Self> {
        let mut c = Self::default();
        // The block being disassembled: (start, instructions so far).
        let mut block: Option<(u32, u32)> = None;
        let mut addrs: Vec<u32> = Vec::new();
        // The symbol of the last block outside the helpers: a helper's caller.
        let mut caller = String::new();
        let mut caller_pc = 0u32;
        for line in r.lines() {
            let line = line.context("reading the QEMU log")?;
            if let Some(rest) = line.strip_prefix("Trace ") {
                c.close(&mut block, &mut addrs);
                // "Trace 0: 0x7f… [00800408/00000400/00000110/ff020200] name"
                let Some((fields, name)) =
                    rest.split_once('[').and_then(|(_, r)| r.split_once(']'))
                else {
                    continue;
                };
                let f: Vec<&str> = fields.split('/').collect();
                let (Some(pc), Some(cflags)) = (
                    f.get(1).and_then(|v| u32::from_str_radix(v, 16).ok()),
                    f.get(3).and_then(|v| u32::from_str_radix(v, 16).ok()),
                ) else {
                    continue;
                };
                let size = u64::from(c.size.get(&pc).copied().unwrap_or(1));
                // A block translated with an instruction limit (low 9 bits of cflags).
                let limit = u64::from(cflags & 0x1ff);
                let w = if limit > 0 { size.min(limit) } else { size };
                let name = name.trim();
                *c.per.entry(name.to_string()).or_default() += w;
                *c.execs.entry((pc, cflags & 0x1ff)).or_default() += 1;
                if is_helper(name) {
                    *c.helpers
                        .entry((caller.clone(), name.to_string()))
                        .or_default() += w;
                    *c.helper_sites
                        .entry((caller_pc, name.to_string()))
                        .or_default() += w;
                } else {
                    caller_pc = pc;
                    if name != caller {
                        caller = name.to_string();
                    }
                }
            } else if let Some(addr) = line.strip_prefix("0x").and_then(|l| l.split_once(':')) {
                if let Ok(a) = u32::from_str_radix(addr.0, 16) {
                    addrs.push(a);
                    match block.as_mut() {
                        Some((_, n)) => *n += 1,
                        None => block = Some((a, 1)),
                    }
                }
            } else {
                // "IN: name", "----------------", blank lines: a block ends.
                c.close(&mut block, &mut addrs);
            }
        }
        c.close(&mut block, &mut addrs);
        Ok(c)
    }

    fn close(&mut self, block: &mut Option<(u32, u32)>, addrs: &mut Vec<u32>) {
        if let Some((pc, n)) = block.take() {
            let e = self.size.entry(pc).or_default();
            *e = (*e).max(n);
            let v = self.insns.entry(pc).or_default();
            if addrs.len() > v.len() {
                *v = std::mem::take(addrs);
            }
        }
        addrs.clear();
    }

    /// Instructions per instruction address: each block's executions on its first
    /// `min(limit, size)` instructions.
    fn by_address(&self) -> HashMap<u32, u64> {
        let mut per: HashMap<u32, u64> = HashMap::new();
        for (&(pc, limit), &n) in &self.execs {
            let Some(v) = self.insns.get(&pc) else {
                continue;
            };
            let k = if limit > 0 {
                v.len().min(limit as usize)
            } else {
                v.len()
            };
            for a in v.iter().take(k) {
                *per.entry(*a).or_default() += n;
            }
        }
        per
    }

    /// Instructions per symbol (demangled, no hash), largest first, and the total.
    fn by_function(&self) -> (Vec<(String, u64)>, u64) {
        let mut per: HashMap<String, u64> = HashMap::new();
        for (name, n) in &self.per {
            *per.entry(demangle(name)).or_default() += n;
        }
        let total = per.values().sum();
        (sorted(per), total)
    }

    /// Helper instructions per `caller → helper`, largest first.
    fn helpers_by_caller(&self) -> Vec<(String, u64)> {
        let mut per: HashMap<String, u64> = HashMap::new();
        for ((caller, helper), n) in &self.helpers {
            *per.entry(format!("{} → {}", demangle(caller), demangle(helper)))
                .or_default() += n;
        }
        sorted(per)
    }
}

fn demangle(name: &str) -> String {
    if name.is_empty() {
        "?".to_string()
    } else {
        format!("{:#}", rustc_demangle::demangle(name))
    }
}

fn sorted(m: HashMap<String, u64>) -> Vec<(String, u64)> {
    let mut v: Vec<(String, u64)> = m.into_iter().collect();
    v.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
    v
}

/// Runs the profile.
pub fn run(a: &ProfileArgs) -> Result<()> {
    let target = fw_dir().join("target");
    if !a.no_build {
        let mut c = cargo();
        c.args(["build", "--release", "--bin", &a.bin]);
        c.env("CARGO_TARGET_DIR", &target);
        let st = c.status().context("cargo build (firmware)")?;
        ensure!(st.success(), "the firmware build failed");
    }
    let elf = target.join("thumbv7em-none-eabihf/release").join(&a.bin);
    ensure!(elf.exists(), "no firmware binary {}", elf.display());
    let fifo: PathBuf = target.join(format!("profile-{}.fifo", std::process::id()));
    let _ = std::fs::remove_file(&fifo);
    let st = Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .context("mkfifo")?;
    ensure!(st.success(), "mkfifo {} failed", fifo.display());
    // The reader opens the pipe (blocking until QEMU opens it for writing) and parses as it
    // streams.
    let reader = {
        let fifo = fifo.clone();
        std::thread::spawn(move || -> Result<Counts> {
            let f = std::fs::File::open(&fifo).context("opening the log pipe")?;
            Counts::parse(BufReader::with_capacity(1 << 20, f))
        })
    };
    // The runner line of `cargo xtask firmware`, the log options before its `-kernel`.
    let r = runner()?;
    let mut args: Vec<std::ffi::OsString> = r.iter().skip(1).map(Into::into).collect();
    let at = args
        .iter()
        .position(|s| s == "-kernel")
        .unwrap_or(args.len());
    let log: [std::ffi::OsString; 4] = [
        "-d".into(),
        "in_asm,exec,nochain".into(),
        "-D".into(),
        fifo.clone().into_os_string(),
    ];
    args.splice(at..at, log);
    args.push(elf.clone().into_os_string());
    let mut cmd = Command::new(r.first().context("empty runner line")?);
    cmd.args(&args);
    eprintln!("profiling {} under QEMU (every block logged)...", a.bin);
    let (code, stdout, stderr) = run_with_timeout(cmd, Duration::from_secs(a.timeout))?;
    let counts = reader
        .join()
        .map_err(|_| anyhow::anyhow!("the log reader panicked"))??;
    let _ = std::fs::remove_file(&fifo);
    ensure!(
        code == Some(0) && stdout.contains("DONE ok"),
        "the firmware run failed (exit {code:?}): {}",
        stderr.lines().next().unwrap_or("")
    );
    let frames: Vec<u64> = stdout
        .lines()
        .filter(|l| l.starts_with("FRAME "))
        .filter_map(|l| {
            l.split_whitespace()
                .find_map(|w| w.strip_prefix("total="))
                .and_then(|v| v.parse().ok())
        })
        .collect();
    let systick: u64 = frames.iter().sum();
    let (funcs, total) = counts.by_function();
    println!(
        "{}: {} instructions in the whole run (SysTick: {} in {} frames, {:.1} % of the run); \
         per frame below = run / frames",
        a.bin,
        total,
        systick,
        frames.len(),
        100.0 * systick as f64 / total.max(1) as f64
    );
    let nf = frames.len().max(1) as u64;
    print_table("function", &funcs, (a.top, nf, total));
    println!("\nhelpers by caller (the helper's instructions, charged to the block before it):");
    print_table(
        "caller → helper",
        &counts.helpers_by_caller(),
        (a.top, nf, total),
    );
    if a.lines > 0 {
        let lines = source_lines(&elf, &counts.by_address())?;
        println!("\nsource lines (innermost inlined location in the tracker's own sources):");
        print_table("file:line", &lines, (a.lines, nf, total));
        // The helpers' call sites: the last instruction of the block before the helper.
        let sites: Vec<((u32, String), u64)> = counts
            .helper_sites
            .iter()
            .filter_map(|((pc, h), n)| {
                let call = *counts.insns.get(pc)?.last()?;
                Some(((call, h.clone()), *n))
            })
            .collect();
        let at = locate(
            &elf,
            &sites.iter().map(|((a, _), _)| *a).collect::<Vec<_>>(),
        )?;
        let mut per: HashMap<String, u64> = HashMap::new();
        for (((_, h), n), loc) in sites.iter().zip(at) {
            *per.entry(format!("{loc} → {}", demangle(h))).or_default() += n;
        }
        println!("\nhelpers by call site:");
        print_table("file:line → helper", &sorted(per), (a.lines, nf, total));
    }
    Ok(())
}

/// Instructions per `file:line` (`arm-none-eabi-addr2line`, addresses on its stdin), largest
/// first; paths shortened to the part from `src/` (or the crate directory) on.
fn source_lines(elf: &std::path::Path, per: &HashMap<u32, u64>) -> Result<Vec<(String, u64)>> {
    let addrs: Vec<(u32, u64)> = per.iter().map(|(a, n)| (*a, *n)).collect();
    let at = locate(elf, &addrs.iter().map(|(a, _)| *a).collect::<Vec<_>>())?;
    let mut lines: HashMap<String, u64> = HashMap::new();
    for ((_, n), loc) in addrs.iter().zip(at) {
        *lines.entry(loc).or_default() += n;
    }
    Ok(sorted(lines))
}

/// Each address's `file:line`: the innermost inlined frame in the core's own sources (`src/`),
/// else the innermost frame (`arm-none-eabi-addr2line -a -i`).
fn locate(elf: &std::path::Path, addrs: &[u32]) -> Result<Vec<String>> {
    use std::io::Write;
    let mut child = Command::new("arm-none-eabi-addr2line")
        .args(["-a", "-i", "-e"])
        .arg(elf)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .context("arm-none-eabi-addr2line (binutils-arm-none-eabi)")?;
    let input: String = addrs.iter().map(|a| format!("{a:#x}\n")).collect();
    let mut stdin = child.stdin.take().context("addr2line stdin")?;
    let writer = std::thread::spawn(move || stdin.write_all(input.as_bytes()));
    let out = child.wait_with_output().context("addr2line")?;
    writer
        .join()
        .map_err(|_| anyhow::anyhow!("the addr2line writer panicked"))?
        .context("writing to addr2line")?;
    let text = String::from_utf8_lossy(&out.stdout);
    // With `-a -i`: each address's "0x…" line, then its inlined frames, innermost first.
    let mut frames: Vec<Vec<String>> = Vec::new();
    for l in text.lines() {
        if l.starts_with("0x") {
            frames.push(Vec::new());
        } else if let Some(f) = frames.last_mut() {
            f.push(short_path(l));
        }
    }
    ensure!(
        frames.len() == addrs.len(),
        "addr2line answered {} addresses of {}",
        frames.len(),
        addrs.len()
    );
    Ok(frames
        .into_iter()
        .map(|f| {
            let mut own = f.iter().filter(|l| l.starts_with("src/"));
            match (own.next(), own.next()) {
                // A one-line helper (`linalg::get`, `math::max`, …): and where it is called.
                (Some(h), Some(c)) if is_small_helper(h) => format!("{h} ← {c}"),
                (Some(h), _) => h.clone(),
                (None, _) => f.first().cloned().unwrap_or_else(|| "??".to_string()),
            }
        })
        .collect())
}

/// The core's small inlined helpers (bounds-checked element access, `math` wrappers): their
/// lines are split by the line that calls them.
fn is_small_helper(loc: &str) -> bool {
    loc.starts_with("src/linalg.rs:") || loc.starts_with("src/math.rs:")
}

/// `…/registry/src/…/nalgebra-0.33.2/src/base/ops.rs:42 (discriminator 3)` →
/// `nalgebra-0.33.2/src/base/ops.rs:42`; `/work/main/src/persist/mod.rs:7` → `src/persist/mod.rs:7`
/// (the workspace root); `/work/main/bench/firmware/src/lib.rs:9` → `bench/firmware/src/lib.rs:9`.
fn short_path(loc: &str) -> String {
    let loc = loc.split(" (").next().unwrap_or(loc).trim();
    match loc.rfind("/src/") {
        Some(i) => {
            let head = &loc[..i];
            let krate = head.rsplit('/').next().unwrap_or("");
            let root = concat!(env!("CARGO_MANIFEST_DIR"), "/..");
            let own = std::path::Path::new(head).join("Cargo.toml").exists()
                && !head.contains("/registry/");
            let rel = std::fs::canonicalize(head).ok().and_then(|h| {
                let r = std::fs::canonicalize(root).ok()?;
                Some(h.strip_prefix(r).ok()?.to_string_lossy().into_owned())
            });
            match rel {
                // The workspace root (the core): `src/…`; a member: `bench/firmware/src/…`.
                Some(r) if own && r.is_empty() => loc[i + 1..].to_string(),
                Some(r) if own => format!("{r}{}", &loc[i..]),
                _ => format!("{krate}{}", &loc[i..]),
            }
        }
        None => loc.to_string(),
    }
}

/// The first `top` rows: instructions per frame (`frames` frames), share of `total`, name.
fn print_table(what: &str, rows: &[(String, u64)], (top, frames, total): (usize, u64, u64)) {
    println!("{:>12} {:>6}  {what}", "per frame", "%");
    for (name, n) in rows.iter().take(top) {
        println!(
            "{:>12} {:>5.1}%  {name}",
            n / frames,
            100.0 * *n as f64 / total.max(1) as f64
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Blocks weigh by their instructions, one translated with an instruction limit of 1 by its
    /// limit; a helper's instructions are charged to the block before it.
    #[test]
    fn blocks_weigh_by_their_instructions() {
        let log = "\
----------------
IN: _ZN3foo3bar17h0123456789abcdefE
0x00000400:  b580       push     {r7, lr}
0x00000402:  af00       add      r7, sp, #0
0x00000404:  e7fe       b        #0x404

Trace 0: 0x7f00 [00800408/00000400/00000110/ff020200] _ZN3foo3bar17h0123456789abcdefE
Trace 0: 0x7f00 [00800408/00000400/00000110/ff020200] _ZN3foo3bar17h0123456789abcdefE
----------------
IN: baz
0x00000500:  4770       bx       lr

Trace 0: 0x7f40 [00800408/00000500/00000110/ff020200] baz
Trace 0: 0x7f80 [00800408/00000400/00000110/ff020201] _ZN3foo3bar17h0123456789abcdefE
----------------
IN: __aeabi_memclr4
0x00000600:  2200       movs     r2, #0
0x00000602:  4770       bx       lr

Trace 0: 0x7fc0 [00800408/00000600/00000110/ff020200] __aeabi_memclr4
";
        let c = Counts::parse(log.as_bytes()).expect("parses");
        let (f, total) = c.by_function();
        assert_eq!(total, 3 + 3 + 1 + 1 + 2);
        assert_eq!(f[0], ("foo::bar".to_string(), 7));
        assert_eq!(f[1], ("__aeabi_memclr4".to_string(), 2));
        assert_eq!(f[2], ("baz".to_string(), 1));
        assert_eq!(
            c.helpers_by_caller(),
            vec![("foo::bar → __aeabi_memclr4".to_string(), 2)]
        );
        // Per address: the first block's 3 instructions twice, then its first only (limit 1).
        let a = c.by_address();
        assert_eq!(a.get(&0x400), Some(&3));
        assert_eq!(a.get(&0x402), Some(&2));
        assert_eq!(a.get(&0x404), Some(&2));
        assert_eq!(a.get(&0x500), Some(&1));
        assert_eq!(a.values().sum::<u64>(), total);
    }
}
