#!/usr/bin/env python3
"""What the tight filter would read if its slow part were the fix's.

Reads the CSVs that `insuwb eval LOG --anchors FILE --filters iakf_tdoa
--tracks OUT.csv` writes (`track_offset.load`) and forms, causally, at the
truth times of the flight segment:

  blend = tight + LP_tau(fix - tight)

LP_tau a first-order low-pass of time constant tau (started at the first
difference): below about 1 / (2 pi tau) the blend follows the fix, above
it the tight filter. Printed per flight (the file name's stem), the RMSE
of the tight filter and of the blend for each tau as a ratio to the
manifest's `uwb_ls_ref_m` when MANIFEST is given, else in metres; then
the median / worst / above 1.0x over the files.

A diagnostic, not an estimator in the product: it asks how much of the
tight filter's loss to the radio on a flight lies in its slow part.

Usage: python3 tools/track_blend.py [--manifest flights.csv] TRACKS.csv...
"""

import csv
import math
import os
import statistics as st
import sys

from track_offset import load

TAUS_S = (2.0, 5.0, 10.0, 30.0)


def blended_rmse(tight, fix, tau_s):
    """Horizontal RMSE of the blend (tau 0: the tight filter alone)."""
    ts = sorted(t for t in tight if t in fix)
    lp = None
    prev = None
    se = 0.0
    for t in ts:
        ee, en = tight[t][0], tight[t][1]
        fe, fn = fix[t][0], fix[t][1]
        d = (fe - ee, fn - en)
        if tau_s <= 0.0:
            lp = (0.0, 0.0)
        elif lp is None:
            lp = d
        else:
            a = min(1.0, (t - prev) * 1e-9 / tau_s)
            lp = (lp[0] + a * (d[0] - lp[0]), lp[1] + a * (d[1] - lp[1]))
        prev = t
        se += (ee + lp[0]) ** 2 + (en + lp[1]) ** 2
    return math.sqrt(se / len(ts)) if ts else float("nan")


def main():
    args = sys.argv[1:]
    refs = {}
    if len(args) >= 2 and args[0] == "--manifest":
        refs = {r["file"]: float(r["uwb_ls_ref_m"]) for r in csv.DictReader(open(args[1]))}
        args = args[2:]
    if not args:
        raise SystemExit(__doc__)
    cols = (0.0,) + TAUS_S
    print(f"{'flight':18s} {'tight':>7s} " + " ".join(f"{'tau ' + str(t):>8s}" for t in TAUS_S))
    table = []
    for path in args:
        name = os.path.splitext(os.path.basename(path))[0]
        rows = load(path)
        if "iakf_tdoa" not in rows or "uwb" not in rows:
            print(f"{name}: no iakf_tdoa and uwb tracks", file=sys.stderr)
            continue
        # load() keeps errors: the fix's error stands in for its position
        # (the truth is the same at a truth time).
        v = [blended_rmse(rows["iakf_tdoa"], rows["uwb"], tau) for tau in cols]
        if name in refs:
            v = [x / refs[name] for x in v]
        table.append(v)
        print(f"{name:18s} " + " ".join(f"{x:8.3f}" for x in v))
    if table:
        print("median / worst / above 1.0: " + ", ".join(
            f"{'tight' if tau == 0 else 'tau ' + str(tau)} "
            f"{st.median(c):.3f} / {max(c):.3f} / {sum(x > 1 for x in c)}"
            for tau, c in zip(cols, zip(*table))))


if __name__ == "__main__":
    main()
