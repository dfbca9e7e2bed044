//! Real iceoryx2 shared memory: two nodes in one process, a second process
//! (`insuwb-runtime-probe`), history, gaps, restarts, signals, dead-node
//! cleanup, inspection, and no file left behind.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use insuwb_msg::{
    topics, FusionCounters, Header, Health, HealthState, ImuSample, StageCounters, LAYOUT_VERSION,
};
use insuwb_runtime::cleanup::{self, NodeLiveness, ServiceKind};
use insuwb_runtime::{monotonic_ns, HealthCounters, RuntimeConfig, Stage, Wake};

const PROBE: &str = env!("CARGO_BIN_EXE_insuwb-runtime-probe");

static COUNTER: AtomicUsize = AtomicUsize::new(0);

/// A test's own prefix and root folder; files are removed on drop.
struct Env {
    prefix: String,
    root: PathBuf,
}

impl Env {
    fn new(test: &str) -> Self {
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let prefix = format!("iwt{}_{}_{}_", std::process::id(), test, n);
        let root = std::env::temp_dir().join(format!("{prefix}iox2"));
        Self { prefix, root }
    }

    fn cfg(&self, stage: &str) -> RuntimeConfig {
        RuntimeConfig {
            prefix: self.prefix.clone(),
            root_path: Some(self.root.clone()),
            stage_name: stage.into(),
            ..Default::default()
        }
    }

    fn shm_files(&self) -> Vec<String> {
        std::fs::read_dir("/dev/shm")
            .unwrap()
            .filter_map(|e| e.ok())
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with(&self.prefix))
            .collect()
    }

    fn probe(&self, args: &[&str]) -> Command {
        let mut c = Command::new(PROBE);
        c.args(args)
            .arg(format!("prefix={}", self.prefix))
            .arg(format!("root={}", self.root.display()))
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit());
        c
    }

    /// Removes the test's files and checks nothing of the prefix is left.
    fn finish(self) {
        cleanup::remove_prefix_files(&self.prefix, Some(&self.root)).unwrap();
        assert_eq!(self.shm_files(), Vec::<String>::new());
        assert!(!self.root.exists(), "{} left", self.root.display());
    }
}

impl Drop for Env {
    fn drop(&mut self) {
        let _ = cleanup::remove_prefix_files(&self.prefix, Some(&self.root));
    }
}

/// Reads one stdout line of a probe (blocking).
fn line(out: &mut BufReader<ChildStdout>) -> String {
    let mut s = String::new();
    out.read_line(&mut s).unwrap();
    s.trim().to_owned()
}

