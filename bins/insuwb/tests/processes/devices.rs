//! The group fed through emulated devices, and `insuwb emulate` itself:
//! real processes, real pseudo-terminals, real loopback sockets.
//!
//! - `insuwb demo --via-devices` (WitMotion on a pty, Eliko over TCP) keeps
//!   the 10 Hz loop and the plain demo's accuracy on the same seed;
//! - `insuwb emulate imu` serves a pty whose bytes, read through a
//!   `insuwb_devices::link::Link` and decoded, are the scenario's IMU
//!   samples in order, none early; `insuwb emulate uwb --protocol eliko`
//!   serves the scenario's fixes over TCP after the Eliko handshake;
//!   `insuwb emulate uwb --protocol dwm1001` prints `twr-3.4`'s ranging
//!   rounds as `lec` lines and refuses a TDOA scenario; all stop cleanly
//!   on SIGINT.
//!
//! The tests start processes and measure time: one at a time (a lock).

// Test helpers outside `#[test]` functions may unwrap and panic too.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::io::{BufRead as _, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use insuwb_devices::frame::{wire_time_ns, AnyDecoder, Reading};
use insuwb_devices::link::{Link, Read, ReconnectPolicy};
use insuwb_devices::{eliko, Protocol};
use insuwb_runtime::monotonic_ns;

use crate::common;
use common::{f, insuwb, one_at_a_time as lock};

/// Runs `insuwb demo` for 10 s with `extra` arguments; returns the JSON
/// report.
fn demo(extra: &[&str]) -> serde_json::Value {
    let mut args = vec!["--duration", "10"];
    args.extend_from_slice(extra);
    common::demo_json(&args)
}

#[test]
fn demo_via_devices_keeps_10hz_and_the_plain_demos_accuracy() {
    let _lock = lock();
    let plain = demo(&[]);
    let devices = demo(&["--via-devices"]);
    let rate = f(&devices, "fused_rate_hz");
    let (rmse_plain, rmse_devices) = (f(&plain, "rmse_horizontal"), f(&devices, "rmse_horizontal"));
    eprintln!(
        "plain: fused {:.3} Hz, rmse {rmse_plain:.4} m; via devices: fused {rate:.3} Hz, rmse {rmse_devices:.4} m ({:.3} x), imu {:.2} Hz, latency p50 {} us",
        f(&plain, "fused_rate_hz"),
        rmse_devices / rmse_plain,
        f(&devices, "imu_rate_hz"),
        f(&devices, "latency_p50_us"),
    );
    assert!(
        (9.8..=10.2).contains(&rate),
        "fused rate {rate} Hz: {devices}"
    );
    assert!(
        rmse_devices <= 1.2 * rmse_plain,
        "rmse via devices {rmse_devices} m against {rmse_plain} m plain: {devices}"
    );
    assert!(
        (99.0..=101.0).contains(&f(&devices, "imu_rate_hz")),
        "{devices}"
    );
    assert_eq!(f(&devices, "restarts"), 0.0, "{devices}");
}

/// `insuwb emulate` started with `args`, its first stdout line (the path or
/// port) read.
fn emulate(args: &[&str]) -> (Child, String) {
    let mut child = Command::new(insuwb())
        .arg("emulate")
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    assert!(
        !line.trim().is_empty(),
        "insuwb emulate {args:?} printed nothing"
    );
    (child, line.trim().to_owned())
}

/// SIGINT to `child`; its exit must be clean; returns its stderr.
fn interrupt(child: Child) -> String {
    let status = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(
        out.status.success(),
        "emulate after SIGINT: {:?}\n{stderr}",
        out.status
    );
    assert!(stderr.contains("interrupted"), "{stderr}");
    stderr
}

/// Reads `link` until `want` readings came (or 10 s passed): each reading
/// with the host time of the read that completed it.
fn read_readings(link: &mut Link, decoder: &mut AnyDecoder, want: usize) -> Vec<(Reading, u64)> {
    let mut buf = [0_u8; 4096];
    let mut got = Vec::new();
    let give_up = monotonic_ns() + 10_000_000_000;
    while got.len() < want && monotonic_ns() < give_up {
        if let Read::Data { n, host_time_ns } =
            link.read(&mut buf, Duration::from_millis(50)).unwrap()
        {
            decoder.push(&buf[..n], &mut |r| got.push((r, host_time_ns)));
        }
    }
    got
}

/// An IMU played by `insuwb emulate imu --protocol <protocol>` on a pty
/// behind a stable link in a temporary folder, due from 1.5 s from now, and
/// a serial `Link` opened on it: (emulator, link, epoch, folder).
fn emulated_imu(protocol: &str, extra: &[&str]) -> (Child, Link, u64, std::path::PathBuf) {
    emulated("imu", protocol, extra)
}

