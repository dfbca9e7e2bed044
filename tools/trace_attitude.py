#!/usr/bin/env python3
"""The attitude and velocity of a filter (or of the INS alone) against
motion capture, from the trace example's CSV.

    cargo run --release -p insuwb-fusion --example trace -- LOG ANCHORS CONFIG.toml [FILTER|ins] > T.csv
    python3 tools/trace_attitude.py T.csv...

Over the flight segment (motion-capture height above 0.3 m), on a 100 Hz
grid, per file:

  tilt    the error of the body z axis's horizontal components times g
          (the horizontal acceleration a multirotor's model predicts from
          its attitude, wrong by this much), m/s^2: RMS, its mean (east,
          north), its 1 s mean less that mean (what changes over seconds),
          and the rest (faster than 1 s);
  yaw     the heading error, deg: its 3 s means, first and largest
          (filters only);
  vel     the horizontal velocity error against the motion capture's
          (differenced, 0.2 s means), RMS m/s, beside the truth's RMS speed;
  sigma   the filter's own horizontal velocity sigma, median over the
          segment (filters only).

Truth scores the run and nothing else. numpy required.
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from util_drag_check import G, smooth  # noqa: E402


def report(path):
    r = np.genfromtxt(path, delimiter=",", names=True)
    t = r["t"]
    tg = np.arange(t[0], t[-1], 0.01)

    def grid(c):
        return np.interp(tg, t, r[c])

    air = grid("tz") > 0.3
    e = np.stack([grid("tilt_e") - grid("truth_tilt_e"), grid("tilt_n") - grid("truth_tilt_n")], 1) * G
    mean = e[air].mean(0)
    slow = smooth(e, 100)

    def rms(z):
        return float(np.sqrt(np.mean(np.sum(z**2, 1))))

    tilt = (rms(e[air]), mean, rms(slow[air] - mean), rms((e - slow)[air]))
    tv = smooth(np.stack([np.gradient(grid("tx"), 0.01), np.gradient(grid("ty"), 0.01)], 1), 20)
    v = np.stack([grid("vx"), grid("vy")], 1)
    vel = (rms((v - tv)[air]), rms(tv[air]))
    names = r.dtype.names
    yaw = sigma = None
    if "yaw" in names:
        d = np.degrees(np.angle(np.exp(1j * (grid("yaw") - grid("tyaw")))))
        ta = tg[air]
        means = [d[air][(ta >= s) & (ta < s + 3)].mean() for s in np.arange(ta[0], ta[-1] - 1.5, 3.0)]
        yaw = (means[0], max(means, key=abs))
        sigma = float(np.median(np.hypot(grid("svx"), grid("svy"))[air]) / np.sqrt(2))
    return tilt, yaw, vel, sigma


def main():
    if len(sys.argv) < 2:
        raise SystemExit(__doc__)
    print("file                        tilt: rms  mean (e, n)      1 s-mean  fast | yaw: first  largest | vel rms / speed | sigma")
    for path in sys.argv[1:]:
        (tr, m, ts, tf), yaw, (ve, sp), sigma = report(path)
        y = f"{yaw[0]:+6.0f} {yaw[1]:+8.0f}" if yaw else " " * 15
        s = f"{sigma:5.2f}" if sigma is not None else "  -"
        name = path.rsplit("/", 1)[-1][:26]
        print(
            f"{name:26}  {tr:9.2f}  ({m[0]:+5.2f}, {m[1]:+5.2f})  {ts:8.2f}  {tf:4.2f} |"
            f" {y}    | {ve:5.2f} / {sp:4.2f}     | {s}"
        )


if __name__ == "__main__":
    main()
