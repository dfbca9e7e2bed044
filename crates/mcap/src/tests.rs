#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::collections::BTreeMap;
use std::io::Cursor;
use std::path::PathBuf;

use insuwb_log::{LogWriter, Metadata, Record};
use insuwb_msg as m;
use insuwb_ros2::msgs::{Imu, Odometry, TfMessage};

use super::*;

fn hdr(seq: u64, t_ns: u64) -> m::Header {
    let mut h = m::Header::new(seq, t_ns);
    h.pub_time_ns = t_ns + 1_000;
    h
}

/// One record of every topic, at `t_ns`.
fn one_of_each(t_ns: u64) -> Vec<Record> {
    let q = [1.0, 0.0, 0.0, 0.0];
    vec![
        Record::Imu(m::ImuSample {
            header: hdr(1, t_ns),
            accel_mps2: [0.0, 0.0, 9.81],
            gyro_rps: [0.0, 0.0, 0.5],
        }),
        Record::Tdoa(m::UwbTdoa {
            header: hdr(2, t_ns),
            anchor_a: 1,
            anchor_b: 2,
            diff_m: 0.25,
            ..Default::default()
        }),
        Record::Fix(m::UwbFix {
            header: hdr(3, t_ns),
            pos_m: [1.0, 2.0, 3.0],
            ..Default::default()
        }),
        Record::Nav(m::NavState {
            header: hdr(4, t_ns),
            quat: q,
            ..Default::default()
        }),
        Record::Correction(m::InsCorrection {
            header: hdr(5, t_ns),
            reset_quat: q,
            ..Default::default()
        }),
        Record::Fused(m::FusedState {
            header: hdr(6, t_ns),
            pos_m: [4.0, 5.0, 0.5],
            quat: q,
            ..Default::default()
        }),
        Record::Diag(m::FilterDiag {
            header: hdr(7, t_ns),
            nis: 1.5,
            dim: 2,
            ..Default::default()
        }),
        Record::Truth(m::GroundTruth {
            header: hdr(8, t_ns),
            quat: q,
            ..Default::default()
        }),
        Record::Health(m::Health {
            header: hdr(9, t_ns),
            stage: m::fixed_name("fusion"),
            pid: 7,
            ..Default::default()
        }),
        Record::Range(m::UwbRange {
            header: hdr(11, t_ns),
            anchor: 4,
            range_m: 3.5,
            anchor_pos_m: [1.0, -2.0, 0.5],
            ..Default::default()
        }),
        Record::BodyVel(m::BodyVelocity {
            header: hdr(10, t_ns),
            vel_mps: [0.5, -0.25, 0.0],
            sigma_mps: [0.05, 0.05, 0.0],
            source: m::BodyVelocity::SOURCE_FLOW,
            range_mm: 0,
        }),
        Record::Height(m::Height {
            header: hdr(12, t_ns),
            range_m: 1.25,
            source: m::Height::SOURCE_RANGE_FINDER,
        }),
    ]
}

fn export_to_vec(records: &[Record]) -> (Vec<u8>, ExportStats) {
    let mut w = RecordWriter::new(Cursor::new(Vec::new()), ExportOptions::default()).unwrap();
    for r in records {
        w.write(r).unwrap();
    }
    let (c, stats) = w.finish().unwrap();
    (c.into_inner(), stats)
}

/// Messages by topic: (schema name, schema encoding, message encoding, data, log and publish time).
type Read = BTreeMap<String, Vec<(String, String, String, Vec<u8>, u64, u64)>>;

fn read(bytes: &[u8]) -> Read {
    let mut out: Read = BTreeMap::new();
    for msg in mcap::MessageStream::new(bytes).unwrap() {
        let msg = msg.unwrap();
        let schema = msg.channel.schema.as_ref().unwrap();
        out.entry(msg.channel.topic.clone()).or_default().push((
            schema.name.clone(),
            schema.encoding.clone(),
            msg.channel.message_encoding.clone(),
            msg.data.to_vec(),
            msg.log_time,
            msg.publish_time,
        ));
    }
    out
}

