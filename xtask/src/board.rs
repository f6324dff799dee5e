//! The board example (`board/`) under QEMU, a step of `cargo xtask capi`: its `qemu` binary
//! reads the firmware's `typical` frames through an `embedded-hal` `SpiDevice` fed from a host
//! file and writes lane frames (the format of `board/src/lib.rs`) to the UART, which QEMU puts
//! in `board/target/lanes.stjl`. Every lane frame must decode (magic, version, CRC) and its lanes
//! must equal the filtered lanes the Rust firmware's `lanes_typical` prints for the same frames.

use std::path::PathBuf;
use std::process::Command;
use std::time::Duration;

use anyhow::{bail, ensure, Context, Result};
use stjpdacf_tools::repo_root;

use crate::firmware;

/// Bytes per lane in a lane frame (`stjpdacf_board::LANE_LEN`).
const LANE_LEN: usize = 156;

fn board_dir() -> PathBuf {
    repo_root().join("board")
}

/// The lane frames of a UART capture as the firmware's `LANE F <frame> ...` lines.
fn decode(bytes: &[u8]) -> Result<Vec<String>> {
    let mut lines = Vec::new();
    let mut rest = bytes;
    let mut k = 0usize;
    while !rest.is_empty() {
        ensure!(rest.len() >= 24, "lane frame {k}: truncated header");
        ensure!(
            rest[..4] == *b"STJL" && rest[4] == 1,
            "lane frame {k}: bad magic or version"
        );
        let n = usize::from(rest[5]);
        let len = 24 + LANE_LEN * n;
        ensure!(rest.len() >= len, "lane frame {k}: truncated");
        let (frame, tail) = rest.split_at(len);
        let crc = u32::from_le_bytes(frame[len - 4..].try_into()?);
        ensure!(
            stjpdacf::wire::crc32(&frame[..len - 4]) == crc,
            "lane frame {k}: CRC mismatch"
        );
        let u32_at = |b: &[u8], at: usize| -> Result<u32> {
            Ok(u32::from_le_bytes(b[at..at + 4].try_into()?))
        };
        for lane in frame[20..len - 4].chunks_exact(LANE_LEN) {
            let misses = u16::from_le_bytes(lane[6..8].try_into()?);
            let mut line = format!(
                "LANE F {k} {} {} {misses} {} {}",
                u32_at(lane, 0)?,
                lane[4],
                u32_at(lane, 8)?,
                u32_at(lane, 12)?
            );
            for at in (16..LANE_LEN).step_by(4) {
                line.push_str(&format!(" {:08x}", u32_at(lane, at)?));
            }
            lines.push(line);
        }
        rest = tail;
        k += 1;
    }
    Ok(lines)
}

/// Builds and runs the board example; `rust_lanes` are the `LANE` lines of the Rust
/// firmware's `lanes_typical` on the same frames.
pub fn run(frames: &str, rust_lanes: &[&str]) -> Result<()> {
    let dir = board_dir();
    let st = firmware::cargo()
        .current_dir(&dir)
        .args(["build", "--release", "--bin", "qemu"])
        .status()
        .context("cargo build (board)")?;
    ensure!(st.success(), "building the board example failed");
    std::fs::create_dir_all(dir.join("target"))?;
    std::fs::copy(repo_root().join(frames), dir.join("target/frames.stjf"))?;
    let capture = dir.join("target/lanes.stjl");
    if capture.exists() {
        std::fs::remove_file(&capture)?;
    }
    let runner = firmware::runner_in(&dir)?;
    let (prog, args) = runner.split_first().context("empty runner")?;
    let mut c = Command::new(prog);
    c.current_dir(&dir)
        .args(args)
        .arg("target/thumbv7em-none-eabihf/release/qemu");
    println!("$ (in board/) {prog} {} …/qemu", args.join(" "));
    let (code, out, err) = firmware::run_with_timeout(c, Duration::from_secs(300))?;
    print!("{out}");
    ensure!(
        code == Some(0),
        "board example under QEMU: exit {code:?}\n{err}"
    );
    let summary = out
        .lines()
        .find(|l| l.starts_with("BOARD "))
        .context("no BOARD line")?;
    let m = firmware::kv(summary);
    ensure!(
        m.get("bad_frames") == Some(&0) && m.get("frames").is_some_and(|&f| f > 0),
        "board example: {summary}"
    );
    let got = decode(&std::fs::read(&capture)?)?;
    let want: Vec<&str> = rust_lanes
        .iter()
        .copied()
        .filter(|l| l.starts_with("LANE F "))
        .collect();
    // Identical and not empty: two empty lists would agree on nothing.
    ensure!(
        !want.is_empty(),
        "the Rust firmware printed no filtered lane on the board's frames"
    );
    if got != want {
        let i = got.iter().zip(&want).position(|(a, b)| a != b);
        bail!(
            "the board example's UART lanes differ from the Rust firmware's ({} vs {} lanes, first \
             difference at {i:?})",
            got.len(),
            want.len()
        );
    }
    println!(
        "board example: {} frames in over SPI (host file), {} lanes out on the UART in {} B of \
         lane frames, identical to the Rust firmware's filtered lanes",
        m.get("frames").copied().unwrap_or(0),
        got.len(),
        std::fs::metadata(&capture)?.len()
    );
    Ok(())
}
