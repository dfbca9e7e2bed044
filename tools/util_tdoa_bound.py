#!/usr/bin/env python3
"""How far IMU + UWB fusion can go on a UTIL TDOA flight: a bound from truth.

For every TDOA difference of a flight (UTIL's binary log, dataset README),
the error against motion capture is e = z - h(truth antenna position). Each
anchor pair's error splits into a fast part (above about 1 Hz: e minus its
centred 1 s mean), a slow part (the 1 s mean) and its flight mean (the
pair's constant bias). Least-squares fixes every 0.1 s (3D Gauss-Newton,
started at the truth, the last difference of each pair in the epoch, no
difference more than 1 m off used) are then made from:

  meas        the measured differences;
  slow        truth + the slow part only: what a filter would reach if its
              IMU bridged 1 s perfectly and removed every fast error;
  slow-const  truth + the slow part less each pair's flight mean: the same,
              with every pair's constant bias also known;
  self-cal    the measured differences less each pair's constant bias as
              the measurements alone estimate it: the whole flight solved
              at once for every epoch's position and every pair's bias
              (alternating least squares, 30 rounds), the best any
              estimator without truth could do with constant pair biases.
  meas-cv     the measured differences less a site calibration learnt on
              the other flights of the manifest (leave one flight out):
              each pair's residual median on a 1 m x-y grid, shrunk
              towards the pair's median by n / (n + 20), bilinear between
              cell centres, as `insuwb calibrate`'s default family, looked
              up at the truth's position;
  slow-cv     truth + the slow part less that calibration: a filter whose
              IMU bridged 1 s perfectly, with the best calibration learnt
              elsewhere in the site.

An epoch where any of the first three leaves the truth by more than 3 m (a
geometry that does not fix 3D) is skipped for all three and counted.
Printed: the horizontal RMSE of each over the flight segment (truth height
above 0.3 m) and their ratios to meas, per flight and their medians. Truth is used throughout: this is an analysis of the data,
not an estimator.

Usage: python3 tools/util_tdoa_bound.py DATA_DIR [FLIGHT ...]
(DATA_DIR holds flights.csv; numpy required.)
"""
import csv
import struct
import sys
from pathlib import Path

import numpy as np

# UWB antenna in the Crazyflie body frame (dataset README), as config/util.toml.
LEVER = np.array([-0.01245, 0.00127, 0.0908])


def load(path):
    """UTIL's binary log: {event name: array (time_us, values...)}."""
    b = Path(path).read_bytes()
    if not b or b[0] != 0xBC:
        raise SystemExit(f"{path}: not a UTIL binary log")
    _, ntypes = struct.unpack_from("<HH", b, 1)
    o = 5
    types = {}
    for _ in range(ntypes):
        (eid,) = struct.unpack_from("<H", b, o)
        o += 2
        e = b.index(b"\0", o)
        name = b[o:e].decode()
        o = e + 1
        (nv,) = struct.unpack_from("<H", b, o)
        o += 2
        fmt = "<"
        for _ in range(nv):
            e = b.index(b"\0", o)
            fmt += b[o:e].decode()[-2]
            o = e + 1
        types[eid] = (name, struct.Struct(fmt))
    out = {}
    end = len(b) - 4
    while o < end:
        eid, ts = struct.unpack_from("<HQ", b, o)
        o += 10
        name, st = types[eid]
        out.setdefault(name, []).append((ts,) + st.unpack_from(b, o))
        o += st.size
    return {k: np.array(v, dtype=float) for k, v in out.items()}


def anchors(path):
    a = {}
    for line in Path(path).read_text().splitlines():
        k, *v = line.strip().split(",")
        if k.endswith("_p"):
            a[int(k[2:-2])] = np.array([float(x) for x in v])
    return a


def rotate(q, v):
    """Rotates v (n x 3) by unit quaternions q (n x 4, x y z w)."""
    x, y, z, w = q.T
    r = np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )
    return np.einsum("nij,nj->ni", r, v)


def solve(x, pa, pb, z):
    x = x.copy()
    for _ in range(10):
        ra = np.linalg.norm(x - pa, axis=1)
        rb = np.linalg.norm(x - pb, axis=1)
        h = (x - pb) / rb[:, None] - (x - pa) / ra[:, None]
        dx = np.linalg.lstsq(h, z - (rb - ra), rcond=None)[0]
        x += dx
        if np.linalg.norm(dx) < 1e-6:
            break
    return x


def mocap_and_tdoa(d):
    """A loaded log's motion capture (times in s, rows; repeated stamps
    dropped) and its TDOA records inside it (times, rows), on the log's
    clock from its first accelerometer sample."""
    t0 = d["estAcceleration"][0, 0]
    p = d["estPose"]
    tp = (p[:, 0] - t0) * 1e-6
    keep = np.concatenate([[True], np.diff(tp) > 1e-4])
    tp, p = tp[keep], p[keep]
    td = d["estTDOA"]
    tt = (td[:, 0] - t0) * 1e-6
    m = (tt > tp[0]) & (tt < tp[-1])
    return tp, p, td[m], tt[m]


