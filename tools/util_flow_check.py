#!/usr/bin/env python3
"""The flow deck's body velocities against the motion capture, per UTIL flight.

For every flight of `flights.csv` whose log holds `estFlow` and `estTOF`
records, the body-frame velocity of the firmware's flow model
(`crates/data/src/flow.rs`: 35 pixels over 0.71674 rad, 10 counts a pixel,
the deck's axes flipped, the mean gyro rate over the read, the range
finder's distance) is compared with the motion capture's body velocity
(positions differenced over 50 ms, rotated by its attitude), over the
reads taken 0.3 m or more above the floor:

- `slope`: least-squares slope of the flow velocity on the true one (x, y);
  1 would be an exact scale;
- `rsd`: robust standard deviation (1.4826 MAD) of the per-read error, m/s;
- `rsd10`: the same of the error averaged over 10 consecutive reads;
- `sigma`: the median standard deviation the model states (2 counts);
- `nees`: median of (error / sigma)^2 over both axes divided by 0.455 (the
  median of a chi-square with one degree of freedom): 1 when the stated
  sigma is honest.
- `lag+20ms`: the per-read RMS error with the truth taken 20 ms later,
  against `rms` at no lag (the flow is not late).

Then, pooled over the flights, the slope per band of optical rate (the
true horizontal body speed over the range, rad/s, both averaged over 10
reads): whether the scale is a property of the sensor's rate rather than
of the flight.

Usage: python3 tools/util_flow_check.py ../shared/data/util
"""
import csv
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from util_tdoa_bound import load  # noqa: E402

RAD_PER_COUNT = 0.71674 / (35.0 * 10.0)


def rotation(q):
    """Rotation matrices of scalar-last quaternions (n x 4)."""
    x, y, z, w = q.T
    r = np.empty((len(x), 3, 3))
    r[:, 0] = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], 1)
    r[:, 1] = np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], 1)
    r[:, 2] = np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], 1)
    return r


def rsd(e):
    return 1.4826 * np.median(np.abs(e - np.median(e)))


def records(path, needed):
    """A flight's records (times in s) and its motion-capture poses (repeated
    times dropped); None when a record type of `needed` is missing."""
    r = {k: v.copy() for k, v in load(path).items()}
    if any(n not in r for n in needed):
        return None
    for v in r.values():
        v[:, 0] *= 1e-6  # microseconds to seconds
    p = r["estPose"]
    return r, p[np.concatenate([[True], np.diff(p[:, 0]) > 1e-3])]


def body_velocities(r, t, p, lag=0.0):
    """The deck's body velocities against the motion capture's, per flow
    read: `r` the records and `t`, `p` the poses' times and rows, all times
    on one clock in seconds. Returns (flow read times, read intervals,
    flow x, flow y, true body velocity (n x 3), the attitude's rotations,
    range, reads in use: 0.3 m or more up, range in 0.1-4 m)."""
    fl = r["estFlow"]
    dt = np.diff(fl[:, 0], prepend=fl[0, 0] - 0.01)
    dt = np.where(dt > 0.015, 0.01, dt)
    ts = fl[:, 0] - dt / 2 + lag
    a = np.stack([np.interp(ts - 0.025, t, p[:, i]) for i in (1, 2, 3)], 1)
    b = np.stack([np.interp(ts + 0.025, t, p[:, i]) for i in (1, 2, 3)], 1)
    q = np.stack([np.interp(ts, t, p[:, i]) for i in (4, 5, 6, 7)], 1)
    q /= np.linalg.norm(q, axis=1)[:, None]
    rot = rotation(q)
    true_b = np.einsum("nji,nj->ni", rot, (b - a) / 0.05)
    z = np.interp(ts, t, p[:, 3])
    tof = r["estTOF"]
    rng = np.interp(fl[:, 0], tof[:, 0], tof[:, 1]) * 1e-3
    g = r["estGyroscope"]
    om = np.stack([np.interp(ts, g[:, 0], g[:, i]) for i in (1, 2, 3)], 1) * np.pi / 180
    vx = rng * (-fl[:, 2] * RAD_PER_COUNT / dt + om[:, 1])
    vy = rng * (-fl[:, 1] * RAD_PER_COUNT / dt - om[:, 0])
    m = (z > 0.3) & (dt > 0.005) & (rng > 0.1) & (rng < 4.0)
    return fl[:, 0], dt, vx, vy, true_b, rot, rng, m


def check(path, lag=0.0):
    got = records(path, ("estFlow", "estTOF"))
    if got is None:
        return None
    r, p = got
    _, dt, vx, vy, true_b, _, rng, m = body_velocities(r, p[:, 0], p, lag)
    sigma = rng * 2.0 * RAD_PER_COUNT / dt
    ex, ey = vx[m] - true_b[m, 0], vy[m] - true_b[m, 1]
    n = len(ex) // 10 * 10
    e10 = np.concatenate([ex[:n].reshape(-1, 10).mean(1), ey[:n].reshape(-1, 10).mean(1)])
    slope = np.sum(np.concatenate([vx[m], vy[m]]) * true_b[m, :2].T.ravel()) / np.sum(
        true_b[m, :2] ** 2
    )
    e = np.concatenate([ex, ey])
    s = np.concatenate([sigma[m], sigma[m]])

    def mean10(x):
        return x[:n].reshape(-1, 10).mean(1)

    v10 = np.stack([mean10(vx[m]), mean10(vy[m])], 1)
    t10 = np.stack([mean10(true_b[m, 0]), mean10(true_b[m, 1])], 1)
    rate10 = np.hypot(t10[:, 0], t10[:, 1]) / mean10(rng[m])
    return {
        "by_rate": (v10, t10, rate10),
        "slope": slope,
        "rsd": rsd(e),
        "rsd10": rsd(e10),
        "sigma": np.median(s),
        "nees": np.median((e / s) ** 2) / 0.455,
        "rms": np.sqrt(np.mean(e**2)),
    }


def main():
    root = Path(sys.argv[1] if len(sys.argv) > 1 else "../shared/data/util")
    print(f"{'flight':18} {'slope':>6} {'rsd':>6} {'rsd10':>6} {'sigma':>6} {'nees':>5} {'rms':>6} {'lag+20ms':>8}")
    pooled = []
    with open(root / "flights.csv") as f:
        for row in csv.DictReader(f):
            c = check(root / row["file"])
            if c is None:
                continue
            late = check(root / row["file"], 0.02)
            pooled.append(c["by_rate"])
            print(
                f"{row['file']:18} {c['slope']:6.3f} {c['rsd']:6.3f} {c['rsd10']:6.3f} "
                f"{c['sigma']:6.3f} {c['nees']:5.2f} {c['rms']:6.3f} {late['rms']:8.3f}"
            )
    if not pooled:
        return
    v = np.concatenate([p[0] for p in pooled])
    t = np.concatenate([p[1] for p in pooled])
    rate = np.concatenate([p[2] for p in pooled])
    print(f"\n{'optical rate, rad/s':20} {'slope':>6} {'reads/10':>8}")
    for lo, hi in [(0.0, 0.2), (0.2, 0.4), (0.4, 0.6), (0.6, 0.8), (0.8, 1.0), (1.0, 1.3), (1.3, 3.0)]:
        k = (rate >= lo) & (rate < hi)
        if k.sum() < 20:
            continue
        slope = np.sum(v[k] * t[k]) / np.sum(t[k] ** 2)
        print(f"{lo:4.1f}-{hi:<15.1f} {slope:6.3f} {k.sum():8d}")


if __name__ == "__main__":
    main()
