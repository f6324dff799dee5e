#!/usr/bin/env bash
# Bounded, reproducible fuzz smoke run for CI: builds the cargo-fuzz targets (libFuzzer, no
# sanitizer: stable Rust), fuzzes each from its committed seed corpus (fuzz/seeds/<target>/) for a
# fixed number of executions from a fixed seed (-seed=1 -runs=N: the same inputs on every machine,
# so a CI failure reproduces locally with this script; exploration is the job of the long runs,
# fuzz/README.md), then replays every crash found and fails on any violation that is not an open,
# reported finding listed in fuzz/known-findings.txt (or on any crash without an invariant message,
# e.g. a panic inside the core). libFuzzer stops at the first crash. Usage: fuzz/smoke.sh [CAP]
# (a wall-clock cap per target in seconds, default 60: a slow machine runs a prefix of the same
# sequence).
set -euo pipefail
cd "$(dirname "$0")/.."
cap="${1:-60}"
cargo fuzz build --sanitizer none -O
bin=fuzz/target/x86_64-unknown-linux-gnu/release
known="$( (grep -v "^#" fuzz/known-findings.txt || true) | (grep -v "^$" || true) | paste -sd"|")"
# No open finding: a pattern that matches nothing (an empty one would match every message).
[ -n "$known" ] || known='^$a'
work="$(mktemp -d)"
status=0
# Executions per target: about 10 s each on one core of the CI machines.
for spec in tracker_step:20000 temporal_ops:20000 tables_validate:15000 wire_decode:4000; do
  t="${spec%%:*}"; runs="${spec##*:}"
  mkdir -p "$work/$t/corpus" "$work/$t/crashes"
  cp fuzz/seeds/$t/* "$work/$t/corpus/"
  start=$SECONDS
  "$bin/$t" -seed=1 -runs="$runs" -max_total_time="$cap" -rss_limit_mb=4096 \
    -artifact_prefix="$work/$t/crashes/" "$work/$t/corpus" > "$work/$t/log" 2>&1 || true
  secs=$((SECONDS - start))
  execs="$( (grep -o '^Done [0-9]* runs' "$work/$t/log" || grep -o '^#[0-9]*' "$work/$t/log" || true) | tail -1 | tr -dc '0-9')"
  n=0; unknown=0
  for c in "$work/$t"/crashes/*; do
    [ -e "$c" ] || continue
    n=$((n + 1))
    msg="$("$bin/$t" "$c" 2>&1 | grep -m1 'invariant violated' || true)"
    echo "${msg:-no invariant message}" | sed -E 's/-?[0-9][0-9.]*(e-?[0-9]+)?/N/g' >> "$work/$t/messages"
    if [ -z "$msg" ] || ! grep -Eq "$known" <<< "$msg"; then
      unknown=$((unknown + 1))
      echo "NEW FINDING in $t: ${msg:-no invariant message (panic in the core?)}: $c"
      echo "input (base64): $(base64 -w0 "$c")"
    fi
  done
  echo "fuzz smoke $t: ${execs:-0} of $runs executions (seed 1) in ${secs} s, $n crash inputs, $unknown not known findings"
  if [ -e "$work/$t/messages" ]; then sort "$work/$t/messages" | uniq -c | sed 's/^/    /'; fi
  [ "$unknown" -eq 0 ] || status=1
done
rm -rf "$work"
exit "$status"
