//! A robot speaks only for itself: a station (`insuwb fleet --config
//! station.toml --json`) listening on `tls/127.0.0.1:PORT` with mutual TLS
//! and `[station.identity] robots = ["r1", "r2"]`, and a client on the
//! PyPI `eclipse-zenoh` package (`bins/insuwb/tests/zenoh/impostor.py`, no
//! insuwb code) that puts well-formed health reports with the
//! certificates of `tools/fleet_certs.sh`:
//!
//! - with r1's certificate under `insuwb/r2/health` (60 puts, blocking
//!   congestion control): every put is refused at the station's router
//!   (the snapshots' `delivery.refused` is 60), r2's row never appears,
//!   and the station logs the refusal once, naming r1 and the key;
//! - with r1's certificate under its own keys (20 puts): r1's row appears
//!   with its 20 health reports;
//! - without a certificate: the TLS handshake is refused, the client
//!   never connects;
//! - with the certificate of a robot the station does not list (r9): the
//!   station logs the peer as no listed robot when it connects, its
//!   publisher never matches and its row never appears;
//! - over plain TCP on the loopback (the station also listens on
//!   `tcp/127.0.0.1:PORT2`, `loopback_robots = ["bench"]`): as `bench`
//!   (20 puts) its row appears, as r2 (10 puts) every put is refused.
//!
//! Where the Python environment or `openssl` is missing the test says so
//! and skips, unless `CI` is set: then it fails. Every wait is bounded.
//! The test starts processes, so it holds the one-at-a-time lock.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use crate::common;
use crate::fleet_station::{fleet_certs, robot, Station};

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use common::{one_at_a_time, skip_or_fail};
use serde_json::Value;

/// Bound of every wait.
const BOUND: Duration = Duration::from_secs(60);

fn refused(snap: &Value) -> u64 {
    snap["delivery"]["refused"].as_u64().unwrap_or(0)
}

/// Runs the impostor client; its JSON result.
fn client(
    py: &Path,
    work: &Path,
    endpoint: &str,
    cert: Option<&str>,
    as_robot: &str,
    count: u32,
) -> Value {
    let certs = work.join("certs");
    let out = work.join(format!("{}-as-{as_robot}.json", cert.unwrap_or("none")));
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/zenoh/impostor.py");
    let mut cmd = Command::new(py);
    cmd.arg(script)
        .args(["--connect", endpoint, "--ca"])
        .arg(certs.join("ca.pem"))
        .args(["--as", as_robot, "--count", &count.to_string()])
        .args(["--match-timeout", "5", "--out"])
        .arg(&out)
        .stdin(Stdio::null());
    if let Some(c) = cert {
        cmd.arg("--cert")
            .arg(certs.join(format!("{c}.pem")))
            .arg("--key")
            .arg(certs.join(format!("{c}.key")));
    }
    let o = common::run_bounded(&mut cmd, BOUND);
    assert!(
        o.status.success(),
        "the client ({cert:?} as {as_robot}) failed:\n{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    let v: Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    eprintln!("client {cert:?} as {as_robot}: {v}");
    v
}

#[test]
fn a_robot_puts_only_under_its_certificates_id() {
    let _one = one_at_a_time();
    let Some(py) = common::pyenv_python("zenoh") else {
        skip_or_fail("no Python environment with eclipse-zenoh (target/pyenv: run .ci/run, or python3 -m venv target/pyenv && target/pyenv/bin/pip install eclipse-zenoh==1.10.2)");
        return;
    };
    let work = std::env::temp_dir().join(format!("insuwb-test-{}-identity", std::process::id()));
    let _ = std::fs::remove_dir_all(&work);
    std::fs::create_dir_all(&work).unwrap();
    if fleet_certs(&work.join("certs"), &["r1", "r2", "r9"]).is_none() {
        skip_or_fail("no openssl command: the fleet's certificates cannot be made");
        return;
    }
    let endpoint = format!("tls/127.0.0.1:{}", common::free_port());
    let plain = format!("tcp/127.0.0.1:{}", common::free_port());
    let station_toml = work.join("station.toml");
    std::fs::write(
        &station_toml,
        format!(
            "[station]\nlisten = [\"{endpoint}\", \"{plain}\"]\nstamp_clock = \"monotonic\"\n\
             [station.tls]\nroot_ca_certificate = \"certs/ca.pem\"\n\
             certificate = \"certs/station.pem\"\nprivate_key = \"certs/station.key\"\n\
             [station.identity]\nrobots = [\"r1\", \"r2\"]\nloopback_robots = [\"bench\"]\n"
        ),
    )
    .unwrap();
    let mut st = Station::with_config(&station_toml, 120, work.join("station.err"));
    let first = st.wait_for("a first snapshot", |_| true);
    assert_eq!(refused(&first), 0, "{first}");

    // r1's certificate, r2's keys: every put refused, r2 never shown.
    let impostor = client(&py, &work, &endpoint, Some("r1"), "r2", 60);
    assert_eq!(impostor["connected"], true, "{impostor}");
    assert_eq!(impostor["sent"], 60, "{impostor}");
    let counted = st.wait_for("the 60 refusals counted", |s| refused(s) >= 60);
    assert_eq!(refused(&counted), 60, "{counted}");
    // r1 as itself.
    let itself = client(&py, &work, &endpoint, Some("r1"), "r1", 20);
    assert_eq!(itself["matched"], true, "{itself}");
    st.wait_for("r1's 20 health reports", |s| {
        robot(s, "r1").is_some_and(|r| r["health"].as_u64() == Some(20))
    });
    // No certificate: refused at the handshake.
    let bare = client(&py, &work, &endpoint, None, "r1", 5);
    assert_eq!(bare["connected"], false, "{bare}");
    // A certificate of a robot the station does not list.
    let stranger = client(&py, &work, &endpoint, Some("r9"), "r9", 5);
    assert_eq!(stranger["matched"], false, "{stranger}");
    // Plain TCP on the loopback: the loopback robot only.
    let bench = client(&py, &work, &plain, None, "bench", 20);
    assert_eq!(bench["matched"], true, "{bench}");
    let loopback_impostor = client(&py, &work, &plain, None, "r2", 10);
    assert_eq!(loopback_impostor["sent"], 10, "{loopback_impostor}");
    let bench_row = st.wait_for("bench's 20 health reports and 70 refusals", |s| {
        robot(s, "bench").is_some_and(|r| r["health"].as_u64() == Some(20)) && refused(s) >= 70
    });
    let last = st.wait_for("one more snapshot", |s| {
        s["t_s"].as_f64() > bench_row["t_s"].as_f64().map(|t| t + 1.0)
    });
    let snaps = st.stop();
    for s in &snaps {
        assert!(robot(s, "r2").is_none(), "r2 appeared: {s}");
        assert!(robot(s, "r9").is_none(), "r9 appeared: {s}");
    }
    assert_eq!(refused(&last), 70, "{last}");
    let log = std::fs::read_to_string(work.join("station.err")).unwrap();
    let named = log
        .lines()
        .filter(|l| l.contains("r1 may not put on insuwb/r2/health"))
        .count();
    assert_eq!(named, 1, "the refusal is logged once:\n{log}");
    assert!(log.contains("is no listed robot"), "{log}");
    eprintln!(
        "station: {} refused, r1 {} health reports",
        refused(&last),
        robot(&last, "r1").map_or(0, |r| r["health"].as_u64().unwrap_or(0))
    );
    let _ = std::fs::remove_dir_all(&work);
}
