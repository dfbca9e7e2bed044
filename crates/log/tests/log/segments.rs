//! The logger's segmented run directory: rotation, restart, flush policy,
//! permissions, configuration.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // tests may unwrap

use crate::common;

use common::{imu_run, mixed, Scratch};
use insuwb_log::{
    list_segments, parse_segment_name, read_all, read_segments, segment_file_name, CreateError,
    FlushPolicy, Metadata, SegmentConfig, SegmentConfigError, SegmentWriter, TailReason,
};

const MS: u64 = 1_000_000;

fn cfg(max_segment_bytes: u64, flush: FlushPolicy) -> SegmentConfig {
    SegmentConfig {
        max_segment_bytes,
        flush,
    }
}

fn no_flush() -> FlushPolicy {
    FlushPolicy {
        every_records: None,
        every_ms: None,
        fsync: false,
    }
}

fn file_len(p: &std::path::Path) -> u64 {
    std::fs::metadata(p).unwrap().len()
}

#[test]
fn segment_names() {
    assert_eq!(segment_file_name(0), "seg-00000.iulog");
    assert_eq!(segment_file_name(123_456), "seg-123456.iulog");
    assert_eq!(parse_segment_name("seg-00042.iulog"), Some(42));
    assert_eq!(parse_segment_name("seg-123456.iulog"), Some(123_456));
    for bad in [
        "seg-42.iulog",
        "seg-0000x.iulog",
        "seg-00001.log",
        "xseg-00001.iulog",
        "seg-00001.iulog.tmp",
        "seg-99999999999.iulog",
    ] {
        assert_eq!(parse_segment_name(bad), None, "{bad}");
    }
}

#[test]
fn rotation_by_size_gives_ordered_segments_under_the_limit() {
    let dir = Scratch::new("rotate");
    let run = dir.join("run");
    let max = 4096;
    let records = imu_run(300);
    let mut w =
        SegmentWriter::open(&run, Metadata::new("logger"), cfg(max, no_flush()), 5).unwrap();
    for (i, r) in records.iter().enumerate() {
        w.append(r, 10 + i as u64).unwrap();
    }
    let opened = w.segments_opened();
    assert_eq!(w.records_written(), 300);
    w.finish().unwrap();

    let segs = list_segments(&run).unwrap();
    assert!(segs.len() >= 4, "{} segments", segs.len());
    assert_eq!(segs.len() as u32, opened);
    for (i, s) in segs.iter().enumerate() {
        assert_eq!(s.index, i as u32);
        assert_eq!(
            s.path.file_name().unwrap().to_str().unwrap(),
            segment_file_name(i as u32)
        );
        let len = file_len(&s.path);
        assert!(len <= max, "segment {i} is {len} bytes");
        // All but the last are full: one more frame would not have fitted.
        if i + 1 < segs.len() {
            assert!(len + 80 > max, "segment {i} closed early at {len} bytes");
        }
    }
    let got = read_segments(&run).unwrap();
    assert_eq!(got.records, records);
    assert_eq!(got.tails().count(), 0);
    assert_eq!(got.segments.iter().map(|s| s.records).sum::<u64>(), 300);
    // Each segment is a complete log with its own header.
    let first = got.segments[0].header.as_ref().unwrap();
    assert_eq!(first.created_ns, 5);
    assert_eq!(first.meta, Metadata::new("logger"));
    let second = got.segments[1].header.as_ref().unwrap();
    assert!(
        second.created_ns > 10,
        "created at the rotating append's time"
    );
}

#[test]
fn a_restarted_writer_opens_a_new_segment_and_never_touches_old_ones() {
    let dir = Scratch::new("restart");
    let run = dir.join("run");
    let a = mixed(9);
    let b = imu_run(4);
    let mut w =
        SegmentWriter::open(&run, Metadata::new("first"), SegmentConfig::default(), 0).unwrap();
    for r in &a {
        w.append(r, 1).unwrap();
    }
    assert_eq!(w.segment_index(), 0);
    w.finish().unwrap();
    let seg0 = run.join(segment_file_name(0));
    let seg0_bytes = std::fs::read(&seg0).unwrap();

    let mut w =
        SegmentWriter::open(&run, Metadata::new("second"), SegmentConfig::default(), 100).unwrap();
    assert_eq!(w.segment_index(), 1);
    assert_eq!(w.current_path().unwrap(), run.join(segment_file_name(1)));
    for r in &b {
        w.append(r, 101).unwrap();
    }
    w.finish().unwrap();
    assert_eq!(
        std::fs::read(&seg0).unwrap(),
        seg0_bytes,
        "old segment untouched"
    );

    let got = read_segments(&run).unwrap();
    let mut all = a.clone();
    all.extend(b.iter().copied());
    assert_eq!(got.records, all);
    assert_eq!(got.segments.len(), 2);
    assert_eq!(
        got.segments[1].header.as_ref().unwrap().meta.source,
        "second"
    );
}

