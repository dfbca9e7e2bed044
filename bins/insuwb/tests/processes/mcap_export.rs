//! `insuwb log export LOG --mcap OUT.mcap` against MCAP and ROS 2 readers
//! nobody here wrote: a group runs the simulated `nlos-long` scenario with
//! its logger (every topic recorded, in a run directory of segments), the
//! real binary exports the run directory, and `tests/mcap/check_mcap.py`
//! checks the file with the PyPI `mcap` reader and `mcap-ros2-support`
//! decoder (profile, encodings, every message decoded, counts per topic
//! equal to the log's, fused positions to 1e-9 m) and with `rosbags`
//! (opened as a bag, types registered from the file's `ros2msg` schemas,
//! odometry, IMU and `insuwb_msgs/msg/UwbFix` decoded and compared with the
//! log). A copy of a segment cut mid-record exports its whole records and
//! says where it stopped. No stage of the simulated group publishes body
//! velocities or heights, so a log written here carries them: exported on
//! `/insuwb/body_vel` and `/insuwb/height` and decoded by `rosbags` as
//! `insuwb_msgs/msg/BodyVelocity` and `insuwb_msgs/msg/Height`, each equal
//! to its record.
//!
//! The Python environment is `target/pyenv` (or `INSUWB_PYENV`), installed
//! by `.ci/run`; where it is missing the test says so and skips, unless
//! `CI` is set: then it fails. Every wait is bounded; the test starts
//! processes, so it holds the one-at-a-time lock.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::Duration;

use common::{insuwb, one_at_a_time, run_bounded, skip_or_fail, wait_bounded, Group};
use insuwb_log::{LogReader, LogWriter, Metadata, Record};
use insuwb_msg::{BodyVelocity, Header, Height, ImuSample};

const SIM: &str = "imu = \"sim\"\nuwb = \"sim\"\nscenario = \"nlos-long\"\nseed = 1";
/// Seconds the group runs.
const GROUP_S: f64 = 6.0;
/// Bound of every wait.
const BOUND: Duration = Duration::from_secs(120);
const PACKAGES: &str = "mcap==1.6.0 mcap-ros2-support==0.6.0 rosbags==0.11.9";

/// The Python of the virtual environment `.ci/run` makes (`INSUWB_PYENV`
/// or `<workspace>/target/pyenv`), when it has the MCAP packages.
fn python() -> Option<PathBuf> {
    common::pyenv_python("mcap, mcap_ros2, rosbags")
}

fn script() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/mcap/check_mcap.py")
}

fn os(s: &str) -> &std::ffi::OsStr {
    std::ffi::OsStr::new(s)
}

fn insuwb_run(args: &[&std::ffi::OsStr]) -> Output {
    run_bounded(Command::new(insuwb()).args(args), BOUND)
}

