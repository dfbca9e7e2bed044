//! The fleet's station with real processes, all on 127.0.0.1: a station
//! (`insuwb fleet record DIR --config station.toml --json`, listening on
//! `tcp/127.0.0.1:PORT` and, with mutual TLS, on `tls/127.0.0.1:PORT2`,
//! free ports) and three groups on one machine (their own prefixes and run
//! directories, robot ids r1-r3, the simulated demo scenario at 10 Hz),
//! each with its Zenoh bridge connected to the station: r1 and r2 over
//! TCP, r3 over TLS with its client certificate (`tools/fleet_certs.sh`;
//! where `openssl` is missing r3 uses TCP too and the test says so, unless
//! `CI` is set: then it fails).
//!
//! - The station sees three robots at 10 +/- 0.5 Hz each (poses received
//!   over 5 s of its snapshots).
//! - r2's bridge is killed (SIGKILL) and its launcher restarts it after 3 s
//!   (r2's `[launch]` backoff, so that it stays away longer than the lost
//!   time): the station's events mark r2 lost 2 s after the last pose it
//!   got, a tick (50 ms) of the station at most after that (asserted:
//!   within 2.3 s of the kill, so a loaded machine's scheduling delay does
//!   not fail it), and back within 2 s of the new bridge's start; r1 and
//!   r3 keep their rate meanwhile.
//! - The station is stopped (SIGTERM) and a new one started on the same
//!   port 2 s later: the bridges reconnect to it, and every robot's own
//!   log (its logger's) holds its fused states without a gap across the
//!   station's downtime: nothing waited for the station.
//! - The first station's recording is read back: `insuwb log info` of
//!   each robot's folder (metadata naming robot and station, its fused
//!   states, one for every pose the station received, and heartbeats),
//!   `log export` to MCAP, and `eval` (the recorded track).
//!
//! Every wait is bounded; the figures (rates, lost and back times) are
//! printed. The test starts processes, so it holds the one-at-a-time lock.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::time::{Duration, Instant};

use common::{f, insuwb, one_at_a_time, succeeded, wait_bounded, Group};
use insuwb_log::Record;
use insuwb_runtime::monotonic_ns;
use serde_json::Value;

const SIM: &str = "imu = \"sim\"\nuwb = \"sim\"\nscenario = \"nlos-long\"\nseed = 1";
/// The robots, one group each.
const ROBOTS: [&str; 3] = ["r1", "r2", "r3"];
/// The robot whose bridge is killed.
const VICTIM: usize = 1;
/// The stages of every group, in start order.
const STAGES: [&str; 6] = ["imu", "uwb", "ins", "fusion", "zenoh", "logger"];
/// Seconds the groups run (they outlast both stations: about 20 s of
/// checks).
const GROUP_S: f64 = 30.0;
/// The robot whose bridge connects over TLS.
const TLS_ROBOT: usize = 2;
/// The victim's restart delay, ms: longer than the lost time.
const RESTART_DELAY_MS: u64 = 3000;
/// The station's name in its recordings.
const STATION: &str = "test-station";
/// Bound of every wait.
const BOUND: Duration = Duration::from_secs(60);

/// A station process and its snapshots as they come (the hostile peers'
/// test uses it too).
pub(crate) struct Station {
    pub(crate) child: Child,
    rx: Receiver<Value>,
    pub(crate) snaps: Vec<Value>,
    err: PathBuf,
}