#[test]
fn after_a_crash_the_torn_segment_is_reported_and_reading_goes_on() {
    let dir = Scratch::new("crash");
    let run = dir.path().to_path_buf();
    let a = imu_run(10);
    let mut w = SegmentWriter::open(&run, Metadata::new("x"), SegmentConfig::default(), 0).unwrap();
    for r in &a {
        w.append(r, 0).unwrap();
    }
    w.finish().unwrap();
    // Tear the last record of segment 0.
    let seg0 = run.join(segment_file_name(0));
    let full = file_len(&seg0);
    let f = std::fs::OpenOptions::new().write(true).open(&seg0).unwrap();
    f.set_len(full - 3).unwrap();
    drop(f);
    // A zero-length segment, as left by a crash right at creation.
    std::fs::write(run.join(segment_file_name(1)), b"").unwrap();
    // A foreign file is ignored.
    std::fs::write(run.join("notes.txt"), b"hello").unwrap();

    let mut w = SegmentWriter::open(&run, Metadata::new("x"), SegmentConfig::default(), 0).unwrap();
    assert_eq!(
        w.segment_index(),
        2,
        "numbered after every existing segment"
    );
    let b = imu_run(2);
    for r in &b {
        w.append(r, 0).unwrap();
    }
    w.finish().unwrap();

    let got = read_segments(&run).unwrap();
    let mut expected = a[..9].to_vec();
    expected.extend(b.iter().copied());
    assert_eq!(got.records, expected);
    assert_eq!(got.segments.len(), 3);
    let t0 = got.segments[0].tail.as_ref().unwrap();
    let (_, _, h0) = (0, 0, got.segments[0].header.as_ref().unwrap());
    assert_eq!(t0.bytes_ignored, full - 3 - t0.last_good_offset);
    assert!(t0.last_good_offset > h0.header_len);
    assert!(matches!(t0.reason, TailReason::TruncatedPayload { .. }));
    assert_eq!(got.segments[1].header, None);
    assert_eq!(
        got.segments[1].tail.as_ref().unwrap().reason,
        TailReason::TruncatedHeader
    );
    assert_eq!(got.segments[2].tail, None);
    assert_eq!(got.tails().count(), 2);
}

#[test]
fn flush_by_record_count() {
    let dir = Scratch::new("count");
    let policy = FlushPolicy {
        every_records: Some(3),
        every_ms: None,
        fsync: false,
    };
    let mut w =
        SegmentWriter::open(dir.path(), Metadata::new("c"), cfg(1 << 20, policy), 0).unwrap();
    let path = w.current_path().unwrap().to_path_buf();
    let header_len = file_len(&path);
    let recs = imu_run(6);
    w.append(&recs[0], 0).unwrap();
    w.append(&recs[1], 0).unwrap();
    assert_eq!(file_len(&path), header_len, "two records stay buffered");
    w.append(&recs[2], 0).unwrap();
    let after3 = file_len(&path);
    assert!(after3 > header_len, "third record triggers the flush");
    let (on_disk, tail, _) = read_all(&path).unwrap();
    assert_eq!(on_disk, recs[..3]);
    assert_eq!(tail, None);
    w.append(&recs[3], 0).unwrap();
    assert_eq!(file_len(&path), after3);
    drop(w); // dropping flushes what is buffered
    assert_eq!(read_all(&path).unwrap().0, recs[..4]);
}

