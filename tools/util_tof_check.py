#!/usr/bin/env python3
"""The flow deck's range finder against the motion capture, per UTIL flight.

For every flight of `flights.csv` whose log holds `estTOF` records, the
height the range finder gives (`range * R33`, the range along the body z
axis projected on the vertical with the motion capture's attitude) is
compared with the motion capture's height, over the reads between 0.3 m and
3.5 m:

- `offset`: median of (range height - true height), m: where the sensor
  sits below the body's origin (or the floor above the frame's zero);
- `rsd`: robust standard deviation (1.4826 MAD) of the error about it, m;
- `p95`: 95th percentile of its absolute deviation, m.

Usage: python3 tools/util_tof_check.py ../shared/data/util
"""
import csv
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from util_flow_check import records, rotation  # noqa: E402


def check(path):
    got = records(path, ("estTOF",))
    if got is None:
        return None
    r, p = got
    t = p[:, 0]
    tof = r["estTOF"]
    tof = tof[(tof[:, 0] > t[0]) & (tof[:, 0] < t[-1])]
    rng = tof[:, 1] * 1e-3  # mm to m
    z = np.interp(tof[:, 0], t, p[:, 3])
    idx = np.searchsorted(t, tof[:, 0]).clip(0, len(t) - 1)
    height = rng * rotation(p[idx, 4:8])[:, 2, 2]
    ok = (rng > 0.3) & (rng < 3.5)
    e = height[ok] - z[ok]
    if len(e) == 0:
        return None
    off = np.median(e)
    dev = np.abs(e - off)
    return len(e), off, 1.4826 * np.median(dev), np.percentile(dev, 95)


def main():
    root = Path(sys.argv[1] if len(sys.argv) > 1 else "../shared/data/util")
    print(f"{'flight':18s} {'reads':>6s} {'offset':>7s} {'rsd':>6s} {'p95':>6s}")
    for row in csv.DictReader(open(root / "flights.csv")):
        c = check(root / row["file"])
        if c is None:
            continue
        n, off, s, p95 = c
        print(f"{row['file']:18s} {n:6d} {off:+7.3f} {s:6.3f} {p95:6.3f}")


if __name__ == "__main__":
    main()