impl Station {
    /// Starts `insuwb ARGS`, its standard error into `err`.
    pub(crate) fn start(args: &[&str], err: PathBuf) -> Self {
        let mut child = Command::new(insuwb())
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&err).unwrap())
            .spawn()
            .unwrap();
        let rx = common::json_lines(child.stdout.take().unwrap());
        Self {
            child,
            rx,
            snaps: Vec::new(),
            err,
        }
    }

    /// Starts `insuwb fleet --config CONFIG --json --period 0.5 --duration
    /// SECONDS`, its standard error into `err`.
    pub(crate) fn with_config(config: &Path, seconds: u32, err: PathBuf) -> Self {
        let seconds = seconds.to_string();
        Self::start(
            &[
                "fleet",
                "--config",
                config.to_str().unwrap(),
                "--json",
                "--period",
                "0.5",
                "--duration",
                &seconds,
            ],
            err,
        )
    }

    pub(crate) fn log(&self) -> String {
        std::fs::read_to_string(&self.err).unwrap_or_default()
    }

    /// The first snapshot from now on for which `pred` holds.
    pub(crate) fn wait_for(&mut self, what: &str, pred: impl Fn(&Value) -> bool) -> Value {
        let t0 = Instant::now();
        loop {
            match self.rx.recv_timeout(Duration::from_millis(100)) {
                Ok(v) => {
                    self.snaps.push(v.clone());
                    if pred(&v) {
                        return v;
                    }
                }
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => {
                    panic!("the station ended before {what}:\n{}", self.log())
                }
            }
            assert!(
                t0.elapsed() < BOUND,
                "no snapshot with {what} within {BOUND:?}; last: {:?}\n{}",
                self.snaps.last(),
                self.log()
            );
        }
    }

    /// SIGTERM; its snapshots (the last one at its exit).
    pub(crate) fn stop(mut self) -> Vec<Value> {
        common::signal(self.child.id(), "TERM");
        wait_bounded(&mut self.child, "the station", BOUND);
        assert!(
            self.child.wait().unwrap().success(),
            "the station failed:\n{}",
            self.log()
        );
        // The reader thread ends with the pipe.
        while let Ok(v) = self.rx.recv_timeout(Duration::from_secs(5)) {
            self.snaps.push(v);
        }
        self.snaps
    }
}

/// Robot `id` in a snapshot.
pub(crate) fn robot<'a>(snap: &'a Value, id: &str) -> Option<&'a Value> {
    snap["robots"].as_array()?.iter().find(|r| r["id"] == id)
}

/// Whether robot `id` is heard with recent poses (`ok`, or `degraded` for
/// a stage's condition, e.g. fusion coasting through an NLOS spell).
pub(crate) fn live(snap: &Value, id: &str) -> bool {
    robot(snap, id).is_some_and(|r| r["status"] == "ok" || r["status"] == "degraded")
}

pub(crate) fn poses(snap: &Value, id: &str) -> u64 {
    robot(snap, id)
        .and_then(|r| r["poses"].as_u64())
        .unwrap_or(0)
}

/// Poses of `id` received per second between two snapshots.
pub(crate) fn rate(a: &Value, b: &Value, id: &str) -> f64 {
    (poses(b, id) - poses(a, id)) as f64 / (f(b, "t_s") - f(a, "t_s"))
}

/// The time of the first `kind` event of robot `id` at or after `from_ns`.
fn event_at(snaps: &[Value], kind: &str, id: &str, from_ns: u64) -> Option<u64> {
    snaps
        .iter()
        .filter_map(|s| s["events"].as_array())
        .flatten()
        .filter(|e| e["event"] == kind && e["robot"] == id)
        .filter_map(|e| e["at_ns"].as_u64())
        .find(|&t| t >= from_ns)
}

/// The Zenoh bridge among the launcher's children.
fn bridge_pid(launcher: u32) -> Option<u32> {
    common::child_processes(launcher)
        .into_iter()
        .find(|(_, comm)| comm == "insuwb-stage-ze")
        .map(|(pid, _)| pid)
}

/// The robot's `[zenoh]` table: `endpoint`, and where `certs` is given,
/// TLS with `certs/<robot>.pem`.
fn zenoh_table(robot: &str, endpoint: &str, certs: Option<&Path>, victim: bool) -> String {
    let mut t = format!("[zenoh]\nrobot = \"{robot}\"\nconnect = [\"{endpoint}\"]\n");
    if let Some(c) = certs {
        let c = c.display();
        t.push_str(&format!(
            "[zenoh.tls]\nroot_ca_certificate = \"{c}/ca.pem\"\n\
             certificate = \"{c}/{robot}.pem\"\nprivate_key = \"{c}/{robot}.key\"\n"
        ));
    }
    if victim {
        t.push_str(&format!(
            "[launch]\nbackoff_initial_ms = {RESTART_DELAY_MS}\nbackoff_max_ms = {RESTART_DELAY_MS}\n"
        ));
    }
    t
}

