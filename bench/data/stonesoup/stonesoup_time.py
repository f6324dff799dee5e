#!/usr/bin/env python3
"""Stone Soup's JPDA on the stored scans of stonesoup_bench.json, timed per scan, for
`cargo run --release -p stjpdacf-bench --example stonesoup_report` (which runs this script and
reads its stdout) or by hand.

The tracker is `run_stonesoup` of stonesoup_bench.py (the generating script, unchanged): Stone
Soup's JPDA tutorial loop, timed per scan from `JPDA.associate` to the last track's
`gm_reduce_single` (prediction, hypotheses, joint events, updates). It runs `--repeats` times on
the scans *read from the JSON* (not regenerated) and prints one JSON object:

  {"versions": {...}, "repeats": R,
   "per_scan_s": [[t_0, ..., t_199], ...R lists],
   "associate_only_s": [[...], ...],
   "replay_cpu_s": [c_1, ..., c_R],                 # thread CPU time of each whole replay
   "means": [[[x, v] x 4] x 200],                 # from the first repeat
   "beta": [[[[-1, b_miss], [j, b_j], ...] x 4] x 200]}   # gated hypotheses only

`beta` comes from one more, untimed pass of the same loop that also records each track's
hypothesis probabilities (j = index of the point in the scan, -1 = missed); its means are
checked to equal the timed run's.  `--beta-out PATH` writes only {versions, means, beta}
(the file bench/data/stonesoup/stonesoup_beta.json, used by the Rust test) and skips timing.

Needs stonesoup (1.9.1 was used), numpy and scipy:
  python3 -m venv .venv && .venv/bin/pip install stonesoup==1.9.1 numpy scipy
"""
import argparse
import datetime
import json
import os
import sys
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.dont_write_bytecode = True  # no __pycache__ in the repository

import stonesoup_bench as sb  # noqa: E402
from common import to_jsonable, versions  # noqa: E402

warnings.filterwarnings("ignore")


def stonesoup_beta(scans, lam, P0):
    """The loop of sb.run_stonesoup (same objects, same order), untimed, recording the
    hypothesis probabilities of every track."""
    from stonesoup.dataassociator.probability import JPDA
    from stonesoup.functions import gm_reduce_single
    from stonesoup.hypothesiser.probability import PDAHypothesiser
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.linear import (CombinedLinearGaussianTransitionModel,
                                                    ConstantVelocity)
    from stonesoup.predictor.kalman import KalmanPredictor
    from stonesoup.types.array import StateVectors
    from stonesoup.types.detection import Detection
    from stonesoup.types.state import GaussianState
    from stonesoup.types.track import Track
    from stonesoup.types.update import GaussianStateUpdate
    from stonesoup.updater.kalman import KalmanUpdater

    t0 = datetime.datetime(2024, 1, 1)
    tm = CombinedLinearGaussianTransitionModel([ConstantVelocity(sb.Q_CV)])
    mm = LinearGaussian(ndim_state=2, mapping=(0,), noise_covar=np.array([[sb.R_STD ** 2]]))
    predictor = KalmanPredictor(tm)
    updater = KalmanUpdater(mm)
    hyp = PDAHypothesiser(predictor=predictor, updater=updater, clutter_spatial_density=lam,
                          prob_detect=sb.PD, prob_gate=sb.PG)
    assoc = JPDA(hypothesiser=hyp)
    tracks = [Track([GaussianState(np.array([[p], [0.0]]) + sb.INIT_OFFSET, P0.copy(),
                                   timestamp=t0 - datetime.timedelta(seconds=1))])
              for p in sb.LANES]
    means, betas = [], []
    for k, zs in enumerate(scans):
        ts = t0 + datetime.timedelta(seconds=k)
        dets = [Detection(np.array([[z]]), timestamp=ts, measurement_model=mm) for z in zs]
        index = {id(d): j for j, d in enumerate(dets)}
        hyps = assoc.associate(list(tracks), list(dets), ts)
        scan_beta = []
        for tr in tracks:
            th = hyps[tr]
            ms, covs, ws, tb = [], [], [], []
            for h in th:
                if not h:
                    ms.append(h.prediction.state_vector)
                    covs.append(h.prediction.covar)
                    tb.append([-1, float(h.probability)])
                else:
                    u = updater.update(h)
                    ms.append(u.state_vector)
                    covs.append(u.covar)
                    tb.append([index[id(h.measurement)], float(h.probability)])
                ws.append(h.probability)
            m, P = gm_reduce_single(StateVectors(ms), np.stack(covs, axis=2), np.array(ws))
            tr.append(GaussianStateUpdate(m, P, th, ts))
            scan_beta.append(sorted(tb))
        betas.append(scan_beta)
        means.append([np.asarray(tr.state_vector, dtype=float).ravel() for tr in tracks])
    return np.array(means), betas


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--json", default=os.path.join(HERE, "stonesoup_bench.json"))
    ap.add_argument("--repeats", type=int, default=sb.REPEATS)
    ap.add_argument("--beta-out", default=None)
    args = ap.parse_args()
    with open(args.json) as fh:
        data = json.load(fh)
    scans = data["scans"]
    lam = float(data["params"]["clutter_density"])
    P0 = np.array(data["params"]["P0"], dtype=float)
    stored = np.array(data["stonesoup_track_means"])
    b_means, betas = stonesoup_beta(scans, lam, P0)
    if args.beta_out:
        diff = float(np.max(np.abs(b_means - stored)))
        out = {"source": "stonesoup_time.py --beta-out on stonesoup_bench.json",
               "versions": versions(), "max_abs_diff_to_stored_means": diff,
               "means": b_means, "beta": betas}
        with open(args.beta_out, "w") as fh:
            json.dump(to_jsonable(out), fh, separators=(",", ":"))
            fh.write("\n")
        print("wrote %s (means vs stored: max |diff| %.3g)" % (args.beta_out, diff),
              file=sys.stderr)
        return
    # Thread CPU time of each whole replay as well (robust to waiting for a core on a loaded
    # machine; includes building the scan's Detection objects, which the per-scan times exclude).
    runs, cpu = [], []
    for _ in range(args.repeats):
        c0 = time.thread_time()
        runs.append(sb.run_stonesoup(scans, lam, P0))
        cpu.append(time.thread_time() - c0)
    means = runs[0][2]
    for r in runs:
        assert np.array_equal(r[2], means), "repeats differ"
    assert np.array_equal(b_means, means), "beta pass differs from the timed runs"
    out = {"versions": versions(), "repeats": args.repeats,
           "per_scan_s": [r[0] for r in runs], "associate_only_s": [r[1] for r in runs],
           "replay_cpu_s": cpu,
           "means": means, "beta": betas}
    json.dump(to_jsonable(out), sys.stdout, separators=(",", ":"))
    sys.stdout.write("\n")


if __name__ == "__main__":
    main()