fn ok(out: &Output, what: &str) -> String {
    assert!(
        out.status.success(),
        "{what} failed:\n{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `insuwb log export LOG --mcap OUT`: (stdout, stderr), after checking it exited 0.
fn export(log: &Path, mcap: &Path) -> (String, String) {
    let out = insuwb_run(&[
        os("log"),
        os("export"),
        log.as_os_str(),
        os("--mcap"),
        mcap.as_os_str(),
    ]);
    let stdout = ok(&out, "insuwb log export");
    (stdout, String::from_utf8_lossy(&out.stderr).into_owned())
}

/// `insuwb log cat LOG --csv [--topic T]` into `file` (a file, not a pipe:
/// the dump is larger than a pipe's buffer); returns its lines.
fn cat_csv(log: &Path, topic: Option<&str>, file: &Path) -> Vec<String> {
    let mut cmd = Command::new(insuwb());
    cmd.args([os("log"), os("cat"), log.as_os_str(), os("--csv")]);
    if let Some(t) = topic {
        cmd.args([os("--topic"), os(t)]);
    }
    let mut child = cmd
        .stdin(Stdio::null())
        .stdout(std::fs::File::create(file).unwrap())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    wait_bounded(&mut child, "insuwb log cat", BOUND);
    assert!(
        child.wait().unwrap().success(),
        "insuwb log cat {}",
        log.display()
    );
    std::fs::read_to_string(file)
        .unwrap()
        .lines()
        .map(str::to_owned)
        .collect()
}

/// Runs the checker on `mcap` against the CSV dumps of `log`, in `dir`.
fn check(py: &Path, dir: &Path, name: &str, log: &Path, mcap: &Path, partial: bool) -> Vec<String> {
    let all = dir.join(format!("{name}-all.csv"));
    let fused = dir.join(format!("{name}-fused.csv"));
    let lines = cat_csv(log, None, &all);
    cat_csv(log, Some("fused"), &fused);
    let mut cmd = Command::new(py);
    cmd.arg(script()).arg(mcap).arg(&all).arg(&fused);
    if partial {
        cmd.arg("--partial");
    }
    let out = run_bounded(&mut cmd, BOUND);
    let stdout = String::from_utf8_lossy(&out.stdout);
    eprintln!(
        "check_mcap.py {name}:\n{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        out.status.success() && stdout.trim_end().ends_with("OK"),
        "check_mcap.py failed on {name}"
    );
    lines
}

/// Record counts per topic that `insuwb log info` prints, summed over the files.
fn info_counts(log: &Path) -> std::collections::BTreeMap<String, u64> {
    let text = ok(
        &insuwb_run(&[os("log"), os("info"), log.as_os_str()]),
        "insuwb log info",
    );
    let mut counts = std::collections::BTreeMap::new();
    for line in text.lines() {
        let w: Vec<&str> = line.split_whitespace().collect();
        if let [topic, n, "records"] = w[..] {
            *counts.entry(topic.to_owned()).or_default() += n.parse::<u64>().unwrap();
        }
    }
    counts
}

#[test]
fn a_group_log_exports_to_mcap_that_foreign_readers_decode() {
    let _one = one_at_a_time();
    let Some(py) = python() else {
        skip_or_fail(&format!(
            "no Python environment with mcap, mcap-ros2-support and rosbags (target/pyenv: run .ci/run, or python3 -m venv target/pyenv && target/pyenv/bin/pip install {PACKAGES})"
        ));
        return;
    };
    let g = Group::new("mcap", SIM, "iakf");
    g.launch(GROUP_S, &[]);
    let log = g.log_dir();

    // The whole run directory.
    let mcap = g.dir.join("run.mcap");
    let (stdout, stderr) = export(&log, &mcap);
    eprintln!("{stdout}{stderr}");
    assert!(
        !stderr.contains("warning"),
        "an intact log warned: {stderr}"
    );
    assert!(stdout.contains("/insuwb/odom"), "{stdout}");
    let lines = check(&py, &g.dir, "run", &log, &mcap, false);
    // The CSV dump the checker compared against holds what `log info` counts.
    let mut from_csv = std::collections::BTreeMap::new();
    for l in &lines {
        let topic = l.split(',').next().unwrap().to_owned();
        *from_csv.entry(topic).or_insert(0u64) += 1;
    }
    assert_eq!(from_csv, info_counts(&log));

    // A copy of the first segment, cut inside a record halfway through.
    let seg = insuwb_log::list_segments(&log).unwrap()[0].path.clone();
    let mut r = LogReader::open(&seg).unwrap();
    let mut ends = Vec::new();
    while let Some(rec) = r.next() {
        rec.unwrap();
        ends.push(r.offset());
    }
    assert!(ends.len() > 100, "{} records", ends.len());
    let whole = ends.len() / 2;
    let good = ends[whole - 1];
    let cut_at = good + 8 + (ends[whole] - good - 8) / 2;
    let bytes = std::fs::read(&seg).unwrap();
    let cut = g.dir.join("cut.iulog");
    std::fs::write(&cut, &bytes[..cut_at as usize]).unwrap();
    let cut_mcap = g.dir.join("cut.mcap");
    let (_, stderr) = export(&cut, &cut_mcap);
    let warning: Vec<&str> = stderr.lines().filter(|l| l.contains("warning")).collect();
    assert_eq!(warning.len(), 1, "{stderr}");
    for want in [
        cut.display().to_string(),
        format!("torn tail at byte {good}"),
        format!("exported its {whole} whole records"),
    ] {
        assert!(warning[0].contains(&want), "{want:?} not in {stderr}");
    }
    let cut_lines = check(&py, &g.dir, "cut", &cut, &cut_mcap, true);
    let seg_lines = cat_csv(&seg, None, &g.dir.join("seg.csv"));
    assert_eq!(cut_lines.len(), whole);
    assert_eq!(cut_lines[..], seg_lines[..whole]);
}

#[test]
fn body_velocities_and_heights_export_to_mcap_that_foreign_readers_decode() {
    let Some(py) = python() else {
        skip_or_fail(&format!(
            "no Python environment with mcap, mcap-ros2-support and rosbags (target/pyenv: run .ci/run, or python3 -m venv target/pyenv && target/pyenv/bin/pip install {PACKAGES})"
        ));
        return;
    };
    let dir = std::env::temp_dir().join(format!("insuwb-mcap-vel-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let log = dir.join("vel.iulog");
    let mut w = LogWriter::create(&log, &Metadata::new("body velocities"), 0).unwrap();
    const N: u64 = 40;
    for k in 0..N {
        let t = 1_000_000_000 + k * 10_000_000;
        w.append(&Record::Imu(ImuSample {
            header: Header::new(k, t),
            accel_mps2: [0.0, 0.0, 9.81],
            gyro_rps: [0.0, 0.0, 0.1],
        }))
        .unwrap();
        let (source, sigma_mps, range_mm) = if k % 2 == 0 {
            (BodyVelocity::SOURCE_ODOMETRY, [0.02, 0.0, 0.0], 0)
        } else {
            (
                BodyVelocity::SOURCE_FLOW,
                [0.05, 0.05, 0.0],
                1500 + k as u32,
            )
        };
        w.append(&Record::BodyVel(BodyVelocity {
            header: Header::new(k, t + 5_000_000),
            vel_mps: [0.5 + 0.01 * k as f64, -0.25, 0.0],
            sigma_mps,
            source,
            range_mm,
        }))
        .unwrap();
        // The flow deck's range finder beside its flow.
        if source == BodyVelocity::SOURCE_FLOW {
            w.append(&Record::Height(Height {
                header: Header::new(k / 2, t + 6_000_000),
                range_m: f64::from(range_mm) * 1e-3,
                source: Height::SOURCE_RANGE_FINDER,
            }))
            .unwrap();
        }
    }
    w.finish().unwrap();
    let mcap = dir.join("vel.mcap");
    let (stdout, stderr) = export(&log, &mcap);
    assert!(!stderr.contains("warning"), "{stderr}");
    assert!(
        stdout
            .lines()
            .any(|l| l.contains("/insuwb/body_vel") && l.ends_with(&format!(" {N} messages"))),
        "{stdout}"
    );
    assert!(
        stdout
            .lines()
            .any(|l| l.contains("/insuwb/height") && l.ends_with(&format!(" {} messages", N / 2))),
        "{stdout}"
    );
    assert_eq!(info_counts(&log).get("body_vel"), Some(&N));
    assert_eq!(info_counts(&log).get("height"), Some(&(N / 2)));
    let lines = check(&py, &dir, "vel", &log, &mcap, true);
    assert_eq!(
        lines.iter().filter(|l| l.starts_with("body_vel,")).count() as u64,
        N
    );
    assert_eq!(
        lines.iter().filter(|l| l.starts_with("height,")).count() as u64,
        N / 2
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_input_is_an_error_naming_the_file() {
    let dir = std::env::temp_dir().join(format!("insuwb-mcap-bad-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("x.mcap");
    let missing = dir.join("missing.iulog");
    let text = dir.join("notes.txt");
    std::fs::write(&text, "not a log at all").unwrap();
    for (input, why) in [(&missing, "No such file"), (&text, "not an insuwb log")] {
        let r = insuwb_run(&[
            os("log"),
            os("export"),
            input.as_os_str(),
            os("--mcap"),
            out.as_os_str(),
        ]);
        let stderr = String::from_utf8_lossy(&r.stderr);
        assert!(!r.status.success(), "{stderr}");
        let name = input.file_name().unwrap().to_string_lossy();
        assert!(
            stderr.contains(name.as_ref()) && stderr.contains(why),
            "{stderr}"
        );
        assert!(!out.exists());
    }
    let _ = std::fs::remove_dir_all(&dir);
}