/// The fleet's certificates in `dir` (`tools/fleet_certs.sh`, the station's
/// for 127.0.0.1, those of `robots`, valid 2 days); `None` where there is
/// no `openssl` and `CI` is not set (then the caller says what it leaves
/// out).
pub(crate) fn fleet_certs(dir: &Path, robots: &[&str]) -> Option<PathBuf> {
    if Command::new("openssl").arg("version").output().is_err() {
        assert!(
            std::env::var_os("CI").is_none(),
            "no openssl command; CI is set, so this fails instead of skipping TLS"
        );
        return None;
    }
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tools/fleet_certs.sh");
    let out = Command::new("bash")
        .arg(script)
        .arg(dir)
        .arg("IP:127.0.0.1")
        .args(robots)
        .env("INSUWB_CERT_DAYS", "2")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "fleet_certs.sh: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    Some(dir.to_owned())
}

/// The count of `topic` records in `insuwb log info`'s output.
fn info_count(info: &str, topic: &str) -> u64 {
    info.lines()
        .find_map(|l| {
            let mut w = l.split_whitespace();
            (w.next() == Some(topic)).then(|| w.next()?.parse().ok())?
        })
        .unwrap_or(0)
}

/// A robot's own log: its fused states from one fusion process, every
/// sequence number once in order, none missing, none more than 0.2 s after
/// the one before; some of them published while the station was down.
fn check_contiguous(g: &Group, down: (u64, u64)) {
    let fused: Vec<_> = common::records(&g.log_dir())
        .into_iter()
        .filter_map(|r| match r {
            Record::Fused(s) => Some(s),
            _ => None,
        })
        .collect();
    assert!(
        fused.len() > 200,
        "{}: {} fused states",
        g.name,
        fused.len()
    );
    for w in fused.windows(2) {
        let (a, b) = (&w[0].header, &w[1].header);
        assert_eq!(a.generation, b.generation, "{}: fusion restarted", g.name);
        assert_eq!(
            b.seq,
            a.seq + 1,
            "{}: fused state(s) missing after {}",
            g.name,
            a.seq
        );
        let gap = b.meas_time_ns.saturating_sub(a.meas_time_ns) as f64 * 1e-9;
        assert!(
            gap <= 0.2,
            "{}: {gap} s between fused states {} and {}",
            g.name,
            a.seq,
            b.seq
        );
    }
    let during = fused
        .iter()
        .filter(|s| (down.0..down.1).contains(&s.header.pub_time_ns))
        .count();
    let down_s = (down.1 - down.0) as f64 * 1e-9;
    eprintln!(
        "{}: {} fused states, contiguous; {during} of them in the {down_s:.1} s without a station",
        g.name,
        fused.len()
    );
    assert!(
        during as f64 >= down_s * 10.0 - 3.0,
        "{}: {during} fused states in {down_s} s without a station",
        g.name
    );
}

