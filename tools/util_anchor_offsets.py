#!/usr/bin/env python3
"""Where a flight's radio puts the tag over the whole flight: the frame's
offset, then each anchor's, and where they put the fix.

For every flight of the manifest, over the flight segment (truth height
above 0.3 m), inliers within 1 m:

  fix       the mean error (east, north, up) of least-squares TDOA fixes
            every 0.1 s (3D Gauss-Newton from the truth, the last
            difference of each pair in the epoch; `util_tdoa_bound`'s
            `meas` fixes);
  frame     the one translation t of the tag that explains the
            differences' errors best (each error against motion capture
            is g . t, g the gradient of |p - b| - |p - a|; least squares,
            then Huber weights at 1.5 robust SDs, as
            `crates/uwb/src/survey.rs`), and the RMS of the errors before
            and after it;
  anchor k  after the frame's offset is taken out, the median of the
            errors of the differences anchor k is in, signed so that a
            range to k read long counts positive (`z = |p - b| - |p - a|`
            reads `+e_b - e_a`).

A frame offset of tenths of a metre that takes most of the errors with it
says the anchors' survey and the motion capture's frame disagree for the
whole flight (the survey's origin, or a frame moved between flights); one
anchor far from the others after it says that anchor is off.

With `--shifted DIR`, each flight's anchor survey moved by its frame
offset is written to DIR/FLIGHT.anchors.txt (the anchors as the radio saw
them in the motion capture's frame): `insuwb eval LOG --anchors
DIR/FLIGHT.anchors.txt` then evaluates the flight without that offset.

Usage: python3 tools/util_anchor_offsets.py DATA_DIR [--shifted DIR] [FLIGHT ...]
(DATA_DIR holds flights.csv; numpy required.)
"""
import sys
from pathlib import Path

import numpy as np

from util_tdoa_bound import fix_epochs, manifest, prepare, solve


def gradients(f):
    """The gradient of each difference |p - b| - |p - a| at the antenna."""
    da = f["ant"] - f["pa"]
    db = f["ant"] - f["pb"]
    return db / np.linalg.norm(db, axis=1)[:, None] - da / np.linalg.norm(da, axis=1)[:, None]


def frame(f, air):
    """The translation t that explains the errors in `air` best (least
    squares, then 10 rounds of Huber weights at 1.5 robust SDs)."""
    g, e = gradients(f)[air], f["e"][air]
    t = np.zeros(3)
    for k in range(11):
        w = np.ones_like(e)
        if k:
            r = e - g @ t
            scale = 1.5 * 1.4826 * np.median(np.abs(r))
            w = np.minimum(1.0, scale / np.maximum(np.abs(r), 1e-12))
        t = np.linalg.solve((g * w[:, None]).T @ g, (g * w[:, None]).T @ e)
    rms = lambda x: float(np.sqrt(np.mean(x * x)))
    return t, rms(e), rms(e - g @ t)


def offsets(f):
    """The fix's mean error, the frame offset, and each anchor's median
    signed error after it."""
    a, b, pa, pb, z, ok, pos = (f[k] for k in ("a", "b", "pa", "pb", "z", "ok", "pos"))
    errs = []
    for idx, truth in fix_epochs(f):
        x = solve(truth, pa[idx], pb[idx], z[idx])
        if np.all(np.abs(x - truth) < 3.0):
            errs.append(x - truth)
    air = (pos[:, 2] > 0.3) & ok
    t, before, after = frame(f, air)
    rest = f["e"] - gradients(f) @ t
    anchors = {}
    for k in sorted(set(a) | set(b)):
        m = air & ((a == k) | (b == k))
        if m.any():
            sign = np.where(b[m] == k, 1.0, -1.0)
            anchors[int(k)] = float(np.median(sign * rest[m]))
    return np.mean(errs, axis=0), (t, before, after), anchors


def main():
    args = list(sys.argv)
    shifted = None
    if "--shifted" in args:
        i = args.index("--shifted")
        shifted = Path(args[i + 1])
        del args[i : i + 2]
        shifted.mkdir(parents=True, exist_ok=True)
    data_dir, rows = manifest(args, __doc__)
    want = set(args[2:])
    print("flight             fix mean error e/n/u (m)   frame offset e/n/u (m), error RMS before -> after   "
          "each anchor's median signed error after it (m)")
    for r in rows:
        if want and r["file"] not in want:
            continue
        fix, (t, before, after), anchors = offsets(prepare(data_dir, r["file"], r["anchors"]))
        print(f"{r['file']:18s} {fix[0]:+.3f} {fix[1]:+.3f} {fix[2]:+.3f}   "
              f"{t[0]:+.2f} {t[1]:+.2f} {t[2]:+.2f}, {before:.3f} -> {after:.3f}   "
              + " ".join(f"{k}:{v:+.2f}" for k, v in anchors.items()), flush=True)
        if shifted is not None:
            # The radio reads |p + t - a|: the anchors at a - t in the
            # motion capture's frame.
            lines = []
            for line in (data_dir / r["anchors"]).read_text().splitlines():
                key, *v = line.strip().split(",")
                if key.endswith("_p") and len(v) == 3:
                    v = [repr(float(x) - float(d)) for x, d in zip(v, t)]
                lines.append(",".join([key, *v]))
            (shifted / f"{r['file']}.anchors.txt").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
