#!/usr/bin/env python3
"""How far ahead of or behind the motion-capture truth each solution runs.

Reads the CSV that `insuwb eval LOG --anchors FILE --tracks OUT.csv` writes
(one row per solution and truth time: `solution, t_ns, east_m, north_m,
truth_east_m, truth_north_m, ..., in_segment`) and, for every solution but
INS-only, finds the time shift s (from -150 to +150 ms in 5 ms steps) that
minimises the horizontal RMSE over the flight segment of the solution taken
at t + s against the truth at t, by linear interpolation of the solution's
own track. s > 0: the solution lags the truth's stamps by s; s < 0: it runs
ahead of them. Printed per solution: the RMSE as evaluated (s = 0), the
smallest RMSE and its shift.

A diagnostic of the data and the filters, not an estimator: the truth is
used throughout, and no shift found here belongs in a setting.

Usage: python3 tools/track_time_shift.py TRACKS.csv [TRACKS.csv ...]
"""

import csv
import sys

import numpy as np


def load(path):
    """Rows per solution: (t_s, east, north, truth_east, truth_north, in_segment)."""
    rows = {}
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            rows.setdefault(r["solution"], []).append(
                (
                    int(r["t_ns"]) * 1e-9,
                    float(r["east_m"]),
                    float(r["north_m"]),
                    float(r["truth_east_m"]),
                    float(r["truth_north_m"]),
                    r["in_segment"] == "1",
                )
            )
    return rows


def best_shift(rows):
    """(RMSE at s = 0, smallest RMSE, its shift in s) for one solution's rows."""
    a = np.array([r[:5] for r in rows])
    seg = np.array([r[5] for r in rows])
    t = a[:, 0]
    results = []
    for s in np.arange(-0.150, 0.1501, 0.005):
        e = np.interp(t[seg] + s, t, a[:, 1]) - a[seg, 3]
        n = np.interp(t[seg] + s, t, a[:, 2]) - a[seg, 4]
        results.append((float(np.sqrt((e * e + n * n).mean())), round(float(s), 3)))
    at_zero = min(results, key=lambda x: abs(x[1]))[0]
    best, shift = min(results)
    return at_zero, best, shift


def main(paths):
    if not paths:
        sys.exit(__doc__)
    for path in paths:
        rows = load(path)
        cells = []
        for solution, r in rows.items():
            if solution == "ins" or not any(x[5] for x in r):
                continue
            at_zero, best, shift = best_shift(r)
            cells.append(f"{solution} {at_zero:.3f} -> {best:.3f} at {shift * 1e3:+.0f} ms")
        print(f"{path}: " + " | ".join(cells))


if __name__ == "__main__":
    main(sys.argv[1:])
