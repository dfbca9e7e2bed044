//! Real flights: the four UTIL logs of `shared/data/util` through the lockstep
//! runner with the `config/util.toml` preset (the one parameter set `insuwb
//! eval` uses for Crazyflie logs), scored by the horizontal RMSE over the
//! flight segment at the UWB fix epochs, as `insuwb eval` scores them, and
//! compared with the radio alone (`flights.csv`'s least-squares reference).
//!
//! The data are not part of the repository: they are looked for at
//! `INSUWB_UTIL_DIR`, else at `<workspace>/../shared/data/util`. When they
//! are absent the tests say so and pass, unless the environment variable
//! `CI` is set, where they fail.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use crate::common;

use common::{data_dir, load, preset, Preset};
use insuwb_data::segment::{flight_segment, interpolate_truth};
use insuwb_data::util::UtilFlight;
use insuwb_fusion::config::build_estimator;
use insuwb_fusion::runner;
use insuwb_msg::{FilterKind, FusedState, UwbFix};

/// Log, anchor file, the radio alone: the least-squares TDOA fix's
/// horizontal RMSE measured outside this project (`flights.csv`,
/// `uwb_ls_ref_m`), m.
const LOGS: [(&str, &str, f64); 4] = [
    ("cfBolt-log00", "anchors-const3.txt", 0.150),
    ("test-log00", "anchors-const3.txt", 0.121),
    ("0426-traj3", "anchors-0426.txt", 0.141),
    ("0426-traj5", "anchors-0426.txt", 0.157),
];

const FILTERS: [FilterKind; 5] = [
    FilterKind::Kf,
    FilterKind::Shaf,
    FilterKind::Stf,
    FilterKind::Iakf,
    FilterKind::IakfTdoa,
];

fn min_height_m(p: &Preset) -> f64 {
    p.eval
        .as_ref()
        .and_then(|e| e.get("min_height_m"))
        .and_then(toml::Value::as_float)
        .unwrap_or(insuwb_data::segment::DEFAULT_MIN_HEIGHT_M)
}

/// Horizontal errors at `epochs` inside `segment`, of the estimates `est(t)`.
fn horizontal_rmse(
    flight: &UtilFlight,
    segment: (u64, u64),
    points: impl Iterator<Item = (u64, [f64; 2])>,
) -> (f64, usize) {
    let (mut sum, mut n) = (0.0, 0usize);
    for (t, p) in points {
        if t < segment.0 || t > segment.1 {
            continue;
        }
        assert!(
            p.iter().all(|v| v.is_finite()),
            "non-finite estimate at {t} ns"
        );
        let Some(g) = interpolate_truth(&flight.truth, t) else {
            continue;
        };
        sum += (p[0] - g.pos_m[0]).powi(2) + (p[1] - g.pos_m[1]).powi(2);
        n += 1;
    }
    assert!(n > 0, "no estimate inside the flight segment");
    ((sum / n as f64).sqrt(), n)
}

/// The fused state published last at each fix epoch (as `insuwb eval` samples it).
fn fused_at_epochs<'a>(
    fused: &'a [FusedState],
    fixes: &'a [UwbFix],
) -> impl Iterator<Item = (u64, [f64; 2])> + 'a {
    let mut j = 0usize;
    fixes.iter().filter_map(move |f| {
        let t = f.header.meas_time_ns;
        while j < fused.len() && fused[j].header.meas_time_ns < t {
            j += 1;
        }
        let mut k = j;
        while k + 1 < fused.len() && fused[k + 1].header.meas_time_ns == t {
            k += 1;
        }
        fused
            .get(k)
            .filter(|s| s.header.meas_time_ns == t)
            .map(|s| (t, [s.pos_m[0], s.pos_m[1]]))
    })
}

struct LogResult {
    uwb: f64,
    uwb_epochs: usize,
    filters: Vec<(FilterKind, f64, usize)>,
}

fn run_log(dir: &std::path::Path, log: &str, anchors: &str, p: &Preset) -> LogResult {
    let flight = load(dir, log, anchors, p);
    let segment = flight_segment(&flight.truth, min_height_m(p)).expect("a flight segment");
    let cfg = &p.fusion;
    let fixes = runner::run_fixes(&flight.tdoa, cfg).unwrap();
    let (uwb, uwb_epochs) = horizontal_rmse(
        &flight,
        segment,
        fixes
            .iter()
            .map(|f| (f.header.meas_time_ns, [f.pos_m[0], f.pos_m[1]])),
    );
    let mut filters = Vec::new();
    for kind in FILTERS {
        let out = runner::run(&flight.imu, &flight.tdoa, cfg, kind).unwrap();
        for s in &out.fused {
            assert!(
                s.pos_m
                    .iter()
                    .chain(&s.vel_mps)
                    .chain(&s.quat)
                    .all(|v| v.is_finite()),
                "{log} {kind:?}: non-finite fused state at {} ns",
                s.header.meas_time_ns
            );
        }
        let (rmse, n) = horizontal_rmse(&flight, segment, fused_at_epochs(&out.fused, &fixes));
        filters.push((kind, rmse, n));
    }
    LogResult {
        uwb,
        uwb_epochs,
        filters,
    }
}

#[test]
fn preset_parses_and_validates() {
    let p = preset();
    for kind in FILTERS {
        build_estimator(kind, &p.fusion).unwrap();
    }
    assert!(min_height_m(&p) > 0.0);
}

/// The four logs the preset was first built on, through the lockstep runner
/// (the 23 shared flights go through `insuwb eval --flights` in the
/// `insuwb` crate's `real_flights` test): no filter diverges, every filter
/// has an estimate at (nearly) every fix epoch, and the tight filter stays
/// within 1.5 times the radio alone (a guard against regressions; issue
/// 16's bound of 1.0 times does not hold yet on 0426-traj3: 0.177 m against
/// 0.141 m).
#[test]
fn util_logs_tight_filter_near_the_radio_alone() {
    let Some(dir) = data_dir(LOGS[0].0) else {
        return;
    };
    let p = preset();
    let mut failures = Vec::new();
    for (log, anchors, ls_ref) in LOGS {
        let r = run_log(&dir, log, anchors, &p);
        let line: Vec<String> = r
            .filters
            .iter()
            .map(|(k, e, _)| format!("{k:?} {e:.3}"))
            .collect();
        eprintln!(
            "{log}: UWB {:.3}, {} (least squares {ls_ref:.3})",
            r.uwb,
            line.join(", ")
        );
        let tight = r
            .filters
            .iter()
            .find(|f| f.0 == FilterKind::IakfTdoa)
            .map_or(f64::NAN, |f| f.1);
        if tight.is_nan() || tight > 1.5 * ls_ref {
            failures.push(format!(
                "{log}: tight filter {tight:.3} m > 1.5 x the radio alone {ls_ref:.3} m"
            ));
        }
        for (k, e, n) in &r.filters {
            if e.is_nan() || *e >= 1.0 {
                failures.push(format!("{log}: {k:?} diverged ({e:.3} m)"));
            }
            // An estimate at (nearly) every fix epoch of the flight.
            if 10 * n < 9 * r.uwb_epochs {
                failures.push(format!(
                    "{log}: {k:?} has estimates at {n} of {} epochs",
                    r.uwb_epochs
                ));
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
