//! Faults around the filter, with real processes, real files and real
//! iceoryx2 shared memory: a logger that cannot write (unwritable directory,
//! a write refused by the operating system at run time) while the rest of
//! the group keeps its fused output; bad samples and impossible geometry
//! dropped or skipped and counted in `insuwb launch --json`; owner-only
//! files and no network port while the group runs; config paths checked.
//!
//! Each group runs under its own prefix and run directory, and leaves no
//! /dev/shm file of its prefix. The tests start processes, so they run one
//! at a time. They check that the output goes on, not how regularly: the
//! fused rate and the longest gap of a loaded machine are figures of
//! `insuwb chaos` (docs/RELIABILITY.md), not pass marks here.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use crate::common;

use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::{f, insuwb, one_at_a_time, Group};
use insuwb_log::{LogWriter, Record};
use insuwb_msg::{ImuSample, UwbTdoa};

const SIM: &str = "imu = \"sim\"\nuwb = \"sim\"\nscenario = \"nlos-long\"\nseed = 3";

/// `insuwb launch` running in the background, its output captured.
struct Running {
    child: Child,
    started: Instant,
}

impl Running {
    /// Starts `insuwb launch` on `g` for `secs`. With `ignore_xfsz`, through
    /// `sh` with SIGXFSZ ignored (inherited by every stage), so a file size
    /// limit makes writes fail with EFBIG instead of killing the writer.
    fn start(g: &Group, secs: f64, ignore_xfsz: bool) -> Self {
        let cfg = g.dir.join("robot.toml");
        let secs = secs.to_string();
        let args = [
            "launch".as_ref(),
            cfg.as_os_str(),
            "--duration".as_ref(),
            secs.as_ref(),
            "--json".as_ref(),
        ];
        let mut cmd = if ignore_xfsz {
            let mut c = Command::new("sh");
            c.args(["-c", "trap '' XFSZ; exec \"$0\" \"$@\""])
                .arg(insuwb())
                .args(args);
            c
        } else {
            let mut c = Command::new(insuwb());
            c.args(args);
            c
        };
        let child = cmd
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        Self {
            child,
            started: Instant::now(),
        }
    }

    /// Sleeps until `secs` after the start.
    fn at(&self, secs: f64) {
        let t = Duration::from_secs_f64(secs);
        if let Some(left) = t.checked_sub(self.started.elapsed()) {
            std::thread::sleep(left);
        }
    }

    /// The launcher and its stage processes: `(pid, command name)`.
    fn processes(&self) -> Vec<(u32, String)> {
        let me = self.child.id();
        let mut out = vec![(me, "insuwb".to_owned())];
        out.extend(common::child_processes(me));
        out
    }

    /// Waits for the launcher: (exit success, JSON report or Null, stderr).
    fn finish(self, g: &Group) -> (bool, serde_json::Value, String) {
        let out = self.child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        let v = serde_json::from_slice(&out.stdout).unwrap_or(serde_json::Value::Null);
        assert_eq!(
            g.leftover_shm(),
            Vec::<String>::new(),
            "{}: /dev/shm files left",
            g.name
        );
        (out.status.success(), v, stderr)
    }
}

