//! Crazyflie logs cut short (a battery dying mid-flight) and garbled, through
//! the real `insuwb` process: a cut log is read up to its last whole record
//! with one warning naming the byte where it stopped, and an error names
//! each cause once. Generated logs; one real flight when the UTIL data is
//! present.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Output;

use common::{run, succeeded};
use insuwb_log::Record;

const ACC: u16 = 1;
const GYRO: u16 = 2;
const TDOA: u16 = 3;
const POSE: u16 = 4;

/// The event table of a UTIL log (the variables the importer reads).
const EVENTS: [(u16, &str, &[&str]); 4] = [
    (
        ACC,
        "estAcceleration",
        &["acc.x(f)", "acc.y(f)", "acc.z(f)"],
    ),
    (
        GYRO,
        "estGyroscope",
        &["gyro.x(f)", "gyro.y(f)", "gyro.z(f)"],
    ),
    (TDOA, "estTDOA", &["idA(B)", "idB(B)", "distanceDiff(f)"]),
    (
        POSE,
        "estPose",
        &[
            "locSrv.x(f)",
            "locSrv.y(f)",
            "locSrv.z(f)",
            "locSrv.qx(f)",
            "locSrv.qy(f)",
            "locSrv.qz(f)",
            "locSrv.qw(f)",
        ],
    ),
];

/// A version-2 Crazyflie log: its bytes (CRC included) and where each
/// record starts, then where the CRC starts.
struct CfLog {
    bytes: Vec<u8>,
    bounds: Vec<usize>,
}

