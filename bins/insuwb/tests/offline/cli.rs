//! The command line as a user meets it: the paper's claims on its own
//! simulation, the consistency check, the output contract of `--json`, and
//! bad input refused with a clear message and a non-zero exit.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use crate::common;

use std::path::PathBuf;
use std::process::{Command, Output};

fn insuwb(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_insuwb"))
        .args(args)
        .output()
        .unwrap()
}

fn json(out: &Output) -> serde_json::Value {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "stdout is not exactly one JSON object ({e}): {}",
            String::from_utf8_lossy(&out.stdout)
        )
    })
}

fn num(v: &serde_json::Value, sol: &str, key: &str) -> f64 {
    v[sol][key]
        .as_f64()
        .unwrap_or_else(|| panic!("{sol}.{key} missing in {v}"))
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("insuwb-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn paper_3_4_claims_hold_over_20_runs() {
    let v = json(&insuwb(&[
        "eval",
        "--scenario",
        "paper-3.4",
        "--runs",
        "20",
        "--json",
    ]));
    for sol in ["uwb", "ins", "kf", "shaf", "stf", "iakf"] {
        for key in [
            "rmse_east",
            "rmse_north",
            "rmse_mean",
            "rmse_horizontal",
            "max_dist",
        ] {
            assert!(num(&v, sol, key).is_finite(), "{sol}.{key}");
        }
    }
    let iakf = num(&v, "iakf", "rmse_mean");
    // The paper: IAKF 0.374 of UWB-only; we must reach at most 0.40.
    assert!(iakf <= 0.40 * num(&v, "uwb", "rmse_mean"), "{v}");
    for other in ["kf", "shaf", "stf"] {
        assert!(
            iakf < num(&v, other, "rmse_mean"),
            "IAKF rmse_mean not below {other}: {v}"
        );
        assert!(
            num(&v, "iakf", "max_dist") < num(&v, other, "max_dist"),
            "IAKF max_dist not below {other}: {v}"
        );
    }
    assert!(num(&v, "iakf", "max_dist") <= 0.30, "{v}");
    // The UWB row was calibrated to Table 1 (0.0650 E, 0.0723 N).
    assert!(
        (0.055..=0.080).contains(&num(&v, "uwb", "rmse_east")),
        "{v}"
    );
    assert!(
        (0.060..=0.085).contains(&num(&v, "uwb", "rmse_north")),
        "{v}"
    );
}

#[test]
fn kf_is_consistent_on_data_from_its_own_model() {
    let v = json(&insuwb(&[
        "eval",
        "--scenario",
        "model-true",
        "--runs",
        "20",
        "--filters",
        "kf",
        "--json",
    ]));
    let frac = num(&v, "kf", "nees_in_band_fraction");
    assert!(
        frac >= 0.9,
        "NEES inside its 95 % band at {frac} of the epochs: {v}"
    );
    assert!(num(&v, "kf", "nis_in_band_fraction") >= 0.9, "{v}");
    let band = &v["kf"]["nees_band"];
    assert!(
        (band[0].as_f64().unwrap() - 2.86).abs() < 0.02
            && (band[1].as_f64().unwrap() - 5.33).abs() < 0.02
    );
}

/// `insuwb sim` of paper-4.4-dynamic with `seed` into `dir/s.iulog`.
fn simulated_log(dir: &std::path::Path, seed: &str) -> PathBuf {
    let log = dir.join("s.iulog");
    let out = insuwb(&[
        "sim",
        "--scenario",
        "paper-4.4-dynamic",
        "--seed",
        seed,
        "--out",
        log.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    log
}

#[test]
fn a_simulated_log_evaluates_like_its_scenario_and_a_torn_log_still_reads() {
    let d = tmp("sim");
    let log = simulated_log(&d, "2");
    let from_log = json(&insuwb(&[
        "eval",
        log.to_str().unwrap(),
        "--filters",
        "iakf",
        "--json",
    ]));
    let from_sc = json(&insuwb(&[
        "eval",
        "--scenario",
        "paper-4.4-dynamic",
        "--seed",
        "2",
        "--filters",
        "iakf",
        "--json",
    ]));
    let a = num(&from_log, "iakf", "rmse_horizontal");
    let b = num(&from_sc, "iakf", "rmse_horizontal");
    assert!((a - b).abs() < 1e-9, "log {a} vs scenario {b}");

    // Cut the log in the middle of a record: read up to the last good one, with a warning.
    let bytes = std::fs::read(&log).unwrap();
    let cut = d.join("cut.iulog");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3 + 5]).unwrap();
    let out = insuwb(&["eval", cut.to_str().unwrap(), "--filters", "iakf", "--json"]);
    let v = json(&out);
    assert!(num(&v, "iakf", "rmse_horizontal").is_finite());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("torn tail at byte"), "{err}");
    let _ = std::fs::remove_dir_all(&d);
}