def prepare(data_dir, name, anchor_file):
    """A flight's TDOA differences with their truth and errors."""
    d = load(data_dir / name)
    anc = anchors(data_dir / anchor_file)
    tp, p, td, tt = mocap_and_tdoa(d)
    pos = np.stack([np.interp(tt, tp, p[:, 1 + i]) for i in range(3)], -1)
    q = np.stack([np.interp(tt, tp, p[:, 4 + i]) for i in range(4)], -1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    ant = pos + rotate(q, np.broadcast_to(LEVER, pos.shape))
    a, b = td[:, 1].astype(int), td[:, 2].astype(int)
    pa = np.array([anc[i] for i in a])
    pb = np.array([anc[i] for i in b])
    h = np.linalg.norm(ant - pb, axis=1) - np.linalg.norm(ant - pa, axis=1)
    e = td[:, 3] - h
    ok = np.abs(e) < 1.0
    slow = np.zeros_like(e)
    const = np.zeros_like(e)
    for key in set(zip(a, b)):
        s = np.where((a == key[0]) & (b == key[1]) & ok)[0]
        if len(s) < 5:
            continue
        cs = np.concatenate([[0], np.cumsum(e[s])])
        lo = np.searchsorted(tt[s], tt[s] - 0.5)
        hi = np.searchsorted(tt[s], tt[s] + 0.5)
        slow[s] = (cs[hi] - cs[lo]) / np.maximum(hi - lo, 1)
        air = pos[s, 2] > 0.3
        const[s] = e[s][air].mean() if air.any() else e[s].mean()
    # Unordered pair keys, and the sign that turns e into the key's order.
    key = np.minimum(a, b) * 1000 + np.maximum(a, b)
    sign = np.where(a < b, 1.0, -1.0)
    return dict(tt=tt, a=a, b=b, pa=pa, pb=pb, z=td[:, 3], h=h, e=e, ok=ok,
                slow=slow, const=const, pos=pos, ant=ant, key=key, sign=sign)


CELL_M = 1.0
SHRINK_N = 20.0


def learn_grid(flights):
    """Each pair's residual median and its 1 m x-y cells' shrunk medians,
    from the in-air differences of `flights` (as `insuwb calibrate`'s
    default family; residuals beyond 4 robust SDs and 0.3 m of the pair's
    median left out)."""
    keys = np.concatenate([f["key"][m] for f, m in flights])
    x = np.concatenate([f["ant"][m, 0] for f, m in flights])
    y = np.concatenate([f["ant"][m, 1] for f, m in flights])
    e = np.concatenate([(f["sign"] * f["e"])[m] for f, m in flights])
    grid = {}
    for k in np.unique(keys):
        s = keys == k
        ek, xk, yk = e[s], x[s], y[s]
        med = np.median(ek)
        rsd = 1.4826 * np.median(np.abs(ek - med))
        keep = ~((np.abs(ek - med) > 4 * rsd) & (np.abs(ek - med) > 0.3))
        ek, xk, yk = ek[keep], xk[keep], yk[keep]
        med = np.median(ek)
        ci = np.floor(xk / CELL_M).astype(int)
        cj = np.floor(yk / CELL_M).astype(int)
        cells = {}
        for c in set(zip(ci, cj)):
            m = (ci == c[0]) & (cj == c[1])
            n = m.sum()
            if n >= SHRINK_N:
                w = n / (n + SHRINK_N)
                cells[c] = med + w * (np.median(ek[m]) - med)
        grid[k] = (med, cells)
    return grid


def cal_at(grid, key, x, y):
    """The calibration's bias of pair `key` at (x, y), bilinear between
    cell centres (0 for a pair never learnt)."""
    if key not in grid:
        return 0.0
    med, cells = grid[key]
    u, v = x / CELL_M - 0.5, y / CELL_M - 0.5
    i0, j0 = int(np.floor(u)), int(np.floor(v))
    fu, fv = u - i0, v - j0
    val = 0.0
    for di, wi in ((0, 1 - fu), (1, fu)):
        for dj, wj in ((0, 1 - fv), (1, fv)):
            val += wi * wj * cells.get((i0 + di, j0 + dj), med)
    return val


def in_air(f):
    return f["ok"] & (f["pos"][:, 2] > 0.3)


def fix_epochs(f):
    """Each 0.1 s epoch of the flight segment with at least 4 pairs: the
    indices of each pair's last inlier difference in it, and the truth's
    antenna position at its last."""
    tt, a, b, ok, pos, ant = (f[k] for k in ("tt", "a", "b", "ok", "pos", "ant"))
    for tk in np.arange(tt[0] + 0.1, tt[-1], 0.1):
        last = {}
        for i in np.where((tt > tk - 0.1) & (tt <= tk) & ok)[0]:
            last[(a[i], b[i])] = i
        idx = np.array(list(last.values()))
        if len(idx) < 4 or pos[idx[-1], 2] <= 0.3:
            continue
        yield idx, ant[idx[-1]]


def flight(f, grid=None):
    a, b, pa, pb, h = (f[k] for k in ("a", "b", "pa", "pb", "h"))
    z, slow, const = (f[k] for k in ("z", "slow", "const"))
    sq = {"meas": [], "slow": [], "slow-const": []}
    if grid is not None:
        sq.update({"meas-cv": [], "slow-cv": []})
    skipped = 0
    epochs = []
    for idx, truth in fix_epochs(f):
        zs = [
            ("meas", z[idx]),
            ("slow", h[idx] + slow[idx]),
            ("slow-const", h[idx] + slow[idx] - const[idx]),
        ]
        if grid is not None:
            cal = np.array([f["sign"][i] * cal_at(grid, f["key"][i], truth[0], truth[1]) for i in idx])
            zs += [("meas-cv", z[idx] - cal), ("slow-cv", h[idx] + slow[idx] - cal)]
        xs = {k: solve(truth, pa[idx], pb[idx], zz) for k, zz in zs}
        # A degenerate geometry (the differences do not fix 3D) sends
        # Gauss-Newton away: such an epoch counts for none of them.
        if any(not np.all(np.abs(x - truth) < 3.0) for x in xs.values()):
            skipped += 1
            continue
        for k, x in xs.items():
            sq[k].append(np.sum((x[:2] - truth[:2]) ** 2))
        epochs.append((idx, truth, xs["meas"]))
    out = {k: float(np.sqrt(np.mean(v))) for k, v in sq.items()}
    out["self-cal"] = self_calibrated(epochs, z, a, b, pa, pb)
    out["skipped"] = skipped
    out["epochs"] = len(sq["meas"])
    return out


def self_calibrated(epochs, z, a, b, pa, pb, rounds=30):
    """Horizontal RMSE of the fixes from z less per-pair constant biases
    solved jointly with every epoch's position from the measurements alone
    (truth only scores the result)."""
    pairs = {k: j for j, k in enumerate(sorted(set(zip(a, b))))}
    pid = np.array([pairs[k] for k in zip(a, b)])
    bias = np.zeros(len(pairs))
    xs = [x for _, _, x in epochs]
    for _ in range(rounds):
        idx = np.concatenate([i for i, _, _ in epochs])
        res = np.concatenate([
            z[i] - (np.linalg.norm(x - pb[i], axis=1) - np.linalg.norm(x - pa[i], axis=1))
            for (i, _, _), x in zip(epochs, xs)
        ])
        sums = np.bincount(pid[idx], weights=res, minlength=len(pairs))
        counts = np.bincount(pid[idx], minlength=len(pairs))
        bias = sums / np.maximum(counts, 1)
        xs = [solve(x, pa[i], pb[i], z[i] - bias[pid[i]]) for (i, _, _), x in zip(epochs, xs)]
    sq = [np.sum((x[:2] - t[:2]) ** 2) for (_, t, _), x in zip(epochs, xs)]
    return float(np.sqrt(np.mean(sq)))


def manifest(argv, usage):
    """The data directory of `argv[1]` and its manifest's rows; `usage`
    (a tool's docstring) when it is missing."""
    if len(argv) < 2:
        raise SystemExit(usage)
    data_dir = Path(argv[1])
    return data_dir, list(csv.DictReader(open(data_dir / "flights.csv")))


def main():
    data_dir, rows = manifest(sys.argv, __doc__)
    want = set(sys.argv[2:])
    # Every flight of the manifest is prepared: the calibration of one is
    # learnt on all the others, whichever are printed.
    prepared = {r["file"]: prepare(data_dir, r["file"], r["anchors"]) for r in rows}
    cols = ("slow", "slow-const", "self-cal", "meas-cv", "slow-cv")
    ratios = []
    print(f"{'flight':18s} {'meas':>6s} " + " ".join(f"{c:>10s}" for c in cols) + "   (RMSE m, then / meas)")
    for r in rows:
        if want and r["file"] not in want:
            continue
        others = [(f, in_air(f)) for name, f in prepared.items() if name != r["file"]]
        f = flight(prepared[r["file"]], learn_grid(others))
        rs = [f[k] / f["meas"] for k in cols]
        ratios.append(rs)
        print(f"{r['file']:18s} {f['meas']:6.3f} " + " ".join(f"{f[c]:10.3f}" for c in cols)
              + "  " + " ".join(f"{x:5.2f}" for x in rs)
              + f"  epochs {f['epochs']}, skipped {f['skipped']}", flush=True)
    if ratios:
        med = np.median(np.array(ratios), axis=0)
        print("median / meas: " + ", ".join(f"{c} {m:.2f}" for c, m in zip(cols, med)))


if __name__ == "__main__":
    main()
