//! Round trips of every record type, the byte-exact worked example of
//! docs/LOG_FORMAT.md, header errors and path errors.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // tests may unwrap

use crate::common;

use std::io::ErrorKind;

use common::{one_of_each, Scratch};
use insuwb_log::{
    encode_header, is_log, read_all, CreateError, HeaderError, LogReader, LogWriter, Metadata,
    OpenError, Record, RecordEncoder, FIXED_HEADER_LEN, MAX_RECORD_LEN,
};
use insuwb_msg::{topics, BodyVelocity, FusedState, Header, ImuSample};

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

/// The worked example of docs/LOG_FORMAT.md, byte for byte (hand-encoded:
/// varints, LE f64, CRCs computed independently with zlib).
fn example_bytes() -> Vec<u8> {
    hex(
        "49 4e 53 55 57 42 4c 47  01 00  02 00  15 cd 5b 07 00 00 00 00  0d 00 00 00  fb 53 32 7f
         04 74 65 73 74  01  04 73 65 65 64 01 37
         3c 00 00 00  6c df f6 63
         00  02 03 00 02 00  ac 02  c0 84 3d  00
         00 00 00 00 00 00 00 00  00 00 00 00 00 00 00 00  1f 85 eb 51 b8 9e 23 40
         00 00 00 00 00 00 00 00  00 00 00 00 00 00 00 00  00 00 00 00 00 00 e0 3f",
    )
}

fn example_record() -> Record {
    Record::Imu(ImuSample {
        header: Header {
            layout_version: 2,
            source_id: 3,
            flags: 0,
            generation: 2,
            reserved: 0,
            seq: 300,
            meas_time_ns: 1_000_000,
            pub_time_ns: 0,
        },
        accel_mps2: [0.0, 0.0, 9.81],
        gyro_rps: [0.0, 0.0, 0.5],
    })
}

fn example_meta() -> Metadata {
    Metadata::new("test").with("seed", "7")
}

#[test]
fn crc_is_the_zlib_crc32() {
    assert_eq!(crc32fast::hash(b"123456789"), 0xCBF4_3926);
}

#[test]
fn encoding_matches_the_documented_example_byte_for_byte() {
    let expected = example_bytes();
    assert_eq!(expected.len(), 109);
    let header = encode_header(123_456_789, &example_meta()).unwrap();
    assert_eq!(header.as_slice(), &expected[..41]);
    let mut enc = RecordEncoder::new();
    let frame = enc.encode(&example_record()).unwrap();
    assert_eq!(frame, &expected[41..]);
}

#[test]
fn writer_produces_the_documented_file_and_reader_decodes_it() {
    let dir = Scratch::new("example");
    let path = dir.join("example.iulog");
    let mut w = LogWriter::create(&path, &example_meta(), 123_456_789).unwrap();
    w.append(&example_record()).unwrap();
    assert_eq!(w.bytes_written(), 109);
    w.finish().unwrap();
    assert_eq!(std::fs::read(&path).unwrap(), example_bytes());

    let (recs, tail, header) = read_all(&path).unwrap();
    assert_eq!(recs, vec![example_record()]);
    assert_eq!(tail, None);
    assert_eq!(header.created_ns, 123_456_789);
    assert_eq!(header.header_len, 41);
    assert_eq!(header.format_version, 1);
    assert_eq!(header.layout_version, insuwb_msg::LAYOUT_VERSION);
    assert_eq!(header.meta, example_meta());
}

#[test]
fn every_record_type_round_trips_through_a_file() {
    let dir = Scratch::new("every");
    let path = dir.join("all.iulog");
    let meta = Metadata::new("unit test").with("a", "1").with("b", "two");
    let mut recs = one_of_each(5);
    recs.extend(one_of_each(u64::MAX / 3));
    let mut w = LogWriter::create(&path, &meta, 99).unwrap();
    for r in &recs {
        w.append(r).unwrap();
    }
    let kinds = Record::TOPICS.len();
    assert_eq!(w.records_written(), 2 * kinds as u64);
    w.sync().unwrap();
    w.finish().unwrap();
    let (back, tail, header) = read_all(&path).unwrap();
    assert_eq!(back, recs);
    assert_eq!(tail, None);
    assert_eq!(header.meta, meta);
    assert_eq!(header.created_ns, 99);
    // Topics and headers come back per variant.
    let topics: Vec<_> = back.iter().take(kinds).map(Record::topic).collect();
    assert_eq!(topics, Record::TOPICS);
    assert_eq!(back[0].topic(), topics::IMU);
    assert_eq!(back[5].topic(), topics::FUSED);
    assert_eq!(back[9].topic(), topics::BODY_VEL);
    for r in &back[..kinds] {
        assert_eq!(r.header().seq, 5);
        assert_eq!(r.header().source_id, 0x1234);
    }
}

