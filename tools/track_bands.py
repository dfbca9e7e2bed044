#!/usr/bin/env python3
"""Splits two solutions' horizontal errors into frequency bands.

Reads the track files of `insuwb eval LOG --anchors FILE --tracks OUT.csv`
(one or more), resamples each solution's east/north error over the flight
segment to 100 Hz, and prints, per file and band, the RMS amplitude of
SOLUTION's error over BASE's (1.0: the same; above: SOLUTION amplifies the
errors of that band), then the share of BASE's error power in each band.

    python3 tools/track_bands.py [--solution iakf_tdoa] [--base uwb] TRACKS.csv...

numpy only. Nothing here is used at run time: it says where in frequency a
filter gains or loses against the fix it is compared with.
"""
import argparse
import csv
from pathlib import Path

import numpy as np

BANDS = [(0.0, 0.1), (0.1, 0.3), (0.3, 0.6), (0.6, 1.2), (1.2, 3.0), (3.0, 10.0)]
STEP_S = 0.01


def errors(path, solution):
    """(times s, east/north errors) of `solution` in the flight segment."""
    rows = []
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            if r["solution"] == solution and r["in_segment"] == "1":
                rows.append((int(r["t_ns"]) * 1e-9, float(r["err_east_m"]), float(r["err_north_m"])))
    if len(rows) < 10:
        raise SystemExit(f"{path}: fewer than 10 rows of {solution!r} in the flight segment")
    a = np.array(rows)
    return a[:, 0], a[:, 1:]


def band_power(t, e, t0, t1):
    """Error power per band over [t0, t1], resampled every STEP_S."""
    tg = np.arange(t0, t1, STEP_S)
    x = np.column_stack([np.interp(tg, t, e[:, i]) for i in range(2)])
    spec = np.fft.rfft(x - x.mean(0), axis=0)
    freq = np.fft.rfftfreq(len(tg), STEP_S)
    p = (np.abs(spec) ** 2).sum(1)
    return np.array([p[(freq >= lo) & (freq < hi)].sum() for lo, hi in BANDS])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--solution", default="iakf_tdoa")
    ap.add_argument("--base", default="uwb")
    ap.add_argument("tracks", nargs="+")
    a = ap.parse_args()
    head = " ".join(f"{lo:4.1f}-{hi:<4.1f}" for lo, hi in BANDS)
    print(f"{'file':24s} {a.solution}/{a.base} RMS per band (Hz): {head} | {a.base}'s power share")
    for path in a.tracks:
        ts, es = errors(path, a.solution)
        tb, eb = errors(path, a.base)
        t0, t1 = max(ts[0], tb[0]), min(ts[-1], tb[-1])
        ps, pb = band_power(ts, es, t0, t1), band_power(tb, eb, t0, t1)
        ratio = " ".join(f"{np.sqrt(s / b):9.2f}" if b > 0 else "        -" for s, b in zip(ps, pb))
        share = " ".join(f"{b / pb.sum():.2f}" for b in pb)
        print(f"{Path(path).stem[:24]:24s} {ratio} | {share}")


if __name__ == "__main__":
    main()
