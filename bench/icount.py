#!/usr/bin/env python3
"""Instruction counts (x86-64 host, valgrind's callgrind) of the spatial JPDACF per row, per frame
and per stage, on the inputs of bench/benches/spatial.rs and bench/benches/tracker.rs
(bench/examples/spatial_icount.rs builds them). Deterministic, unlike wall-clock time on a shared
machine; host x86-64 instructions, not Cortex-M ones.

    python3 bench/icount.py [--iters N] [--no-stages] [--scalar] [INPUT ...]

Prints, per input, instructions per call (a row step or a frame; setup excluded: only the calls
inside `measure_spatial_*` are counted) and, for frame inputs, the split by stage of the core's
probes (the work between two `Probe::enter` calls is charged to the stage entered first).

`--scalar` builds with LLVM's loop and SLP vectorisers off (in `target/icount-scalar`): x86-64
then does one float operation per instruction, as a Cortex-M4F does (no SIMD), so the counts are
a closer proxy for the microcontroller than the default build's.
"""
import argparse
import glob
import os
import re
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TARGET = os.environ.get("CARGO_TARGET_DIR") or os.path.join(ROOT, "target")
EXE = os.path.join(os.path.abspath(TARGET), "release", "examples", "spatial_icount")
SCALAR_DIR = os.path.join(ROOT, "target", "icount-scalar")
SCALAR_FLAGS = "-C llvm-args=-vectorize-loops=false -C llvm-args=-vectorize-slp=false"
STAGES = ["binning", "row_predict", "gating", "events", "update", "management", "backward"]


def callgrind(args, out, extra=()):
    cmd = ["valgrind", "--tool=callgrind", "--toggle-collect=*measure_spatial*",
           f"--callgrind-out-file={out}", *extra, EXE, *args]
    res = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return res.stdout


def summary(path):
    with open(path) as f:
        trigger, total = None, 0
        for line in f:
            if line.startswith("desc: Trigger:"):
                m = re.search(r"stage_mark_(\w+)", line)
                trigger = m.group(1) if m else None
            elif line.startswith("summary:"):
                total = int(line.split()[1])
                break
    return trigger, total


def stages(name, tmp):
    out = os.path.join(tmp, f"{name}.stages")
    text = callgrind(["--stages", name], out, ["--dump-before=*stage_mark_*"])
    frames = int(re.search(r"frames (\d+)", text).group(1))
    parts = sorted(glob.glob(out + ".*"), key=lambda p: int(p.rsplit(".", 1)[1]))
    cost = {s: 0 for s in STAGES}
    current = None  # the stage entered last; part i ends at the mark that triggered its dump
    for p in parts + [out]:
        trigger, total = summary(p)
        if current in cost:
            cost[current] += total
        current = trigger
    return frames, cost


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--iters", type=int, default=3, help="calls per input (counts are divided)")
    ap.add_argument("--no-stages", action="store_true", help="skip the per-stage split")
    ap.add_argument("--scalar", action="store_true", help="build without SIMD vectorisation")
    ap.add_argument("inputs", nargs="*")
    a = ap.parse_args()
    global EXE
    env = dict(os.environ)
    if a.scalar:
        env["CARGO_TARGET_DIR"] = SCALAR_DIR
        env["RUSTFLAGS"] = (env.get("RUSTFLAGS", "") + " " + SCALAR_FLAGS).strip()
        EXE = os.path.join(SCALAR_DIR, "release", "examples", "spatial_icount")
    subprocess.run(["cargo", "build", "--release", "-q", "-p", "stjpdacf-bench",
                    "--example", "spatial_icount"], cwd=ROOT, check=True, env=env)
    inputs = a.inputs or subprocess.run([EXE, "--list"], capture_output=True, text=True,
                                        check=True).stdout.split()
    with tempfile.TemporaryDirectory() as tmp:
        print(f"{'input':16s} {'calls':>6s} {'instr/call':>11s}  counters")
        split = []
        for name in inputs:
            out = os.path.join(tmp, f"{name}.cg")
            text = callgrind([name, str(a.iters)], out)
            line = next(l for l in text.splitlines() if l.startswith(name + ":"))
            frames = int(re.search(r"frames (\d+)", line).group(1))
            calls = a.iters * frames
            _, total = summary(out)
            counters = re.sub(r"^.*frames \d+ ", "", line)
            print(f"{name:16s} {calls:6d} {total // calls:11d}  {counters}", flush=True)
            if not a.no_stages and not name.startswith("row_"):
                split.append((name, *stages(name, tmp)))
        if split:
            print()
            print(f"{'per frame':16s} " + " ".join(f"{s:>11s}" for s in STAGES))
            for name, frames, cost in split:
                print(f"{name:16s} " + " ".join(f"{cost[s] // frames:11d}" for s in STAGES))


if __name__ == "__main__":
    sys.exit(main())