/// A `device` (`imu`, `uwb`) played by `insuwb emulate <device> --protocol
/// <protocol>` on a pty, as [`emulated_imu`].
fn emulated(
    device: &str,
    protocol: &str,
    extra: &[&str],
) -> (Child, Link, u64, std::path::PathBuf) {
    let dir = std::env::temp_dir().join(format!(
        "insuwb-test-{}-emulate-{protocol}",
        std::process::id()
    ));
    std::fs::create_dir_all(&dir).unwrap();
    let link_path = dir.join(device);
    let epoch = monotonic_ns() + 1_500_000_000;
    let epoch_arg = epoch.to_string();
    let mut args = vec![
        device,
        "--protocol",
        protocol,
        "--link",
        link_path.to_str().unwrap(),
        "--start-epoch-ns",
        &epoch_arg,
    ];
    args.extend_from_slice(extra);
    let (child, path) = emulate(&args);
    assert_eq!(path, link_path.display().to_string());
    let link = Link::new(
        format!("serial:{path}").parse().unwrap(),
        115_200,
        ReconnectPolicy::default(),
        Vec::new(),
        monotonic_ns,
    )
    .unwrap();
    (child, link, epoch, dir)
}

#[test]
fn emulated_imu_pty_carries_the_scenarios_samples_in_order_and_never_early() {
    let _lock = lock();
    let (child, mut link, epoch, dir) = emulated_imu("witmotion", &[]);
    let mut decoder = AnyDecoder::new(Protocol::WitMotion);
    let got = read_readings(&mut link, &mut decoder, 150);
    let stderr = interrupt(child);
    let _ = std::fs::remove_dir_all(&dir);
    assert_eq!(got.len(), 150, "{stderr}");
    assert_eq!(
        decoder.stats().checksum_errors + decoder.stats().bytes_skipped,
        0
    );

    let sc = insuwb_fusion::scenario::ScenarioFile::load("nlos-long").unwrap();
    let data = sc.simulate(1).unwrap();
    for (k, ((reading, host_ns), s)) in got.iter().zip(&data.imu).enumerate() {
        let Reading::Imu {
            accel_mps2,
            gyro_rps,
            ..
        } = reading
        else {
            panic!("reading {k}: {reading:?}")
        };
        for i in 0..3 {
            // Half an LSB: 16 g / 32768 / 2 and 2000 deg/s / 32768 / 2.
            assert!(
                (accel_mps2[i] - s.accel_mps2[i]).abs() <= 0.0024,
                "sample {k}: {reading:?} vs {s:?}"
            );
            assert!(
                (gyro_rps[i] - s.gyro_rps[i]).abs() <= 5.4e-4,
                "sample {k}: {reading:?} vs {s:?}"
            );
        }
        // Bytes of the sample measured at epoch + t arrive no earlier than
        // its 22 bytes take on a 115200 baud line.
        let due = epoch + s.header.meas_time_ns + wire_time_ns(22, 115_200);
        assert!(
            *host_ns >= due,
            "sample {k} read {} ns before it was due",
            due - host_ns
        );
    }
}

#[test]
fn emulated_eliko_server_streams_the_scenarios_fixes_after_the_handshake() {
    let _lock = lock();
    let epoch = monotonic_ns() + 1_500_000_000;
    let (child, port) = emulate(&[
        "uwb",
        "--protocol",
        "eliko",
        "--tag",
        "4660",
        "--speed",
        "4",
        "--start-epoch-ns",
        &epoch.to_string(),
    ]);
    let port: u16 = port.parse().unwrap();
    let mut link = Link::new(
        format!("tcp:127.0.0.1:{port}").parse().unwrap(),
        0,
        ReconnectPolicy::default(),
        eliko::HANDSHAKE.concat().into_bytes(),
        monotonic_ns,
    )
    .unwrap();
    let mut decoder = AnyDecoder::Eliko(eliko::Decoder::with_tags([4660]));
    let got = read_readings(&mut link, &mut decoder, 60);
    let stderr = interrupt(child);
    assert_eq!(got.len(), 60, "{stderr}");
    assert_eq!(decoder.stats().seq_gaps, 0);

    let sc = insuwb_fusion::scenario::ScenarioFile::load("nlos-long").unwrap();
    let data = sc.simulate(1).unwrap();
    let fixes =
        insuwb_fusion::runner::run_fixes(&data.tdoa, &sc.fusion_for_seed(1).unwrap()).unwrap();
    for (k, ((reading, _), fix)) in got.iter().zip(&fixes).enumerate() {
        let Reading::Position {
            tag: 4660,
            pos_m,
            device_time: Some(t),
            seq: Some(seq),
            ..
        } = reading
        else {
            panic!("line {k}: {reading:?}")
        };
        assert_eq!(*seq as usize, k % 256);
        for (got, want) in pos_m.iter().zip(&fix.pos_m) {
            assert!(
                (got - want).abs() <= 0.0005,
                "line {k}: {reading:?} vs {fix:?}"
            );
        }
        // The server's Unix time: 1700000000 s at the epoch, then the time
        // played (the fix time / 4), in microseconds.
        let expected_us = 1_700_000_000_000_000 + fix.header.meas_time_ns / 4 / 1000;
        assert_eq!(t.ticks * t.tick_ns / 1000, expected_us, "line {k}");
    }
}

