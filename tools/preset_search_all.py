#!/usr/bin/env python3
"""The tight filter's preset searched on all three of its figures at once,
and whether the anchors' states without a lasting part hold on flights
the choice did not see.

Draws configurations at random (fixed seed) around the `util` preset,
each a copy of config/util.toml with the keys below replaced, about half
with `tdoa_anchor_highpass_s` 0 (each anchor's plain Gauss-Markov state)
and half above (its running mean removed), and scores each draw on

  uncalibrated  `insuwb eval --flights MANIFEST --filters iakf_tdoa`;
  calibrated    `insuwb calibrate --flights MANIFEST --cross-validate
                --candidates grid:1 --filters iakf_tdoa` (each flight with
                a calibration learnt on the others);
  flow          `insuwb eval --flights FLOW --aiding flow` on the flights
                of MANIFEST that carry the flow deck (FLOW: a manifest of
                those, as tests/offline/real_flights.rs writes it);

each as the tight filter's ratio to `uwb_ls_ref_m` per flight. Prints the
draws that miss the goals least (flights above 1.0x in all three, the
calibrated median above 0.75 and the flow median above 0.85, the worst
ratios' excess over 1), then a split-half check: for 300 random halves of
the flights, the draw that scores best on one half (per figure: flights
above 1.0x, plus 5 x the worst ratio's excess over 1, plus twice the
median, summed over the three) among the draws with the running mean
removed and among those without, each scored on the other half (means
over the splits).

Keys drawn (log-uniform):

  fusion.multirotor.damping_per_s             0.5-1.6 /s
  fusion.multirotor.model_noise_mps2_per_rthz 0.2-0.6
  fusion.eskf.tdoa_sigma_m                    0.2-0.36 m
  fusion.eskf.tdoa_corr_time_s                0.01-0.1 s
  fusion.eskf.kappa                           1-2
  fusion.eskf.tdoa_anchor_corr_time_s         0.1-0.4 s
  fusion.eskf.tdoa_anchor_sigma_m             0.1-0.35 m
  fusion.eskf.tdoa_anchor_highpass_s          0 (half the draws) or 0.3-5 s

Usage: python3 tools/preset_search_all.py MANIFEST FLOW [DRAWS [SEED]]
(run from the repository root after `cargo build --release -p insuwb`;
a draw takes about 6 s on the project's 2-core VM.)
"""
import json
import math
import os
import random
import statistics as st
import subprocess
import sys

from preset_search import INSUWB, PRESET, write_config

# The binary (env INSUWB overrides, e.g. a copy while the tree rebuilds).
INSUWB = os.environ.get("INSUWB", INSUWB)

FIGURES = ("uncalibrated", "calibrated", "flow")


def draw(rng):
    """One configuration: {"section.key": TOML value}."""
    lu = lambda a, b: math.exp(rng.uniform(math.log(a), math.log(b)))
    return {
        "fusion.multirotor.damping_per_s": f"{lu(0.5, 1.6):.3f}",
        "fusion.multirotor.model_noise_mps2_per_rthz": f"{lu(0.2, 0.6):.3f}",
        "fusion.eskf.tdoa_sigma_m": f"{lu(0.2, 0.36):.3f}",
        "fusion.eskf.tdoa_corr_time_s": f"{lu(0.01, 0.1):.3f}",
        "fusion.eskf.kappa": f"{lu(1.0, 2.0):.3f}",
        "fusion.eskf.tdoa_anchor_corr_time_s": f"{lu(0.1, 0.4):.3f}",
        "fusion.eskf.tdoa_anchor_sigma_m": f"{lu(0.1, 0.35):.3f}",
        "fusion.eskf.tdoa_anchor_highpass_s": f"{rng.choice([0.0, lu(0.3, 5.0)]):.3f}",
    }


def run(args):
    out = subprocess.run([INSUWB] + args, capture_output=True, text=True,
                         env=dict(os.environ, RUST_LOG="warn"))
    return json.loads(out.stdout) if out.returncode == 0 else None


def ratios(flights):
    return {os.path.basename(f["file"]):
            f["iakf_tdoa"]["rmse_horizontal"] / f["uwb_ls_ref_m"] for f in flights}


