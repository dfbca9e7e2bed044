#!/usr/bin/env python3
"""Whether each UTIL flight's accelerometer follows its horizontal motion.

Per flight of `flights.csv`, over the first 5, 10 and 20 s with the motion
capture 0.3 m or more above the floor: the RMS variation (standard
deviation about the window's mean, both axes) of the horizontal channels'
201-sample means (about 0.2 s), `lpstd`, over the RMS of their residual
about 51-sample means (about 50 ms: the vibration), `vib`; their ratio; and
the vertical channel's vibration `vz` (m/s^2). A multirotor whose
horizontal channels hold only drag and vibration reads well below 2; a
vehicle whose IMU follows the motion reads several times its vibration
(`[fusion.multirotor] free_above_signal_ratio`, docs/REAL_FLIGHTS.md).

Usage: python3 tools/util_accel_signal.py ../shared/data/util
"""
import csv
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from util_tdoa_bound import load  # noqa: E402

G = 9.81


def moving_mean(x, n):
    """Centred n-sample mean of each column."""
    k = np.ones(n) / n
    return np.stack([np.convolve(x[:, i], k, "same") for i in range(x.shape[1])], 1)


def windows(path):
    """(seconds, lpstd, vib, ratio, vz) for each window after lift-off."""
    r = load(path)
    a = r["estAcceleration"]
    t = a[:, 0] * 1e-6
    p = r["estPose"]
    z = np.interp(t, p[:, 0] * 1e-6, p[:, 3])
    acc = a[:, 1:4] * G
    hp = acc - moving_mean(acc, 51)
    lp = moving_mean(acc, 201)
    t0 = t[np.argmax(z > 0.3)]
    out = []
    for span in (5, 10, 20):
        m = (t >= t0) & (t < t0 + span)
        lps = np.sqrt(np.mean(np.var(lp[m, :2], axis=0)))
        vib = np.sqrt(np.mean(hp[m, :2] ** 2))
        vz = np.sqrt(np.mean(hp[m, 2] ** 2))
        out.append((span, lps, vib, lps / vib, vz))
    return out


def main():
    root = Path(sys.argv[1] if len(sys.argv) > 1 else "../shared/data/util")
    with open(root / "flights.csv") as f:
        for row in csv.DictReader(f):
            cells = [
                f"{s:2d} s: lpstd {lps:.2f} vib {vib:.2f} ratio {ratio:.2f} vz {vz:.2f}"
                for s, lps, vib, ratio, vz in windows(root / row["file"])
            ]
            print(f"{row['file']:16} " + " | ".join(cells))


if __name__ == "__main__":
    main()
