#!/usr/bin/env python3
"""What the radio gives a filter that knows the motion exactly.

For every flight of the manifest (or those named), every 0.1 s epoch of
the flight segment (`util_tdoa_bound.fix_epochs`: each anchor pair's last
difference in the epoch, truth height above 0.3 m), each difference whose
residual against the solution exceeds GATE_M (1 m) left out, as a robust
estimator would leave it out (truth does not choose them):

  fix       a least-squares fix from the epoch's differences alone
            (3D Gauss-Newton started at the truth, solved again without
            the differences it leaves beyond the gate);
  known-W   the truth's trajectory plus one constant 3D offset, fitted by
            least squares to the differences of all epochs so far,
            weighted by exp(-age / W), each epoch's differences gated
            against the offset so far (the first epoch's: its fix's):
            what a filter whose velocity sensor were perfect (and whose
            heading were right) would do with the radio, with a memory of
            W seconds (1, 3, 10 s; `--memories W,W,...` for others).

With `--flow` (the flights whose logs hold the flow deck's records), the
motion is no longer the truth's but dead-reckoned from the deck's body
velocities (`util_flow_check.py`'s model: pixel flow, the range finder,
the gyro), rotated into the world by the motion capture's attitude and
integrated from the first epoch, the truth's vertical kept: the same fits
with what these vehicles' motion sensor gives, under a perfect attitude
and height (an optimistic bound on what the deck allows a filter that
weights the radio so). The columns then read `flow-W`.

With `--imu` (every flight), the motion is dead-reckoned from the IMU
through the multirotor model (`util_drag_check.py`: the specific force
along the true body z plus linear drag of DRAG /s, default 0.4, in body x
and y) under the motion capture's attitude, the truth's vertical kept,
less the model's mean error over the flight (a filter takes that up as a
tilt): what the vehicle model gives under a perfect attitude. A filter
fed so must learn its velocity from the radio too, so each fit is then of
an offset and a velocity (`imu-W`): an optimistic bound on what the IMU
allows a filter that weights the radio so. `--fit-velocity` fits the
velocity too with the truth's or the deck's motion (`known+v-W`,
`flow+v-W`): what the motion's shape is worth when the velocity is learnt
from the radio. `--random-walk Q,...` replaces the memories by a Kalman
filter of the offset, a random walk of Q m^2/s, and a velocity constant
over the flight (prior 1 m/s), every difference weighted alike (0.3 m),
the same gate (`rw+v-Q`): the velocity never forgotten, as a filter
with a perfect accelerometer could hold it.

Printed: the horizontal RMSE of each, as a ratio to the manifest's
`uwb_ls_ref_m`, per flight and the median / worst / flights above 1.0.
The offset's fit is linearised at the truth (the differences' geometry
there); truth starts the solver and scores it, and gives the trajectory:
an analysis of the data, not an estimator.

Usage: python3 tools/util_known_motion.py DATA_DIR [--flow | --imu [--drag DRAG]]
       [--fit-velocity] [--memories W,... | --random-walk Q,...] [FLIGHT ...]
(DATA_DIR holds flights.csv; numpy required.)
"""
import statistics as st
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from util_tdoa_bound import fix_epochs, load, manifest, mocap_and_tdoa, prepare, solve  # noqa: E402
from util_flow_check import body_velocities  # noqa: E402
from util_drag_check import model_error  # noqa: E402

MEMORIES_S = (1.0, 3.0, 10.0)
GATE_M = 1.0
# `--random-walk`'s filter: the offset's and the velocity's prior
# variances (m^2, m^2/s^2) and each difference's (m^2).
RW_OFFSET_VAR = 0.3
RW_VELOCITY_VAR = 1.0
RW_R_M2 = 0.09


def interpolator(times, rows):
    """A function of time giving `rows` (n x 3) linearly interpolated
    between `times`."""

    def at(t):
        return np.stack([np.interp(t, times, rows[:, i]) for i in range(3)], -1)

    return at


