//! What the integration tests that run a group share: a group under its own
//! service prefix and run directory (removed afterwards, with a check that
//! no /dev/shm file of the prefix is left), `insuwb launch` with faults, the
//! recording, and the lock that runs such tests one at a time.
//!
//! Each test file uses only part of it.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use insuwb_log::Record;

static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// Tests that start processes and measure time run one at a time (2 cores).
pub fn one_at_a_time() -> MutexGuard<'static, ()> {
    ONE_AT_A_TIME
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// The `insuwb` binary under test.
pub fn insuwb() -> PathBuf {
    PathBuf::from(env!("CARGO_BIN_EXE_insuwb"))
}

/// Runs `insuwb ARGS` to its end.
pub fn run(args: &[&str]) -> std::process::Output {
    Command::new(insuwb()).args(args).output().unwrap()
}

/// Runs `insuwb demo --json` with `args`; returns its JSON report.
pub fn demo_json(args: &[&str]) -> serde_json::Value {
    let out = Command::new(insuwb())
        .arg("demo")
        .args(args)
        .arg("--json")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "demo {args:?} failed:\n{stderr}");
    serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("demo {args:?}: stdout is not one JSON object ({e}):\n{stderr}"))
}

/// `out`, after checking that it exited 0 (its standard error otherwise).
pub fn succeeded(out: &std::process::Output) -> &std::process::Output {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// A robot group of its own: config file, run directory, service prefix.
pub struct Group {
    pub name: String,
    pub dir: PathBuf,
    pub prefix: String,
}

impl Group {
    /// A group with `sources` (the body of `[sources]`) and `filter`.
    pub fn new(name: &str, sources: &str, filter: &str) -> Self {
        Self::with_config(name, sources, &format!("filter = \"{filter}\"\n"), "")
    }

    /// A group with `sources` (the body of `[sources]`), `fusion` (the body
    /// of `[fusion]`) and `extra` TOML tables appended.
    pub fn with_config(name: &str, sources: &str, fusion: &str, extra: &str) -> Self {
        let id = format!("{}_{name}", std::process::id());
        let dir = std::env::temp_dir().join(format!("insuwb-test-{id}"));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let prefix = format!("iutest{}_{name}_", std::process::id());
        let text = format!(
            "[group]\nname = \"{name}\"\nprefix = \"{prefix}\"\nrun_dir = \"{}\"\n\
             [sources]\n{sources}\n[fusion]\n{fusion}\n\
             [logger.segments.flush]\nevery_ms = 100\n{extra}",
            dir.join("run").display()
        );
        std::fs::write(dir.join("robot.toml"), text).unwrap();
        Self {
            name: name.to_owned(),
            dir,
            prefix,
        }
    }

    /// Runs `insuwb launch` for `secs` with `faults`; returns the JSON report.
    pub fn launch(&self, secs: f64, faults: &[&str]) -> serde_json::Value {
        let mut cmd = Command::new(insuwb());
        cmd.arg("launch").arg(self.dir.join("robot.toml")).args([
            "--duration",
            &secs.to_string(),
            "--json",
        ]);
        for f in faults {
            cmd.args(["--fault", f]);
        }
        let out = cmd.output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            out.status.success(),
            "{}: launch failed:\n{stderr}",
            self.name
        );
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
            panic!(
                "{}: stdout is not one JSON object ({e}):\n{stderr}",
                self.name
            )
        });
        assert_eq!(
            self.leftover_shm(),
            Vec::<String>::new(),
            "{}: /dev/shm files left",
            self.name
        );
        v
    }

    /// Files of this group's prefix in /dev/shm.
    pub fn leftover_shm(&self) -> Vec<String> {
        std::fs::read_dir("/dev/shm")
            .map(|d| {
                d.filter_map(Result::ok)
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .filter(|n| n.starts_with(&self.prefix))
                    .collect()
            })
            .unwrap_or_default()
    }

    /// The logger's recording.
    pub fn log_dir(&self) -> PathBuf {
        self.dir.join("run").join("log")
    }
}

