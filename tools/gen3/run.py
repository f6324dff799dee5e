#!/usr/bin/env python3
"""Runs gen3's conditions through `stjpdacf track` (the tracker), `track --baseline` and
`track --baseline 4` (the per-frame RANSAC fit, uncapped and capped at 4 lanes), scores each
with `stjpdacf eval --labelled-only` and prints a Markdown table: the mean over the seeds and
the margin of the tracker over the better baseline (mean and worst seed).

    cargo build --release -p stjpdacf-tools
    python3 tools/gen3/run.py --out /tmp/gen3            # all conditions, seeds 1-3 (~2 min)
    python3 tools/gen3/run.py --out /tmp/gen3 --conds reference,clutter --seeds 1
    python3 tools/gen3/run.py --out /tmp/gen3 --model small   # the model of the MCU / C API
    python3 tools/gen3/run.py --out /tmp/gen3 --curve         # the robustness curve (CURVE below)

Python 3 standard library only, like gen3.py.
"""
import argparse, json, os, subprocess, sys

HERE = os.path.dirname(os.path.abspath(__file__))
CONDS = ['clean', 'reference', 'clutter', 'structures', 'curvy', 'dense', 'fps10', 'lanechange']
# The robustness curve (--curve): gen3's reference condition (30 uniform clutter points a frame,
# 3 px column noise, 20 fps) with its clutter × 1 … × 8, with clutter blobs, with its noise × 2
# and × 4, and at 5 and 1 fps (CULane's sequences: every 30th frame of a 30 fps video).
CURVE = [('clutter ×1', ['--cond', 'reference']),
         ('clutter ×2', ['--cond', 'reference', '--clutter', '60']),
         ('clutter ×4', ['--cond', 'reference', '--clutter', '120']),
         ('clutter ×8', ['--cond', 'reference', '--clutter', '240']),
         ('clutter ×1 + 6 blobs', ['--cond', 'reference', '--blobs', '6']),
         ('clutter ×1, noise ×2', ['--cond', 'reference', '--noise', '6']),
         ('clutter ×1, noise ×4', ['--cond', 'reference', '--noise', '12']),
         ('clutter ×1, 5 fps', ['--cond', 'reference', '--fps', '5']),
         ('clutter ×1, 1 fps', ['--cond', 'reference', '--fps', '1'])]


def score(cli, d, name, extra):
    """`track` with `extra` on condition folder `d`, scored; its predictions in `d/name.jsonl`."""
    pred = os.path.join(d, name + '.jsonl')
    p = subprocess.run([cli, 'track', '--frames', os.path.join(d, 'frames.jsonl'), '--out', pred] + extra,
                       capture_output=True, text=True, env=dict(os.environ, RUST_BACKTRACE='0'))
    if p.returncode != 0:
        sys.exit(f'{name} on {d} failed:\n{p.stderr}')
    e = subprocess.run([cli, 'eval', '--pred', pred, '--gt', os.path.join(d, 'gt.jsonl'), '--labelled-only', '--json'],
                       capture_output=True, text=True, check=True)
    return json.loads(e.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--cli', default=os.path.join(HERE, '..', '..', 'target', 'release', 'stjpdacf'))
    ap.add_argument('--out', required=True, help='folder for the generated frames and predictions')
    ap.add_argument('--conds', default=','.join(CONDS))
    ap.add_argument('--seeds', default='1,2,3')
    ap.add_argument('--model', default='reference', help="the tracker's model (track --model)")
    ap.add_argument('--min-margin', type=float, default=None,
                    help="exit 1 when a condition's mean margin over the better fit is below this (a regression check)")
    ap.add_argument('--curve', action='store_true',
                    help='the robustness curve (clutter × 1 … × 8, blobs, noise × 2 and × 4, 5 and 1 fps) instead of --conds')
    a = ap.parse_args()
    seeds = [int(s) for s in a.seeds.split(',')]
    runs_of = CURVE if a.curve else [(c, ['--cond', c]) for c in a.conds.split(',')]
    below = []
    print('| condition | tracker accuracy / FP / FN | RANSAC | RANSAC ≤ 4 lanes | margin over the better (worst seed) |')
    print('|---|---|---|---|---|')
    for cond, args in runs_of:
        runs = []
        for seed in seeds:
            tag = '_'.join(x.lstrip('-') for x in args)
            d = os.path.join(a.out, f'{tag}_s{seed}')
            subprocess.run([sys.executable, os.path.join(HERE, 'gen3.py'), '--seed', str(seed),
                            '--out-dir', d] + args, check=True, capture_output=True)
            runs.append({name: score(a.cli, d, name, extra) for name, extra in
                         [('tracker', ['--model', a.model]), ('base', ['--baseline']), ('base4', ['--baseline', '4'])]})
        mean = lambda name, k: sum(r[name][k] for r in runs) / len(runs)
        fmt = lambda name: ' / '.join(f'{mean(name, k):.3f}' for k in ('Accuracy', 'FP', 'FN'))
        margins = [r['tracker']['Accuracy'] - max(r['base']['Accuracy'], r['base4']['Accuracy']) for r in runs]
        print(f'| {cond} | {fmt("tracker")} | {fmt("base")} | {fmt("base4")} | '
              f'{sum(margins) / len(margins):+.3f} ({min(margins):+.3f}) |', flush=True)
        if a.min_margin is not None and sum(margins) / len(margins) < a.min_margin:
            below.append(cond)
    if below:
        sys.exit(f'margin over the per-frame fit below {a.min_margin:+.3f} on: {", ".join(below)}')


if __name__ == '__main__':
    main()
