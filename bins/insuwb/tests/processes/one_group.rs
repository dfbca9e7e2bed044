//! One group per prefix, one process per stage role, with real processes:
//! a second `insuwb launch` of a running group (same config, or the same
//! prefix with another run directory) and a stage binary started by hand
//! beside its group refuse, naming what runs, and leave the running group
//! undisturbed (no restart, nothing dropped, its rates).
//!
//! Each group runs under its own prefix and run directory and leaves no
//! /dev/shm file of its prefix, nor a lock file. The tests start processes,
//! so they run one at a time; every wait is bounded, and no assertion is a
//! time limit.

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use common::{f, insuwb, one_at_a_time, run_bounded, Group};
use insuwb_msg::StageRole;

const SIM: &str = "imu = \"sim\"\nuwb = \"sim\"\nscenario = \"nlos-long\"\nseed = 3";
/// Stages of a group.
const ROLES: [&str; 5] = ["imu", "uwb", "ins", "fusion", "logger"];
/// Bound of every wait (a loaded 2-core machine starts a group in seconds).
const BOUND: Duration = Duration::from_secs(60);

/// `insuwb launch` of `g` running in the background, its output captured.
fn start(g: &Group, secs: f64) -> Child {
    Command::new(insuwb())
        .arg("launch")
        .arg(g.dir.join("robot.toml"))
        .args(["--duration", &secs.to_string(), "--json"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// The group's run directory.
fn run_dir(g: &Group) -> PathBuf {
    g.dir.join("run")
}

/// Waits until every stage of `g` holds its role's lock (each stage takes
/// it first thing), or fails after [`BOUND`].
fn wait_until_running(g: &Group, launcher: &mut Child) {
    let deadline = Instant::now() + BOUND;
    loop {
        if ROLES
            .iter()
            .all(|r| run_dir(g).join(format!("stage-{r}.lock")).is_file())
        {
            return;
        }
        if let Some(status) = launcher.try_wait().unwrap() {
            panic!("{}: the launcher ended early: {status}", g.name);
        }
        assert!(Instant::now() < deadline, "{}: stages not up", g.name);
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The pid of `launcher`'s child running `program` (its command name).
fn child_pid(launcher: &Child, program: &str) -> u32 {
    common::child_processes(launcher.id())
        .into_iter()
        .find_map(|(pid, comm)| (comm == program).then_some(pid))
        .unwrap_or_else(|| panic!("no child {program} of the launcher {}", launcher.id()))
}

/// Waits for the first launcher and checks that its group ran undisturbed:
/// it succeeded, no stage restarted, nothing was dropped, the IMU rate is
/// one driver's (a second group doubles it), fused output went on (at
/// least half of the 10 Hz fixes: a busy machine drops a late fix by
/// design), and it left no /dev/shm file and no lock file.
fn assert_undisturbed(g: &Group, launcher: Child) -> serde_json::Value {
    let out = launcher.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{}: launch failed:\n{stderr}", g.name);
    let r: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("{}: no JSON report ({e}):\n{stderr}", g.name));
    assert_eq!(f(&r, "restarts"), 0.0, "{r}");
    assert_eq!(f(&r, "dropped"), 0.0, "{r}");
    assert_eq!(f(&r, "deadlocks"), 0.0, "{r}");
    let imu = f(&r, "imu_rate_hz");
    assert!((99.0..=101.0).contains(&imu), "IMU rate {imu} Hz: {r}");
    let fused = f(&r, "fused_rate_hz");
    assert!((5.0..=10.2).contains(&fused), "fused rate {fused} Hz: {r}");
    assert_eq!(
        g.leftover_shm(),
        Vec::<String>::new(),
        "/dev/shm files left"
    );
    let shm_locks: Vec<String> = std::fs::read_dir("/dev/shm")
        .unwrap()
        .filter_map(Result::ok)
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(&format!(".{}.", g.prefix)))
        .collect();
    assert_eq!(shm_locks, Vec::<String>::new(), "lock files left");
    assert!(!run_dir(g).join("group.lock").exists());
    r
}

/// A second config of `g`'s group named `name`: its prefix, another run directory.
fn same_prefix_config(g: &Group, name: &str) -> (PathBuf, PathBuf) {
    let other_run = g.dir.join("other-run");
    let text = format!(
        "[group]\nname = \"{name}\"\nprefix = \"{}\"\nrun_dir = \"{}\"\n[sources]\n{SIM}\n",
        g.prefix,
        other_run.display()
    );
    let path = g.dir.join("other.toml");
    std::fs::write(&path, text).unwrap();
    (path, other_run)
}

fn stderr_of(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn launch_cmd(cfg: &Path) -> Command {
    let mut cmd = Command::new(insuwb());
    cmd.arg("launch")
        .arg(cfg)
        .args(["--duration", "5", "--json"]);
    cmd
}

#[test]
fn a_second_launch_of_a_running_group_is_refused_and_leaves_it_alone() {
    let _lock = one_at_a_time();
    let g = Group::new("twice", SIM, "iakf");
    let mut first = start(&g, 7.0);
    wait_until_running(&g, &mut first);
    let pid = first.id();

    // The same config: refused, naming the running group and its launcher.
    let out = run_bounded(&mut launch_cmd(&g.dir.join("robot.toml")), BOUND);
    let err = stderr_of(&out);
    assert!(!out.status.success(), "the second launch ran:\n{err}");
    assert!(out.stdout.is_empty(), "a report from the second launch");
    for want in [
        "group 'twice' is already running".to_owned(),
        format!("prefix {}", g.prefix),
        format!("run dir {}", run_dir(&g).display()),
        format!("launcher PID {pid}"),
    ] {
        assert!(err.contains(&want), "'{want}' missing from:\n{err}");
    }
    eprintln!("second launch, same config: {}", err.trim());

    // Another config with the same prefix and another run directory: the
    // same services, refused before it creates its run directory.
    let (other, other_run) = same_prefix_config(&g, "copy");
    let out = run_bounded(&mut launch_cmd(&other), BOUND);
    let err = stderr_of(&out);
    assert!(!out.status.success(), "the same-prefix launch ran:\n{err}");
    for want in [
        "group 'twice' is already running".to_owned(),
        format!("launcher PID {pid}"),
    ] {
        assert!(err.contains(&want), "'{want}' missing from:\n{err}");
    }
    assert!(
        !other_run.exists(),
        "the refused launch created its run dir"
    );
    eprintln!("second launch, same prefix: {}", err.trim());

    let r = assert_undisturbed(&g, first);
    eprintln!("first group: {r}");

    // Once the first group has stopped, the same config launches again.
    let again = g.launch(3.0, &[]);
    assert_eq!(f(&again, "restarts"), 0.0, "{again}");
}

#[test]
fn a_stage_started_by_hand_beside_its_group_is_refused() {
    let _lock = one_at_a_time();
    let g = Group::new("byhand", SIM, "iakf");
    let mut launcher = start(&g, 7.0);
    wait_until_running(&g, &mut launcher);
    let bin_dir = insuwb().parent().unwrap().to_owned();
    for role in [StageRole::Ins, StageRole::Fusion, StageRole::Imu] {
        let running = child_pid(&launcher, role.process_name());
        let program = bin_dir.join(role.program());
        assert!(program.is_file(), "{} not built", program.display());
        let mut cmd = Command::new(program);
        cmd.arg("--config").arg(g.dir.join("robot.toml"));
        let out = run_bounded(&mut cmd, BOUND);
        let err = stderr_of(&out);
        assert!(!out.status.success(), "a second {role} ran:\n{err}");
        let want = format!("stage '{role}' of group 'byhand' is already running as PID {running}");
        assert!(err.contains(&want), "'{want}' missing from:\n{err}");
        eprintln!("{role} by hand: {}", err.trim());
    }
    let r = assert_undisturbed(&g, launcher);
    eprintln!("group: {r}");
}
