#!/usr/bin/env python3
"""The two-way ranges of a UTIL TWR log against motion capture, per anchor.

For every `estDistance` record (anchor id, range) of the log, the error is
the range minus the distance from the anchor to the UWB antenna, whose
position is the motion capture's pose (interpolated to the record's time)
plus the antenna lever arm rotated by its attitude. Printed per anchor: the
records, the mean, median and standard deviation of the error, and the mean
true distance; then the same over every anchor. A common offset shared by
every anchor is the tag's antenna delay (what the fix builder estimates from
the ranges alone, `[fusion.fix] range_offset_tau_s`).

Usage: python3 tools/util_twr_check.py DATA_DIR [LOG ANCHORS]
(default: the shared twr-flight-45c1546b with anchors-const3.txt; numpy.)
"""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import util_tdoa_bound as u  # noqa: E402  (the log and anchor readers)


def main(argv):
    if len(argv) not in (2, 4):
        raise SystemExit(__doc__)
    data = Path(argv[1])
    log, anchors = (argv[2], argv[3]) if len(argv) == 4 else (
        "twr-flight-45c1546b", "anchors-const3.txt")
    d = u.load(data / log)
    if "estDistance" not in d:
        raise SystemExit(f"{data / log}: no estDistance records (not a TWR log)")
    a = u.anchors(data / anchors)
    dist, pose = d["estDistance"], d["estPose"]
    t = pose[:, 0]
    errors = []
    print(f"{'anchor':>6} {'ranges':>6} {'mean':>7} {'median':>7} {'sd':>6} {'distance':>8}")
    for k in sorted(a):
        m = dist[dist[:, 1] == k]
        if len(m) == 0:
            print(f"{k:>6} {0:>6}   (never ranged)")
            continue
        p = np.stack([np.interp(m[:, 0], t, pose[:, i]) for i in (1, 2, 3)], axis=1)
        q = np.stack([np.interp(m[:, 0], t, pose[:, i]) for i in (4, 5, 6, 7)], axis=1)
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        ant = p + u.rotate(q, np.tile(u.LEVER, (len(q), 1)))
        r = np.linalg.norm(ant - np.asarray(a[k]), axis=1)
        e = m[:, 2] - r
        errors.append(e)
        print(f"{k:>6} {len(m):>6} {e.mean():>7.3f} {np.median(e):>7.3f} {e.std():>6.3f} {r.mean():>8.2f}")
    e = np.concatenate(errors)
    print(f"{'all':>6} {len(e):>6} {e.mean():>7.3f} {np.median(e):>7.3f} {e.std():>6.3f}")


if __name__ == "__main__":
    main(sys.argv)
