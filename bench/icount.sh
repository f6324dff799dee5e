#!/usr/bin/env bash
# Instruction counts (x86-64 host, valgrind's callgrind) of the spatial JPDACF per row and per
# frame on the inputs of bench/benches/spatial.rs and bench/benches/tracker.rs: deterministic,
# unlike wall-clock time on a shared machine. Usage: bench/icount.sh [ITERS] [INPUT...]
# Prints one line per input: instructions per call (row or frame), from the calls inside
# `measure_spatial_*` only (setup excluded). Figures in docs/benchmarks.md.
set -euo pipefail
cd "$(dirname "$0")/.."
iters="${1:-5}"
shift || true
cargo build --release -q -p stjpdacf-bench --example spatial_icount
exe=target/release/examples/spatial_icount
inputs=("$@")
if [ ${#inputs[@]} -eq 0 ]; then
  mapfile -t inputs < <("$exe" --list)
fi
out="$(mktemp -d)"
trap 'rm -rf "$out"' EXIT
printf '%-16s %8s %12s  %s\n' input calls instr/call counters
for name in "${inputs[@]}"; do
  valgrind --tool=callgrind --toggle-collect='*measure_spatial*' \
    --callgrind-out-file="$out/$name.cg" "$exe" "$name" "$iters" >"$out/$name.txt" 2>"$out/$name.err"
  total=$(awk '/^summary:|^totals:/ {print $2; exit}' "$out/$name.cg")
  line=$(grep "^$name:" "$out/$name.txt")
  frames=$(sed -E 's/.* frames ([0-9]+).*/\1/' <<<"$line")
  calls=$((iters * frames))
  printf '%-16s %8d %12d  %s\n' "$name" "$calls" $((total / calls)) "${line#*frames [0-9]* }"
done