fn f32s(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// 1 ms steps of accelerometer, gyroscope and ground truth, a TDOA every
/// other step: `steps` steps.
fn records(steps: u64) -> Vec<(u16, u64, Vec<u8>)> {
    let mut r = Vec::new();
    for k in 0..steps {
        let t = 1_000 + 1_000 * k;
        r.push((ACC, t, f32s(&[0.01, 0.0, 1.0])));
        r.push((GYRO, t + 15, f32s(&[0.5, -0.5, 0.0])));
        if k % 2 == 0 {
            let mut p = vec![(k % 3) as u8, ((k + 1) % 3) as u8];
            p.extend_from_slice(&0.25f32.to_le_bytes());
            r.push((TDOA, t + 300, p));
        }
        let x = 0.001 * k as f32;
        r.push((POSE, t + 500, f32s(&[x, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0])));
    }
    r
}

/// CRC-32 (zlib polynomial), bit by bit: the test needs no dependency.
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &byte in bytes {
        crc ^= u32::from(byte);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// Builds the log of `records`, with a correct CRC-32.
fn build(records: &[(u16, u64, Vec<u8>)]) -> CfLog {
    let mut b = vec![0xBC];
    b.extend_from_slice(&2u16.to_le_bytes());
    b.extend_from_slice(&(EVENTS.len() as u16).to_le_bytes());
    for (id, name, vars) in EVENTS {
        b.extend_from_slice(&id.to_le_bytes());
        b.extend_from_slice(name.as_bytes());
        b.push(0);
        b.extend_from_slice(&(vars.len() as u16).to_le_bytes());
        for v in vars {
            b.extend_from_slice(v.as_bytes());
            b.push(0);
        }
    }
    let mut bounds = Vec::new();
    for (id, t, payload) in records {
        bounds.push(b.len());
        b.extend_from_slice(&id.to_le_bytes());
        b.extend_from_slice(&t.to_le_bytes());
        b.extend_from_slice(payload);
    }
    bounds.push(b.len());
    let crc = crc32(&b);
    b.extend_from_slice(&crc.to_le_bytes());
    CfLog { bytes: b, bounds }
}

/// A fresh folder for one test, with the anchor file.
fn folder(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("insuwb-cut-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    std::fs::write(
        d.join("anchors.txt"),
        "an0_p,0,0,0\nan1_p,4,0,0\nan2_p,0,4,1\n",
    )
    .unwrap();
    d
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `insuwb import util LOG` into `out` (removed first), with `extra` arguments.
fn import(dir: &Path, log: &Path, out: &str, extra: &[&str]) -> (Output, PathBuf) {
    let out = dir.join(out);
    let _ = std::fs::remove_file(&out);
    let anchors = dir.join("anchors.txt");
    let mut args = vec![
        "import",
        "util",
        s(log),
        "--anchors",
        s(&anchors),
        "--out",
        s(&out),
    ];
    args.extend_from_slice(extra);
    (run(&args), out)
}

/// The samples of a project log (its metadata names the source file: left out).
fn samples(log: &Path) -> Vec<Record> {
    let (records, tail, _) = insuwb_log::read_all(log).unwrap();
    assert!(tail.is_none());
    records
}

/// Standard error's warning lines.
fn warnings(out: &Output) -> Vec<String> {
    String::from_utf8_lossy(&out.stderr)
        .lines()
        .filter(|l| l.contains("WARN"))
        .map(str::to_owned)
        .collect()
}

#[test]
fn a_cut_log_is_read_up_to_its_last_whole_record_with_one_warning() {
    let dir = folder("generated");
    let recs = records(400);
    let log = build(&recs);
    let b = &log.bounds;
    let crc_at = log.bytes.len() - 4;
    let mid = b.len() / 2;
    // (cut, records whole before it, where reading stops, what the warning says)
    let cuts = [
        (
            b[mid] + 7,
            mid,
            b[mid],
            "the file ends inside a record of event",
        ),
        (b[mid], mid, b[mid], "without its CRC-32"),
        (
            crc_at + 2,
            recs.len(),
            crc_at,
            "inside the trailing CRC-32: 2 of its 4 bytes",
        ),
        (crc_at, recs.len(), crc_at, "without its CRC-32"),
    ];
    for (cut, whole, stop, what) in cuts {
        let path = dir.join(format!("cut-{cut}"));
        std::fs::write(&path, &log.bytes[..cut]).unwrap();
        // The same records, whole, with their CRC: what must come out.
        let reference = dir.join(format!("whole-{cut}"));
        std::fs::write(&reference, build(&recs[..whole]).bytes).unwrap();
        let (want, want_out) = import(&dir, &reference, "whole.iulog", &[]);
        succeeded(&want);
        assert!(warnings(&want).is_empty(), "{:?}", warnings(&want));
        for extra in [&[][..], &["--ignore-crc"][..]] {
            let (got, got_out) = import(&dir, &path, "cut.iulog", extra);
            succeeded(&got);
            let warned = warnings(&got);
            assert_eq!(warned.len(), 1, "cut at {cut} {extra:?}: {warned:?}");
            let w = &warned[0];
            assert!(
                w.contains(&format!("cut short at byte {stop}: ")),
                "cut at {cut}: {w}"
            );
            assert!(w.contains(what), "cut at {cut}: {w}");
            assert!(
                w.contains(&format!("using the {whole} records before it")),
                "cut at {cut}: {w}"
            );
            assert_eq!(samples(&got_out), samples(&want_out), "cut at {cut}");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_crc_mismatch_is_refused_naming_the_cause_once() {
    let dir = folder("crc");
    let mut log = build(&records(100));
    let at = log.bounds[150] + 5; // a timestamp byte
    log.bytes[at] ^= 0x01;
    let path = dir.join("garbled");
    std::fs::write(&path, &log.bytes).unwrap();
    let anchors = dir.join("anchors.txt");
    let out = run(&["eval", s(&path), "--anchors", s(&anchors)]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    let line = err
        .lines()
        .find(|l| l.starts_with("error: "))
        .unwrap_or_else(|| panic!("no error line in {err}"));
    assert!(
        line.starts_with(&format!(
            "error: {}: CRC mismatch: stored 0x",
            path.display()
        )),
        "{line}"
    );
    assert_eq!(line.matches("CRC mismatch").count(), 1, "{line}");
    assert_eq!(line.matches(s(&path)).count(), 1, "{line}");
    // --ignore-crc reads it, with one warning.
    let (read, _) = import(&dir, &path, "out.iulog", &["--ignore-crc"]);
    succeeded(&read);
    let warned = warnings(&read);
    assert_eq!(warned.len(), 1, "{warned:?}");
    assert_eq!(warned[0].matches("CRC mismatch").count(), 1, "{warned:?}");
    assert!(warned[0].contains("--ignore-crc"), "{warned:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_missing_file_is_named_with_its_cause_once() {
    let dir = folder("missing");
    let log = dir.join("log");
    std::fs::write(&log, build(&records(10)).bytes).unwrap();
    let anchors = dir.join("anchors.txt");
    let absent = dir.join("absent.txt");
    let absent_toml = dir.join("absent.toml");
    for (args, name) in [
        (vec!["eval", s(&log), "--anchors", s(&absent)], "absent.txt"),
        (
            vec!["eval", s(&absent), "--anchors", s(&anchors)],
            "absent.txt",
        ),
        (vec!["log", "info", s(&absent)], "absent.txt"),
        (
            vec![
                "eval",
                s(&log),
                "--anchors",
                s(&anchors),
                "--config",
                s(&absent_toml),
            ],
            "absent.toml",
        ),
    ] {
        let out = run(&args);
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        let line = err.lines().find(|l| l.starts_with("error: ")).unwrap();
        assert_eq!(line.matches("No such file").count(), 1, "{args:?}: {line}");
        assert_eq!(line.matches(name).count(), 1, "{args:?}: {line}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_real_flight_cut_mid_record_keeps_every_whole_record() {
    let Some(util) = common::util_data_dir("cfBolt-log00") else {
        return;
    };
    let dir = folder("real");
    std::fs::copy(util.join("anchors-const3.txt"), dir.join("anchors.txt")).unwrap();
    let bytes = std::fs::read(util.join("cfBolt-log00")).unwrap();
    // Cut 5 bytes past the middle: somewhere inside a record.
    let path = dir.join("cut");
    std::fs::write(&path, &bytes[..bytes.len() / 2 + 5]).unwrap();
    let (out, _) = import(&dir, &path, "out.iulog", &[]);
    succeeded(&out);
    let warned = warnings(&out);
    assert_eq!(warned.len(), 1, "{warned:?}");
    let w = &warned[0];
    let at: usize = w
        .split("cut short at byte ")
        .nth(1)
        .and_then(|r| r.split(':').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no byte offset in {w}"));
    assert!(
        at <= bytes.len() / 2 + 5 && at + 64 > bytes.len() / 2,
        "{w}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
