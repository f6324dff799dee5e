//! Helpers shared by the tools crate's CLI tests (`mod common;` in each test file).
#![allow(dead_code)] // each test binary uses a part of them

use std::process::{Command, Output};

/// The `stjpdacf` binary under test.
pub fn stjpdacf() -> Command {
    Command::new(env!("CARGO_BIN_EXE_stjpdacf"))
}

/// Asserts that the run succeeded; on failure the message is its stderr.
#[track_caller]
pub fn assert_success(out: &Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Asserts that the run failed and that its stderr contains `needle`; returns the stderr.
#[track_caller]
pub fn assert_failure_mentions(out: &Output, needle: &str) -> String {
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(err.contains(needle), "{err}");
    err
}
