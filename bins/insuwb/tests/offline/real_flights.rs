//! Every shared UTIL flight through the batch path, `insuwb eval --flights
//! flights.csv --json`, held to the product's goals for the built-in preset
//! (uncalibrated) against the radio-alone reference `uwb_ls_ref_m`:
//!
//! - `iakf_tdoa`: ratio at most 1.0 on every flight and 0.90 at the median,
//!   no worse than UTIL's own filter (`util_eskf_m`) on any flight,
//!   `max_dist` at most 1.0 m on every flight, `nees_mean` at most 20 on
//!   every flight and between 2 and 8 at the median;
//! - `iakf`: ratio at most 1.2 on every flight, median ratio no worse than
//!   the KF's;
//! - `uwb`: ratio at most 1.05 on every flight.
//!
//! Those do not hold yet, so that test is ignored; a second one, run in CI,
//! holds the flights to today's figures with margin ([`TODAY`]) so that a
//! regression shows. Every failing flight and bound is reported in one message. The data are
//! not part of the repository: they are looked for at `INSUWB_UTIL_DIR`,
//! else at `<workspace>/../shared/data/util`. When they are absent the test
//! says so and passes, unless the environment variable `CI` is set, where it
//! fails. The 23 flights take a few seconds in release (`cargo test
//! --release`), spread over all cores by the batch path itself.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use crate::common;

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

/// The manifest of the shared flights.
const MANIFEST: &str = "flights.csv";
/// Flights the manifest lists.
const FLIGHTS: usize = 23;
/// The reference column the bounds are stated against.
const REFERENCE: &str = "uwb_ls_ref_m";
/// The batch is killed and the test fails after this long.
const WATCHDOG: Duration = Duration::from_secs(900);

fn data_dir() -> Option<PathBuf> {
    common::util_data_dir(MANIFEST)
}

/// Runs the batch under a watchdog; its JSON output.
fn run_batch(manifest: &std::path::Path) -> Value {
    run_batch_with(manifest, &[])
}

