#!/usr/bin/env python3
"""The multirotor model of a UTIL flight against motion capture.

For every flight of the manifest, on a 100 Hz grid over the flight segment
(motion-capture height above 0.3 m), with velocity and acceleration
differenced from the motion capture (20-sample means) and the IMU's
specific force (the same means):

  drag     the rotor drag coefficient, 1/s, of body x and y: the
           accelerometer's horizontal channel regressed on the body-frame
           velocity (least squares with an offset; the offset is the
           channel's vibration-rectified bias, printed beside it, m/s^2);
  thrust   the horizontal acceleration predicted by the thrust alone (the
           measured z specific force along the true body z, less gravity)
           against the true acceleration: RMS error, m/s^2;
  +drag    the same with linear drag DRAG /s (default 0.4) in body x/y;
  slow     the +drag error's 1 s mean: what an INS with the true attitude
           would integrate wrongly over a second;
  -const   the same less its mean over the flight (a constant is the
           motion capture's body frame against the IMU's, or a thrust axis
           off the IMU's z: a filter takes it up as a tilt).

Truth is used throughout: an analysis of the data and the model, not an
estimator. It shows that the thrust-and-drag model with the physical drag
predicts the horizontal acceleration to 0.2-0.4 m/s^2 on most flights when
the attitude is right, and where it does not (cfBolt-log00, test-log00).

Usage: python3 tools/util_drag_check.py DATA_DIR [DRAG]
(DATA_DIR holds flights.csv; numpy required.)
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from util_tdoa_bound import load, manifest, rotate  # noqa: E402

G = 9.81


def smooth(y, n):
    k = np.ones(n) / n
    return np.stack([np.convolve(y[:, i], k, "same") for i in range(y.shape[1])], 1)


def model_error(d, drag):
    """A loaded log's multirotor model under the motion capture's attitude:
    the 100 Hz grid's times (s, the log's clock from its first accelerometer
    sample), the model's acceleration error (ENU, m/s^2) and which rows are
    in the air."""
    t, _, _, _, pred_drag, a_true, air = grid(d, drag)
    return t, pred_drag - a_true, air


def grid(d, drag):
    """The flight on a 100 Hz grid: times, the body-frame velocity, the
    specific force, the thrust-only and thrust-and-drag predictions of the
    acceleration, the true acceleration and the rows in the air."""
    t0 = d["estAcceleration"][0, 0]
    acc = d["estAcceleration"]
    ta = (acc[:, 0] - t0) * 1e-6
    p = d["estPose"]
    tp = (p[:, 0] - t0) * 1e-6
    keep = np.concatenate([[True], np.diff(tp) > 1e-4])
    tp, p = tp[keep], p[keep]
    dt = 0.01
    t = np.arange(max(tp[0], ta[0]) + 0.5, min(tp[-1], ta[-1]) - 0.5, dt)
    x = np.stack([np.interp(t, tp, p[:, 1 + i]) for i in range(3)], 1)
    q = np.stack([np.interp(t, tp, p[:, 4 + i]) for i in range(4)], 1)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    v = smooth(np.gradient(x, axis=0) / dt, 20)
    a_true = smooth(np.gradient(v, axis=0) / dt, 20)
    f = smooth(np.stack([np.interp(t, ta, acc[:, 1 + i]) for i in range(3)], 1), 20) * G
    air = x[:, 2] > 0.3
    air[:50] = False
    air[-50:] = False
    q_inv = q.copy()
    q_inv[:, :3] *= -1
    vb = rotate(q_inv, v)
    gravity = np.array([0.0, 0.0, -G])
    thrust = np.zeros_like(f)
    thrust[:, 2] = f[:, 2]
    pred_thrust = rotate(q, thrust) + gravity
    with_drag = thrust.copy()
    with_drag[:, 0] = -drag * vb[:, 0]
    with_drag[:, 1] = -drag * vb[:, 1]
    pred_drag = rotate(q, with_drag) + gravity
    return t, vb, f, pred_thrust, pred_drag, a_true, air


def flight(path, drag):
    _, vb, f, pred_thrust, pred_drag, a_true, air = grid(load(path), drag)
    coef = []
    for ax in (0, 1):
        m = np.column_stack([vb[air, ax], np.ones(air.sum())])
        c = np.linalg.lstsq(m, f[air, ax], rcond=None)[0]
        coef.append((-c[0], c[1]))

    def rms(e):
        return float(np.sqrt(np.mean(np.sum(e[air, :2] ** 2, 1))))

    slow = smooth((pred_drag - a_true)[:, :2], 100)
    varying = slow - slow[air].mean(0)
    return coef, rms(pred_thrust - a_true), rms(pred_drag - a_true), rms(slow), rms(varying), rms(a_true)


def main():
    data, rows = manifest(sys.argv, __doc__)
    drag = float(sys.argv[2]) if len(sys.argv) > 2 else 0.4
    print(f"flight            drag x (offset)  drag y (offset)   |a_h|  thrust  +drag {drag:g}  slow  -const")
    ks = []
    for row in rows:
        coef, e_t, e_d, e_s, e_v, a_h = flight(data / row["file"], drag)
        (kx, bx), (ky, by) = coef
        ks += [kx, ky]
        print(
            f"{row['file'][-16:]:16}  {kx:5.2f} ({bx:+5.2f})   {ky:5.2f} ({by:+5.2f})"
            f"    {a_h:5.2f}  {e_t:5.2f}  {e_d:5.2f}     {e_s:5.2f}  {e_v:5.2f}"
        )
    print(f"median drag coefficient over both axes and all flights: {np.median(ks):.2f} /s")


if __name__ == "__main__":
    main()