#[test]
fn flush_by_monotonic_time() {
    let dir = Scratch::new("time");
    let policy = FlushPolicy {
        every_records: None,
        every_ms: Some(100),
        fsync: true,
    };
    let t0 = 5_000 * MS;
    let mut w =
        SegmentWriter::open(dir.path(), Metadata::new("t"), cfg(1 << 20, policy), t0).unwrap();
    let path = w.current_path().unwrap().to_path_buf();
    let header_len = file_len(&path);
    let recs = imu_run(3);
    w.append(&recs[0], t0 + 10 * MS).unwrap();
    w.append(&recs[1], t0 + 99 * MS).unwrap();
    assert_eq!(file_len(&path), header_len, "under 100 ms: buffered");
    assert!(!w.tick(t0 + 99 * MS).unwrap());
    assert!(
        w.tick(t0 + 100 * MS).unwrap(),
        "100 ms after opening: flushed"
    );
    assert_eq!(read_all(&path).unwrap().0, recs[..2]);
    assert!(!w.tick(t0 + 500 * MS).unwrap(), "nothing pending");
    w.append(&recs[2], t0 + 150 * MS).unwrap();
    assert_eq!(
        read_all(&path).unwrap().0,
        recs[..2],
        "50 ms after the last flush"
    );
    w.append(&recs[2], t0 + 200 * MS).unwrap();
    assert_eq!(read_all(&path).unwrap().0.len(), 4);
    w.finish().unwrap();
}

#[cfg(unix)]
#[test]
fn directory_is_0700_and_segments_0600() {
    use std::os::unix::fs::PermissionsExt;
    let dir = Scratch::new("perm");
    let run = dir.join("a/b/run");
    let w = SegmentWriter::open(&run, Metadata::default(), SegmentConfig::default(), 0).unwrap();
    let seg = w.current_path().unwrap().to_path_buf();
    w.finish().unwrap();
    let mode = |p: &std::path::Path| std::fs::metadata(p).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode(&run), 0o700);
    assert_eq!(mode(&seg), 0o600);
}

#[test]
fn bad_directory_and_bad_config_are_refused() {
    let dir = Scratch::new("bad");
    let file = dir.join("plain");
    std::fs::write(&file, b"x").unwrap();
    let e =
        SegmentWriter::open(&file, Metadata::default(), SegmentConfig::default(), 0).unwrap_err();
    assert!(
        matches!(
            e,
            CreateError::BadPath {
                reason: "not a directory",
                ..
            }
        ),
        "{e}"
    );
    let e = SegmentWriter::open(
        dir.path(),
        Metadata::default(),
        cfg(100, FlushPolicy::default()),
        0,
    )
    .unwrap_err();
    assert!(matches!(e, CreateError::Config(_)));
    assert_eq!(e.to_string(), "max_segment_bytes must be >= 4096, got 100");
    assert!(
        list_segments(dir.path()).unwrap().is_empty(),
        "nothing created"
    );
    let e = read_segments(dir.join("missing")).unwrap_err();
    assert!(e.to_string().contains("cannot list"), "{e}");
}

#[test]
fn config_defaults_validation_and_parsing() {
    let d = SegmentConfig::default();
    assert_eq!(d.max_segment_bytes, 64 * 1024 * 1024);
    assert_eq!(
        d.flush,
        FlushPolicy {
            every_records: None,
            every_ms: Some(1000),
            fsync: false
        }
    );
    assert_eq!(d.validate(), Ok(()));
    let bad = FlushPolicy {
        every_records: Some(0),
        ..FlushPolicy::default()
    };
    assert_eq!(bad.validate(), Err(SegmentConfigError::EveryRecordsZero));
    assert_eq!(
        bad.validate().unwrap_err().to_string(),
        "flush.every_records must be > 0 (or absent), got 0"
    );
    let bad = FlushPolicy {
        every_ms: Some(0),
        ..FlushPolicy::default()
    };
    assert_eq!(bad.validate(), Err(SegmentConfigError::EveryMsZero));

    let parsed: SegmentConfig =
        toml::from_str("max_segment_bytes = 8192\n[flush]\nevery_records = 10\nfsync = true\n")
            .unwrap();
    assert_eq!(
        parsed,
        cfg(
            8192,
            FlushPolicy {
                every_records: Some(10),
                every_ms: Some(1000),
                fsync: true
            }
        )
    );
    assert!(toml::from_str::<SegmentConfig>("max_segment_byte = 8192\n").is_err());
    assert!(toml::from_str::<SegmentConfig>("[flush]\nevery_sec = 1\n").is_err());
    let round: SegmentConfig = toml::from_str(&toml::to_string(&d).unwrap()).unwrap();
    assert_eq!(round, d);
}
