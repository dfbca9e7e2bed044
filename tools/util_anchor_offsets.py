#!/usr/bin/env python3
"""Each anchor's offset over a whole flight, and where it puts the fix.

For every flight of the manifest, over the flight segment (truth height
above 0.3 m), inliers within 1 m:

  fix       the mean error (east, north, up) of least-squares TDOA fixes
            every 0.1 s (3D Gauss-Newton from the truth, the last
            difference of each pair in the epoch; `util_tdoa_bound`'s
            `meas` fixes);
  anchor k  the median of the errors against motion capture of the
            differences anchor k is in, signed so that a range to k read
            long counts positive (`z = |p - b| - |p - a|` reads `+e_b -
            e_a`).

A pattern over the anchors' heights (the high anchors long, the low ones
short) with the fix low by the same amount says the radio and the motion
capture disagree about the vehicle's height for the whole flight; one
anchor far from the others says that anchor is off.

Usage: python3 tools/util_anchor_offsets.py DATA_DIR [FLIGHT ...]
(DATA_DIR holds flights.csv; numpy required.)
"""
import sys

import numpy as np

from util_tdoa_bound import fix_epochs, manifest, prepare, solve


def offsets(f):
    """The fix's mean error and each anchor's median signed error."""
    a, b, pa, pb, z, ok, pos = (f[k] for k in ("a", "b", "pa", "pb", "z", "ok", "pos"))
    errs = []
    for idx, truth in fix_epochs(f):
        x = solve(truth, pa[idx], pb[idx], z[idx])
        if np.all(np.abs(x - truth) < 3.0):
            errs.append(x - truth)
    air = (pos[:, 2] > 0.3) & ok
    anchors = {}
    for k in sorted(set(a) | set(b)):
        m = air & ((a == k) | (b == k))
        if m.any():
            sign = np.where(b[m] == k, 1.0, -1.0)
            anchors[int(k)] = float(np.median(sign * f["e"][m]))
    return np.mean(errs, axis=0), anchors


def main():
    data_dir, rows = manifest(sys.argv, __doc__)
    want = set(sys.argv[2:])
    print("flight             fix mean error e/n/u (m)    each anchor's median signed error (m)")
    for r in rows:
        if want and r["file"] not in want:
            continue
        fix, anchors = offsets(prepare(data_dir, r["file"], r["anchors"]))
        print(f"{r['file']:18s} {fix[0]:+.3f} {fix[1]:+.3f} {fix[2]:+.3f}   "
              + " ".join(f"{k}:{v:+.2f}" for k, v in anchors.items()), flush=True)


if __name__ == "__main__":
    main()