/// `insuwb log info`, `log export` and `eval` of a robot's folder of the
/// recording: its metadata, one fused state per pose the station got, the
/// heartbeats.
fn check_recording(dir: &Path, id: &str, last: &Value, work: &Path) {
    let d = dir.join(id);
    let ds = d.to_str().unwrap();
    let out = common::run(&["log", "info", ds]);
    let info = String::from_utf8_lossy(&succeeded(&out).stdout).into_owned();
    assert!(info.contains(&format!("meta robot = {id}")), "{info}");
    assert!(
        info.contains(&format!("meta station = {STATION}")),
        "{info}"
    );
    assert!(
        info.contains("intact") && !info.contains("DAMAGED"),
        "{info}"
    );
    let fused = info_count(&info, "fused");
    assert_eq!(
        fused,
        poses(last, id),
        "{id}: a fused state per pose received:\n{info}"
    );
    assert!(info_count(&info, "health") >= 10, "{info}");
    let mcap = work.join(format!("{id}.mcap"));
    let out = common::run(&["log", "export", ds, "--mcap", mcap.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&succeeded(&out).stdout).into_owned();
    assert!(mcap.is_file() && text.contains("messages"), "{text}");
    let out = common::run(&["eval", ds, "--json"]);
    let v: Value = serde_json::from_slice(&succeeded(&out).stdout).unwrap();
    // The track: the states flagged valid.
    let rec = &v["recorded"];
    let states = rec["states"].as_u64().unwrap();
    assert!(states <= fused && states * 10 >= fused * 9, "{v}");
    // Over the recording's span: the victim's outage lowers its mean.
    let r = f(rec, "rate_hz");
    let low = if id == ROBOTS[VICTIM] { 3.0 } else { 9.0 };
    assert!((low..=11.0).contains(&r), "{id}: recorded at {r} Hz");
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("no ground truth"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    eprintln!(
        "{id}: recorded {fused} fused states at {r:.2} Hz; log info, export and eval read them"
    );
}

#[test]
fn three_robots_at_a_station_one_lost_and_back_and_a_station_restart() {
    let _one = one_at_a_time();
    let work = std::env::temp_dir().join(format!("insuwb-test-{}-fleet", std::process::id()));
    let _ = std::fs::remove_dir_all(&work);
    std::fs::create_dir_all(&work).unwrap();
    let rec = work.join("rec");
    let certs = fleet_certs(&work.join("certs"), &[ROBOTS[TLS_ROBOT]]);
    if certs.is_none() {
        eprintln!("no openssl command: r3 connects over TCP, TLS is not tested");
    }
    let tcp = format!("tcp/127.0.0.1:{}", common::free_port());
    let tls = format!("tls/127.0.0.1:{}", common::free_port());
    // The station's config: certificate paths relative to the file.
    let station_toml = work.join("station.toml");
    std::fs::write(
        &station_toml,
        if certs.is_some() {
            format!(
                "[station]\nlisten = [\"{tcp}\", \"{tls}\"]\n[station.tls]\n\
                 root_ca_certificate = \"certs/ca.pem\"\ncertificate = \"certs/station.pem\"\n\
                 private_key = \"certs/station.key\"\n"
            )
        } else {
            format!("[station]\nlisten = [\"{tcp}\"]\n")
        },
    )
    .unwrap();
    let station_toml = station_toml.to_str().unwrap();
    // The station first: it listens, the bridges connect to it.
    let mut st = Station::start(
        &[
            "fleet",
            "record",
            rec.to_str().unwrap(),
            "--config",
            station_toml,
            "--json",
            "--period",
            "0.5",
            "--duration",
            "300",
            "--name",
            STATION,
        ],
        work.join("station1.err"),
    );
    let groups: Vec<Group> = ROBOTS
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let g = Group::with_config(
                &format!("fleet_{r}"),
                SIM,
                "filter = \"iakf\"\n",
                &match (&certs, i == TLS_ROBOT) {
                    (Some(c), true) => zenoh_table(r, &tls, Some(c), i == VICTIM),
                    _ => zenoh_table(r, &tcp, None, i == VICTIM),
                },
            );
            g.set_stages(&STAGES);
            g
        })
        .collect();
    if certs.is_some() {
        eprintln!(
            "{} connects over TLS ({tls}) with its client certificate, the others over TCP ({tcp})",
            ROBOTS[TLS_ROBOT]
        );
    }
    let mut launchers: Vec<Child> = groups.iter().map(|g| g.spawn_launch(GROUP_S)).collect();
    for (g, l) in groups.iter().zip(&mut launchers) {
        common::wait_for_lock(g, l, BOUND, "zenoh");
    }

    // Three robots at 10 Hz.
    let a = st.wait_for("every robot live", |s| ROBOTS.iter().all(|r| live(s, r)));
    let t_a = f(&a, "t_s");
    let b = st.wait_for("5 s more", |s| f(s, "t_s") >= t_a + 5.0);
    for r in ROBOTS {
        let hz = rate(&a, &b, r);
        eprintln!("{r}: {hz:.2} Hz at the station");
        assert!((9.5..=10.5).contains(&hz), "{r}: {hz} Hz");
    }

    // r2's bridge killed, restarted by its launcher 3 s later.
    let victim = ROBOTS[VICTIM];
    let launcher = launchers[VICTIM].id();
    let old = bridge_pid(launcher).expect("r2's bridge");
    let before = st.snaps.last().unwrap().clone();
    let kill_ns = monotonic_ns();
    common::signal(old, "KILL");
    let t0 = Instant::now();
    let restart_ns = loop {
        if bridge_pid(launcher).is_some_and(|p| p != old) {
            break monotonic_ns();
        }
        assert!(t0.elapsed() < BOUND, "r2's bridge was not restarted");
        std::thread::sleep(Duration::from_millis(5));
    };
    let back = st.wait_for("r2 back", |s| {
        event_at(std::slice::from_ref(s), "back", victim, kill_ns).is_some()
    });
    let lost_ns = event_at(&st.snaps, "lost", victim, kill_ns).expect("no lost event of r2");
    let back_ns = event_at(&st.snaps, "back", victim, kill_ns).unwrap();
    let s = |ns: u64| ns as f64 * 1e-9;
    eprintln!(
        "r2: bridge killed; lost {:.3} s after, restarted {:.3} s after, back {:.3} s after its restart",
        s(lost_ns - kill_ns),
        s(restart_ns - kill_ns),
        s(back_ns.saturating_sub(restart_ns))
    );
    assert!(
        (1.5..=2.3).contains(&s(lost_ns - kill_ns)),
        "lost {} s after the kill",
        s(lost_ns - kill_ns)
    );
    assert!(lost_ns < restart_ns, "lost only after its restart");
    assert!(back_ns > restart_ns, "back before its restart");
    assert!(
        s(back_ns - restart_ns) <= 2.0,
        "back {} s after its restart",
        s(back_ns - restart_ns)
    );
    // The lost robot is shown lost; the others kept their rate.
    let lost_snap = st
        .snaps
        .iter()
        .find(|x| x["now_ns"].as_u64().is_some_and(|t| t >= lost_ns))
        .unwrap();
    assert_eq!(
        robot(lost_snap, victim).unwrap()["status"],
        "lost",
        "{lost_snap}"
    );
    for r in [ROBOTS[0], ROBOTS[2]] {
        assert!(live(lost_snap, r), "{r} while r2 is lost: {lost_snap}");
        let hz = rate(&before, &back, r);
        eprintln!(
            "{r}: {hz:.2} Hz over the {:.1} s of r2's outage",
            f(&back, "t_s") - f(&before, "t_s")
        );
        assert!((9.5..=10.5).contains(&hz), "{r}: {hz} Hz while r2 was away");
    }

    // The new bridge's health (once a second) counts its restart.
    st.wait_for("r2's restart counted", |s| {
        robot(s, victim).is_some_and(|r| r["restarts"] == 1)
    });

    // The station restarted: 2 s down, then a new one on the same port.
    let snaps1 = st.stop();
    let down_from = monotonic_ns();
    let last1 = snaps1.last().unwrap().clone();
    std::thread::sleep(Duration::from_secs(2));
    let mut st2 = Station::start(
        &[
            "fleet",
            "--config",
            station_toml,
            "--json",
            "--period",
            "0.5",
            "--duration",
            "300",
        ],
        work.join("station2.err"),
    );
    let seen = st2.wait_for("every robot at the new station", |s| {
        ROBOTS.iter().all(|r| live(s, r))
    });
    let down_to = monotonic_ns();
    eprintln!(
        "a station was away for {:.1} s; the new one saw every robot {:.1} s after its start",
        s(down_to - down_from),
        f(&seen, "t_s")
    );
    st2.stop();

    // The first station's view at its end.
    for (i, r) in ROBOTS.iter().enumerate() {
        let v = robot(&last1, r).unwrap();
        assert_eq!(v["gaps"], 0, "{r}: samples lost on the way: {v}");
        let (runs, restarts) = if i == VICTIM { (2, 1) } else { (1, 0) };
        assert_eq!(v["runs"], runs, "{r}: {v}");
        assert_eq!(v["restarts"], restarts, "{r}: {v}");
    }

    // The groups: only r2's bridge restarted, and no robot's own log lost
    // a fused state while the station was away.
    for (i, (g, mut l)) in groups.iter().zip(launchers).enumerate() {
        wait_bounded(
            &mut l,
            "insuwb launch",
            Duration::from_secs(GROUP_S as u64) + BOUND,
        );
        let out = l.wait_with_output().unwrap();
        let log = g.launch_log();
        assert!(out.status.success(), "{}: launch failed:\n{log}", g.name);
        let report: Value = serde_json::from_slice(&out.stdout)
            .unwrap_or_else(|e| panic!("{}: no JSON report ({e}):\n{log}", g.name));
        if i == VICTIM {
            common::assert_restarted_once(&report, &log, "zenoh", g);
        } else {
            assert_eq!(f(&report, "restarts"), 0.0, "{}: {report}", g.name);
        }
        check_contiguous(g, (down_from, down_to));
    }

    // The recording, read back.
    for r in ROBOTS {
        check_recording(&rec, r, &last1, &work);
    }
    let _ = std::fs::remove_dir_all(&work);
}