/// Waits for a child to exit, killing it after a generous guard (a hang guard,
/// not a timing assertion).
fn wait_exit(child: &mut Child) -> std::process::ExitStatus {
    let guard = Instant::now();
    loop {
        if let Some(st) = child.try_wait().unwrap() {
            return st;
        }
        if guard.elapsed() > Duration::from_secs(30) {
            let _ = child.kill();
            panic!("child did not exit");
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

fn imu(meas: u64) -> ImuSample {
    ImuSample {
        header: Header::new(0, meas),
        accel_mps2: [0.0, 0.0, 9.81],
        gyro_rps: [0.0; 3],
    }
}

fn stat(line: &str, key: &str) -> u64 {
    line.split_whitespace()
        .find_map(|kv| kv.strip_prefix(&format!("{key}=")))
        .unwrap_or_else(|| panic!("{key} missing in {line:?}"))
        .parse()
        .unwrap()
}

#[test]
fn two_nodes_in_one_process_exchange_stamped_samples() {
    let env = Env::new("two");
    {
        let a = Stage::new(RuntimeConfig {
            generation: Some(3),
            source_id: Some(42),
            ..env.cfg("a")
        })
        .unwrap();
        let b = Stage::new(env.cfg("b")).unwrap();
        assert_eq!((a.generation(), a.source_id()), (3, 42));
        let mut p = a.publisher::<ImuSample>(topics::IMU).unwrap();
        let s = b.subscriber::<ImuSample>(topics::IMU).unwrap();
        let t0 = monotonic_ns();
        for i in 0..5u64 {
            let mut x = imu(1000 + i);
            x.header.flags = 9;
            x.header.seq = 777; // overwritten
            x.header.layout_version = 0; // overwritten
            assert_eq!(p.publish(x).unwrap(), i);
        }
        let mut got = Vec::new();
        assert_eq!(s.drain(|x| got.push(x)).unwrap(), 5);
        let t1 = monotonic_ns();
        for (i, x) in got.iter().enumerate() {
            let h = x.header;
            assert_eq!(h.seq, i as u64);
            assert_eq!(h.meas_time_ns, 1000 + i as u64);
            assert_eq!((h.generation, h.source_id, h.flags), (3, 42, 9));
            assert_eq!(h.layout_version, LAYOUT_VERSION);
            assert!(h.pub_time_ns >= t0 && h.pub_time_ns <= t1);
            assert_eq!(x.accel_mps2, [0.0, 0.0, 9.81]);
        }
        assert!(got
            .windows(2)
            .all(|w| w[0].header.pub_time_ns <= w[1].header.pub_time_ns));
        let st = s.stats();
        assert_eq!((st.received, st.seq_gaps, st.restarts), (5, 0, 0));
        assert_eq!(s.last_header().unwrap().seq, 4);
        assert_eq!(s.receive().unwrap(), None);

        // A wrong layout version is dropped and counted; a skipped seq is a gap.
        let mut bad = imu(1);
        bad.header.layout_version = LAYOUT_VERSION + 1;
        p.publish_raw(bad).unwrap();
        p.skip_seq(2);
        p.publish(imu(2)).unwrap();
        let x = s.receive().unwrap().unwrap();
        assert_eq!(x.header.seq, 7);
        assert_eq!(s.receive().unwrap(), None);
        let st = s.stats();
        assert_eq!((st.received, st.dropped_version, st.seq_gaps), (6, 1, 2));

        // Heartbeat carries the counters, the stage name and the pid.
        let hs = b.subscriber::<Health>(topics::HEALTH).unwrap();
        let mut hr = a.health_reporter().unwrap();
        let mut c = HealthCounters {
            published: p.published(),
            dropped_time: 4,
            stage: StageCounters::Fusion(FusionCounters {
                updates: 1,
                outliers: 2,
                resets: 3,
                corrections: 4,
            }),
            ..Default::default()
        };
        c.add_sub(&st);
        hr.report(&c, HealthState::Degraded).unwrap();
        let h = hs.receive().unwrap().unwrap();
        assert_eq!(insuwb_msg::name_str(&h.stage), "a");
        assert_eq!(h.pid, std::process::id());
        assert_eq!(h.state(), Ok(HealthState::Degraded));
        assert_eq!(
            (
                h.received,
                h.published,
                h.dropped_version,
                h.seq_gaps,
                h.dropped_time
            ),
            (6, 7, 1, 2, 4)
        );
        assert_eq!(h.counters(), Ok(c.stage));
        assert_eq!((h.header.source_id, h.header.generation), (42, 3));
        // Not due again right away.
        assert_eq!(
            hr.report_if_due(monotonic_ns(), &c, HealthState::Ok)
                .unwrap(),
            None
        );
    }
    env.finish();
}

#[test]
fn waiter_reports_which_attachment_fired_and_times_out() {
    let env = Env::new("wait");
    {
        let st = Stage::new(env.cfg("w")).unwrap();
        let mut p = st.publisher::<ImuSample>(topics::IMU).unwrap();
        let s_imu = st.subscriber::<ImuSample>(topics::IMU).unwrap();
        let s_fix = st
            .subscriber::<insuwb_msg::UwbFix>(topics::UWB_FIX)
            .unwrap();
        let w = st.waiter().unwrap();
        let a_imu = w.attach(&s_imu).unwrap();
        let a_fix = w.attach(&s_fix).unwrap();

        // Nothing published: timeout.
        assert!(matches!(
            w.wait_timeout(Duration::from_millis(30)).unwrap(),
            Wake::Timeout
        ));
        p.publish(imu(5)).unwrap();
        let Wake::Fired(f) = w.wait_timeout(Duration::from_secs(10)).unwrap() else {
            panic!("expected a wake-up")
        };
        assert!(f.contains(&a_imu) && !f.contains(&a_fix));
        assert_eq!(f.len(), 1);
        assert_eq!(s_imu.drain(|_| {}).unwrap(), 1);
        // The wake-up was consumed by reading until empty: no spurious wake.
        assert!(matches!(
            w.wait_timeout(Duration::from_millis(30)).unwrap(),
            Wake::Timeout
        ));

        // An interval fires on its own.
        let tick = w.attach_interval(Duration::from_millis(10)).unwrap();
        let Wake::Fired(f) = w.wait_timeout(Duration::from_secs(10)).unwrap() else {
            panic!("expected the tick")
        };
        assert!(f.contains(&tick) && !f.contains(&a_imu));
        assert!(w.attach_interval(Duration::ZERO).is_err());
    }
    env.finish();
}

#[test]
fn deadlines_end_a_wait_never_early_and_without_millisecond_rounding() {
    let env = Env::new("deadline");
    {
        let st = Stage::new(env.cfg("d")).unwrap();
        let mut p = st.publisher::<ImuSample>(topics::IMU).unwrap();
        let s_imu = st.subscriber::<ImuSample>(topics::IMU).unwrap();
        let w = st.waiter().unwrap();
        let a_imu = w.attach(&s_imu).unwrap();
        // 40 deadlines 2.3 ms ahead: epoll's millisecond timeout would end
        // every wait at 3 ms or later, at least 700 us late.
        let mut late_us = Vec::new();
        for _ in 0..40 {
            let due = insuwb_runtime::monotonic_ns() + 2_300_000;
            assert!(matches!(w.wait_deadline(due).unwrap(), Wake::Timeout));
            let now = insuwb_runtime::monotonic_ns();
            assert!(now >= due, "woke {} ns early", due - now);
            late_us.push((now - due) / 1000);
        }
        late_us.sort_unstable();
        let median = late_us[late_us.len() / 2];
        eprintln!("deadline lateness: median {median} us, all {late_us:?}");
        // Millisecond rounding makes every wait at least 700 us late; one
        // wait that ended sooner shows that it is not rounded. The best of
        // 40 and not the median: on a busy machine the scheduler delays
        // most wake-ups by any amount (the median is a figure, in
        // BENCHMARKS.md "IPC: one-way latency and timer wake-ups").
        let best = late_us[0];
        assert!(
            best < 700,
            "every wait ended at least {best} us late: {late_us:?}"
        );

        // A deadline already passed returns at once; a publication before
        // the deadline wakes the waiter for it, and the timer armed for that
        // deadline does not fire a later, longer wait early.
        assert!(matches!(
            w.wait_deadline(insuwb_runtime::monotonic_ns() - 1).unwrap(),
            Wake::Timeout
        ));
        p.publish(imu(1)).unwrap();
        let due = insuwb_runtime::monotonic_ns() + 20_000_000;
        let Wake::Fired(f) = w.wait_deadline(due).unwrap() else {
            panic!("expected the sample")
        };
        assert!(f.contains(&a_imu));
        assert_eq!(s_imu.drain(|_| {}).unwrap(), 1);
        std::thread::sleep(Duration::from_millis(25));
        // The 20 ms deadline has passed (its timer expired unread): a new
        // 30 ms wait must last its 30 ms.
        let t0 = insuwb_runtime::monotonic_ns();
        assert!(matches!(
            w.wait_deadline(t0 + 30_000_000).unwrap(),
            Wake::Timeout
        ));
        assert!(insuwb_runtime::monotonic_ns() - t0 >= 30_000_000);

        // Intervals keep their phase through the same timer.
        let tick = w.attach_interval(Duration::from_millis(7)).unwrap();
        let t0 = insuwb_runtime::monotonic_ns();
        let mut ticks = 0;
        while ticks < 10 {
            if let Wake::Fired(f) = w.wait_timeout(Duration::from_secs(10)).unwrap() {
                ticks += u32::from(f.contains(&tick));
            }
        }
        let elapsed = insuwb_runtime::monotonic_ns() - t0;
        assert!(elapsed >= 70_000_000, "10 ticks of 7 ms in {elapsed} ns");
    }
    env.finish();
}

#[test]
fn busy_poll_waiter_wakes_times_out_and_fires_intervals() {
    let env = Env::new("busy");
    {
        let st = Stage::new(RuntimeConfig {
            busy_poll: true,
            ..env.cfg("b")
        })
        .unwrap();
        let mut p = st.publisher::<ImuSample>(topics::IMU).unwrap();
        let s = st.subscriber::<ImuSample>(topics::IMU).unwrap();
        let w = st.waiter().unwrap();
        assert!(w.is_busy_poll());
        let a = w.attach(&s).unwrap();
        assert!(matches!(
            w.wait_timeout(Duration::from_millis(10)).unwrap(),
            Wake::Timeout
        ));
        p.publish(imu(1)).unwrap();
        let Wake::Fired(f) = w.wait_timeout(Duration::from_secs(10)).unwrap() else {
            panic!("expected a wake-up")
        };
        assert!(f.contains(&a));
        assert_eq!(s.drain(|_| {}).unwrap(), 1);
        let t = w.attach_interval(Duration::from_millis(5)).unwrap();
        let Wake::Fired(f) = w.wait_timeout(Duration::from_secs(10)).unwrap() else {
            panic!("expected the tick")
        };
        assert!(f.contains(&t) && !f.contains(&a));
    }
    env.finish();
}

/// Busy-poll latency across processes (burns a core for 2 s: run on demand,
/// `cargo test -p insuwb-runtime --release -- --ignored --nocapture`).
#[test]
#[ignore = "burns a CPU core; latency figure on demand"]
fn busy_poll_one_way_latency() {
    let env = Env::new("blat");
    let n = 200;
    let mut child = env
        .probe(&["sub", &format!("expect={n}"), "busy=1"])
        .spawn()
        .unwrap();
    let mut out = BufReader::new(child.stdout.take().unwrap());
    assert_eq!(line(&mut out), "ready");
    {
        let st = Stage::new(env.cfg("tx")).unwrap();
        let mut p = st.publisher::<ImuSample>(topics::IMU).unwrap();
        while p.subscriber_count() == 0 {
            std::thread::sleep(Duration::from_millis(1));
        }
        for i in 0..n {
            p.publish(imu(i)).unwrap();
            st.sleep(Duration::from_millis(10)).unwrap();
        }
        let stats = line(&mut out);
        assert!(wait_exit(&mut child).success());
        assert_eq!(stat(&stats, "received"), n);
        println!(
            "one-way latency publish->receive, busy poll, 2 processes, 100 Hz, n={n}: p50 {:.1} us, p99 {:.1} us, max {:.1} us",
            stat(&stats, "p50_ns") as f64 / 1e3,
            stat(&stats, "p99_ns") as f64 / 1e3,
            stat(&stats, "max_ns") as f64 / 1e3
        );
    }
    env.finish();
}

#[test]
fn late_subscriber_in_another_process_gets_history_while_publisher_lives() {
    let env = Env::new("hist");
    let mut child = env
        .probe(&["pub", "count=20", "linger=1", "gen=5"])
        .spawn()
        .unwrap();
    let mut out = BufReader::new(child.stdout.take().unwrap());
    assert_eq!(line(&mut out), "done 20");
    {
        let st = Stage::new(env.cfg("late")).unwrap();
        let s = st.subscriber::<ImuSample>(topics::IMU).unwrap();
        let mut got = Vec::new();
        let guard = Instant::now();
        while got.len() < 20 && guard.elapsed() < Duration::from_secs(20) {
            s.drain(|x| got.push(x)).unwrap();
        }
        let seqs: Vec<u64> = got.iter().map(|x| x.header.seq).collect();
        assert_eq!(seqs, (0..20).collect::<Vec<_>>());
        assert!(got.iter().all(|x| x.header.generation == 5));
        assert_eq!(got[7].gyro_rps[0], 7.0);
        assert_eq!(s.stats().seq_gaps, 0);
    }
    drop(child.stdin.take());
    assert!(wait_exit(&mut child).success());
    env.finish();
}

#[test]
fn gaps_and_restarts_across_processes() {
    let env = Env::new("gap");
    {
        let st = Stage::new(env.cfg("rx")).unwrap();
        let s = st.subscriber::<ImuSample>(topics::IMU).unwrap();
        let w = st.waiter().unwrap();
        let a = w.attach(&s).unwrap();
        let mut got: Vec<ImuSample> = Vec::new();
        let mut recv_until = |n: usize| {
            while got.len() < n {
                match w.wait_timeout(Duration::from_secs(20)).unwrap() {
                    Wake::Fired(f) => {
                        assert!(f.contains(&a));
                        s.drain(|x| got.push(x)).unwrap();
                    }
                    other => panic!("{other:?}"),
                }
            }
            got.clone()
        };

        // Generation 0 (from the environment), seq jumps by 3 before sample 5.
        let mut c1 = env.probe(&[
            "pub",
            "count=10",
            "gap_at=5",
            "gap=3",
            "wait_subs=1",
            "linger=1",
        ]);
        c1.env("INSUWB_GENERATION", "0");
        let mut c1 = c1.spawn().unwrap();
        let all = recv_until(10);
        let seqs: Vec<u64> = all.iter().map(|x| x.header.seq).collect();
        assert_eq!(seqs, vec![0, 1, 2, 3, 4, 8, 9, 10, 11, 12]);
        assert_eq!((s.stats().seq_gaps, s.stats().restarts), (3, 0));
        drop(c1.stdin.take());
        assert!(wait_exit(&mut c1).success());

        // The restarted publisher (generation 1 via INSUWB_GENERATION) starts at seq 0.
        let mut c2 = env.probe(&["pub", "count=4", "wait_subs=1", "linger=1"]);
        c2.env("INSUWB_GENERATION", "1");
        let mut c2 = c2.spawn().unwrap();
        let all = recv_until(14);
        let tail: Vec<(u32, u64)> = all[10..]
            .iter()
            .map(|x| (x.header.generation, x.header.seq))
            .collect();
        assert_eq!(tail, vec![(1, 0), (1, 1), (1, 2), (1, 3)]);
        let stt = s.stats();
        assert_eq!((stt.seq_gaps, stt.restarts, stt.received), (3, 1, 14));
        drop(c2.stdin.take());
        assert!(wait_exit(&mut c2).success());
    }
    env.finish();
}

#[test]
fn receiver_in_another_process_and_one_way_latency() {
    let env = Env::new("lat");
    let n = 200;
    let mut child = env.probe(&["sub", &format!("expect={n}")]).spawn().unwrap();
    let mut out = BufReader::new(child.stdout.take().unwrap());
    assert_eq!(line(&mut out), "ready");
    {
        let st = Stage::new(env.cfg("tx")).unwrap();
        let mut p = st.publisher::<ImuSample>(topics::IMU).unwrap();
        let guard = Instant::now();
        while p.subscriber_count() == 0 && guard.elapsed() < Duration::from_secs(20) {
            std::thread::sleep(Duration::from_millis(1));
        }
        // 100 Hz, the receiver idles between samples (the realistic case).
        for i in 0..n {
            p.publish(imu(i)).unwrap();
            st.sleep(Duration::from_millis(10)).unwrap();
        }
        let stats = line(&mut out);
        assert!(wait_exit(&mut child).success());
        assert_eq!(stat(&stats, "received"), n);
        assert_eq!(stat(&stats, "gaps"), 0);
        println!(
            "one-way latency publish->receive, Waiter, 2 processes, 100 Hz, n={n}: p50 {:.1} us, p99 {:.1} us, max {:.1} us",
            stat(&stats, "p50_ns") as f64 / 1e3,
            stat(&stats, "p99_ns") as f64 / 1e3,
            stat(&stats, "max_ns") as f64 / 1e3
        );
    }
    env.finish();
}

fn signal_stops_waiting_process(sig: &str) {
    let env = Env::new(&format!("sig{}", sig.to_lowercase()));
    let mut child = env.probe(&["wait"]).spawn().unwrap();
    let mut out = BufReader::new(child.stdout.take().unwrap());
    assert_eq!(line(&mut out), "ready");
    let t = Instant::now();
    let ok = Command::new("kill")
        .args([&format!("-{sig}"), &child.id().to_string()])
        .status()
        .unwrap();
    assert!(ok.success());
    let st = wait_exit(&mut child);
    println!("SIG{sig} -> exit in {:?}", t.elapsed());
    assert_eq!(st.code(), Some(0), "{st:?}");
    assert_eq!(line(&mut out), "shutdown");
    // A clean exit leaves no node behind.
    let nodes = cleanup::list_nodes(&env.cfg("x")).unwrap();
    assert!(nodes.is_empty(), "{nodes:?}");
    env.finish();
}

#[test]
fn sigterm_stops_a_process_blocked_in_the_wait_loop_with_status_0() {
    signal_stops_waiting_process("TERM");
}

#[test]
fn sigint_stops_a_process_blocked_in_the_wait_loop_with_status_0() {
    signal_stops_waiting_process("INT");
}

#[test]
fn sigkilled_node_is_dead_until_a_new_stage_cleans_it() {
    let env = Env::new("kill");
    let mut child = env.probe(&["wait", "name=victim"]).spawn().unwrap();
    let pid = child.id() as i32;
    let mut out = BufReader::new(child.stdout.take().unwrap());
    assert_eq!(line(&mut out), "ready");
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();

    let nodes = cleanup::list_nodes(&env.cfg("x")).unwrap();
    assert_eq!(nodes.len(), 1, "{nodes:?}");
    assert_eq!(nodes[0].state, NodeLiveness::Dead);
    assert_eq!(nodes[0].name, "victim");
    assert_eq!(nodes[0].pid, Some(pid));
    {
        let st = Stage::new(env.cfg("new")).unwrap();
        let nodes = cleanup::list_nodes(&env.cfg("x")).unwrap();
        let dead = nodes
            .iter()
            .filter(|n| n.state == NodeLiveness::Dead)
            .count();
        assert_eq!(dead, 0, "{nodes:?}");
        assert_eq!(nodes.len(), 1);
        assert_eq!(nodes[0].name, "new");
        assert_eq!(nodes[0].pid, Some(std::process::id() as i32));
        // The dead publisher's port is gone too: the topic is usable again.
        let mut p = st.publisher::<ImuSample>(topics::IMU).unwrap();
        let s = st.subscriber::<ImuSample>(topics::IMU).unwrap();
        p.publish(imu(1)).unwrap();
        assert!(s.receive().unwrap().is_some());
        assert_eq!(s.publisher_count(), 1);
        assert_eq!(cleanup::cleanup_dead_nodes(&env.cfg("x")).unwrap(), 0);
    }
    env.finish();
}

#[test]
fn inspection_lists_services_with_port_counts() {
    let env = Env::new("insp");
    {
        let st = Stage::new(env.cfg("i")).unwrap();
        let _p = st.publisher::<ImuSample>(topics::IMU).unwrap();
        let _s1 = st.subscriber::<ImuSample>(topics::IMU).unwrap();
        let _s2 = st.subscriber::<ImuSample>(topics::IMU).unwrap();
        let _h = st.health_reporter().unwrap();
        let services = cleanup::list_services(&env.cfg("x")).unwrap();
        let names: Vec<&str> = services.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(names, vec!["health", "health.ev", "imu", "imu.ev"]);
        let imu = &services[2];
        assert_eq!(imu.kind, ServiceKind::PublishSubscribe);
        assert_eq!((imu.publishers, imu.subscribers), (Some(1), Some(2)));
        let ev = &services[3];
        assert_eq!(ev.kind, ServiceKind::Event);
        assert_eq!((ev.notifiers, ev.listeners), (Some(1), Some(2)));
        assert_eq!(
            (services[0].publishers, services[0].subscribers),
            (Some(1), Some(0))
        );
        assert!(imu.nodes.iter().all(|(_, l)| *l == NodeLiveness::Alive));
        // The inspection node is gone again.
        let nodes = cleanup::list_nodes(&env.cfg("x")).unwrap();
        assert_eq!(nodes.len(), 1);
    }
    env.finish();
}

#[test]
fn remove_prefix_files_refuses_wide_prefixes_and_spares_others() {
    assert!(cleanup::remove_prefix_files("", None).is_err());
    assert!(cleanup::remove_prefix_files("a*", None).is_err());
    assert!(cleanup::remove_prefix_files("../", None).is_err());
    // Another prefix's files survive.
    let env = Env::new("keep");
    let other = Env::new("keepo");
    let st = Stage::new(env.cfg("k")).unwrap();
    let _p = st.publisher::<ImuSample>(topics::IMU).unwrap();
    let r = cleanup::remove_prefix_files(&other.prefix, Some(&other.root)).unwrap();
    assert_eq!(r, cleanup::Removed::default());
    assert!(!env.shm_files().is_empty());
    drop(_p);
    drop(st);
    other.finish();
    env.finish();
}

#[test]
fn stage_rejects_bad_config_and_bad_generation_env() {
    let bad = RuntimeConfig {
        prefix: "bad prefix".into(),
        ..Default::default()
    };
    let e = Stage::new(bad).unwrap_err().to_string();
    assert!(e.contains("runtime.prefix"), "{e}");
    // Through a probe, so the test process's environment stays untouched.
    let env = Env::new("genv");
    let o = env
        .probe(&["wait"])
        .env("INSUWB_GENERATION", "x1")
        .stdin(Stdio::null())
        .stderr(Stdio::piped())
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("INSUWB_GENERATION") && err.contains("x1"),
        "{err}"
    );
    env.finish();
}