#[test]
fn variant_indices_are_frozen() {
    // The payload's first byte is the variant index (a one-byte varint):
    // the order of `Record::TOPICS`, as docs/LOG_FORMAT.md lists it. A new
    // topic is appended; these never move.
    let want = [
        (topics::IMU, 0u8),
        (topics::UWB_TDOA, 1),
        (topics::UWB_FIX, 2),
        (topics::NAV, 3),
        (topics::CORRECTION, 4),
        (topics::FUSED, 5),
        (topics::DIAG, 6),
        (topics::TRUTH, 7),
        (topics::HEALTH, 8),
        (topics::BODY_VEL, 9),
        (topics::UWB_RANGE, 10),
        (topics::HEIGHT, 11),
    ];
    let mut enc = RecordEncoder::new();
    let recs = one_of_each(1);
    assert_eq!(recs.len(), want.len());
    assert_eq!(Record::TOPICS.len(), want.len());
    for (r, (topic, index)) in recs.iter().zip(want) {
        assert_eq!(r.topic(), topic);
        assert_eq!(enc.encode(r).unwrap()[8], index, "{topic}");
        assert_eq!(Record::TOPICS[usize::from(index)], topic);
    }
}

#[test]
fn a_body_velocity_is_its_fields_after_the_tag() {
    let v = BodyVelocity {
        header: Header::new(1, 2),
        vel_mps: [0.5, -0.25, 0.0],
        sigma_mps: [0.1, 0.1, 0.0],
        source: BodyVelocity::SOURCE_ODOMETRY,
        range_mm: 0,
    };
    let mut enc = RecordEncoder::new();
    let frame = enc.encode(&Record::BodyVel(v)).unwrap().to_vec();
    // 1 (tag) + 8 one-byte header varints + 6 * 8 (f64) + 2 one-byte varints.
    assert_eq!(frame.len(), 8 + 59);
    let p = &frame[8..];
    assert_eq!(p[0], 9);
    assert_eq!(&p[1..9], &[2, 0, 0, 0, 0, 1, 2, 0]);
    assert_eq!(&p[9..17], &0.5f64.to_le_bytes());
    assert_eq!(&p[33..41], &0.1f64.to_le_bytes());
    assert_eq!(&p[57..], &[1, 0]);
}

#[test]
fn largest_payloads_match_the_documented_bounds() {
    // Every integer at its maximum: varints at their longest.
    let max_header = Header {
        layout_version: u16::MAX,
        source_id: u16::MAX,
        flags: u32::MAX,
        generation: u32::MAX,
        reserved: u32::MAX,
        seq: u64::MAX,
        meas_time_ns: u64::MAX,
        pub_time_ns: u64::MAX,
    };
    let fused = Record::Fused(FusedState {
        header: max_header,
        uwb_seq: u64::MAX,
        uwb_meas_time_ns: u64::MAX,
        uwb_pub_time_ns: u64::MAX,
        ins_seq: u64::MAX,
        ins_meas_time_ns: u64::MAX,
        ins_pub_time_ns: u64::MAX,
        filter_kind: u32::MAX,
        reserved: u32::MAX,
        ..FusedState::default()
    });
    let mut enc = RecordEncoder::new();
    // 1 (variant) + 51 (header) + 47 * 8 (f64) + 16 (frame_id) + 6 * 10 + 2 * 5.
    assert_eq!(enc.encode(&fused).unwrap().len(), 8 + 514);
    // A default IMU sample: 1 + 8 one-byte varints + 6 * 8.
    let imu = Record::Imu(ImuSample::default());
    assert_eq!(enc.encode(&imu).unwrap().len(), 8 + 57);
    const { assert!(514 < MAX_RECORD_LEN) };
}

#[test]
fn encoder_buffer_does_not_grow_in_the_steady_state() {
    let mut enc = RecordEncoder::new();
    let cap = enc.capacity();
    for seq in [0, 1, u64::MAX] {
        for r in one_of_each(seq) {
            let n = enc.encode(&r).unwrap().len();
            assert!(n > 8);
        }
    }
    assert_eq!(enc.capacity(), cap, "encoder reallocated");
}

#[test]
fn metadata_over_the_limit_is_refused() {
    let big = Metadata::new("x".repeat(70_000));
    assert!(encode_header(0, &big).is_err());
    let dir = Scratch::new("bigmeta");
    let err = LogWriter::create(dir.join("a.iulog"), &big, 0).unwrap_err();
    assert!(matches!(err, CreateError::Header(_)), "{err}");
    assert!(!dir.join("a.iulog").exists(), "no file left behind");
}