impl Drop for Group {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// A number of the JSON report.
pub fn f(v: &serde_json::Value, key: &str) -> f64 {
    v[key]
        .as_f64()
        .unwrap_or_else(|| panic!("no number '{key}' in {v}"))
}

/// Every record of a recording (all segments).
pub fn records(dir: &Path) -> Vec<Record> {
    insuwb_log::read_segments(dir).unwrap().records
}

/// The shared UTIL data folder (`INSUWB_UTIL_DIR`, else
/// `<workspace>/../shared/data/util`) when it holds `probe`; otherwise
/// `None` after saying so, or a failure when the environment variable `CI`
/// is set.
pub fn util_data_dir(probe: &str) -> Option<PathBuf> {
    let dir = std::env::var_os("INSUWB_UTIL_DIR").map_or_else(
        || PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/util"),
        PathBuf::from,
    );
    if dir.join(probe).is_file() {
        return Some(dir);
    }
    assert!(
        std::env::var_os("CI").is_none(),
        "{} not found (set INSUWB_UTIL_DIR); CI is set, so this fails instead of skipping",
        dir.join(probe).display()
    );
    eprintln!(
        "SKIPPED: {} not found (set INSUWB_UTIL_DIR)",
        dir.join(probe).display()
    );
    None
}

/// The recording's fused states that are updates of the filter: neither
/// degraded (coasting) nor UWB-only ([`uwb_only`]).
pub fn undegraded_fused(log_dir: &Path) -> Vec<insuwb_msg::FusedState> {
    records(log_dir)
        .into_iter()
        .filter_map(|r| match r {
            Record::Fused(s) if s.header.flags & insuwb_msg::FusedState::FLAG_DEGRADED == 0 => {
                Some(s)
            }
            _ => None,
        })
        .filter(|s| !uwb_only(s))
        .collect()
}

/// A pose on the UWB fix alone, published while the INS input was stale on
/// the wall clock: not an update of the filter, so not one that replay and
/// eval must agree on.
pub fn uwb_only(s: &insuwb_msg::FusedState) -> bool {
    s.header.flags & insuwb_msg::FusedState::FLAG_UWB_ONLY != 0
}

/// The pipeline's fused states against eval's, paired by the UWB sample
/// they fused: asserts that all but two of eval's updates found their pair
/// and that no pair is more than 1 mm apart horizontally.
pub fn assert_same_fused(piped: &[insuwb_msg::FusedState], eval: &[insuwb_msg::FusedState]) {
    let (mut matched, mut worst) = (0usize, 0.0f64);
    for p in piped.iter().filter(|s| !uwb_only(s)) {
        if let Some(o) = eval
            .iter()
            .filter(|s| !uwb_only(s))
            .find(|o| o.uwb_seq == p.uwb_seq)
        {
            let d = ((p.pos_m[0] - o.pos_m[0]).powi(2) + (p.pos_m[1] - o.pos_m[1]).powi(2)).sqrt();
            worst = worst.max(d);
            matched += 1;
        }
    }
    let updates = eval.iter().filter(|s| !uwb_only(s)).count();
    assert!(matched + 2 >= updates, "matched {matched} of {updates}");
    assert!(worst <= 1e-3, "pipeline and eval differ by up to {worst} m");
}

/// The pipeline's fused states of a replay against eval's, paired by
/// epoch (a piped state's time is the recording's plus the replay's start
/// epoch, one offset for all): asserts that all but two of eval's found
/// their pair and that no pair is more than 1 mm apart.
pub fn assert_same_fused_by_time(
    piped: &[insuwb_msg::FusedState],
    eval: &[insuwb_msg::FusedState],
) {
    let eval: Vec<_> = eval.iter().filter(|s| !uwb_only(s)).collect();
    let first = piped.first().expect("no fused state recorded");
    let offset = first
        .header
        .meas_time_ns
        .checked_sub(
            eval.first()
                .expect("no fused state in process")
                .header
                .meas_time_ns,
        )
        .expect("the replay's first state is before eval's");
    let (mut matched, mut worst) = (0usize, 0.0f64);
    for p in piped {
        let t = p.header.meas_time_ns - offset;
        if let Some(o) = eval.iter().rev().find(|o| o.header.meas_time_ns == t) {
            let d = (0..3)
                .map(|i| (p.pos_m[i] - o.pos_m[i]).powi(2))
                .sum::<f64>()
                .sqrt();
            worst = worst.max(d);
            matched += 1;
        }
    }
    assert!(
        matched + 2 >= eval.len(),
        "matched {matched} of {} (piped {})",
        eval.len(),
        piped.len()
    );
    assert!(worst <= 1e-3, "pipeline and eval differ by up to {worst} m");
}

/// A project log through `insuwb eval`'s in-process code path, with the
/// fusion settings the log carries and filter `kind`: from its TDOA
/// differences, or from its ranges when it holds no differences.
pub fn offline_run(log: &Path, kind: insuwb_msg::FilterKind) -> insuwb_fusion::runner::RunOutput {
    offline_run_aided(log, kind, false)
}

/// [`offline_run`], aided by the log's body velocities and heights when
/// `aided` (`insuwb eval --aiding`).
pub fn offline_run_aided(
    log: &Path,
    kind: insuwb_msg::FilterKind,
    aided: bool,
) -> insuwb_fusion::runner::RunOutput {
    let (recs, _, header) = insuwb_log::read_all(log).unwrap();
    let (mut imu, mut tdoa, mut range, mut vel) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut height = Vec::new();
    for r in recs {
        match r {
            Record::Imu(s) => imu.push(s),
            Record::Tdoa(s) => tdoa.push(s),
            Record::Range(s) => range.push(s),
            Record::BodyVel(s) if aided => vel.push(s),
            Record::Height(s) if aided => height.push(s),
            _ => {}
        }
    }
    #[derive(serde::Deserialize)]
    struct Wrap {
        fusion: insuwb_fusion::config::FusionConfig,
    }
    let table: toml::Table = toml::from_str(&header.meta.entries["fusion_config"]).unwrap();
    let mut only = toml::Table::new();
    only.insert("fusion".into(), table["fusion"].clone());
    let w: Wrap = toml::from_str(&toml::to_string(&only).unwrap()).unwrap();
    let est = insuwb_fusion::config::build_estimator(kind, &w.fusion).unwrap();
    // A ranging log (ranges, no TDOA) is run from its ranges, as eval does.
    if tdoa.is_empty() && !range.is_empty() {
        return insuwb_fusion::runner::run_aided(&imu, &range, &vel, &height, &w.fusion, est)
            .unwrap();
    }
    insuwb_fusion::runner::run_aided(&imu, &tdoa, &vel, &height, &w.fusion, est).unwrap()
}

/// The child processes of `parent`: `(pid, command name)` (the stages of a
/// launcher).
pub fn child_processes(parent: u32) -> Vec<(u32, String)> {
    let parent = parent.to_string();
    let mut out = Vec::new();
    let Ok(dir) = std::fs::read_dir("/proc") else {
        return out;
    };
    for e in dir.filter_map(Result::ok) {
        let Ok(pid) = e.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        let Ok(stat) = std::fs::read_to_string(format!("/proc/{pid}/stat")) else {
            continue;
        };
        // "pid (comm) state ppid ...": comm may hold spaces, so split at ')'.
        let (Some(open), Some(close)) = (stat.find('('), stat.rfind(')')) else {
            continue;
        };
        if stat[close + 1..].split_whitespace().nth(1) == Some(parent.as_str()) {
            out.push((pid, stat[open + 1..close].to_owned()));
        }
    }
    out
}

/// Runs `cmd` to its end with its output captured, killing it (and failing)
/// after `bound`.
pub fn run_bounded(cmd: &mut Command, bound: Duration) -> Output {
    let mut child = cmd
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_bounded(&mut child, &format!("{cmd:?}"), bound);
    child.wait_with_output().unwrap()
}

/// Waits for `child` to end, killing it and failing after `bound`.
pub fn wait_bounded(child: &mut Child, what: &str, bound: Duration) {
    let deadline = Instant::now() + bound;
    while child.try_wait().unwrap().is_none() {
        if Instant::now() >= deadline {
            let _ = child.kill();
            let err = child
                .stderr
                .take()
                .map(|mut e| {
                    let mut s = String::new();
                    let _ = std::io::Read::read_to_string(&mut e, &mut s);
                    s
                })
                .unwrap_or_default();
            let _ = child.wait();
            panic!("{what} did not end within {bound:?}: {err}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Skips (prints why) where `CI` is not set; fails where it is.
pub fn skip_or_fail(why: &str) {
    assert!(
        std::env::var_os("CI").is_none(),
        "{why}; CI is set, so this fails instead of skipping"
    );
    eprintln!("SKIPPED: {why}");
}

/// The Python of the virtual environment `.ci/run` makes (`INSUWB_PYENV`
/// or `<workspace>/target/pyenv`), when it imports `modules` (e.g.
/// `"cyclonedds"`, `"mcap, mcap_ros2, rosbags"`).
pub fn pyenv_python(modules: &str) -> Option<PathBuf> {
    let env = std::env::var_os("INSUWB_PYENV").map_or_else(
        || PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../target/pyenv"),
        PathBuf::from,
    );
    let py = env.join("bin/python");
    let ok = Command::new(&py)
        .args(["-c", &format!("import {modules}")])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    ok.then_some(py)
}

fn is_root() -> bool {
    std::fs::read_to_string("/proc/self/status").is_ok_and(|s| {
        s.lines()
            .find_map(|l| l.strip_prefix("Uid:"))
            .and_then(|v| v.split_whitespace().nth(1).map(|e| e == "0"))
            .unwrap_or(false)
    })
}

/// Loopback up with multicast on and 224.0.0.0/4 routed to it: DDS
/// discovery then stays inside the namespace.
const NETNS_SETUP: &str = "ip link set lo up multicast on && ip route add 224.0.0.0/4 dev lo";

/// Runs the test `test` of this test binary again inside a private network
/// namespace (`unshare -n`, or `unshare -rn` when not root) with the
/// environment variable `inner_env` set, and asserts that it passed there.
/// Where no namespace can be made it skips, or fails where `CI` is set
/// ([`skip_or_fail`]). Every wait is bounded by `bound`.
pub fn run_in_private_netns(inner_env: &str, test: &str, bound: Duration) {
    let flag = if is_root() { "-n" } else { "-rn" };
    let probe = run_bounded(
        Command::new("unshare").args([flag, "sh", "-c", NETNS_SETUP]),
        bound,
    );
    if !probe.status.success() {
        skip_or_fail(&format!(
            "no private network namespace (unshare {flag}): {}",
            String::from_utf8_lossy(&probe.stderr).trim()
        ));
        return;
    }
    let out = run_bounded(
        Command::new("unshare")
            .args([
                flag,
                "sh",
                "-c",
                &format!("{NETNS_SETUP} && exec \"$0\" \"$@\""),
            ])
            .arg(std::env::current_exe().unwrap())
            .args(["--exact", test, "--nocapture", "--test-threads=1"])
            .env(inner_env, "1"),
        bound,
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    eprintln!("{stdout}\n{stderr}");
    assert!(
        out.status.success(),
        "the test body in the namespace failed"
    );
    assert!(
        stdout.contains("1 passed"),
        "the test body did not run in the namespace"
    );
}

/// CLOCK_REALTIME now, ns (what ROS stamps are in).
pub fn realtime_ns() -> i128 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_nanos() as i128
}

/// A script of this package (a path under its folder, e.g.
/// `tests/ros2/imu_publisher.py`) run by the Python `py`.
pub fn python_script(py: &Path, script: &str) -> Command {
    let mut c = Command::new(py);
    c.arg(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(script));
    c
}

/// Three numbers of a JSON array; a value that is not a number (a script's
/// "nan" or "inf") reads as NaN.
pub fn json_f64x3(x: &serde_json::Value) -> [f64; 3] {
    let a: Vec<f64> = x
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e.as_f64().unwrap_or(f64::NAN))
        .collect();
    [a[0], a[1], a[2]]
}

/// Launches group `g` for `group_s` seconds (`insuwb launch --json`), waits
/// until stage `role` is up, runs `script` (e.g. a Python publisher) beside
/// it, and waits for both within `bound`. Echoes the script's output and
/// the launcher's lines holding `echo`; asserts that both succeeded, that
/// no stage restarted and that no /dev/shm file is left. Returns the
/// launcher's JSON report.
pub fn launch_beside_script(
    g: &Group,
    group_s: f64,
    role: &str,
    script: &mut Command,
    echo: &str,
    bound: Duration,
) -> serde_json::Value {
    let mut launcher = Command::new(insuwb())
        .arg("launch")
        .arg(g.dir.join("robot.toml"))
        .args(["--duration", &group_s.to_string(), "--json"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for_lock(g, &mut launcher, bound, role);
    let script_out = run_bounded(script, bound);
    let script_err = String::from_utf8_lossy(&script_out.stderr);
    eprintln!(
        "{}{script_err}",
        String::from_utf8_lossy(&script_out.stdout)
    );
    wait_bounded(&mut launcher, "insuwb launch", bound);
    let out = launcher.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "launch failed:\n{stderr}");
    for l in stderr.lines().filter(|l| l.contains(echo)) {
        eprintln!("{l}");
    }
    assert!(
        script_out.status.success(),
        "{script:?} failed:\n{script_err}\n{stderr}"
    );
    let report: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("no JSON report ({e}):\n{stderr}"));
    assert_eq!(f(&report, "restarts"), 0.0, "{report}");
    assert_eq!(
        g.leftover_shm(),
        Vec::<String>::new(),
        "/dev/shm files left"
    );
    report
}

/// The Python of the virtual environment `.ci/run` makes, when it has the
/// PyPI `cyclonedds` package (the DDS nobody here wrote).
pub fn cyclonedds_python() -> Option<PathBuf> {
    pyenv_python("cyclonedds")
}

/// The entry of a test against `cyclonedds`, one at a time: in the process
/// re-executed inside the network namespace (`inner_env` set) it runs
/// `inner`; otherwise it skips (or fails under `CI`) without the Python
/// environment, else runs the test `test` again in a private network
/// namespace ([`run_in_private_netns`]).
pub fn cyclonedds_test(inner_env: &str, test: &str, bound: Duration, inner: impl FnOnce()) {
    let _one = one_at_a_time();
    if std::env::var_os(inner_env).is_some() {
        inner();
        return;
    }
    if cyclonedds_python().is_none() {
        skip_or_fail("no Python environment with cyclonedds (target/pyenv: run .ci/run, or python3 -m venv target/pyenv && target/pyenv/bin/pip install cyclonedds==11.0.1)");
        return;
    }
    // The test body again, in a namespace of its own with loopback only.
    run_in_private_netns(inner_env, test, bound);
}

/// Waits until stage `role` of `g` holds its lock (it takes it first thing);
/// fails if the launcher ends first or after `bound`.
pub fn wait_for_lock(g: &Group, launcher: &mut Child, bound: Duration, role: &str) {
    let lock = g.dir.join("run").join(format!("stage-{role}.lock"));
    let deadline = Instant::now() + bound;
    while !lock.is_file() {
        if let Some(status) = launcher.try_wait().unwrap() {
            let mut err = String::new();
            if let Some(mut e) = launcher.stderr.take() {
                let _ = std::io::Read::read_to_string(&mut e, &mut err);
            }
            panic!("the launcher ended early ({status}):\n{err}");
        }
        assert!(Instant::now() < deadline, "stage {role} not up");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The launcher's report and log of a run where stage `role` was killed
/// once: it came back, nothing else restarted or was given up, it sent
/// heartbeats, and no /dev/shm file of the group is left.
pub fn assert_restarted_once(report: &serde_json::Value, stderr: &str, role: &str, g: &Group) {
    assert_eq!(f(report, "restarts"), 1.0, "{report}");
    assert_eq!(report["gave_up"], serde_json::json!([]), "{report}");
    assert!(
        stderr.contains(&format!("stage {role} restarted")),
        "stage {role} was not restarted:\n{stderr}"
    );
    assert!(
        report["stages"][role].is_object(),
        "no {role} heartbeat: {report}"
    );
    assert_eq!(
        g.leftover_shm(),
        Vec::<String>::new(),
        "/dev/shm files left"
    );
}

/// A loopback port free now (the kernel's pick, released for the process
/// that listens on it next).
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// utime + stime of process `pid`, in clock ticks.
pub fn cpu_ticks(pid: u32) -> Option<u64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    // Fields 14 and 15 of stat(5), counted from the state (field 3).
    Some(f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?)
}

impl Group {
    /// Puts `stages = [...]` at the top of the group's config (a top-level
    /// key: before the first table).
    pub fn set_stages(&self, stages: &[&str]) {
        let path = self.dir.join("robot.toml");
        let text = std::fs::read_to_string(&path).unwrap();
        let list: Vec<String> = stages.iter().map(|s| format!("\"{s}\"")).collect();
        std::fs::write(&path, format!("stages = [{}]\n{text}", list.join(", "))).unwrap();
    }

    /// Starts `insuwb launch` for `secs` with `--json`, its standard error
    /// into `launch.err` of the group's folder (read it with
    /// [`Group::launch_log`]), its standard output piped.
    pub fn spawn_launch(&self, secs: f64) -> Child {
        let err = std::fs::File::create(self.dir.join("launch.err")).unwrap();
        Command::new(insuwb())
            .arg("launch")
            .arg(self.dir.join("robot.toml"))
            .args(["--duration", &secs.to_string(), "--json"])
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(err)
            .spawn()
            .unwrap()
    }

    /// What [`Group::spawn_launch`]'s launcher wrote on standard error.
    pub fn launch_log(&self) -> String {
        std::fs::read_to_string(self.dir.join("launch.err")).unwrap_or_default()
    }
}

/// Sends signal `sig` (`TERM`, `KILL`, ...) to process `pid`.
pub fn signal(pid: u32, sig: &str) {
    let status = Command::new("kill")
        .args([&format!("-{sig}"), &pid.to_string()])
        .status()
        .unwrap();
    assert!(status.success(), "kill -{sig} {pid}");
}

/// The JSON objects a child prints one a line on its standard output, as
/// they come (a thread reads them; lines that are not JSON are skipped).
pub fn json_lines(out: std::process::ChildStdout) -> std::sync::mpsc::Receiver<serde_json::Value> {
    use std::io::BufRead;
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(out).lines() {
            let Ok(line) = line else { break };
            if let Ok(v) = serde_json::from_str(&line) {
                if tx.send(v).is_err() {
                    break;
                }
            }
        }
    });
    rx
}
