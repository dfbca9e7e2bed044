//! The IMU driver over a real serial device: WitMotion frames from a
//! pseudo-terminal emulator (`insuwb_devices::emulator`) behind a stable
//! symlink, the UWB driver simulated, the whole group under `insuwb launch`.
//! (a) the group fuses with a sane error and the driver recovers the
//! measurement times; (b) unplugging the device for 0.5 s: the driver
//! reports `disconnected`, reconnects after the device's return and nothing
//! restarts (how soon is printed, not asserted: it depends on what else the
//! machine runs); (c) a device that sends only bytes that never make a
//! frame (what a wrong baud rate gives): the driver keeps running, says
//! DEGRADED, and logs an error naming the port, the baud rate and the
//! protocol; (d) a DWM1001 tag as the UWB source of a two-way ranging group
//! (`[uwb] kind = "twr"`, the IMU simulated): its `lec` lines become
//! ranges on `uwb_range`, fixes on `uwb_fix`, and fused states.
//!
//! The emulator plays in step with the group: the test reads the start
//! epoch the launcher hands its stages (`INSUWB_START_EPOCH_NS`, from
//! `/proc/<pid>/environ` of a stage of this group) and plays the scenario's
//! IMU samples at `epoch + t`, as the UWB simulation is paced.
//!
//! The tests start processes: one at a time (a lock).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use insuwb_devices::emulator::{Faults, PlayReport, Player, PtyEmulator};
use insuwb_devices::play::{self, Encoding};
use insuwb_devices::Protocol;
use insuwb_eval::metrics::TruthTrack;
use insuwb_group::recording::{self, Recording};
use insuwb_log::Record;
use insuwb_msg::{
    DeviceCounters, FusedState, GroundTruth, Health, HealthState, ImuSample, StageCounters,
    UwbRange,
};
use insuwb_runtime::monotonic_ns;
use insuwb_sim::rng::{RngExt as _, SeedableRng as _, SimRng};

use crate::common;
use common::{f, one_at_a_time as lock, records, Group};

const SEED: u64 = 3;
const BAUD: u32 = 115_200;

/// A group whose IMU is a WitMotion device at `<dir>/imu` and whose UWB is
/// simulated (`nlos-long`, [`SEED`]); `device_extra` is added to
/// `[devices.imu]`.
fn device_group(name: &str, device_extra: &str) -> (Group, PathBuf) {
    let g = Group::with_config(
        name,
        &format!("imu = \"device\"\nuwb = \"sim\"\nscenario = \"nlos-long\"\nseed = {SEED}"),
        "filter = \"iakf\"",
        "",
    );
    let link = g.dir.join("imu");
    let table = format!(
        "[devices.imu]\nsource = \"serial:{}\"\nprotocol = \"witmotion\"\nbaud = {BAUD}\n{device_extra}\n",
        link.display()
    );
    let cfg = g.dir.join("robot.toml");
    let text = std::fs::read_to_string(&cfg).unwrap() + &table;
    std::fs::write(&cfg, text).unwrap();
    (g, link)
}

/// `insuwb launch` of `g` for `secs`, running; stdout and stderr go to
/// files in the group's folder.
fn spawn_launch(g: &Group, secs: f64) -> Child {
    Command::new(common::insuwb())
        .arg("launch")
        .arg(g.dir.join("robot.toml"))
        .args(["--duration", &secs.to_string(), "--json"])
        .stdin(Stdio::null())
        .stdout(std::fs::File::create(g.dir.join("stdout")).unwrap())
        .stderr(std::fs::File::create(g.dir.join("stderr")).unwrap())
        .spawn()
        .unwrap()
}