/// [`run_batch`] with more arguments for `insuwb eval --flights`.
fn run_batch_with(manifest: &std::path::Path, extra: &[&str]) -> Value {
    // One folder per call: the tests of this file run in parallel.
    static CALLS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let call = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let tmp =
        std::env::temp_dir().join(format!("insuwb-real-flights-{}-{call}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    let (out_path, err_path) = (tmp.join("stdout.json"), tmp.join("stderr.txt"));
    let mut child = Command::new(env!("CARGO_BIN_EXE_insuwb"))
        .args(["eval", "--flights", manifest.to_str().unwrap(), "--json"])
        .args(extra)
        // The tables only, not each flight's messages.
        .env("RUST_LOG", "warn")
        .stdout(Stdio::from(std::fs::File::create(&out_path).unwrap()))
        .stderr(Stdio::from(std::fs::File::create(&err_path).unwrap()))
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if t0.elapsed() > WATCHDOG {
            let _ = child.kill();
            let _ = child.wait();
            panic!("insuwb eval --flights still running after {WATCHDOG:?}: killed");
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    let stderr = std::fs::read_to_string(&err_path).unwrap_or_default();
    let stdout = std::fs::read(&out_path).unwrap();
    let _ = std::fs::remove_dir_all(&tmp);
    assert!(status.success(), "insuwb eval --flights failed:\n{stderr}");
    // The per-flight table and the summary, for the test's log.
    eprintln!("{stderr}");
    serde_json::from_slice(&stdout).unwrap()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Bounds against the reference: per-flight ratio limits, the tight
/// filter's median ratio, `max_dist` and NEES limits.
struct Bounds {
    tight: f64,
    tight_median: f64,
    iakf: f64,
    uwb: f64,
    /// The IAKF's median ratio may not exceed the KF's.
    iakf_vs_kf: bool,
    /// The tight filter's ratio to UTIL's own filter (`util_eskf_m`), per
    /// flight.
    util_eskf: f64,
    max_dist_m: f64,
    nees: f64,
    nees_median: (f64, f64),
}

/// The goals (uncalibrated, built-in preset).
const GOALS: Bounds = Bounds {
    tight: 1.0,
    tight_median: 0.90,
    iakf: 1.2,
    uwb: 1.05,
    iakf_vs_kf: true,
    util_eskf: 1.0,
    max_dist_m: 1.0,
    nees: 20.0,
    nees_median: (2.0, 8.0),
};

/// What the shared flights give today (docs/REAL_FLIGHTS.md), with margin:
/// a guard against regressions while the goals do not all hold. Today
/// (multirotor model, the anchors' TDOA error states without a lasting
/// part): `iakf_tdoa` worst 1.09, median 0.84, at most 0.97x UTIL's filter,
/// `max_dist` 0.57 m, NEES median 4.0 and worst 16.1; `iakf` worst 1.05 and
/// `uwb` worst 1.02 (both held to the goals' bounds).
const TODAY: Bounds = Bounds {
    tight: 1.15,
    tight_median: 0.9,
    iakf: 1.2,
    uwb: 1.05,
    iakf_vs_kf: false,
    util_eskf: 1.05,
    max_dist_m: 1.0,
    nees: 20.0,
    nees_median: (2.0, 8.0),
};

/// The bounds' failures, one line each.
fn failures(v: &Value) -> Vec<String> {
    failures_against(v, &GOALS)
}

/// The failures against `b`, one line each.
fn failures_against(v: &Value, b: &Bounds) -> Vec<String> {
    failures_of(v, b, FLIGHTS)
}

/// The failures against `b` of a batch of `expected` flights, one line each.
fn failures_of(v: &Value, b: &Bounds, expected: usize) -> Vec<String> {
    let mut fails = Vec::new();
    let flights = v["flights"].as_array().map_or(&[][..], Vec::as_slice);
    if flights.len() != expected {
        fails.push(format!(
            "{} flights evaluated, {expected} expected",
            flights.len()
        ));
    }
    let num = |f: &Value, sol: &str, key: &str| f[sol][key].as_f64();
    // Per-flight ratios of each solution, for the medians.
    let mut ratios: std::collections::BTreeMap<&str, Vec<f64>> = Default::default();
    let mut nees = Vec::new();
    for f in flights {
        let name = f["file"].as_str().unwrap_or("?");
        let Some(reference) = f[REFERENCE].as_f64() else {
            fails.push(format!("{name}: no {REFERENCE}"));
            continue;
        };
        for (sol, bound) in [
            ("iakf_tdoa", b.tight),
            ("iakf", b.iakf),
            ("kf", f64::INFINITY),
            ("uwb", b.uwb),
        ] {
            let Some(rmse) = num(f, sol, "rmse_horizontal") else {
                fails.push(format!("{name}: {sol} missing"));
                continue;
            };
            let ratio = rmse / reference;
            ratios.entry(sol).or_default().push(ratio);
            if ratio.is_nan() || ratio > bound {
                fails.push(format!(
                    "{name}: {sol} RMSE {rmse:.3} m is {ratio:.2}x {REFERENCE} ({reference:.3} m), bound {bound}x"
                ));
            }
        }
        let eskf = f["util_eskf_m"].as_f64();
        match (num(f, "iakf_tdoa", "rmse_horizontal"), eskf) {
            (Some(rmse), Some(e)) if rmse / e <= b.util_eskf => {}
            (Some(rmse), Some(e)) => fails.push(format!(
                "{name}: iakf_tdoa RMSE {rmse:.3} m is {:.3}x util_eskf_m ({e:.3} m), bound {}x",
                rmse / e,
                b.util_eskf
            )),
            _ => fails.push(format!("{name}: iakf_tdoa RMSE or util_eskf_m missing")),
        }
        match num(f, "iakf_tdoa", "max_dist") {
            Some(d) if d <= b.max_dist_m => {}
            Some(d) => fails.push(format!(
                "{name}: iakf_tdoa max_dist {d:.2} m, bound {} m",
                b.max_dist_m
            )),
            None => fails.push(format!("{name}: iakf_tdoa max_dist missing")),
        }
        match num(f, "iakf_tdoa", "nees_mean") {
            Some(n) => {
                nees.push(n);
                if n.is_nan() || n > b.nees {
                    fails.push(format!(
                        "{name}: iakf_tdoa nees_mean {n:.1}, bound {}",
                        b.nees
                    ));
                }
            }
            None => fails.push(format!("{name}: iakf_tdoa nees_mean missing")),
        }
    }
    let med = |sol: &str| median(ratios.get(sol).cloned().unwrap_or_default());
    let m = med("iakf_tdoa");
    if m.is_nan() || m > b.tight_median {
        fails.push(format!(
            "iakf_tdoa: median ratio {m:.2}, bound {}",
            b.tight_median
        ));
    }
    let (mi, mk) = (med("iakf"), med("kf"));
    if b.iakf_vs_kf && (mi.is_nan() || mi > mk) {
        fails.push(format!("iakf: median ratio {mi:.2} above the KF's {mk:.2}"));
    }
    let mn = median(nees);
    let (lo, hi) = b.nees_median;
    if !(lo..=hi).contains(&mn) {
        fails.push(format!(
            "iakf_tdoa: median nees_mean {mn:.1}, bound [{lo}, {hi}]"
        ));
    }
    fails
}

#[test]
#[ignore] // enabled once the filters meet the goals
fn every_shared_flight_meets_the_goals() {
    let Some(dir) = data_dir() else {
        return;
    };
    let v = run_batch(&dir.join(MANIFEST));
    let fails = failures(&v);
    assert!(
        fails.is_empty(),
        "{} bound(s) not met over the shared UTIL flights:\n{}",
        fails.len(),
        fails.join("\n")
    );
}

/// Today's figures with margin (see [`TODAY`]); runs in CI.
#[test]
fn every_shared_flight_holds_todays_figures() {
    let Some(dir) = data_dir() else {
        return;
    };
    let v = run_batch(&dir.join(MANIFEST));
    let mut fails = failures_against(&v, &TODAY);
    // The two Crazyflie Bolt flights, whose accelerometers follow the
    // motion, hand over to the free model (`free_above_signal_ratio`,
    // config/util.toml): 0.56x and 0.73x today, 1.22x and 1.16x without.
    // The two NLOS-heavy flights: 0.34x and 0.29x today with the 4-sigma
    // hard gate, 0.44x and 0.40x at 8 sigma.
    for (name, bound) in [
        ("cfBolt-log00", 0.65),
        ("test-log00", 0.8),
        ("flight-23040d17", 0.39),
        ("flight-3109eeee", 0.35),
    ] {
        let f = v["flights"]
            .as_array()
            .and_then(|a| a.iter().find(|f| f["file"] == name));
        let ratio = f.and_then(|f| {
            Some(f["iakf_tdoa"]["rmse_horizontal"].as_f64()? / f[REFERENCE].as_f64()?)
        });
        if !ratio.is_some_and(|r| r <= bound) {
            fails.push(format!(
                "{name}: iakf_tdoa {ratio:?}x {REFERENCE}, bound {bound}x"
            ));
        }
    }
    // No reset in flight: the divergence monitor stays quiet on every
    // flight (6-7 resets on each NLOS-heavy flight with the 8-sigma gate).
    for f in v["flights"].as_array().map_or(&[][..], Vec::as_slice) {
        let n = f["iakf_tdoa"]["divergences"].as_f64();
        if n != Some(0.0) {
            fails.push(format!(
                "{}: iakf_tdoa divergences in flight {n:?}, expected 0",
                f["file"]
            ));
        }
    }
    assert!(
        fails.is_empty(),
        "{} bound(s) not met over the shared UTIL flights:\n{}",
        fails.len(),
        fails.join("\n")
    );
}

/// The shared flights whose logs carry the flow deck's records (`estFlow`,
/// `estTOF`; the dataset README).
const FLOW_FLIGHTS: [&str; 16] = [
    "cfBolt-log00",
    "test-log00",
    "flight-0b43c456",
    "flight-1229e2e7",
    "flight-1b00dbb0",
    "flight-4459574a",
    "flight-4f5069f6",
    "flight-660e0959",
    "flight-6f78492c",
    "flight-7ce32570",
    "flight-9268362f",
    "flight-a92f4787",
    "flight-ced064fb",
    "flight-d59a9998",
    "flight-daf31394",
    "flight-f4653ac3",
];

/// What the flights with flow give today aided by it (`insuwb eval
/// --flights ... --aiding flow`, docs/REAL_FLIGHTS.md), with margin: the
/// tight filter median 0.81, worst 1.10, at most 0.97x UTIL's filter,
/// `max_dist` 0.60 m (held to the goal's 0.8 m), NEES median 3.9 (held to
/// the goal's 2-8) and worst 18.8 (the goals of velocity aiding bound only
/// the median).
const TODAY_FLOW: Bounds = Bounds {
    tight: 1.2,
    tight_median: 0.9,
    max_dist_m: 0.8,
    util_eskf: 1.1,
    nees: 25.0,
    ..TODAY
};

/// The tight filter's RMSE per flight, by file.
fn tight_rmse(v: &Value) -> std::collections::BTreeMap<String, f64> {
    let flights = v["flights"].as_array().map_or(&[][..], Vec::as_slice);
    flights
        .iter()
        .filter_map(|f| {
            Some((
                f["file"].as_str()?.to_owned(),
                f["iakf_tdoa"]["rmse_horizontal"].as_f64()?,
            ))
        })
        .collect()
}

/// The tight filter's height RMSE of every flight with flow, sorted.
fn tight_up(v: &Value) -> Vec<f64> {
    let flights = v["flights"].as_array().map_or(&[][..], Vec::as_slice);
    let mut up: Vec<f64> = flights
        .iter()
        .filter(|f| {
            f["file"]
                .as_str()
                .is_some_and(|n| FLOW_FLIGHTS.contains(&n))
        })
        .filter_map(|f| f["iakf_tdoa"]["rmse_up"].as_f64())
        .collect();
    up.sort_by(f64::total_cmp);
    up
}

/// The flights with flow, aided by it: today's figures with margin, and
/// better than the same flights unaided on the whole: the geometric mean
/// over the flights of the aided over the unaided RMSE at most 0.98 (today
/// 0.944; better on 10 of the 16, the median ratio to the reference 0.814
/// aided, 0.834 unaided). The range finder gives the height: the tight
/// filter's height RMSE at most 0.04 m at the median flight and 0.08 m on
/// every one (today 0.017 and 0.028 m), where unaided it is above 0.1 m at
/// the median (today 0.216 m). The whole manifest is given: the 7 flights
/// without flow records are left out and named.
#[test]
fn flow_aided_flights_hold_todays_figures_and_beat_the_unaided() {
    let Some(dir) = data_dir() else {
        return;
    };
    let path = dir.join(MANIFEST);
    let aided = run_batch_with(&path, &["--aiding", "flow"]);
    let plain = run_batch(&path);
    let mut fails = failures_of(&aided, &TODAY_FLOW, FLOW_FLIGHTS.len());
    let left_out: Vec<&str> = aided["left_out"]
        .as_array()
        .map_or(&[][..], Vec::as_slice)
        .iter()
        .filter_map(Value::as_str)
        .collect();
    if left_out.len() != FLIGHTS - FLOW_FLIGHTS.len()
        || left_out.iter().any(|n| FLOW_FLIGHTS.contains(n))
    {
        fails.push(format!(
            "left out: {left_out:?}, expected the {} flights without flow",
            FLIGHTS - FLOW_FLIGHTS.len()
        ));
    }
    let (a, p) = (tight_rmse(&aided), tight_rmse(&plain));
    let logs: Vec<f64> = a
        .iter()
        .filter_map(|(k, x)| Some((x / p.get(k)?).ln()))
        .collect();
    let gm = (logs.iter().sum::<f64>() / logs.len() as f64).exp();
    if logs.len() != FLOW_FLIGHTS.len() || gm.is_nan() || gm > 0.98 {
        fails.push(format!(
            "iakf_tdoa: aided over unaided RMSE, geometric mean {gm:.3} over {} flights, bound 0.98",
            logs.len()
        ));
    }
    let (up_aided, up_plain) = (tight_up(&aided), tight_up(&plain));
    let median = |v: &[f64]| v.get(v.len() / 2).copied().unwrap_or(f64::NAN);
    let (ma, mp) = (median(&up_aided), median(&up_plain));
    let worst = up_aided.last().copied().unwrap_or(f64::NAN);
    if up_aided.len() != FLOW_FLIGHTS.len() || !(ma <= 0.04 && worst <= 0.08 && mp > 0.1) {
        fails.push(format!(
            "iakf_tdoa: height RMSE aided median {ma:.3} m (bound 0.04), worst {worst:.3} m \
             (bound 0.08), unaided median {mp:.3} m (above 0.1), over {} flights",
            up_aided.len()
        ));
    }
    assert!(
        fails.is_empty(),
        "{} bound(s) not met over the flights with flow:\n{}",
        fails.len(),
        fails.join("\n")
    );
}

#[test]
fn failures_are_all_reported() {
    let flight = |name: &str, tdoa: f64, iakf: f64, uwb: f64, max: f64, nees: f64| {
        serde_json::json!({
            "file": name, REFERENCE: 0.1, "util_eskf_m": 0.15,
            "iakf_tdoa": { "rmse_horizontal": tdoa, "max_dist": max, "nees_mean": nees },
            "iakf": { "rmse_horizontal": iakf },
            "kf": { "rmse_horizontal": 0.1 },
            "uwb": { "rmse_horizontal": uwb },
        })
    };
    let good: Vec<Value> = (0..FLIGHTS)
        .map(|i| flight(&format!("f{i}"), 0.05, 0.09, 0.1, 0.3, 4.0))
        .collect();
    assert!(failures(&serde_json::json!({ "flights": good })).is_empty());
    let mut bad = good.clone();
    bad[3] = flight("f3", 0.2, 0.13, 0.11, 1.5, 30.0);
    let fails = failures(&serde_json::json!({ "flights": bad }));
    // Six bounds on f3 (the tight filter's ratio to the reference and to
    // UTIL's filter, the IAKF's and our fix's ratios, the tight filter's
    // largest error and its NEES); the medians still hold.
    assert_eq!(fails.len(), 6, "{fails:#?}");
    assert!(fails.iter().all(|f| f.starts_with("f3: ")), "{fails:#?}");
    let fails = failures(&serde_json::json!({ "flights": &bad[..3] }));
    assert!(fails[0].contains("3 flights evaluated"), "{fails:#?}");
}

/// The two-way-ranging manifest (one static log, `segment` = all).
const TWR_MANIFEST: &str = "flights-twr.csv";

/// The shared static two-way-ranging log through the batch path: the
/// goals that hold (our range fix at most 1.05x `uwb_ls_ref_m`, the tight
/// filter `iakf_twr` at most 0.8x, its mean NEES within 2-8 with the
/// range sigma learnt from the innovations) and today's figures with
/// margin (docs/REAL_FLIGHTS.md: 0.29x and 0.28x, the tight filter's
/// largest error 0.121 m, NEES 3.5). Without `--segment all` or
/// the manifest's column the log, which never lifts off, is refused with
/// the way out in the message.
#[test]
fn the_static_twr_log_holds_todays_figures() {
    let Some(dir) = data_dir() else {
        return;
    };
    let v = run_batch(&dir.join(TWR_MANIFEST));
    let flights = v["flights"].as_array().map_or(&[][..], Vec::as_slice);
    assert_eq!(flights.len(), 1, "{v}");
    let f = &flights[0];
    let reference = f[REFERENCE].as_f64().unwrap();
    let num = |sol: &str, key: &str| {
        f[sol][key]
            .as_f64()
            .unwrap_or_else(|| panic!("{sol}.{key} missing: {f}"))
    };
    let ratio = |sol: &str| num(sol, "rmse_horizontal") / reference;
    assert!(
        f["iakf_tdoa"].is_null(),
        "a ranging log names the tight filter iakf_twr: {f}"
    );
    for (sol, bound) in [("uwb", 0.4), ("iakf_twr", 0.4), ("iakf", 0.4), ("kf", 0.4)] {
        assert!(
            ratio(sol) <= bound,
            "{sol}: {:.2}x {REFERENCE}, bound {bound}x",
            ratio(sol)
        );
    }
    assert!(num("iakf_twr", "max_dist") <= 0.2, "{f}");
    let nees = num("iakf_twr", "nees_mean");
    assert!((2.0..=8.0).contains(&nees), "iakf_twr nees_mean {nees}");

    let log = dir.join("twr-flight-45c1546b");
    let anchors = dir.join("anchors-const3.txt");
    let out = Command::new(env!("CARGO_BIN_EXE_insuwb"))
        .args(["eval", log.to_str().unwrap(), "--anchors"])
        .arg(&anchors)
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "a log that never lifts off was evaluated as a flight"
    );
    assert!(
        err.contains("never rises above 0.3 m") && err.contains("--segment all"),
        "{err}"
    );

    // Imported into a project log, the ranges evaluate as the Crazyflie log does.
    let tmp = std::env::temp_dir().join(format!("insuwb-twr-{}.iulog", std::process::id()));
    let import = Command::new(env!("CARGO_BIN_EXE_insuwb"))
        .args(["import", "util", log.to_str().unwrap(), "--anchors"])
        .arg(&anchors)
        .arg("--out")
        .arg(&tmp)
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    assert!(
        import.status.success(),
        "{}",
        String::from_utf8_lossy(&import.stderr)
    );
    let eval = Command::new(env!("CARGO_BIN_EXE_insuwb"))
        .args(["eval", tmp.to_str().unwrap(), "--segment", "all", "--json"])
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    let _ = std::fs::remove_file(&tmp);
    assert!(
        eval.status.success(),
        "{}",
        String::from_utf8_lossy(&eval.stderr)
    );
    let back: Value = serde_json::from_slice(&eval.stdout).unwrap();
    for sol in ["uwb", "iakf_twr"] {
        let a = num(sol, "rmse_horizontal");
        let b = back[sol]["rmse_horizontal"].as_f64().unwrap();
        assert!(
            (a - b).abs() < 1e-9,
            "{sol}: {a} from the Crazyflie log, {b} imported"
        );
    }
}

/// A log without the flow deck's records, given alone with `--aiding flow`,
/// stops with an error naming the file; a manifest of such logs only stops
/// naming the manifest (a manifest with some keeps those with flow, above).
#[test]
fn flow_aiding_without_flow_records_stops_naming_the_file() {
    let Some(dir) = data_dir() else {
        return;
    };
    // `insuwb eval ARGS --aiding flow`: it must fail; its standard error.
    let refused = |args: &[&std::ffi::OsStr]| {
        let out = Command::new(env!("CARGO_BIN_EXE_insuwb"))
            .arg("eval")
            .args(args)
            .args(["--aiding", "flow", "--filters", "iakf_tdoa"])
            .env("RUST_LOG", "warn")
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(!out.status.success(), "{err}");
        err
    };
    let log = dir.join("flight-175aea83");
    let anchors = dir.join("anchors-const3.txt");
    let err = refused(&[log.as_os_str(), "--anchors".as_ref(), anchors.as_os_str()]);
    assert!(
        err.contains(&format!("{}: no optical-flow velocities", log.display())),
        "{err}"
    );
    let tmp = std::env::temp_dir().join(format!("insuwb-no-flow-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    let manifest = tmp.join("no-flow.csv");
    let row = format!("{},{},0.105", log.display(), anchors.display());
    std::fs::write(&manifest, format!("file,anchors,uwb_ls_ref_m\n{row}\n")).unwrap();
    let err = refused(&["--flights".as_ref(), manifest.as_os_str()]);
    let _ = std::fs::remove_dir_all(&tmp);
    assert!(
        err.contains(&format!(
            "{}: no flight's log holds optical-flow records",
            manifest.display()
        )),
        "{err}"
    );
}