fn open_bytes(b: &[u8]) -> Result<LogReader<&[u8]>, HeaderError> {
    LogReader::from_reader(b)
}

#[test]
fn bad_headers_give_clear_errors() {
    let good = example_bytes();
    // Empty.
    assert!(matches!(open_bytes(&[]), Err(HeaderError::Empty)));
    // Not a log: the error shows the first bytes.
    let json = br#"{"t": 1, "x": 2}"#;
    let e = open_bytes(json).unwrap_err();
    assert!(matches!(&e, HeaderError::BadMagic { found } if found == b"{\"t\": 1,"));
    let msg = e.to_string();
    assert!(
        msg.contains("magic mismatch") && msg.contains("7b 22 74 22"),
        "{msg}"
    );
    assert!(!is_log(json));
    assert!(is_log(&good));
    assert!(!is_log(&good[..7]));
    // Truncated inside the magic, the fixed part and the metadata.
    for cut in [3, 8, 27, 28, 40] {
        let e = open_bytes(&good[..cut]).unwrap_err();
        let need = if cut < FIXED_HEADER_LEN { 28 } else { 41 };
        assert!(
            matches!(e, HeaderError::Truncated { have, need: n } if have == cut as u64 && n == need),
            "cut {cut}: {e}"
        );
    }
    // Unsupported versions.
    let mut b = good.clone();
    b[8] = 2;
    assert!(matches!(
        open_bytes(&b),
        Err(HeaderError::FormatVersion {
            found: 2,
            supported: 1
        })
    ));
    let mut b = good.clone();
    b[10] = 9;
    assert!(matches!(
        open_bytes(&b),
        Err(HeaderError::LayoutVersion { found: 9, .. })
    ));
    // A log of layout 1 (before `Health` carried named counters): refused
    // at open, never misread.
    let mut b = good.clone();
    b[10] = 1;
    let e = open_bytes(&b).unwrap_err();
    assert_eq!(
        e.to_string(),
        "log record layout version 1 not supported (this reader supports 2)"
    );
    // Metadata length over the limit: refused before reading it.
    let mut b = good.clone();
    b[20..24].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(matches!(
        open_bytes(&b),
        Err(HeaderError::MetaTooLarge { len: u32::MAX, .. })
    ));
    // Metadata corrupted: CRC mismatch.
    let mut b = good.clone();
    b[30] ^= 0x20;
    assert!(matches!(
        open_bytes(&b),
        Err(HeaderError::MetaCrc {
            stored: 0x7f32_53fb,
            ..
        })
    ));
}

#[test]
fn path_errors_are_distinguished() {
    let dir = Scratch::new("paths");
    let meta = Metadata::new("p");
    // A directory is a bad path, for writing and reading.
    let e = LogWriter::create(dir.path(), &meta, 0).unwrap_err();
    assert!(matches!(e, CreateError::BadPath { .. }), "{e}");
    let e = LogReader::open(dir.path()).unwrap_err();
    assert!(matches!(e, OpenError::BadPath { .. }), "{e}");
    let e = LogWriter::create("", &meta, 0).unwrap_err();
    assert!(matches!(e, CreateError::BadPath { .. }), "{e}");
    // Missing parent / missing file: open errors keeping the kind.
    let e = LogWriter::create(dir.join("no/such/dir.iulog"), &meta, 0).unwrap_err();
    assert_eq!(e.io_kind(), Some(ErrorKind::NotFound), "{e}");
    let e = read_all(dir.join("missing.iulog")).unwrap_err();
    assert!(matches!(&e, OpenError::Open { error, .. } if error.kind() == ErrorKind::NotFound));
    // An existing file is never overwritten.
    let p = dir.join("a.iulog");
    LogWriter::create(&p, &meta, 0).unwrap().finish().unwrap();
    let e = LogWriter::create(&p, &meta, 0).unwrap_err();
    assert_eq!(e.io_kind(), Some(ErrorKind::AlreadyExists), "{e}");
    // A file that is not a log.
    let q = dir.join("b.json");
    std::fs::write(&q, b"[1, 2, 3]").unwrap();
    let e = read_all(&q).unwrap_err();
    assert!(e.to_string().contains("magic mismatch"), "{e}");
}

#[cfg(unix)]
#[test]
fn log_files_are_created_0600() {
    use std::os::unix::fs::PermissionsExt;
    let dir = Scratch::new("perm");
    let p = dir.join("a.iulog");
    LogWriter::create(&p, &Metadata::default(), 0)
        .unwrap()
        .finish()
        .unwrap();
    let mode = std::fs::metadata(&p).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode, 0o600);
}