/// Waits for the launch; its JSON report and the group's standard error.
fn finish(g: &Group, mut child: Child) -> (serde_json::Value, String) {
    let status = child.wait().unwrap();
    let stderr = std::fs::read_to_string(g.dir.join("stderr")).unwrap_or_default();
    assert!(status.success(), "{}: launch failed:\n{stderr}", g.name);
    let stdout = std::fs::read(g.dir.join("stdout")).unwrap();
    let v: serde_json::Value = serde_json::from_slice(&stdout)
        .unwrap_or_else(|e| panic!("{}: stdout is not JSON ({e}):\n{stderr}", g.name));
    assert_eq!(
        g.leftover_shm(),
        Vec::<String>::new(),
        "{}: /dev/shm files left",
        g.name
    );
    (v, stderr)
}

/// The start epoch the launcher gave the stages of `g`: read from the
/// environment of a stage process whose command line names `g`'s config.
fn group_epoch(g: &Group) -> u64 {
    let config = g.dir.join("robot.toml").display().to_string();
    let deadline = Instant::now() + Duration::from_secs(20);
    while Instant::now() < deadline {
        for entry in std::fs::read_dir("/proc").unwrap().filter_map(Result::ok) {
            let dir = entry.path();
            let Ok(cmdline) = std::fs::read(dir.join("cmdline")) else {
                continue;
            };
            let args: Vec<&[u8]> = cmdline.split(|b| *b == 0).collect();
            let is_stage = args
                .first()
                .is_some_and(|a| String::from_utf8_lossy(a).contains("insuwb-"));
            if !is_stage || !args.contains(&config.as_bytes()) {
                continue;
            }
            let Ok(environ) = std::fs::read(dir.join("environ")) else {
                continue;
            };
            for var in environ.split(|b| *b == 0) {
                if let Some(v) = var.strip_prefix(b"INSUWB_START_EPOCH_NS=") {
                    return String::from_utf8_lossy(v).parse().unwrap();
                }
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    panic!("{}: no stage process with a start epoch found", g.name);
}

/// The scenario the group simulates, and its IMU samples as WitMotion
/// chunks due (ns after the epoch) when their last byte is in at [`BAUD`].
fn witmotion_chunks() -> (Recording, Vec<(u64, Vec<u8>)>) {
    let rec = recording::from_scenario("nlos-long", SEED).unwrap();
    let enc = Encoding {
        baud: BAUD,
        ..Encoding::new(Protocol::WitMotion)
    };
    let chunks = play::imu_chunks(&rec.imu, &enc).unwrap();
    (rec, chunks)
}

/// Runs `g` for `secs` with the IMU device at `<dir>/imu` playing `chunks`
/// from the group's epoch; the report, the group's stderr, the epoch and
/// what the player did.
fn launch_playing(
    g: &Group,
    chunks: Vec<(u64, Vec<u8>)>,
    secs: f64,
) -> (serde_json::Value, String, u64, PlayReport) {
    let pty = PtyEmulator::open_with_link(&g.dir, "imu").unwrap();
    let child = spawn_launch(g, secs);
    let epoch = group_epoch(g);
    let player = Player::start(pty, chunks, epoch, monotonic_ns, Faults::none()).unwrap();
    let (r, stderr) = finish(g, child);
    player.stop();
    let (_, played) = player.join().unwrap();
    (r, stderr, epoch, played)
}

/// Heartbeats of stage `name` in a recording, in publishing order.
fn health_of(recs: &[Record], name: &str) -> Vec<Health> {
    let mut h: Vec<Health> = recs
        .iter()
        .filter_map(|r| match r {
            Record::Health(h) if insuwb_msg::name_str(&h.stage) == name => Some(*h),
            _ => None,
        })
        .collect();
    h.sort_by_key(|h| h.header.pub_time_ns);
    h
}

/// A device driver's counters in heartbeat `h`.
fn device_counters(h: &Health) -> DeviceCounters {
    match h.counters() {
        Ok(StageCounters::Device(c)) => c,
        other => panic!("not a device driver's counters: {other:?}"),
    }
}

/// The state of heartbeat `h`, known to this version.
fn state(h: &Health) -> HealthState {
    h.state().unwrap()
}

/// Horizontal RMS error of the valid UWB-updated fused states against the
/// scenario's truth placed at `epoch`, and how many states it used.
fn fused_rmse(recs: &[Record], rec: &Recording, epoch: u64) -> (f64, usize) {
    let truth: Vec<GroundTruth> = rec
        .truth
        .iter()
        .map(|t| {
            let mut t = *t;
            t.header.meas_time_ns += epoch;
            t
        })
        .collect();
    let track = TruthTrack::new(&truth, 100_000_000);
    let e2: Vec<f64> = recs
        .iter()
        .filter_map(|r| match r {
            Record::Fused(s)
                if s.header.flags & FusedState::FLAG_VALID != 0
                    && s.header.flags & FusedState::FLAG_DEGRADED == 0 =>
            {
                let (p, _) = track.at(s.header.meas_time_ns)?;
                Some((s.pos_m[0] - p[0]).powi(2) + (s.pos_m[1] - p[1]).powi(2))
            }
            _ => None,
        })
        .collect();
    assert!(!e2.is_empty(), "no valid fused state");
    ((e2.iter().sum::<f64>() / e2.len() as f64).sqrt(), e2.len())
}

#[test]
fn a_witmotion_imu_on_a_pty_feeds_the_group_at_10_hz() {
    let _lock = lock();
    let (g, link) = device_group("devimu", "");
    let (rec, chunks) = witmotion_chunks();
    let (r, stderr, epoch, played) = launch_playing(&g, chunks, 10.0);
    assert!(played.chunks_played > 500, "{played:?}");
    assert_eq!(f(&r, "restarts"), 0.0, "{r}\n{stderr}");
    let fused_hz = f(&r, "fused_rate_hz");
    let imu_hz = f(&r, "imu_rate_hz");
    // At most one fused update per 10 Hz fix; at least half of them, a
    // margin a busy machine keeps (a fix that reaches the fusion stage too
    // late is dropped by design).
    assert!((5.0..=10.5).contains(&fused_hz), "fused {fused_hz} Hz: {r}");
    assert!((95.0..=105.0).contains(&imu_hz), "imu {imu_hz} Hz: {r}");

    let recs = records(&g.log_dir());
    // The driver stamps each sample with its measurement time: read time
    // minus the wire time of its 22 bytes at the configured baud.
    let imu: Vec<ImuSample> = recs
        .iter()
        .filter_map(|r| match r {
            Record::Imu(s) => Some(*s),
            _ => None,
        })
        .collect();
    assert!(imu.len() > 500, "{} IMU samples recorded", imu.len());
    let times: Vec<u64> = rec
        .imu
        .iter()
        .map(|s| epoch + s.header.meas_time_ns)
        .collect();
    let errs = stamp_errors(imu.iter().map(|s| s.header.meas_time_ns), &times);
    let median = errs[errs.len() / 2];
    let p99 = errs[errs.len() * 99 / 100];
    assert!(
        median.abs() < 1_000_000,
        "IMU time error median {median} ns (p99 {p99} ns)"
    );

    let (rmse, n) = fused_rmse(&recs, &rec, epoch);
    let health = health_of(&recs, "imu");
    let last = health
        .iter()
        .rev()
        .find(|h| state(h) != HealthState::Stopping)
        .expect("no IMU heartbeat");
    eprintln!(
        "witmotion IMU over {}: fused {fused_hz:.2} Hz, imu {imu_hz:.1} Hz, rmse_horizontal {rmse:.4} m over {n} states; \
         IMU time error median {median} ns, p99 {p99} ns; last heartbeat {last:?}",
        link.display()
    );
    assert!(rmse < 0.06, "rmse_horizontal {rmse:.4} m");
    assert_eq!(state(last), HealthState::Ok, "{last:?}");
    assert_eq!(last.dropped_invalid, 0, "{last:?}");
    assert_eq!(
        device_counters(last).decoder_errors,
        0,
        "decoder errors: {last:?}"
    );
    assert!(
        last.published > 500 && last.received >= 2 * last.published - 2,
        "{last:?}"
    );
}

#[test]
fn unplugging_the_imu_for_half_a_second_reconnects_without_a_restart() {
    let _lock = lock();
    let (g, _link) = device_group(
        "devunplug",
        "reconnect_initial_ms = 50\nreconnect_max_ms = 500",
    );
    let (_rec, chunks) = witmotion_chunks();
    let (unplug_at, back_at) = (4_000_000_000u64, 4_500_000_000u64);
    let (before, after): (Vec<_>, Vec<_>) = chunks
        .into_iter()
        .filter(|(due, _)| *due < 12_000_000_000)
        .partition(|(due, _)| *due < unplug_at);
    let after: Vec<_> = after
        .into_iter()
        .filter(|(due, _)| *due >= back_at)
        .collect();
    let pty = PtyEmulator::open_with_link(&g.dir, "imu").unwrap();
    let child = spawn_launch(&g, 10.0);
    let epoch = group_epoch(&g);
    let device = std::thread::spawn(move || {
        let (mut pty, _) = Player::start(pty, before, epoch, monotonic_ns, Faults::none())
            .unwrap()
            .join()
            .unwrap();
        // Stamped before the unplug: the driver may report it within
        // microseconds, before this thread runs again.
        let unplugged = monotonic_ns();
        pty.disconnect();
        std::thread::sleep(Duration::from_nanos(
            (epoch + back_at).saturating_sub(monotonic_ns()),
        ));
        pty.reconnect().unwrap();
        let back = monotonic_ns();
        let player = Player::start(pty, after, epoch, monotonic_ns, Faults::none()).unwrap();
        (unplugged, back, player)
    });
    let (r, stderr) = finish(&g, child);
    let (unplugged, back, player) = device.join().unwrap();
    player.stop();
    let _ = player.join().unwrap();
    assert_eq!(f(&r, "restarts"), 0.0, "{r}\n{stderr}");

    let recs = records(&g.log_dir());
    let health = health_of(&recs, "imu");
    let at = |h: &Health| h.header.pub_time_ns;
    let down: Vec<&Health> = health
        .iter()
        .filter(|h| state(h) == HealthState::Disconnected)
        .collect();
    assert!(
        !down.is_empty()
            && down
                .iter()
                .all(|h| (unplugged..back + 1_000_000_000).contains(&at(h))),
        "disconnected heartbeats {:?} outside the unplug [{unplugged}, {back}]; states {:?}\n{stderr}",
        down.iter().map(|h| at(h)).collect::<Vec<_>>(),
        health.iter().map(|h| (at(h), state(h))).collect::<Vec<_>>()
    );
    let recovered = health
        .iter()
        .find(|h| at(h) > back && state(h) == HealthState::Ok)
        .expect("the IMU driver never reported OK after the replug");
    let recovery_ms = (at(recovered) - back) as f64 * 1e-6;
    let first_down_ms = (at(down[0]).saturating_sub(unplugged)) as f64 * 1e-6;
    let last = health
        .iter()
        .rev()
        .find(|h| state(h) != HealthState::Stopping)
        .unwrap();
    // Valid fused output goes on after the device's return.
    let valid_after: Vec<u64> = recs
        .iter()
        .filter_map(|r| match r {
            Record::Fused(s)
                if s.header.meas_time_ns > back
                    && s.header.flags & FusedState::FLAG_VALID != 0
                    && s.header.flags & FusedState::FLAG_DEGRADED == 0 =>
            {
                Some(s.header.meas_time_ns)
            }
            _ => None,
        })
        .collect();
    let resumed_ms = valid_after
        .iter()
        .min()
        .map_or(f64::INFINITY, |t| (t - back) as f64 * 1e-6);
    eprintln!(
        "unplugged 0.5 s: disconnected reported {first_down_ms:.1} ms after the unplug, OK {recovery_ms:.1} ms after the replug; \
         valid fused output {resumed_ms:.0} ms after the replug, {} states after it; last heartbeat {last:?}",
        valid_after.len()
    );
    // The driver came back on its own (OK after the replug, found above)
    // and valid fused output resumed; how soon is the figure printed above.
    assert!(
        device_counters(last).reconnects >= 1,
        "no reconnection counted: {last:?}"
    );
    assert_eq!(state(last), HealthState::Ok, "{last:?}");
    assert!(
        valid_after.len() >= 10,
        "valid fused output {resumed_ms:.0} ms after the replug, {} states",
        valid_after.len()
    );
}

#[test]
fn bytes_that_never_frame_are_named_as_a_wrong_baud_rate_and_the_driver_stays_up() {
    let _lock = lock();
    let (g, link) = device_group("devbaud", "wrong_baud_bytes = 2000");
    // What a WitMotion at another baud rate looks like: bytes, never a
    // frame (no 0x55 header at all), 22 every 10 ms.
    let mut rng = SimRng::seed_from_u64(1);
    let chunks: Vec<(u64, Vec<u8>)> = (0..600u64)
        .map(|k| {
            let bytes = (0..22)
                .map(|_| match rng.random::<u8>() {
                    0x55 => 0x54,
                    b => b,
                })
                .collect();
            (k * 10_000_000, bytes)
        })
        .collect();
    let (r, stderr, _, _) = launch_playing(&g, chunks, 5.0);
    assert_eq!(f(&r, "restarts"), 0.0, "{r}\n{stderr}");
    let line = stderr
        .lines()
        .find(|l| l.contains("no valid witmotion frame in"))
        .unwrap_or_else(|| panic!("no wrong-baud error in the group's stderr:\n{stderr}"));
    eprintln!("the driver said: {line}");
    assert!(line.contains("ERROR"), "{line}");
    assert!(line.contains(&link.display().to_string()), "{line}");
    assert!(
        line.contains(&format!("at {BAUD} baud: wrong baud rate or protocol?")),
        "{line}"
    );
    assert_eq!(
        stderr.matches("no valid witmotion frame in").count(),
        1,
        "the error is given once per episode"
    );
    let recs = records(&g.log_dir());
    let health = health_of(&recs, "imu");
    let running: Vec<&Health> = health
        .iter()
        .filter(|h| state(h) != HealthState::Stopping)
        .collect();
    assert!(running.len() >= 10, "{} IMU heartbeats", running.len());
    assert!(
        running.iter().all(|h| state(h) == HealthState::Degraded),
        "states {:?}",
        running.iter().map(|h| state(h)).collect::<Vec<_>>()
    );
    let last = running.last().unwrap();
    assert_eq!(last.published, 0, "{last:?}");
    assert!(
        device_counters(last).decoder_errors >= 1,
        "no resync counted: {last:?}"
    );
}

#[test]
fn a_dwm1001_tag_on_a_pty_feeds_a_two_way_ranging_group() {
    let _lock = lock();
    let g = Group::with_config(
        "devdwm",
        &format!("imu = \"sim\"\nuwb = \"device\"\nscenario = \"twr-3.4\"\nseed = {SEED}"),
        "filter = \"iakf\"",
        "",
    );
    let link = g.dir.join("uwb");
    let cfg = g.dir.join("robot.toml");
    let text = std::fs::read_to_string(&cfg).unwrap()
        + &format!(
            "[uwb]\nkind = \"twr\"\n[devices.uwb]\nsource = \"serial:{}\"\nprotocol = \"dwm1001\"\nbaud = {BAUD}\n",
            link.display()
        );
    std::fs::write(&cfg, text).unwrap();
    let sc = insuwb_fusion::scenario::ScenarioFile::load("twr-3.4").unwrap();
    let sim = sc.simulate(SEED).unwrap();
    let enc = Encoding {
        baud: BAUD,
        ..Encoding::new(Protocol::Dwm1001)
    };
    let chunks = play::range_chunks(&sim.range, &enc).unwrap();
    let pty = PtyEmulator::open_with_link(&g.dir, "uwb").unwrap();
    let child = spawn_launch(&g, 12.0);
    let epoch = group_epoch(&g);
    let player = Player::start(pty, chunks, epoch, monotonic_ns, Faults::none()).unwrap();
    let (r, stderr) = finish(&g, child);
    player.stop();
    let (_, played) = player.join().unwrap();
    assert!(played.chunks_played > 500, "{played:?}");
    assert_eq!(f(&r, "restarts"), 0.0, "{r}\n{stderr}");

    let recs = records(&g.log_dir());
    let ranges: Vec<UwbRange> = recs
        .iter()
        .filter_map(|r| match r {
            Record::Range(m) => Some(*m),
            _ => None,
        })
        .collect();
    let fixes = recs.iter().filter(|r| matches!(r, Record::Fix(_))).count();
    assert!(ranges.len() > 2000, "{} ranges recorded", ranges.len());
    assert!(fixes > 500, "{fixes} fixes recorded");
    // Anchors as the tag prints them (two decimals), one round end per
    // line of four.
    for m in &ranges {
        let want = sc
            .sim
            .uwb
            .anchors
            .iter()
            .find(|a| a.id == m.anchor)
            .unwrap();
        assert!(
            m.anchor_pos_m
                .iter()
                .zip(&want.pos_m)
                .all(|(a, b)| (a - b).abs() < 0.005),
            "{m:?}"
        );
    }
    let ends = ranges
        .iter()
        .filter(|m| m.header.flags & UwbRange::FLAG_EPOCH_END != 0)
        .count();
    assert!(
        ends * 4 >= ranges.len() - 4 && ends * 4 <= ranges.len() + 4,
        "{ends} round ends in {} ranges",
        ranges.len()
    );
    // Each range is stamped with its round's measurement time: the read
    // time less the wire time of its line.
    let times: Vec<u64> = sim
        .range
        .iter()
        .map(|m| epoch + m.header.meas_time_ns)
        .collect();
    let errs = stamp_errors(ranges.iter().map(|m| m.header.meas_time_ns), &times);
    let median = errs[errs.len() / 2];

    let truth: Vec<GroundTruth> = sim.truth.clone();
    let rec = Recording {
        truth,
        ..Recording::default()
    };
    let (rmse, n) = fused_rmse(&recs, &rec, epoch);
    let health = health_of(&recs, "uwb");
    let last = health
        .iter()
        .rev()
        .find(|h| state(h) != HealthState::Stopping)
        .expect("no UWB heartbeat");
    eprintln!(
        "dwm1001 over {}: {} ranges, {fixes} fixes, range time error median {median} ns; \
         rmse_horizontal {rmse:.4} m over {n} states; fused {:.2} Hz; last heartbeat {last:?}",
        link.display(),
        ranges.len(),
        f(&r, "fused_rate_hz")
    );
    assert!(
        median.abs() < 1_000_000,
        "range time error median {median} ns"
    );
    assert!(rmse < 0.3, "rmse_horizontal {rmse:.4} m");
    assert_eq!(state(last), HealthState::Ok, "{last:?}");
    assert_eq!(last.dropped_invalid, 0, "{last:?}");
    assert_eq!(device_counters(last).decoder_errors, 0, "{last:?}");
    assert!(last.published > 2000, "{last:?}");
}

/// Each of `stamps` less the nearest of the sorted `times` it was played
/// at, ns, sorted.
fn stamp_errors(stamps: impl Iterator<Item = u64>, times: &[u64]) -> Vec<i64> {
    let mut errs: Vec<i64> = stamps
        .map(|t| {
            let k = times.partition_point(|x| *x < t);
            let near = [k.saturating_sub(1), k.min(times.len() - 1)]
                .into_iter()
                .min_by_key(|&i| times[i].abs_diff(t))
                .unwrap();
            t as i64 - times[near] as i64
        })
        .collect();
    errs.sort_unstable();
    errs
}