/// The profile of the MCAP header record (opcode 1 after the 8-byte magic).
fn profile(bytes: &[u8]) -> String {
    assert_eq!(bytes[8], 0x01);
    let len = u32::from_le_bytes(bytes[17..21].try_into().unwrap()) as usize;
    String::from_utf8(bytes[21..21 + len].to_vec()).unwrap()
}

#[test]
fn every_topic_gets_its_channel_and_schema() {
    let (bytes, stats) = export_to_vec(&one_of_each(3_000_000_000));
    assert_eq!(profile(&bytes), "ros2");
    let got = read(&bytes);
    let want = [
        (TOPIC_IMU, "sensor_msgs/msg/Imu"),
        (TOPIC_UWB_TDOA, "insuwb_msgs/msg/UwbTdoa"),
        (TOPIC_UWB_RANGE, "insuwb_msgs/msg/UwbRange"),
        (TOPIC_UWB_FIX, "insuwb_msgs/msg/UwbFix"),
        (TOPIC_NAV, "insuwb_msgs/msg/NavState"),
        (TOPIC_CORRECTION, "insuwb_msgs/msg/InsCorrection"),
        (TOPIC_ODOM, "nav_msgs/msg/Odometry"),
        (TOPIC_TF, "tf2_msgs/msg/TFMessage"),
        (TOPIC_FUSED, "insuwb_msgs/msg/FusedState"),
        (TOPIC_DIAG, "insuwb_msgs/msg/FilterDiag"),
        (TOPIC_TRUTH, "insuwb_msgs/msg/GroundTruth"),
        (TOPIC_DIAGNOSTICS, "diagnostic_msgs/msg/DiagnosticArray"),
        (TOPIC_BODY_VEL, "insuwb_msgs/msg/BodyVelocity"),
        (TOPIC_HEIGHT, "insuwb_msgs/msg/Height"),
    ];
    assert_eq!(got.len(), want.len());
    for (topic, ty) in want {
        let msgs = &got[topic];
        assert_eq!(msgs.len(), 1, "{topic}");
        let (schema, enc, msg_enc, data, log, publish) = &msgs[0];
        assert_eq!(schema, ty, "{topic}");
        assert_eq!((enc.as_str(), msg_enc.as_str()), ("ros2msg", "cdr"));
        assert_eq!(&data[..4], &cdr::CDR_LE);
        assert_eq!((*log, *publish), (3_000_000_000, 3_000_001_000));
    }
    for t in Record::TOPICS {
        assert_eq!(stats.records[t], 1, "{t}");
        for mt in mcap_topics(t) {
            assert_eq!(stats.messages[mt], 1, "{mt}");
        }
    }
    assert!(stats.skipped.is_empty());
    assert_eq!(stats.total_messages(), 14);
}

#[test]
fn a_body_velocity_is_its_sample_in_the_body_frame() {
    let recs = one_of_each(3_000_000_007);
    let (bytes, _) = export_to_vec(&recs);
    let got = read(&bytes);
    let Some(Record::BodyVel(v)) = recs.iter().find(|r| matches!(r, Record::BodyVel(_))) else {
        panic!()
    };
    let stamp = Time { sec: 3, nanosec: 7 };
    let want = msgs::BodyVelocity::from_sample(v, stamp, "base_link");
    assert_eq!(want.header.frame_id, "base_link");
    assert_eq!((want.vel_mps.x, want.vel_mps.y), (0.5, -0.25));
    assert_eq!((want.sigma_mps.x, want.sigma_mps.z), (0.05, 0.0));
    assert_eq!(want.source, m::BodyVelocity::SOURCE_FLOW);
    assert_eq!(want.sample.seq, 10);
    assert_eq!(got[TOPIC_BODY_VEL][0].3, cdr::encode(&want, "x").unwrap());
}

#[test]
fn a_height_is_its_sample_in_the_body_frame() {
    let recs = one_of_each(3_000_000_007);
    let (bytes, _) = export_to_vec(&recs);
    let got = read(&bytes);
    let Some(Record::Height(s)) = recs.iter().find(|r| matches!(r, Record::Height(_))) else {
        panic!()
    };
    let stamp = Time { sec: 3, nanosec: 7 };
    let want = msgs::Height::from_sample(s, stamp, "base_link");
    assert_eq!(want.header.frame_id, "base_link");
    assert_eq!(want.range_m, 1.25);
    assert_eq!(want.source, m::Height::SOURCE_RANGE_FINDER);
    assert_eq!(want.sample.seq, 12);
    assert_eq!(got[TOPIC_HEIGHT][0].3, cdr::encode(&want, "x").unwrap());
}