def evaluate(manifest, flow, over):
    """Each figure's ratio per flight, or None when a command failed."""
    path = write_config(open(PRESET).read(), over)
    common = ["--config", path, "--json", "--filters", "iakf_tdoa"]
    try:
        unc = run(["eval", "--flights", manifest] + common)
        cal = run(["calibrate", "--flights", manifest, "--cross-validate",
                   "--candidates", "grid:1"] + common)
        aided = run(["eval", "--flights", flow, "--aiding", "flow"] + common)
    finally:
        os.unlink(path)
    if not (unc and cal and aided):
        return None
    return {"uncalibrated": ratios(unc["flights"]),
            "calibrated": ratios(cal["families"][0]["flights"]),
            "flow": ratios(aided["flights"])}


def summary(v):
    return st.median(v), max(v), sum(x > 1 for x in v)


def misses(r):
    """How far a draw is from the goals (0: all met)."""
    (um, uw, ua), (cm, cw, ca), (fm, fw, fa) = (summary(list(r[k].values())) for k in FIGURES)
    return (ua + ca + fa + 10 * max(0.0, cm - 0.75) + 10 * max(0.0, fm - 0.85)
            + 2 * (max(0.0, uw - 1) + max(0.0, cw - 1) + max(0.0, fw - 1)))


def score(r, names):
    total = 0.0
    for k in FIGURES:
        v = [r[k][n] for n in names if n in r[k]]
        total += sum(x > 1 for x in v) + 5 * max(0.0, max(v) - 1) + 2 * st.median(v)
    return total


def main():
    if len(sys.argv) < 3:
        raise SystemExit(__doc__)
    manifest, flow = sys.argv[1], sys.argv[2]
    draws = int(sys.argv[3]) if len(sys.argv) > 3 else 60
    rng = random.Random(int(sys.argv[4]) if len(sys.argv) > 4 else 1)
    rows = []
    for i in range(draws):
        over = draw(rng)
        r = evaluate(manifest, flow, over)
        if r is not None:
            rows.append((over, r))
        if (i + 1) % 10 == 0:
            print(f"{i + 1} draws", file=sys.stderr, flush=True)
    preset = evaluate(manifest, flow, {})
    if preset is None or not rows:
        raise SystemExit(f"{INSUWB} failed")
    fmt = lambda r: "  ".join(f"{k} {m:.3f} / {w:.3f} / {a}"
                              for k in FIGURES for m, w, a in [summary(list(r[k].values()))])
    print(f"the preset: {fmt(preset)}")
    rows.sort(key=lambda x: misses(x[1]))
    print(f"{len(rows)} draws; the five that miss the goals least:")
    for over, r in rows[:5]:
        keys = ", ".join(f"{k.rsplit('.', 1)[1]} {v}" for k, v in over.items())
        print(f"  {fmt(r)}\n    {keys}")
    names = sorted(preset["uncalibrated"])
    families = {
        "running mean removed": [r for r in rows if float(r[0]["fusion.eskf.tdoa_anchor_highpass_s"]) > 0],
        "plain": [r for r in rows if float(r[0]["fusion.eskf.tdoa_anchor_highpass_s"]) == 0],
    }
    split = random.Random(0)
    held = {name: [] for name in families}
    for _ in range(300):
        shuffled = names[:]
        split.shuffle(shuffled)
        a, b = shuffled[: len(names) // 2 + 1], shuffled[len(names) // 2 + 1:]
        for name, family in families.items():
            if not family:
                continue
            pick = min(family, key=lambda r: score(r[1], a))[1]
            held[name].append([summary([pick[k][n] for n in b if n in pick[k]]) for k in FIGURES])
    print("split-half, 300 splits: the best draw on one half, on the other half "
          "(median / worst / flights above 1.0x, means over the splits):")
    for name, h in held.items():
        if not h:
            continue
        cells = [f"{k} {st.mean(x[j][0] for x in h):.3f} / {st.mean(x[j][1] for x in h):.3f}"
                 f" / {st.mean(x[j][2] for x in h):.2f}" for j, k in enumerate(FIGURES)]
        print(f"  {name} ({len(families[name])} draws): " + "  ".join(cells))


if __name__ == "__main__":
    main()