def flow_drift(path):
    """The dead-reckoning error of the deck's velocities as a function of
    time (s, the log's clock of `mocap_and_tdoa`): the world-frame
    horizontal integral of (flow velocity - true velocity), each rotated by
    the motion capture's attitude; None without flow records."""
    d = load(path)
    if "estFlow" not in d or "estTOF" not in d:
        return None
    tp, p, _, _ = mocap_and_tdoa(d)
    # The records on `mocap_and_tdoa`'s clock, in seconds.
    t0 = d["estAcceleration"][0, 0]
    r = {k: d[k].copy() for k in ("estFlow", "estTOF", "estGyroscope")}
    for v in r.values():
        v[:, 0] = (v[:, 0] - t0) * 1e-6
    tf, dt, vx, vy, true_b, rot, _, good = body_velocities(r, tp, p)
    # Body-frame error (x, y; the vertical is the truth's), to the world.
    eb = np.zeros((len(tf), 3))
    eb[good, 0] = vx[good] - true_b[good, 0]
    eb[good, 1] = vy[good] - true_b[good, 1]
    ew = np.einsum("nij,nj->ni", rot, eb)
    drift = np.cumsum(ew * dt[:, None], axis=0)
    drift[:, 2] = 0.0
    return interpolator(tf, drift)


def imu_drift(path, drag):
    """The dead-reckoning error of the multirotor model under the motion
    capture's attitude, as a function of time (s, the log's clock of
    `mocap_and_tdoa`): the double integral, from zero, of its horizontal
    acceleration error less that error's flight mean."""
    t, err, air = model_error(load(path), drag)
    err = err - err[air].mean(0)
    err[:, 2] = 0.0
    dt = np.diff(t, prepend=t[0])
    drift = np.cumsum(np.cumsum(err * dt[:, None], axis=0) * dt[:, None], axis=0)
    return interpolator(t, drift)


def random_walk_fit(epochs, jac, res, tt, dr, q):
    """Horizontal RMSE of the Kalman filter of `--random-walk` (offset
    random walk `q` m^2/s, constant velocity), m."""
    x = None
    p = None
    prev = None
    sq = []
    for idx, scored, first in epochs:
        t = tt[idx[-1]]
        if x is None:
            x = np.concatenate([first, np.zeros(3)])
            p = np.diag([RW_OFFSET_VAR] * 3 + [RW_VELOCITY_VAR] * 3)
            prev = t
        dt = t - prev
        prev = t
        f = np.eye(6)
        f[:3, 3:] = dt * np.eye(3)
        x = f @ x
        p = f @ p @ f.T
        p[:3, :3] += q * dt * np.eye(3)
        h = np.hstack([jac[idx], np.zeros((len(idx), 3))])
        v = res[idx] - h @ x
        keep = np.abs(v) < GATE_M
        if keep.any():
            h, v = h[keep], v[keep]
            s = h @ p @ h.T + RW_R_M2 * np.eye(len(v))
            k = np.linalg.solve(s, h @ p).T
            x = x + k @ v
            p = (np.eye(6) - k @ h) @ p
        if scored:
            e = x[:3] + dr[idx[-1]]
            sq.append(e[0] ** 2 + e[1] ** 2)
    return float(np.sqrt(np.mean(sq)))