/// A log of fused states and no sensor records (what `insuwb fleet
/// record` writes of a robot, a folder of segments), here the IAKF's
/// fused states of a simulated flight with its ground truth: `insuwb eval`
/// reports its recorded track, with the figures `eval` gives the IAKF on
/// the sensor records; without the truth, its states and rate and why
/// there is no accuracy; a filter asked for is refused with the reason.
#[test]
fn a_log_of_fused_states_evaluates_as_its_recorded_track() {
    use insuwb_log::{Metadata, Record, SegmentConfig, SegmentWriter};
    let d = tmp("recorded");
    let log = simulated_log(&d, "2");
    let run = common::offline_run(&log, insuwb_msg::FilterKind::Iakf);
    let truth: Vec<Record> = insuwb_log::read_all(&log)
        .unwrap()
        .0
        .into_iter()
        .filter(|r| matches!(r, Record::Truth(_)))
        .collect();
    let write = |dir: &std::path::Path, with_truth: bool| {
        let meta = Metadata::new("test").with("robot", "r1");
        let mut w = SegmentWriter::open(dir, meta, SegmentConfig::default(), 0).unwrap();
        for s in &run.fused {
            w.append(&Record::Fused(*s), 0).unwrap();
        }
        for t in truth.iter().filter(|_| with_truth) {
            w.append(t, 0).unwrap();
        }
        w.finish().unwrap();
    };
    let (with, without) = (d.join("with"), d.join("without"));
    write(&with, true);
    write(&without, false);
    let rec = json(&insuwb(&["eval", with.to_str().unwrap(), "--json"]));
    let sensors = json(&insuwb(&[
        "eval",
        log.to_str().unwrap(),
        "--filters",
        "iakf",
        "--json",
    ]));
    let (a, b) = (
        num(&rec, "recorded", "rmse_horizontal"),
        num(&sensors, "iakf", "rmse_horizontal"),
    );
    eprintln!("recorded track {a} m, the IAKF on the sensor records {b} m");
    // The IAKF's states at the fix epochs are the track: the same figures.
    assert!((a - b).abs() <= 1e-9, "recorded {a} vs iakf {b}");
    let states = num(&rec, "recorded", "states");
    assert!(states > 100.0 && states <= run.fused.len() as f64, "{rec}");
    let hz = num(&rec, "recorded", "rate_hz");
    assert!((9.0..=11.0).contains(&hz), "{hz} Hz");

    let out = insuwb(&["eval", without.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("the recorded track") && text.contains("no ground truth"),
        "{text}"
    );
    let v = json(&insuwb(&["eval", without.to_str().unwrap(), "--json"]));
    assert_eq!(num(&v, "recorded", "states"), states);
    assert!(v["recorded"].get("rmse_horizontal").is_none(), "{v}");
    let out = insuwb(&["eval", without.to_str().unwrap(), "--filters", "kf"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("no IMU and UWB records") && err.contains("--filters"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn bad_input_is_refused_with_a_clear_message() {
    let d = tmp("bad");
    let missing = d.join("nope.iulog");
    let out = insuwb(&["eval", missing.to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("nope.iulog"));

    let empty = d.join("empty.iulog");
    std::fs::write(&empty, b"").unwrap();
    let out = insuwb(&["eval", empty.to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("empty"));

    let text = d.join("notes.txt");
    std::fs::write(&text, b"hello, not a log").unwrap();
    let out = insuwb(&["eval", text.to_str().unwrap()]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("not an insuwb log"));

    // A scenario with two anchors, and one with a negative rate: refused, key named.
    let base = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../config/scenarios/paper-3.4.toml"
    ))
    .unwrap();
    let two = base.replacen(
        "[[sim.uwb.anchors]]\nid = 2",
        "[[sim.uwb.anchors_removed]]\nid = 2",
        1,
    );
    let bad_rate = base.replacen("imu_rate_hz = 100.0", "imu_rate_hz = -100.0", 1);
    let nan = base.replacen("duration_s = 15.0", "duration_s = nan", 1);
    for (name, text, key) in [
        ("rate.toml", bad_rate, "imu_rate_hz"),
        ("nan.toml", nan, "duration_s"),
        ("two.toml", two, "anchors"),
    ] {
        let p = d.join(name);
        std::fs::write(&p, text).unwrap();
        let out = insuwb(&["eval", "--scenario", p.to_str().unwrap()]);
        assert!(!out.status.success(), "{name} accepted");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(name) && err.contains(key), "{name}: {err}");
    }
    let out = insuwb(&["eval", "--scenario", "paper-3.4", "--filters", "kf,xyz"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("xyz"));
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn a_robot_config_naming_an_unknown_stage_or_filter_is_refused_before_anything_starts() {
    let d = tmp("robot");
    for (name, text, key) in [
        ("stage.toml", "stages = [\"imu\", \"gps\"]\n", "stages"),
        (
            "filter.toml",
            "[fusion]\nfilter = \"ukf\"\n",
            "fusion.filter",
        ),
        (
            "source.toml",
            "[sources]\nimu = \"serial:/dev/null\"\n",
            "sources.imu",
        ),
        (
            "replay.toml",
            "[sources]\nimu = \"replay:missing.iulog\"\n",
            "sources.imu",
        ),
    ] {
        let p = d.join(name);
        let group = format!(
            "[group]\nprefix = \"iubad_\"\nrun_dir = \"{}\"\n",
            d.display()
        );
        // Top-level keys must come before the first table.
        let body = if text.starts_with('[') {
            format!("{group}{text}")
        } else {
            format!("{text}{group}")
        };
        std::fs::write(&p, body).unwrap();
        let out = insuwb(&["launch", p.to_str().unwrap(), "--duration", "1"]);
        assert!(!out.status.success(), "{name} accepted");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(name) && err.contains(key), "{name}: {err}");
    }
    let _ = std::fs::remove_dir_all(&d);
}

/// RMS of the horizontal error of one solution's in-segment rows of a
/// `--tracks` file, and the number of those rows.
fn tracks_rmse(csv: &str, solution: &str) -> (f64, usize) {
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some(
            "solution,t_ns,east_m,north_m,truth_east_m,truth_north_m,err_east_m,err_north_m,in_segment,\
             vel_east_mps,vel_north_mps,truth_vel_east_mps,truth_vel_north_mps,yaw_rad,truth_yaw_rad,\
             up_m,truth_up_m"
        )
    );
    let (mut sum, mut n) = (0.0, 0usize);
    for l in lines {
        let f: Vec<&str> = l.split(',').collect();
        assert_eq!(f.len(), 17, "{l}");
        // The filters carry a velocity and a heading, the fix and the INS
        // track none.
        let plain = f[0] == "uwb" || f[0] == "ins";
        assert_eq!(f[9].is_empty(), plain, "{l}");
        assert_eq!(f[13].is_empty(), plain, "{l}");
        if f[0] != solution || f[8] != "1" || f[6].is_empty() {
            continue;
        }
        let (e, nn): (f64, f64) = (f[6].parse().unwrap(), f[7].parse().unwrap());
        sum += e * e + nn * nn;
        n += 1;
    }
    ((sum / n.max(1) as f64).sqrt(), n)
}

#[test]
fn tracks_hold_the_evaluated_errors_at_fix_epochs_and_at_truth_times() {
    let d = tmp("tracks");
    let log = simulated_log(&d, "3");
    let truth_cfg = d.join("truth.toml");
    std::fs::write(&truth_cfg, "[eval]\nepochs = \"truth\"\n").unwrap();
    let mut epochs = Vec::new();
    for cfg in [None, Some(&truth_cfg)] {
        let tracks = d.join("t.csv");
        let mut args = vec![
            "eval",
            log.to_str().unwrap(),
            "--filters",
            "kf",
            "--json",
            "--tracks",
            tracks.to_str().unwrap(),
        ];
        if let Some(c) = cfg {
            args.extend(["--config", c.to_str().unwrap()]);
        }
        let v = json(&insuwb(&args));
        let csv = std::fs::read_to_string(&tracks).unwrap();
        for sol in ["uwb", "kf"] {
            let (rmse, n) = tracks_rmse(&csv, sol);
            let want = num(&v, sol, "rmse_horizontal");
            assert!((rmse - want).abs() < 1e-5, "{sol}: tracks {rmse} vs {want}");
            assert_eq!(n as f64, num(&v, sol, "epochs"), "{sol}");
        }
        epochs.push(num(&v, "uwb", "epochs"));
    }
    // The truth (100 Hz in the simulation) is denser than the fixes (10 Hz).
    assert!(epochs[1] > 5.0 * epochs[0], "{epochs:?}");
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn a_program_that_is_not_built_is_named_with_the_command_that_builds_it() {
    // The `insuwb` executable alone, as `cargo build --release` of a part
    // of the workspace may leave it: no station, no stage beside it.
    let d = std::env::temp_dir().join(format!("insuwb-alone-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    let alone = d.join("insuwb");
    std::fs::copy(env!("CARGO_BIN_EXE_insuwb"), &alone).unwrap();
    for (args, program) in [
        (
            &["fleet", "--listen", "tcp/127.0.0.1:7447"][..],
            "insuwb-station",
        ),
        (&["bench", "fleet", "--robots", "1"], "insuwb-station"),
        (&["demo", "--duration", "1"], "insuwb-stage-"),
    ] {
        let out = Command::new(&alone).args(args).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?}: {stderr}");
        assert!(
            stderr.contains(&format!("cargo build --release -p {program}")),
            "{args:?}: {stderr}"
        );
    }
    let _ = std::fs::remove_dir_all(&d);
}

/// A scenario's simulated wheel odometry aids the filters only with
/// `--aiding odometry` (without it the figures are those of IMU and UWB
/// alone); a scenario without `[sim.odometry]`, a log, and a bad
/// `--window` are refused with the reason; `--window` evaluates inside a
/// UWB outage, where there is no fix epoch.
#[test]
fn a_scenario_s_odometry_aids_only_when_asked() {
    let run = |extra: &[&str]| {
        let mut args = vec![
            "eval",
            "--scenario",
            "ground-outage",
            "--runs",
            "2",
            "--filters",
            "kf",
            "--json",
        ];
        args.extend_from_slice(extra);
        json(&insuwb(&args))
    };
    let alone = run(&[]);
    assert_eq!(alone, run(&["--aiding", "none"]));
    let aided = run(&["--aiding", "odometry"]);
    let (a, b) = (
        num(&alone, "kf", "rmse_horizontal"),
        num(&aided, "kf", "rmse_horizontal"),
    );
    assert!(b < a, "aided {b} against {a}");
    // Through the outage: the INS alone and the filter's coasting states.
    let window = run(&["--window", "30,40", "--aiding", "odometry"]);
    assert!(num(&window, "kf", "epochs") >= 2000.0, "{window}");
    assert!(num(&window, "kf", "rmse_horizontal") < 0.1, "{window}");

    let err = |args: &[&str]| {
        let out = insuwb(args);
        assert!(!out.status.success(), "{args:?} accepted");
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let e = err(&["eval", "--scenario", "paper-3.4", "--aiding", "odometry"]);
    assert!(e.contains("[sim.odometry]"), "{e}");
    let e = err(&["eval", "--scenario", "ground-outage", "--window", "40,30"]);
    assert!(e.contains("--window"), "{e}");
    let d = tmp("odometry");
    let log = simulated_log(&d, "1");
    let e = err(&["eval", log.to_str().unwrap(), "--aiding", "odometry"]);
    assert!(e.contains("--aiding odometry"), "{e}");
    let e = err(&["eval", log.to_str().unwrap(), "--window", "1,2"]);
    assert!(e.contains("--scenario"), "{e}");
    let _ = std::fs::remove_dir_all(&d);
}