/// A station with no endpoint, a bad one, a bad key in its config file or
/// plain TCP off the loopback under `require_tls` is refused before anything
/// opens, the error naming the option, or the file and the key.
#[test]
fn a_station_without_an_endpoint_or_with_a_bad_key_is_refused() {
    let work = std::env::temp_dir().join(format!("insuwb-test-{}-fleet-bad", std::process::id()));
    std::fs::create_dir_all(&work).unwrap();
    let file = |name: &str, text: &str| {
        let p = work.join(name);
        std::fs::write(&p, text).unwrap();
        p.to_str().unwrap().to_owned()
    };
    let tls = file("tls.toml", "[station]\nlisten = [\"tls/127.0.0.1:7447\"]\n");
    let unknown = file("unknown.toml", "[station]\nscouting = true\n");
    let lost = file(
        "lost.toml",
        "[station]\nlisten = [\"tcp/127.0.0.1:7447\"]\nlost_after_s = -1.0\n",
    );
    let plain = file(
        "plain.toml",
        "[station]\nlisten = [\"tcp/192.0.2.1:7447\"]\nrequire_tls = true\n",
    );
    let cases: [(Vec<&str>, String); 7] = [
        // Plain TCP off the loopback under require_tls (the option or the
        // key): refused before a port opens.
        (
            vec!["fleet", "--listen", "tcp/0.0.0.0:7447", "--require-tls"],
            "--listen: endpoint \"tcp/0.0.0.0:7447\" is plain TCP off the loopback".to_owned(),
        ),
        (
            vec!["fleet", "--config", &plain],
            format!("{plain}: key 'station.listen': endpoint \"tcp/192.0.2.1:7447\" is plain TCP off the loopback"),
        ),
        (vec!["fleet"], "give --listen ENDPOINT".to_owned()),
        (
            vec!["fleet", "--listen", "udp/127.0.0.1:7447"],
            "--listen: endpoint \"udp/127.0.0.1:7447\": the protocol must be tcp or tls".to_owned(),
        ),
        (
            vec!["fleet", "--config", &tls],
            format!("{tls}: key 'station.tls.root_ca_certificate'"),
        ),
        (
            vec!["fleet", "--config", &unknown],
            format!("{unknown}:2: key 'station"),
        ),
        (
            vec!["fleet", "--config", &lost],
            format!("{lost}: key 'station.lost_after_s'"),
        ),
    ];
    for (args, want) in cases {
        let out = common::run(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} accepted");
        assert!(err.contains(&want), "{args:?}: {err}");
    }
    let _ = std::fs::remove_dir_all(&work);
}

/// Set inside the network namespace of the plain-TCP test.
const PLAIN_INNER: &str = "INSUWB_TEST_PLAIN_TCP_INNER";

/// A station listening over plain TCP off the loopback starts with a
/// warning naming the key, the endpoint and the TLS section to add. Run in
/// a network namespace of its own with loopback only, so that listening on
/// every interface opens nothing outside.
#[test]
fn plain_tcp_off_the_loopback_starts_with_a_warning() {
    let _one = one_at_a_time();
    if std::env::var_os(PLAIN_INNER).is_none() {
        common::run_in_private_netns(
            PLAIN_INNER,
            "fleet_station::plain_tcp_off_the_loopback_starts_with_a_warning",
            BOUND,
        );
        return;
    }
    let out = common::run(&[
        "fleet",
        "--listen",
        "tcp/0.0.0.0:7447",
        "--duration",
        "1",
        "--json",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("listen: endpoint \"tcp/0.0.0.0:7447\" is plain TCP off the loopback"),
        "{err}"
    );
    assert!(
        err.contains("use a tls/ endpoint with the TLS section")
            && err.contains("require_tls = true refuses it"),
        "{err}"
    );
}
