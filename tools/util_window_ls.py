#!/usr/bin/env python3
"""Why a filter that estimates velocity from the radio alone trails a fix.

For every flight of the manifest, every 0.1 s of the flight segment (truth
height above 0.3 m), a least-squares solution from all TDOA differences of
the last W seconds (every difference, none gated), Gauss-Newton started at
the truth:

  static   one position for the whole window (what a fix does);
  cv       a position at the window's end and a constant velocity over it
           (what a filter whose velocity comes from the radio does: its
           estimate is the end of a line fitted through the window).

Printed: the horizontal RMSE of each against the truth at the window's
end, per flight and the medians. The radio's errors are correlated over
seconds, so a velocity fitted to them takes up their trend and the end
point follows it: over 0.2 s the cv solution is worse than the static one
(the end of a fitted line is noisier than a mean), and its error does not
fall as the window grows to 0.8 s, where the static one lags. An IMU that
carried the velocity over the window would give the static solution's
averaging without its lag; where it does not, damping the velocity
towards rest (the multirotor model's `damping_per_s`) moves a filter from
the cv towards the static case. Truth starts the solver and scores it;
this is an analysis of the data, not an estimator.

Usage: python3 tools/util_window_ls.py DATA_DIR [FLIGHT ...]
(DATA_DIR holds flights.csv; numpy required.)
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from util_tdoa_bound import manifest, prepare  # noqa: E402

WINDOWS = (0.2, 0.8)


def solve(x0, pa, pb, z, dt, vel):
    n = 6 if vel else 3
    x = np.zeros(n)
    x[:3] = x0
    for _ in range(10):
        p = x[:3] + np.outer(dt, x[3:]) if vel else np.broadcast_to(x[:3], (len(z), 3))
        ra = np.linalg.norm(p - pa, axis=1)
        rb = np.linalg.norm(p - pb, axis=1)
        h = (p - pb) / rb[:, None] - (p - pa) / ra[:, None]
        jac = np.hstack([h, h * dt[:, None]]) if vel else h
        dx = np.linalg.lstsq(jac, z - (rb - ra), rcond=None)[0]
        x += dx
        if np.linalg.norm(dx) < 1e-7:
            break
    return x[:3]


def flight(f):
    tt, pa, pb, z, pos, ant = (f[k] for k in ("tt", "pa", "pb", "z", "pos", "ant"))
    out = {}
    for w in WINDOWS:
        sq = {"static": [], "cv": []}
        for tk in np.arange(tt[0] + w, tt[-1], 0.1):
            idx = np.where((tt > tk - w) & (tt <= tk))[0]
            if len(idx) < 10 or pos[idx[-1], 2] <= 0.3:
                continue
            truth = ant[idx[-1]]
            dt = tt[idx] - tt[idx[-1]]
            xs = {k: solve(truth, pa[idx], pb[idx], z[idx], dt, k == "cv") for k in sq}
            if any(not np.all(np.abs(x - truth) < 3.0) for x in xs.values()):
                continue
            for k, x in xs.items():
                sq[k].append(np.sum((x[:2] - truth[:2]) ** 2))
        for k, v in sq.items():
            out[f"{k} {w:g} s"] = float(np.sqrt(np.mean(v)))
    return out


def main():
    data, rows = manifest(sys.argv, __doc__)
    if len(sys.argv) > 2:
        rows = [r for r in rows if r["file"] in sys.argv[2:]]
    cols = None
    all_out = []
    for r in rows:
        o = flight(prepare(data, r["file"], r["anchors"]))
        if cols is None:
            cols = list(o)
            print(f"{'flight':18}" + "".join(f"{c:>14}" for c in cols) + "   (RMSE m)")
        all_out.append(o)
        print(f"{r['file']:18}" + "".join(f"{o[c]:14.3f}" for c in cols), flush=True)
    print(f"{'median':18}" + "".join(f"{np.median([o[c] for o in all_out]):14.3f}" for c in cols))


if __name__ == "__main__":
    main()
