#!/usr/bin/env python3
"""Anchor pairs that read off by tenths of a metre for a whole flight, and
whether the measurements alone can find them.

For every flight of the manifest (or those named), over the flight segment
(truth height above 0.3 m), with `util_tdoa_bound`'s residuals `e = z -
h(truth antenna)`, its 0.1 s epochs (each pair's last difference) and its
Gauss-Newton fixes (an epoch whose plain fix leaves the truth by more than 3 m is
skipped for every column):

  faults    the pairs whose median residual over the flight exceeds
            GATE (0.3 m), as `a-b:median`;
  meas      the horizontal RMSE of plain 3D fixes, m;
  oracle    the same fixes with only those pairs corrected by their
            median (truth decides which pairs and by how much), over meas;
  self-3d   the measurements alone: the whole flight solved at once for
            every epoch's 3D position and each pair's constant offset
            (alternating least squares, 8 rounds), an offset kept only
            where it exceeds GATE (the others zero), over meas;
  self-h    the same with each epoch's height given (the truth's, standing
            for a range finder: 1-3 cm on these flights), 2D fixes, over
            the 2D fixes' own RMSE (printed as meas-h);
  causal-h  self-h as a filter could run it: every 2 s, on the last 15 s
            only, the offsets found there correct the differences that
            follow until the next solve, over meas-h.

The non-causal columns use the whole flight before its first epoch is
fixed: an analysis of the data, not an estimator. Truth is used
throughout (and by `oracle` and the `-h` columns for more than scoring).

Usage: python3 tools/util_pair_faults.py DATA_DIR [FLIGHT ...]
(DATA_DIR holds flights.csv; numpy required.)
"""
import sys

import numpy as np

from util_tdoa_bound import fix_epochs, manifest, prepare, solve

GATE = 0.3
ROUNDS = 8
WINDOW_S = 15.0
STEP_S = 2.0
MIN_SAMPLES = 20


def solve_h(x, pa, pb, z):
    """A 2D Gauss-Newton fix with the height held at x's."""
    x = x.copy()
    for _ in range(10):
        ra = np.linalg.norm(x - pa, axis=1)
        rb = np.linalg.norm(x - pb, axis=1)
        h = ((x - pb) / rb[:, None] - (x - pa) / ra[:, None])[:, :2]
        dx = np.linalg.lstsq(h, z - (rb - ra), rcond=None)[0]
        x[:2] += dx
        if np.linalg.norm(dx) < 1e-6:
            break
    return x


def rmse(xs, ep):
    """Horizontal RMSE of fixes `xs` at epochs `ep` against their truth."""
    d = np.array([x[:2] - t[:2] for x, (_, t) in zip(xs, ep)])
    return float(np.sqrt((d ** 2).sum(1).mean()))


def gated_offsets(f, ep, xs, pid, npairs, fix):
    """Each pair's constant offset solved with the epochs `ep` (starting
    at fixes `xs`), kept where it exceeds GATE; and the fixes."""
    a, b, pa, pb, z = (f[k] for k in ("a", "b", "pa", "pb", "z"))
    off = np.zeros(npairs)
    xs = list(xs)
    for _ in range(ROUNDS):
        idx = np.concatenate([i for i, _ in ep])
        res = np.concatenate([
            z[i] - (np.linalg.norm(x - pb[i], axis=1) - np.linalg.norm(x - pa[i], axis=1))
            for (i, _), x in zip(ep, xs)
        ])
        new = np.zeros(npairs)
        for p in range(npairs):
            r = res[pid[idx] == p]
            if len(r) >= MIN_SAMPLES:
                c = float(np.median(r))
                new[p] = c if abs(c) > GATE else 0.0
        off = new
        xs = [fix(x, pa[i], pb[i], z[i] - off[pid[i]]) for (i, _), x in zip(ep, xs)]
    return off, xs


def flight(f):
    a, b, pa, pb, z, e, tt, pos, ok = (
        f[k] for k in ("a", "b", "pa", "pb", "z", "e", "tt", "pos", "ok"))
    pairs = {k: j for j, k in enumerate(sorted(set(zip(a, b))))}
    pid = np.array([pairs[k] for k in zip(a, b)])
    air = ok & (pos[:, 2] > 0.3)
    med = np.zeros(len(pairs))
    faults = []
    for k, j in pairs.items():
        m = air & (pid == j)
        if m.sum() >= MIN_SAMPLES:
            med[j] = float(np.median(e[m]))
            if abs(med[j]) > GATE:
                faults.append(f"{k[0]}-{k[1]}:{med[j]:+.2f}")
    ep, plain = [], []
    for i, t in fix_epochs(f):
        x = solve(t, pa[i], pb[i], z[i])
        # A geometry that does not fix 3D: skipped for every column.
        if np.all(np.abs(x - t) < 3.0):
            ep.append((i, t))
            plain.append(x)
    meas = rmse(plain, ep)
    gated = np.where(np.abs(med) > GATE, med, 0.0)
    oracle = rmse([solve(t, pa[i], pb[i], z[i] - gated[pid[i]]) for i, t in ep], ep)
    _, xs3 = gated_offsets(f, ep, plain, pid, len(pairs), solve)
    plain_h = [solve_h(t, pa[i], pb[i], z[i]) for i, t in ep]
    meas_h = rmse(plain_h, ep)
    _, xsh = gated_offsets(f, ep, plain_h, pid, len(pairs), solve_h)
    # Causal: the offsets of the last window correct what follows.
    et = np.array([tt[i[-1]] for i, _ in ep])
    off = np.zeros(len(pairs))
    nxt = et[0] + WINDOW_S if len(et) else 0.0
    causal = []
    for k, (i, t) in enumerate(ep):
        if et[k] >= nxt:
            nxt += STEP_S
            win = [j for j in range(k) if et[j] > et[k] - WINDOW_S]
            off, _ = gated_offsets(f, [ep[j] for j in win], [plain_h[j] for j in win],
                                   pid, len(pairs), solve_h)
        causal.append(solve_h(t, pa[i], pb[i], z[i] - off[pid[i]]))
    return (faults, meas, oracle / meas, rmse(xs3, ep) / meas, meas_h,
            rmse(xsh, ep) / meas_h, rmse(causal, ep) / meas_h)


def main():
    data_dir, rows = manifest(sys.argv, __doc__)
    want = set(sys.argv[2:])
    print(f"{'flight':18s} {'meas':>6s} {'oracle':>7s} {'self-3d':>8s} "
          f"{'meas-h':>7s} {'self-h':>7s} {'causal-h':>9s}  faults (pair: median, m)")
    cols = []
    for r in rows:
        if want and r["file"] not in want:
            continue
        faults, meas, orc, s3, meas_h, sh, ch = flight(prepare(data_dir, r["file"], r["anchors"]))
        cols.append((orc, s3, sh, ch))
        print(f"{r['file']:18s} {meas:6.3f} {orc:7.2f} {s3:8.2f} {meas_h:7.3f} "
              f"{sh:7.2f} {ch:9.2f}  {' '.join(faults)}", flush=True)
    if cols:
        c = np.array(cols)
        print("median / worst: oracle %.2f / %.2f, self-3d %.2f / %.2f, self-h %.2f / %.2f, "
              "causal-h %.2f / %.2f" % (np.median(c[:, 0]), c[:, 0].max(), np.median(c[:, 1]),
                                        c[:, 1].max(), np.median(c[:, 2]), c[:, 2].max(),
                                        np.median(c[:, 3]), c[:, 3].max()))


if __name__ == "__main__":
    main()