/// A fresh, empty folder of this test run.
fn scratch(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("insuwb-faults-{}-{tag}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The fused output went on to the end of the run: UWB updates (at most
/// one per 10 Hz fix, so never above 10 Hz; at least half of the fixes, a
/// margin a busy machine keeps: a fix that reaches the fusion stage too late
/// is dropped by design), no stretch of 5 s without one (`deadlocks`), and
/// fused states for at least half of the fixes the UWB driver built over
/// the whole run (a group held up by its logger stops publishing while the
/// driver goes on). The fusion stage must not have restarted (its
/// heartbeat counts from its own start).
fn assert_fused_output_went_on(r: &serde_json::Value) {
    let rate = f(r, "fused_rate_hz");
    assert!((5.0..=10.2).contains(&rate), "fused rate {rate} Hz: {r}");
    assert_eq!(f(r, "deadlocks"), 0.0, "fused output stopped: {r}");
    let count = |stage: &str, key: &str, counter: Option<&str>| {
        let v = &r["stages"][stage][key];
        let v = counter.map_or(v, |c| &v[c]);
        v.as_u64()
            .unwrap_or_else(|| panic!("no stages.{stage}.{key} in {r}"))
    };
    let fixes = count("uwb", "counters", Some("fixes"));
    let updates = count("fusion", "published", None).saturating_sub(f(r, "degraded") as u64);
    assert!(
        fixes >= 20 && 2 * updates >= fixes,
        "{updates} fused updates for {fixes} fixes: {r}"
    );
}

/// A directory the logger cannot create its recording in, and the error
/// text the operating system gives. `chmod 0500` where it is enforced; as
/// root (which writes through it) a path under a regular file.
fn unwritable_dir(base: &Path) -> (PathBuf, &'static str) {
    let locked = base.join("locked");
    std::fs::create_dir_all(&locked).unwrap();
    std::fs::set_permissions(&locked, std::fs::Permissions::from_mode(0o500)).unwrap();
    if std::fs::create_dir(locked.join("probe")).is_err() {
        return (locked.join("log"), "Permission denied");
    }
    let blocker = base.join("blocker");
    std::fs::write(&blocker, b"a file where a directory is needed").unwrap();
    (blocker.join("log"), "Not a directory")
}

#[test]
fn an_unwritable_log_directory_gives_up_the_logger_alone() {
    let _lock = one_at_a_time();
    let dir = scratch("locked");
    let (log_dir, os_error) = unwritable_dir(&dir);
    let g = Group::with_config(
        "nolog",
        SIM,
        "filter = \"iakf\"\n",
        &format!(
            "[logger]\ndir = \"{}\"\n[launch]\nbudget_restarts = 3\n",
            log_dir.display()
        ),
    );
    let (ok, r, stderr) = Running::start(&g, 8.0, false).finish(&g);
    let _ = std::fs::set_permissions(dir.join("locked"), std::fs::Permissions::from_mode(0o700));
    let _ = std::fs::remove_dir_all(&dir);
    assert!(ok, "launch failed:\n{stderr}");
    // The logger said why, naming the path and the operating system's error...
    let said = stderr
        .lines()
        .find(|l| l.contains("[logger]") && l.contains("cannot open a log segment"))
        .unwrap_or_else(|| panic!("no logger error line:\n{stderr}"));
    assert!(
        said.contains(&log_dir.display().to_string()) && said.contains(os_error),
        "{said}"
    );
    // ...exited non-zero, was restarted within its budget, then given up alone.
    assert!(
        stderr.contains("ended: exit code 1"),
        "no non-zero exit:\n{stderr}"
    );
    assert_eq!(r["gave_up"], serde_json::json!(["logger"]), "{r}");
    assert!(f(&r, "restarts") >= 3.0, "{r}");
    assert_fused_output_went_on(&r);
}

#[test]
fn a_write_refused_at_run_time_stops_the_logger_with_a_clear_error() {
    let _lock = one_at_a_time();
    let g = Group::new("full", SIM, "iakf");
    let run = Running::start(&g, 8.0, true);
    run.at(3.0);
    let logger = run
        .processes()
        .into_iter()
        .find(|(_, comm)| comm == insuwb_msg::StageRole::Logger.process_name())
        .map(|(pid, _)| pid)
        .expect("no logger process");
    // The disk "fills up" under the running logger: from now on it may not
    // grow a file past 4 KiB (its segment already holds more), so its next
    // write fails (EFBIG: the same error path as ENOSPC).
    let st = Command::new("prlimit")
        .args(["--pid", &logger.to_string(), "--fsize=4096"])
        .status()
        .expect("prlimit (util-linux) is needed for this test");
    assert!(st.success());
    let (ok, r, stderr) = run.finish(&g);
    assert!(ok, "launch failed:\n{stderr}");
    let first = g.log_dir().join("seg-00000.iulog");
    let said = stderr
        .lines()
        .find(|l| l.contains("[logger]") && l.contains("writing the recording failed"))
        .unwrap_or_else(|| panic!("no logger error line:\n{stderr}"));
    assert!(
        said.contains(&first.display().to_string()) && said.contains("File too large"),
        "{said}"
    );
    assert!(
        stderr.contains(&format!("(pid {logger}) ended: exit code 1")),
        "the logger did not exit with code 1:\n{stderr}"
    );
    // The restarted logger (without the limit) records into a new segment.
    assert!(f(&r, "restarts") >= 1.0, "{r}");
    assert_eq!(r["gave_up"], serde_json::json!([]), "{r}");
    let segs = insuwb_log::list_segments(g.log_dir()).unwrap();
    assert!(segs.len() >= 2, "{segs:?}");
    assert!(common::records(&g.log_dir()).len() > 100);
    assert_fused_output_went_on(&r);
}

/// What [`bad_log`] put in, to compare with the drivers' counts.
#[derive(Debug, Default)]
struct Injected {
    imu_invalid: u64,
    imu_time: u64,
    tdoa_invalid: u64,
    tdoa_time: u64,
    collinear_epochs: u64,
    two_pair_epochs: u64,
}

/// A simulated flight (`paper-4.4-dynamic`) with bad samples written in:
/// NaN, infinite and out-of-range IMU and TDOA values, TDOA of one anchor
/// against itself, duplicated samples (one arriving late, after newer
/// ones), a sample stamped before its predecessor, a stretch of epochs whose anchors are collinear and a stretch
/// with only two pairs per epoch.
fn bad_log(dir: &Path) -> (PathBuf, Injected) {
    let base = dir.join("base.iulog");
    let sim = "sim --scenario paper-4.4-dynamic --seed 5 --out";
    let st = Command::new(insuwb())
        .args(sim.split(' '))
        .arg(&base)
        .status()
        .unwrap();
    assert!(st.success());
    let (records, _, header) = insuwb_log::read_all(&base).unwrap();
    let ms = |t: u64| t / 1_000_000;
    let mut inj = Injected::default();
    let mut out: Vec<Record> = Vec::new();
    let mut late: Vec<Record> = Vec::new();
    let mut epochs_seen = std::collections::BTreeSet::new();
    for r in records {
        match r {
            Record::Imu(s) => {
                let t = ms(s.header.meas_time_ns);
                out.push(r);
                let bad = |f: fn(&mut ImuSample)| {
                    let mut b = s;
                    f(&mut b);
                    Record::Imu(b)
                };
                match t {
                    // Same time as the sample just written: NaN, Inf, 50 g.
                    500 => out.push(bad(|b| b.accel_mps2[0] = f64::NAN)),
                    510 => out.push(bad(|b| b.gyro_rps[2] = f64::INFINITY)),
                    520 => out.push(bad(|b| b.accel_mps2[2] = 500.0)),
                    // An exact duplicate, and one that arrives a second late.
                    530 => out.push(r),
                    540 => late.push(r),
                    1540 => out.append(&mut late),
                    // Stamped 5 ms before the sample written before it
                    // (not a duplicate: a clock that stepped back).
                    600 => out.push(bad(|b| b.header.meas_time_ns -= 5_000_000)),
                    _ => continue,
                }
                if matches!(t, 500..=520) {
                    inj.imu_invalid += 1;
                } else if matches!(t, 530 | 540 | 600) {
                    inj.imu_time += 1;
                }
            }
            Record::Tdoa(s) => {
                let t = ms(s.header.meas_time_ns);
                let first_of_epoch = epochs_seen.insert(t);
                let bad = |f: fn(&mut UwbTdoa)| {
                    let mut b = s;
                    f(&mut b);
                    Record::Tdoa(b)
                };
                match t {
                    // Collinear anchors: all moved onto the line y = 0.
                    1000..=1900 => {
                        let mut b = s;
                        b.anchor_a_pos_m = [b.anchor_a as f64 * 3.0 - 4.0, 0.0, 0.0];
                        b.anchor_b_pos_m = [b.anchor_b as f64 * 3.0 - 4.0, 0.0, 0.0];
                        out.push(Record::Tdoa(b));
                        if first_of_epoch {
                            inj.collinear_epochs += 1;
                        }
                        continue;
                    }
                    // Two pairs only (the fix needs three).
                    2500..=2900 => {
                        if out
                            .iter()
                            .rev()
                            .take_while(
                                |o| matches!(o, Record::Tdoa(p) if ms(p.header.meas_time_ns) == t),
                            )
                            .count()
                            < 2
                        {
                            out.push(r);
                        }
                        if first_of_epoch {
                            inj.two_pair_epochs += 1;
                        }
                        continue;
                    }
                    _ => out.push(r),
                }
                if !first_of_epoch {
                    continue;
                }
                match t {
                    3000 => out.push(bad(|b| b.diff_m = f64::NAN)),
                    3100 => out.push(bad(|b| b.anchor_b_pos_m[1] = f64::NEG_INFINITY)),
                    3200 => out.push(bad(|b| b.diff_m = 2000.0)),
                    3300 => out.push(bad(|b| b.anchor_b = b.anchor_a)),
                    3400 => {
                        out.push(r);
                        inj.tdoa_time += 1;
                        continue;
                    }
                    _ => continue,
                }
                inj.tdoa_invalid += 1;
            }
            other => out.push(other),
        }
    }
    let path = dir.join("bad.iulog");
    let mut w = LogWriter::create(&path, &header.meta, 0).unwrap();
    for r in &out {
        w.append(r).unwrap();
    }
    w.finish().unwrap();
    (path, inj)
}

/// Socket inodes of the TCP and UDP tables (IPv4 and IPv6).
fn inet_socket_inodes() -> Vec<String> {
    let mut inodes = Vec::new();
    for table in ["tcp", "tcp6", "udp", "udp6"] {
        let Ok(text) = std::fs::read_to_string(format!("/proc/net/{table}")) else {
            continue;
        };
        // Column 10 is the inode.
        inodes.extend(
            text.lines()
                .skip(1)
                .filter_map(|l| l.split_whitespace().nth(9).map(str::to_owned)),
        );
    }
    inodes
}

/// Modes under `dir` that give group or other any access, except folders
/// inside `reachable_only_by_owner` (a 0700 folder: nobody else gets in).
fn shared_modes(dir: &Path, owner_only_root: &Path, out: &mut Vec<String>) {
    for e in std::fs::read_dir(dir).unwrap().filter_map(Result::ok) {
        let p = e.path();
        let Ok(meta) = std::fs::symlink_metadata(&p) else {
            continue; // removed meanwhile
        };
        let mode = meta.permissions().mode() & 0o777;
        let inside_root = p.starts_with(owner_only_root) && p != owner_only_root;
        if mode & 0o077 != 0 && !(meta.is_dir() && inside_root) {
            out.push(format!("{mode:o} {}", p.display()));
        }
        if meta.is_dir() {
            shared_modes(&p, owner_only_root, out);
        }
    }
}

#[test]
fn bad_samples_and_impossible_geometry_are_dropped_and_counted_and_files_are_owner_only() {
    let _lock = one_at_a_time();
    let tmp = scratch("bad");
    let (log, inj) = bad_log(&tmp);
    assert!(
        inj.collinear_epochs >= 9 && inj.two_pair_epochs >= 4,
        "{inj:?}"
    );
    let g = Group::new(
        "bad",
        &format!(
            "imu = \"replay:{0}\"\nuwb = \"replay:{0}\"\nspeed = 2.0",
            log.display()
        ),
        "iakf",
    );
    let run = Running::start(&g, 5.0, false);
    run.at(2.5);
    // While it runs: every file of the group is owner-only...
    let mut shm = Vec::new();
    for e in std::fs::read_dir("/dev/shm")
        .unwrap()
        .filter_map(Result::ok)
    {
        let name = e.file_name().to_string_lossy().into_owned();
        if let (true, Ok(m)) = (name.starts_with(&g.prefix), e.metadata()) {
            shm.push((name, m.permissions().mode() & 0o777));
        }
    }
    assert!(shm.len() > 10, "{shm:?}");
    let wide: Vec<_> = shm.iter().filter(|(_, m)| m & 0o077 != 0).collect();
    assert!(wide.is_empty(), "/dev/shm files others can open: {wide:?}");
    let run_dir = g.dir.join("run");
    let root = run_dir.join("iox2");
    let mut shared = Vec::new();
    shared_modes(&run_dir, &root, &mut shared);
    assert!(
        shared.is_empty(),
        "run directory entries others can reach: {shared:?}"
    );
    for d in [&run_dir, &root] {
        let m = std::fs::metadata(d).unwrap().permissions().mode() & 0o777;
        assert_eq!(m, 0o700, "{}", d.display());
    }
    // ...and no process of the group holds a TCP or UDP socket.
    let procs = run.processes();
    assert_eq!(procs.len(), 6, "launcher and 5 stages: {procs:?}");
    let inet = inet_socket_inodes();
    for (pid, comm) in &procs {
        for fd in std::fs::read_dir(format!("/proc/{pid}/fd"))
            .unwrap()
            .filter_map(Result::ok)
        {
            let Ok(target) = std::fs::read_link(fd.path()) else {
                continue;
            };
            let target = target.to_string_lossy().into_owned();
            if let Some(inode) = target
                .strip_prefix("socket:[")
                .and_then(|t| t.strip_suffix(']'))
            {
                assert!(
                    !inet.iter().any(|i| i == inode),
                    "{comm} (pid {pid}) holds a network socket {target}"
                );
            }
        }
    }
    let (ok, r, stderr) = run.finish(&g);
    let _ = std::fs::remove_dir_all(&tmp);
    assert!(ok, "launch failed:\n{stderr}");
    eprintln!("bad log: injected {inj:?}; stages {}", r["stages"]);
    let stage = |name: &str, key: &str| {
        r["stages"][name][key]
            .as_u64()
            .unwrap_or_else(|| panic!("no stages.{name}.{key} in {r}"))
    };
    assert_eq!(stage("imu", "dropped_invalid"), inj.imu_invalid, "{r}");
    assert_eq!(stage("imu", "dropped_time"), inj.imu_time, "{r}");
    assert_eq!(stage("uwb", "dropped_invalid"), inj.tdoa_invalid, "{r}");
    assert_eq!(stage("uwb", "dropped_time"), inj.tdoa_time, "{r}");
    let uwb = |k: &str| r["stages"]["uwb"]["counters"][k].as_u64().unwrap();
    assert_eq!(uwb("skipped_too_few_pairs"), inj.two_pair_epochs, "{r}");
    assert_eq!(uwb("skipped_geometry"), inj.collinear_epochs, "{r}");
    assert!(uwb("fixes") > 30, "{r}");
    // The skips are logged with their reason.
    assert!(
        stderr.contains("epochs skipped without a fix"),
        "no skip line:\n{stderr}"
    );
    assert!(
        f(&r, "dropped") >= (inj.imu_invalid + inj.tdoa_invalid) as f64,
        "{r}"
    );
}

#[test]
fn config_paths_are_checked_before_anything_starts() {
    let _lock = one_at_a_time();
    let cases = [
        ("[logger]\ndir = \"../outside\"\n", "logger.dir"),
        ("[logger]\ndir = \"\"\n", "logger.dir"),
        ("[launch]\noptional = [\"loger\"]\n", "launch.optional"),
    ];
    for (i, (extra, key)) in cases.iter().enumerate() {
        let g = Group::with_config(&format!("cfg{i}"), SIM, "filter = \"iakf\"\n", extra);
        let out = Command::new(insuwb())
            .arg("launch")
            .arg(g.dir.join("robot.toml"))
            .args(["--duration", "1"])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{extra:?} accepted");
        assert!(stderr.contains(key), "{extra:?}: {stderr}");
        assert!(
            !g.dir.join("run").exists(),
            "{extra:?}: run directory created"
        );
    }
}
