#!/usr/bin/env python3
"""Nested leave-one-flight-out of the site calibration's cell weight.

`insuwb calibrate --cross-validate` scores each candidate family on flights
its calibration did not see, but the default family's cell weight was then
chosen on those same scores. This runs the choice itself inside the loop:
for each flight of the manifest, the weight is chosen by leave-one-flight-out
over the other flights alone (the candidates `grid:CELL:wW`, the lowest mean
ratio of the tight filter to `uwb_ls_ref_m`), a calibration with that weight
is learnt on those flights (`insuwb calibrate --out`), and the held-out flight
is evaluated with it (`insuwb eval --flights` on a one-flight manifest).

    python3 tools/util_nested_cv.py ../shared/data/util/flights.csv \
        [--weights 0,0.25,0.5,0.75,1] [--cell 1] [--insuwb target/release/insuwb]

Prints each flight's chosen weight and ratio, then the median / worst /
flights above 1 of the nested figures. Nothing here is used at run time.
"""
import argparse
import csv
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path


def read_manifest(path):
    """Rows of the manifest with absolute file and anchor paths."""
    base = Path(path).resolve().parent
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        r["file"] = str(base / r["file"])
        if r.get("anchors"):
            r["anchors"] = str(base / r["anchors"])
    return rows


def write_manifest(path, rows):
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
        w.writeheader()
        w.writerows(rows)


def run(cmd):
    out = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ, RUST_LOG="warn"))
    if out.returncode != 0:
        sys.exit(f"{' '.join(cmd)}:\n{out.stderr[-2000:]}")
    return out.stdout


def ratios(flights, solution="iakf_tdoa"):
    return [f[solution]["rmse_horizontal"] / f["uwb_ls_ref_m"] for f in flights]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("manifest")
    ap.add_argument("--weights", default="0,0.25,0.5,0.75,1")
    ap.add_argument("--cell", default="1")
    ap.add_argument("--insuwb", default="target/release/insuwb")
    a = ap.parse_args()
    rows = read_manifest(a.manifest)
    weights = [w.strip() for w in a.weights.split(",") if w.strip()]
    candidates = ",".join(f"grid:{a.cell}:w{w}" for w in weights)
    nested, chosen = [], []
    with tempfile.TemporaryDirectory(prefix="insuwb-nested-") as tmp:
        tmp = Path(tmp)
        for i, held in enumerate(rows):
            name = Path(held["file"]).name
            others = rows[:i] + rows[i + 1 :]
            inner = tmp / "inner.csv"
            write_manifest(inner, others)
            cv = json.loads(run([a.insuwb, "calibrate", "--flights", str(inner), "--cross-validate",
                                 "--candidates", candidates, "--filters", "iakf_tdoa", "--json"]))
            scores = [statistics.fmean(ratios(fam["flights"])) for fam in cv["families"]]
            best = min(range(len(weights)), key=lambda k: (scores[k], k))
            site = tmp / "site.toml"
            run([a.insuwb, "calibrate", "--flights", str(inner), "--out", str(site),
                 "--cell-m", a.cell, "--cell-weight", weights[best]])
            one = tmp / "one.csv"
            write_manifest(one, [held])
            ev = json.loads(run([a.insuwb, "eval", "--flights", str(one), "--calibration", str(site),
                                 "--filters", "iakf_tdoa", "--json"]))
            (r,) = ratios(ev["flights"])
            nested.append(r)
            chosen.append(weights[best])
            inner_scores = " ".join(f"{w}:{s:.3f}" for w, s in zip(weights, scores))
            print(f"{name:18s} weight {weights[best]:>4s}  ratio {r:.3f}   (inner mean ratio {inner_scores})", flush=True)
    above = sum(r > 1.0 for r in nested)
    print(f"nested: {statistics.median(nested):.3f} / {max(nested):.3f} / {above} of {len(nested)} "
          f"(weights chosen: {', '.join(sorted(set(chosen)))})")


if __name__ == "__main__":
    main()