#[test]
fn ros_messages_are_the_bridge_conversions() {
    let recs = one_of_each(3_000_000_007);
    let (bytes, _) = export_to_vec(&recs);
    let got = read(&bytes);
    let Record::Fused(fused) = recs[5] else {
        panic!()
    };
    let Record::Imu(imu) = recs[0] else { panic!() };
    let decode = |topic: &str| got[topic][0].3[4..].to_vec();
    let frames = Frames::default();
    let (odom, _) =
        cdr_encoding::from_bytes::<Odometry, byteorder::LittleEndian>(&decode(TOPIC_ODOM)).unwrap();
    assert_eq!(
        odom,
        convert::fused_to_odometry(&fused, &frames, &ClockOffset::ZERO).unwrap()
    );
    assert_eq!((odom.header.stamp.sec, odom.header.stamp.nanosec), (3, 7));
    let (tf, _) =
        cdr_encoding::from_bytes::<TfMessage, byteorder::LittleEndian>(&decode(TOPIC_TF)).unwrap();
    assert_eq!(tf.transforms.len(), 1);
    assert_eq!(tf.transforms[0].transform.translation.x, 4.0);
    let (m, _) =
        cdr_encoding::from_bytes::<Imu, byteorder::LittleEndian>(&decode(TOPIC_IMU)).unwrap();
    assert_eq!(
        m,
        convert::imu_to_ros(&imu, &frames, &ClockOffset::ZERO).unwrap()
    );
    // The custom fused state: its CDR equals the struct's.
    let want = cdr::encode(
        &msgs::FusedState::from_sample(&fused, odom.header.stamp, "map"),
        "x",
    )
    .unwrap();
    assert_eq!(got[TOPIC_FUSED][0].3, want);
}

#[test]
fn diagnostics_carry_the_stage_and_its_rates() {
    let mut h = m::Health {
        header: hdr(1, 1_000_000_000),
        stage: m::fixed_name("imu"),
        pid: 3,
        received: 100,
        ..Default::default()
    };
    let mut recs = vec![Record::Health(h)];
    h.header = hdr(2, 1_500_000_000);
    h.received = 150;
    recs.push(Record::Health(h));
    let (bytes, _) = export_to_vec(&recs);
    let got = read(&bytes);
    let (d, _) = cdr_encoding::from_bytes::<DiagnosticArray, byteorder::LittleEndian>(
        &got[TOPIC_DIAGNOSTICS][1].3[4..],
    )
    .unwrap();
    assert_eq!(d.status.len(), 1);
    let s = &d.status[0];
    assert_eq!((s.name.as_str(), s.level), ("insuwb/imu", 0));
    let rate = s.values.iter().find(|v| v.key == "received_rate_hz");
    assert_eq!(rate.map(|v| v.value.as_str()), Some("100.00"));
}

#[test]
fn a_refused_conversion_skips_that_message_only() {
    let fused = m::FusedState {
        header: hdr(1, 1_000),
        quat: [0.0; 4],
        ..Default::default()
    };
    let (bytes, stats) = export_to_vec(&[Record::Fused(fused)]);
    let got = read(&bytes);
    assert_eq!(got.keys().collect::<Vec<_>>(), [TOPIC_FUSED]);
    assert_eq!(stats.skipped[TOPIC_ODOM], 1);
    assert_eq!(stats.skipped[TOPIC_TF], 1);
    assert!(stats
        .first_skip
        .as_deref()
        .unwrap()
        .contains("BadQuaternion"));
}

struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> Self {
        let d = std::env::temp_dir().join(format!("insuwb-mcap-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        Self(d)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A log of `n` rounds of `one_of_each`; returns where each record ends.
fn write_log(path: &std::path::Path, n: u64) -> Vec<u64> {
    let mut w = LogWriter::create(path, &Metadata::new("test").with("seed", "7"), 0).unwrap();
    let mut ends = Vec::new();
    for k in 0..n {
        for r in one_of_each(1_000_000_000 + k * 10_000_000) {
            w.append(&r).unwrap();
            w.flush().unwrap();
            ends.push(std::fs::metadata(path).unwrap().len());
        }
    }
    w.finish().unwrap();
    ends
}

#[test]
fn a_cut_log_exports_its_whole_records_and_says_where_it_stopped() {
    let d = TempDir::new("cut");
    let log = d.0.join("a.iulog");
    let ends = write_log(&log, 3);
    let bytes = std::fs::read(&log).unwrap();
    // Cut in the middle of the 20th record.
    let cut_at = (ends[18] + ends[19]) / 2;
    std::fs::write(&log, &bytes[..cut_at as usize]).unwrap();
    let out = d.0.join("a.mcap");
    let s = export_log(&log, &out, &ExportOptions::default()).unwrap();
    assert_eq!(s.cuts.len(), 1);
    let c = &s.cuts[0];
    assert_eq!((c.records, c.report.last_good_offset), (19, ends[18]));
    assert_eq!(c.report.bytes_ignored, cut_at - ends[18]);
    let line = c.to_string();
    assert!(line.contains("a.iulog"), "{line}");
    assert!(
        line.contains(&format!("torn tail at byte {}", ends[18])),
        "{line}"
    );
    assert!(line.contains("19 whole records"), "{line}");
    assert_eq!(s.stats.total_records(), 19);
    let got = read(&std::fs::read(&out).unwrap());
    let n: usize = got.values().map(Vec::len).sum();
    // 19 records = the first round (12 records, 14 messages) and the
    // second's first 7, up to its filter diagnostics (9 messages).
    assert_eq!(n, 23);
    assert_eq!(got[TOPIC_IMU].len(), 2);
    assert_eq!(got[TOPIC_BODY_VEL].len(), 1);
}

#[test]
fn a_run_directory_exports_every_segment_in_order_past_a_cut() {
    let d = TempDir::new("dir");
    let run = d.0.join("log");
    std::fs::create_dir_all(&run).unwrap();
    let first = run.join(insuwb_log::segment_file_name(0));
    let ends = write_log(&first, 1);
    let bytes = std::fs::read(&first).unwrap();
    std::fs::write(&first, &bytes[..ends[3] as usize + 5]).unwrap();
    write_log(&run.join(insuwb_log::segment_file_name(1)), 2);
    // A segment cut inside its header.
    std::fs::write(run.join(insuwb_log::segment_file_name(2)), b"INSUWB").unwrap();
    let out = d.0.join("run.mcap");
    let s = export_log(&run, &out, &ExportOptions::default()).unwrap();
    assert_eq!(s.files.len(), 3);
    assert_eq!(s.cuts.len(), 2);
    assert_eq!(s.cuts[0].records, 4);
    assert_eq!(s.cuts[1].report.last_good_offset, 0);
    assert_eq!(s.stats.total_records(), 4 + 2 * Record::TOPICS.len() as u64);
    let got = read(&std::fs::read(&out).unwrap());
    assert_eq!(got[TOPIC_IMU].len(), 3);
    let times: Vec<u64> = got[TOPIC_IMU].iter().map(|m| m.4).collect();
    assert_eq!(times, [1_000_000_000, 1_000_000_000, 1_010_000_000]);
}

#[test]
fn bad_input_is_an_error_naming_the_file_and_writes_nothing() {
    let d = TempDir::new("bad");
    let out = d.0.join("x.mcap");
    let missing = d.0.join("missing.iulog");
    let e = export_log(&missing, &out, &ExportOptions::default()).unwrap_err();
    assert!(e.to_string().contains("missing.iulog"), "{e}");
    let text = d.0.join("notes.txt");
    std::fs::write(&text, "hello, not a log").unwrap();
    let e = export_log(&text, &out, &ExportOptions::default()).unwrap_err();
    assert!(
        e.to_string().contains("notes.txt") && e.to_string().contains("not an insuwb log"),
        "{e}"
    );
    let empty = d.0.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let e = export_log(&empty, &out, &ExportOptions::default()).unwrap_err();
    assert!(e.to_string().contains("no seg-*.iulog"), "{e}");
    assert!(!out.exists());
}
