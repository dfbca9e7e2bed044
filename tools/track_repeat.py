#!/usr/bin/env python3
"""How much of each solution's error repeats where the vehicle flies again.

Reads the CSVs that `insuwb eval LOG --anchors FILE --tracks OUT.csv`
writes (`track_offset.load`: the flight segment at the truth times) and,
for every solution but INS-only, predicts each error (every fifth truth
time) by the mean error of the samples taken within RADIUS_M of the same
truth position more than APART_S away in time (at least MIN_SAMPLES of
them): the part of the error that is a field of the position, which the
vehicle meets again whenever it returns, and which no motion sensor can
tell from the motion. Printed per flight (the file name's stem) and
solution: the horizontal RMSE, the share of the samples that have such
neighbours (`cover`) and the share of their mean squared error that the
prediction explains (`repeat`; negative: the neighbours' error does not
predict it).

A diagnostic, not an estimator: the truth is used throughout, and the
prediction is non-causal (it looks forward as well as back).

Usage: python3 tools/track_repeat.py TRACKS.csv [TRACKS.csv ...]
"""

import os
import sys

import numpy as np

from track_offset import load

RADIUS_M = 0.25
APART_S = 4.0
MIN_SAMPLES = 3
STRIDE = 5


def repeat_share(track):
    """(rmse, cover, repeat) of one solution's track."""
    ts = np.array(sorted(track))
    a = np.array([track[t][:4] for t in ts])[::STRIDE]
    t = ts[::STRIDE] * 1e-9
    e, pos = a[:, 0:2], a[:, 2:4]
    used, pred = [], []
    for i in range(len(e)):
        near = (np.hypot(*(pos - pos[i]).T) < RADIUS_M) & (np.abs(t - t[i]) > APART_S)
        if near.sum() >= MIN_SAMPLES:
            used.append(i)
            pred.append(e[near].mean(0))
    rmse = float(np.sqrt((e ** 2).sum(1).mean()))
    if not used:
        return rmse, 0.0, float("nan")
    eu = e[np.array(used)]
    total = (eu ** 2).sum(1).mean()
    left = ((eu - np.array(pred)) ** 2).sum(1).mean()
    return rmse, len(used) / len(e), 1.0 - left / total


def main():
    paths = sys.argv[1:]
    if not paths:
        raise SystemExit(__doc__)
    for path in paths:
        name = os.path.splitext(os.path.basename(path))[0]
        cols = []
        for solution, track in sorted(load(path).items()):
            rmse, cover, rep = repeat_share(track)
            cols.append(f"{solution} rmse {rmse:.3f} cover {100 * cover:3.0f}% repeat {100 * rep:4.0f}%")
        print(f"{name:18s} " + " | ".join(cols))


if __name__ == "__main__":
    main()
