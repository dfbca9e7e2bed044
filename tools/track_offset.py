#!/usr/bin/env python3
"""Each solution's mean offset from the motion-capture truth, apart from its
lead or lag, and the filter's offset from the fix it fuses.

Reads the CSV that `insuwb eval LOG --anchors FILE --tracks OUT.csv` writes
(one row per solution and truth time: `solution, t_ns, east_m, north_m,
truth_east_m, truth_north_m, err_east_m, err_north_m, in_segment`) and, for
every solution but INS-only, fits over the flight segment the error as
`e = -v * lag + b` by least squares (v the truth's horizontal velocity,
differenced over +-50 ms; one lag for both axes, b per axis). Printed per
solution: the RMSE as evaluated, the lag (ms, > 0: behind the truth's
stamps, < 0: ahead), the offset b (east, north, m) and the RMSE left after
both are removed. With two solutions `uwb` and `iakf_tdoa`, also the tight
filter's mean position minus the fix's at the same truth times. Where the
file carries heights (`up_m`, `truth_up_m`), each solution's mean height
error and its SD about that mean are printed too.

A diagnostic of the data and the filters, not an estimator: the truth is
used throughout, and no figure found here belongs in a setting.

Usage: python3 tools/track_offset.py TRACKS.csv [TRACKS.csv ...]
"""

import csv
import sys

import numpy as np


def load(path):
    """Rows per solution in the segment: t_ns -> (err_e, err_n, truth_e,
    truth_n, err_up or NaN where the file has no heights)."""
    rows = {}
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            if r["in_segment"] != "1" or r["solution"] == "ins":
                continue
            rows.setdefault(r["solution"], {})[int(r["t_ns"])] = (
                float(r["err_east_m"]),
                float(r["err_north_m"]),
                float(r["truth_east_m"]),
                float(r["truth_north_m"]),
                height_error(r),
            )
    return rows


def height_error(r):
    """The row's height minus the truth's, NaN where either is missing."""
    up, truth = r.get("up_m") or "", r.get("truth_up_m") or ""
    return float(up) - float(truth) if up and truth else float("nan")


def fit(track):
    """(rmse, lag_s, b_east, b_north, rmse_left) of one solution's track."""
    ts = sorted(track)
    a = np.array([track[t] for t in ts])
    t = np.array(ts) * 1e-9
    e, p = a[:, 0:2], a[:, 2:4]
    lo = np.searchsorted(t, t - 0.05)
    hi = np.minimum(np.searchsorted(t, t + 0.05), len(t) - 1)
    v = (p[hi] - p[lo]) / np.maximum(t[hi] - t[lo], 1e-3)[:, None]
    n = len(t)
    one, zero = np.ones(n), np.zeros(n)
    design = np.column_stack(
        [np.concatenate([v[:, 0], v[:, 1]]), np.concatenate([one, zero]), np.concatenate([zero, one])]
    )
    y = np.concatenate([e[:, 0], e[:, 1]])
    c, *_ = np.linalg.lstsq(design, y, rcond=None)
    left = y - design @ c
    rms = lambda x: float(np.sqrt(np.mean(x**2) * 2))
    return rms(y), -c[0], c[1], c[2], rms(left)


def main():
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    for path in sys.argv[1:]:
        rows = load(path)
        print(path)
        for s, track in sorted(rows.items()):
            r, lag, be, bn, left = fit(track)
            up = np.array([v[4] for v in track.values()])
            up = up[np.isfinite(up)]
            height = f"  height {up.mean():+.3f} m, SD {up.std():.3f} m" if len(up) else ""
            print(
                f"  {s:10s} rmse {r:.3f} m  lag {lag * 1e3:+5.0f} ms  "
                f"offset ({be:+.3f}, {bn:+.3f}) m  left {left:.3f} m{height}"
            )
        if "uwb" in rows and "iakf_tdoa" in rows:
            common = sorted(set(rows["uwb"]) & set(rows["iakf_tdoa"]))
            d = np.array([np.subtract(rows["iakf_tdoa"][t][:2], rows["uwb"][t][:2]) for t in common])
            print(f"  iakf_tdoa - uwb: mean ({d[:, 0].mean():+.3f}, {d[:, 1].mean():+.3f}) m")


if __name__ == "__main__":
    main()