def flight(f, drift=None, memories=MEMORIES_S, rate=False, walks=()):
    """Horizontal RMSE of the per-epoch fixes and of each known-motion
    solution, m. With `drift` (a function of time), the motion is the
    truth's plus it: the solutions' errors are the drift plus the fitted
    offset. With `rate`, each fit is of an offset and a velocity (the
    offset at the epoch's time is scored). With `walks`, the columns are
    those of `random_walk_fit` instead."""
    f["ok"] = np.ones_like(f["ok"])
    pa, pb, z, ant, tt = (f[k] for k in ("pa", "pb", "z", "ant", "tt"))
    ra = np.linalg.norm(ant - pa, axis=1)
    rb = np.linalg.norm(ant - pb, axis=1)
    # d(rb - ra)/d(antenna position) at the truth, and what is left to fit.
    jac = (ant - pb) / rb[:, None] - (ant - pa) / ra[:, None]
    res = z - (rb - ra)
    dr = np.zeros((len(tt), 3)) if drift is None else drift(tt)
    if drift is not None:
        # The motion is dead-reckoned from the first epoch: its error is
        # the drift since then (linearised at the truth).
        start = next(fix_epochs(f))[0][-1]
        dr = dr - dr[start]
        res = res - np.einsum("ni,ni->n", jac, dr)
    epochs = []
    fix_sq = []
    for idx, truth in fix_epochs(f):
        x = solve(truth, pa[idx], pb[idx], z[idx])
        r = z[idx] - (np.linalg.norm(x - pb[idx], axis=1) - np.linalg.norm(x - pa[idx], axis=1))
        inl = idx[np.abs(r) < GATE_M]
        if len(inl) >= 4 and len(inl) < len(idx):
            x = solve(truth, pa[inl], pb[inl], z[inl])
        # A geometry that does not fix 3D: skipped for every column.
        ok = bool(np.all(np.abs(x - truth) < 3.0))
        if ok:
            fix_sq.append(np.sum((x[:2] - truth[:2]) ** 2))
        epochs.append((idx, ok, x - truth))
    out = [float(np.sqrt(np.mean(fix_sq)))]
    if walks:
        return out + [random_walk_fit(epochs, jac, res, tt, dr, q) for q in walks]
    n = 6 if rate else 3
    for w in memories:
        # The fit's information and right-hand side, of the offset at the
        # last epoch's time (and, with `rate`, the velocity).
        info = np.zeros((n, n))
        rhs = np.zeros(n)
        prev = None
        sq = []
        d = None
        theta = None
        for idx, scored, first in epochs:
            t = tt[idx[-1]]
            if d is None:
                d = first
            if prev is not None:
                decay = np.exp(-(t - prev) / w)
                info *= decay
                rhs *= decay
                if rate:
                    # To the offset at t: theta_t = A theta_prev.
                    a_inv = np.eye(6)
                    a_inv[:3, 3:] = -(t - prev) * np.eye(3)
                    info = a_inv.T @ info @ a_inv
                    rhs = a_inv.T @ rhs
                    d = d + theta[3:] * (t - prev) if theta is not None else d
            prev = t
            inl = idx[np.abs(res[idx] - jac[idx] @ d) < GATE_M]
            # With `rate`, a fit the epoch disagrees with entirely (a
            # velocity fitted from the first epochs alone) does not gate it.
            idx = idx if rate and len(inl) < 4 else inl
            j = jac[idx]
            if rate:
                j = np.hstack([j, j * (tt[idx] - t)[:, None]])
            info += j.T @ j
            rhs += j.T @ res[idx]
            if len(idx) and np.linalg.matrix_rank(info) == n:
                theta = np.linalg.solve(info, rhs)
                d = theta[:3]
            if scored:
                e = d + dr[idx[-1]] if len(idx) else d
                sq.append(e[0] ** 2 + e[1] ** 2)
        out.append(float(np.sqrt(np.mean(sq))))
    return out


def option(argv, name, takes, default):
    """The positive numbers after `name` in `argv` (separated by commas;
    both removed), or `default` without it."""
    if name not in argv:
        return default
    i = argv.index(name)
    try:
        values = tuple(float(v) for v in argv[i + 1].split(","))
    except (IndexError, ValueError):
        sys.exit(f"{name} takes {takes}")
    if any(not v > 0 for v in values):
        sys.exit(f"{name}: every value must be above 0")
    del argv[i : i + 2]
    return values


def main():
    flow = "--flow" in sys.argv
    imu = "--imu" in sys.argv
    if flow and imu:
        sys.exit("--flow and --imu: one motion at a time")
    rate = imu or "--fit-velocity" in sys.argv
    argv = [a for a in sys.argv if a not in ("--flow", "--imu", "--fit-velocity")]
    drag = option(argv, "--drag", "the drag coefficient in 1/s, e.g. 0.4", (0.4,))[0]
    memories = option(argv, "--memories", "seconds separated by commas, e.g. 0.5,1,2", MEMORIES_S)
    walks = option(argv, "--random-walk", "variances in m^2/s separated by commas, e.g. 1e-3,1e-2", ())
    data_dir, rows = manifest(argv, __doc__)
    want = set(argv[2:])
    kind = "flow" if flow else "imu" if imu else "known"
    if rate and not imu:
        kind += "+v"
    names = ["fix"] + [f"{kind}-{w:g}" for w in memories]
    if walks:
        names = ["fix"] + [f"rw+v-{q:g}" for q in walks]
    print(f"{'flight':18s} " + " ".join(f"{n:>9s}" for n in names) + "   (/ uwb_ls_ref_m)")
    cols = [[] for _ in names]
    for r in rows:
        if want and r["file"] not in want:
            continue
        ref = float(r["uwb_ls_ref_m"])
        path = data_dir / r["file"]
        drift = flow_drift(path) if flow else imu_drift(path, drag) if imu else None
        if flow and drift is None:
            continue
        f = prepare(data_dir, r["file"], r["anchors"])
        got = [v / ref for v in flight(f, drift, memories, rate=rate, walks=walks)]
        for c, v in zip(cols, got):
            c.append(v)
        print(f"{r['file']:18s} " + " ".join(f"{v:9.3f}" for v in got), flush=True)
    if cols[0]:
        print("median / worst / above 1.0: " + ", ".join(
            f"{n} {st.median(c):.3f} / {max(c):.3f} / {sum(v > 1.0 for v in c)}"
            for n, c in zip(names, cols)))


if __name__ == "__main__":
    main()
