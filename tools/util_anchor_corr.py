#!/usr/bin/env python3
"""Whether a TDOA difference's error belongs to its pair or to its anchors.

For every flight of the manifest, each TDOA difference's error against
motion capture (the antenna's true position, `util_tdoa_bound.prepare`),
less its pair's flight mean, over the flight segment (truth height above
0.3 m, inliers within 0.5 m). For 3000 differences drawn at random (fixed
seed) and up to 60 later ones within 1.6 s of each, the mean product of
the two errors, binned by the time between them:

  shared    the two differences have exactly one anchor in common; the
            product is signed so that a range error of that anchor
            counts positive in both (`z = |p - b| - |p - a|` reads
            `+e_b - e_a`);
  disjoint  no anchor in common.

If each difference's error were its pair's own, both would be about
zero. A shared covariance near half the variance says the error is the
anchors' (each difference reads two anchors' errors); its decay with
the lag is their correlation time. This is what the tight filter's
per-anchor Gauss-Markov states (`[fusion.eskf] tdoa_anchor_sigma_m`,
`tdoa_anchor_corr_time_s`) model.

Usage: python3 tools/util_anchor_corr.py DATA_DIR [FLIGHT ...]
(DATA_DIR holds flights.csv; numpy required.)
"""
import sys

import numpy as np

from util_tdoa_bound import manifest, prepare

LAGS_S = (0.0, 0.03, 0.1, 0.2, 0.4, 0.8, 1.6)
DRAWS = 3000
LATER = 60


def covariances(f):
    """The variance and the shared / disjoint covariances per lag bin."""
    air = f["pos"][:, 2] > 0.3
    ok = f["ok"] & air & (np.abs(f["e"]) < 0.5)
    idx = np.where(ok)[0]
    a, b, tt = f["a"][idx], f["b"][idx], f["tt"][idx]
    e = (f["e"] - f["const"])[idx]
    rng = np.random.default_rng(0)
    nb = len(LAGS_S) - 1
    shared = [[] for _ in range(nb)]
    disjoint = [[] for _ in range(nb)]
    for i in rng.choice(len(idx), size=min(DRAWS, len(idx)), replace=False):
        lo = np.searchsorted(tt, tt[i] + 1e-6)
        hi = np.searchsorted(tt, tt[i] + LAGS_S[-1])
        later = np.arange(lo, hi)
        if len(later) > LATER:
            later = rng.choice(later, LATER, replace=False)
        for j in later:
            k = np.searchsorted(LAGS_S, tt[j] - tt[i]) - 1
            common = {a[i], b[i]} & {a[j], b[j]}
            if len(common) == 1:
                x = common.pop()
                si = 1.0 if b[i] == x else -1.0
                sj = 1.0 if b[j] == x else -1.0
                shared[k].append(si * sj * e[i] * e[j])
            elif not common:
                disjoint[k].append(e[i] * e[j])
    mean = lambda v: float(np.mean(v)) if v else float("nan")
    return float(np.mean(e**2)), [mean(s) for s in shared], [mean(d) for d in disjoint]


def main():
    data_dir, rows = manifest(sys.argv, __doc__)
    want = set(sys.argv[2:])
    bins = [f"{LAGS_S[k]:.2f}-{LAGS_S[k + 1]:.2f}" for k in range(len(LAGS_S) - 1)]
    print("covariance (m^2) of two differences' errors by the time between them (s): "
          "shared anchor / no anchor in common")
    print(f"{'flight':18s} {'mode':6s} {'var':>7s} " + " ".join(f"{b:>15s}" for b in bins))
    fractions = []
    for r in rows:
        if want and r["file"] not in want:
            continue
        var, sh, dj = covariances(prepare(data_dir, r["file"], r["anchors"]))
        fractions.append([s / var for s in sh])
        print(f"{r['file']:18s} {r['mode']:6s} {var:7.4f} "
              + " ".join(f"{s:+.4f}/{d:+.4f}" for s, d in zip(sh, dj)), flush=True)
    if fractions:
        med = np.median(np.array(fractions), axis=0)
        print("median shared covariance / variance: "
              + ", ".join(f"{b} s {m:.2f}" for b, m in zip(bins, med)))


if __name__ == "__main__":
    main()