/// A MAVLink IMU whose clock runs 100 ppm fast, played by `insuwb emulate`
/// through a pseudo-terminal at 115200 baud: the device-clock filter maps
/// its `time_usec` onto CLOCK_MONOTONIC within 1 ms of when each sample was
/// measured (epoch + t), and estimates the drift.
#[test]
fn device_clock_with_100_ppm_drift_maps_within_1_ms() {
    let _lock = lock();
    let (child, mut link, epoch, dir) = emulated_imu(
        "mavlink",
        &["--clock-start-s", "1234.5", "--drift-ppm", "100"],
    );
    let mut decoder = AnyDecoder::new(Protocol::Mavlink);
    // 8 s of samples at 100 Hz.
    let got = read_readings(&mut link, &mut decoder, 800);
    let stderr = interrupt(child);
    let _ = std::fs::remove_dir_all(&dir);
    assert_eq!(got.len(), 800, "{stderr}");

    let sc = insuwb_fusion::scenario::ScenarioFile::load("nlos-long").unwrap();
    let data = sc.simulate(1).unwrap();
    let mut filter: Option<insuwb_devices::ClockFilter> = None;
    let mut worst_ns: u64 = 0;
    let mut frame = [0_u8; insuwb_devices::mavlink::MAX_FRAME_LEN];
    for (k, ((reading, host_ns), s)) in got.iter().zip(&data.imu).enumerate() {
        let Reading::Imu {
            device_time: Some(dt),
            ..
        } = reading
        else {
            panic!("reading {k} has no device time: {reading:?}")
        };
        let f = filter.get_or_insert_with(|| {
            insuwb_devices::ClockFilter::new(
                dt.tick_ns,
                dt.wrap,
                insuwb_devices::ClockConfig::default(),
            )
            .unwrap()
        });
        // The frame's own length (as the emulator encoded it) on the wire.
        let n = insuwb_devices::mavlink::encode_highres_imu(
            &insuwb_devices::mavlink::Header::v2(0),
            dt.ticks,
            s.accel_mps2,
            s.gyro_rps,
            0,
            &mut frame,
        );
        let _ = f.update(dt.ticks, host_ns - wire_time_ns(n, 115_200));
        // Judged from 2 s on (the filter has seen 200 samples).
        if k >= 200 {
            let mapped = f.to_host(dt.ticks).unwrap();
            let truth = epoch + s.header.meas_time_ns;
            worst_ns = worst_ns.max(mapped.abs_diff(truth));
        }
    }
    let f = filter.unwrap();
    let drift = f.drift_ppm().unwrap();
    eprintln!(
        "100 ppm device clock through a pty: worst mapping error {:.3} ms over 2-8 s, drift estimate {drift:.1} ppm",
        worst_ns as f64 * 1e-6
    );
    assert!(worst_ns <= 1_000_000, "mapped up to {worst_ns} ns off");
    assert!((50.0..=150.0).contains(&drift), "drift {drift} ppm");
}

#[test]
fn emulated_dwm1001_prints_the_scenarios_ranging_rounds_and_refuses_tdoa() {
    let _lock = lock();
    let (child, mut link, _epoch, dir) = emulated("uwb", "dwm1001", &[]);
    let mut decoder = AnyDecoder::new(Protocol::Dwm1001);
    // 100 rounds of 4 anchors.
    let got = read_readings(&mut link, &mut decoder, 400);
    let stderr = interrupt(child);
    let _ = std::fs::remove_dir_all(&dir);
    assert_eq!(got.len(), 400, "{stderr}");
    assert!(stderr.contains("UWB ranging rounds"), "{stderr}");
    assert_eq!(decoder.stats().frames_ok, 100);

    let sc = insuwb_fusion::scenario::ScenarioFile::load("twr-3.4").unwrap();
    let data = sc.simulate(1).unwrap();
    for (k, ((reading, _), m)) in got.iter().zip(&data.range).enumerate() {
        let Reading::Range {
            anchor,
            range_m,
            anchor_pos_m: Some(pos),
            last_of_round,
            ..
        } = reading
        else {
            panic!("reading {k}: {reading:?}")
        };
        assert_eq!(*anchor, m.anchor, "reading {k}");
        assert_eq!(*last_of_round, k % 4 == 3, "reading {k}");
        // Two decimals.
        assert!((range_m - m.range_m).abs() <= 0.005, "{reading:?} vs {m:?}");
        for (a, b) in pos.iter().zip(&m.anchor_pos_m) {
            assert!((a - b).abs() <= 0.005, "{reading:?} vs {m:?}");
        }
    }

    // A TDOA scenario has no ranges to print.
    let out = Command::new(insuwb())
        .args([
            "emulate",
            "uwb",
            "--protocol",
            "dwm1001",
            "--scenario",
            "nlos-long",
        ])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(out.stdout.is_empty(), "{stderr}");
    assert!(
        stderr.contains("dwm1001 is a two-way ranging device")
            && stderr.contains("kind = \"tdoa\"")
            && stderr.contains("--scenario twr-3.4"),
        "{stderr}"
    );
}
