//! Damaged files: cuts at every offset, single-byte corruption anywhere in the
//! records, impossible lengths. The reader must return exactly the records
//! before the damage and say where it is, and never panic.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // tests may unwrap

use crate::common;

use common::{mixed, one_of_each, Scratch};
use insuwb_log::{
    encode_header, read_all, HeaderError, LogReader, LogWriter, Metadata, Record, RecordEncoder,
    TailReason, TailReport, MAX_RECORD_LEN,
};
use insuwb_msg::{
    BodyVelocity, CounterBlock, FilterDiag, FusedState, GroundTruth, Header, Health, ImuSample,
    InsCorrection, NavState, StateCode, UwbFix, UwbTdoa,
};
use proptest::prelude::*;
use proptest::test_runner::RngSeed;

/// A log in memory and the offset where each record ends.
struct Log {
    bytes: Vec<u8>,
    header_len: u64,
    ends: Vec<u64>,
    records: Vec<Record>,
}

fn build(records: Vec<Record>) -> Log {
    let mut bytes = encode_header(77, &Metadata::new("torn").with("k", "v")).unwrap();
    let header_len = bytes.len() as u64;
    let mut enc = RecordEncoder::new();
    let mut ends = Vec::new();
    for r in &records {
        bytes.extend_from_slice(enc.encode(r).unwrap());
        ends.push(bytes.len() as u64);
    }
    Log {
        bytes,
        header_len,
        ends,
        records,
    }
}

/// Reads `bytes` to the end: the records and the tail report.
fn read(bytes: &[u8]) -> Result<(Vec<Record>, Option<TailReport>), HeaderError> {
    let mut r = LogReader::from_reader(bytes)?;
    let recs: Vec<Record> = r.by_ref().map(|x| x.unwrap()).collect();
    assert_eq!(r.records_read(), recs.len() as u64);
    Ok((recs, r.tail().cloned()))
}

/// Checks the reading of `log` cut at `cut` against the record boundaries.
fn check_cut(log: &Log, cut: usize) {
    let c = cut as u64;
    let got = read(&log.bytes[..cut]);
    if c < log.header_len {
        let e = got.unwrap_err();
        if cut == 0 {
            assert!(matches!(e, HeaderError::Empty), "cut {cut}: {e}");
        } else {
            assert!(
                matches!(e, HeaderError::Truncated { have, .. } if have == c),
                "cut {cut}: {e}"
            );
        }
        return;
    }
    let (recs, tail) = got.unwrap();
    let k = log.ends.iter().filter(|&&e| e <= c).count();
    assert_eq!(recs.as_slice(), &log.records[..k], "cut {cut}");
    let boundary = if k == 0 {
        log.header_len
    } else {
        log.ends[k - 1]
    };
    if boundary == c {
        assert_eq!(tail, None, "cut {cut} is a record boundary");
    } else {
        let t = tail.unwrap_or_else(|| panic!("cut {cut}: no tail report"));
        assert_eq!(t.last_good_offset, boundary, "cut {cut}");
        assert_eq!(t.bytes_ignored, c - boundary, "cut {cut}");
        let into = c - boundary;
        if into < 8 {
            assert_eq!(
                t.reason,
                TailReason::TruncatedFrameHeader { have: into },
                "cut {cut}"
            );
        } else {
            assert!(
                matches!(t.reason, TailReason::TruncatedPayload { have, .. } if have == into - 8),
                "cut {cut}: {:?}",
                t.reason
            );
        }
    }
}

fn finite() -> impl Strategy<Value = f64> {
    use proptest::num::f64;
    f64::POSITIVE | f64::NEGATIVE | f64::NORMAL | f64::SUBNORMAL | f64::ZERO | f64::INFINITE
}

fn arb_header() -> impl Strategy<Value = Header> {
    (any::<(u16, u16, u32, u32, u32)>(), any::<(u64, u64, u64)>()).prop_map(
        |((layout_version, source_id, flags, generation, reserved), (seq, m, p))| Header {
            layout_version,
            source_id,
            flags,
            generation,
            reserved,
            seq,
            meas_time_ns: m,
            pub_time_ns: p,
        },
    )
}

fn take<const N: usize>(it: &mut impl Iterator<Item = f64>) -> [f64; N] {
    std::array::from_fn(|_| it.next().unwrap())
}

/// Any record: a type, a header, a pool of floats and integers for the fields.
fn arb_record() -> impl Strategy<Value = Record> {
    (
        0u8..10,
        arb_header(),
        proptest::collection::vec(finite(), 48),
        any::<[u64; 10]>(),
        any::<[u8; 16]>(),
    )
        .prop_map(|(kind, header, floats, ints, name)| {
            let f = &mut floats.into_iter();
            let u32_ = |i: usize| ints[i] as u32;
            match kind {
                0 => Record::Imu(ImuSample {
                    header,
                    accel_mps2: take(f),
                    gyro_rps: take(f),
                }),
                1 => Record::Tdoa(UwbTdoa {
                    header,
                    anchor_a: u32_(0),
                    anchor_b: u32_(1),
                    diff_m: take::<1>(f)[0],
                    anchor_a_pos_m: take(f),
                    anchor_b_pos_m: take(f),
                }),
                2 => Record::Fix(UwbFix {
                    header,
                    pos_m: take(f),
                    vel_mps: take(f),
                    pos_cov_m2: [take(f), take(f), take(f)],
                    vel_cov: [take(f), take(f), take(f)],
                    gdop: take::<1>(f)[0],
                    n_meas: u32_(0),
                    iterations: u32_(1),
                }),
                3 => Record::Nav(NavState {
                    header,
                    correction_id: ints[0],
                    imu_seq: ints[3],
                    imu_generation: u32_(1),
                    reserved: u32_(2),
                    pos_m: take(f),
                    vel_mps: take(f),
                    quat: take(f),
                    accel_nav_mps2: take(f),
                    omega_nav_rps: take(f),
                    accel_bias_mps2: take(f),
                    gyro_bias_rps: take(f),
                }),
                4 => Record::Correction(InsCorrection {
                    header,
                    correction_id: ints[0],
                    apply_at_seq: ints[1],
                    imu_generation: u32_(2),
                    reserved: u32_(3),
                    d_pos_m: take(f),
                    d_vel_mps: take(f),
                    d_att_rad: take(f),
                    d_accel_bias_mps2: take(f),
                    d_gyro_bias_rps: take(f),
                    reset_pos_m: take(f),
                    reset_vel_mps: take(f),
                    reset_quat: take(f),
                }),
                5 => Record::Fused(FusedState {
                    header,
                    pos_m: take(f),
                    vel_mps: take(f),
                    quat: take(f),
                    yaw_rad: take::<1>(f)[0],
                    cov: [take(f), take(f), take(f), take(f), take(f), take(f)],
                    frame_id: name,
                    uwb_seq: ints[0],
                    uwb_meas_time_ns: ints[1],
                    uwb_pub_time_ns: ints[2],
                    ins_seq: ints[3],
                    ins_meas_time_ns: ints[4],
                    ins_pub_time_ns: ints[5],
                    filter_kind: u32_(6),
                    reserved: u32_(7),
                }),
                6 => Record::Diag(FilterDiag {
                    header,
                    innovation: take(f),
                    innovation_var: take(f),
                    lambda: take(f),
                    r_diag: take(f),
                    nis: take::<1>(f)[0],
                    fading: take::<1>(f)[0],
                    dim: u32_(0),
                    filter_kind: u32_(1),
                }),
                7 => Record::Truth(GroundTruth {
                    header,
                    pos_m: take(f),
                    vel_mps: take(f),
                    quat: take(f),
                }),
                8 => Record::Health(Health {
                    header,
                    stage: name,
                    pid: u32_(0),
                    state: StateCode::from_raw(u32_(1)),
                    received: ints[2],
                    published: ints[3],
                    dropped_version: ints[4],
                    dropped_invalid: ints[5],
                    dropped_time: ints[6],
                    seq_gaps: ints[7],
                    // Any kind code, known or not, and any words.
                    counters: CounterBlock::from_raw(
                        u32_(2) % 16,
                        [ints[8], ints[9], ints[0], ints[1], ints[2], ints[3]],
                    ),
                }),
                _ => Record::BodyVel(BodyVelocity {
                    header,
                    vel_mps: take(f),
                    sigma_mps: take(f),
                    source: u32_(0),
                    range_mm: u32_(1),
                }),
            }
        })
}

fn config(cases: u32) -> ProptestConfig {
    ProptestConfig {
        cases,
        rng_seed: RngSeed::Fixed(0x1057_2017),
        failure_persistence: None,
        ..ProptestConfig::default()
    }
}

proptest! {
    #![proptest_config(config(64))]

    #[test]
    fn random_records_round_trip(records in proptest::collection::vec(arb_record(), 0..40)) {
        let log = build(records);
        let (recs, tail) = read(&log.bytes).unwrap();
        prop_assert_eq!(recs, log.records);
        prop_assert_eq!(tail, None);
    }
}

proptest! {
    #![proptest_config(config(12))]

    #[test]
    fn a_cut_at_every_offset_keeps_exactly_the_whole_records(
        records in proptest::collection::vec(arb_record(), 25..=30)
    ) {
        let log = build(records);
        for cut in 0..=log.bytes.len() {
            check_cut(&log, cut);
        }
    }

    #[test]
    fn any_corrupted_byte_stops_at_the_record_it_hits(
        records in proptest::collection::vec(arb_record(), 25..=30),
        mask in 1u8..=255,
    ) {
        let log = build(records);
        let len = log.bytes.len() as u64;
        let mut bytes = log.bytes.clone();
        for pos in log.header_len as usize..bytes.len() {
            bytes[pos] ^= mask;
            let (recs, tail) = read(&bytes).unwrap();
            bytes[pos] ^= mask;
            // The record that holds the corrupted byte and its start.
            let j = log.ends.iter().filter(|&&e| e <= pos as u64).count();
            let start = if j == 0 { log.header_len } else { log.ends[j - 1] };
            prop_assert_eq!(recs.as_slice(), &log.records[..j], "byte {}", pos);
            let t = tail.unwrap();
            prop_assert_eq!(t.last_good_offset, start, "byte {}", pos);
            prop_assert_eq!(t.bytes_ignored, len - start, "byte {}", pos);
        }
    }
}

#[test]
fn cuts_of_a_real_file_read_back_through_read_all() {
    let dir = Scratch::new("cuts");
    let path = dir.join("full.iulog");
    let records = mixed(30);
    let mut w = LogWriter::create(&path, &Metadata::new("torn").with("k", "v"), 77).unwrap();
    for r in &records {
        w.append(r).unwrap();
    }
    w.finish().unwrap();
    let log = build(records);
    let full = std::fs::read(&path).unwrap();
    assert_eq!(full, log.bytes, "writer and in-memory framing agree");
    let cut_path = dir.join("cut.iulog");
    for &cut in &[
        log.header_len,
        log.ends[3],
        log.ends[3] + 5,
        log.ends[10] + 20,
        log.ends[29] - 1,
    ] {
        std::fs::write(&cut_path, &full[..cut as usize]).unwrap();
        let (recs, tail, header) = read_all(&cut_path).unwrap();
        let k = log.ends.iter().filter(|&&e| e <= cut).count();
        assert_eq!(recs.as_slice(), &log.records[..k]);
        assert_eq!(header.created_ns, 77);
        let boundary = if k == 0 {
            log.header_len
        } else {
            log.ends[k - 1]
        };
        match tail {
            None => assert_eq!(boundary, cut),
            Some(t) => {
                assert_eq!(t.last_good_offset, boundary);
                assert_eq!(t.bytes_ignored, cut - boundary);
                assert!(
                    t.to_string()
                        .contains(&format!("torn tail at byte {boundary}")),
                    "{t}"
                );
            }
        }
    }
}

/// A log whose only frame announces `len` bytes and carries `extra` bytes after the frame header.
fn with_frame(len: u32, crc: u32, extra: usize) -> (Vec<u8>, u64) {
    let mut bytes = encode_header(0, &Metadata::default()).unwrap();
    let h = bytes.len() as u64;
    bytes.extend_from_slice(&len.to_le_bytes());
    bytes.extend_from_slice(&crc.to_le_bytes());
    bytes.extend(std::iter::repeat_n(0xA5u8, extra));
    (bytes, h)
}

#[test]
fn impossible_lengths_are_refused_without_reading_the_payload() {
    for len in [0, MAX_RECORD_LEN + 1, u32::MAX] {
        let (bytes, h) = with_frame(len, 0, 100);
        let (recs, tail) = read(&bytes).unwrap();
        assert!(recs.is_empty());
        assert_eq!(
            tail,
            Some(TailReport {
                last_good_offset: h,
                bytes_ignored: 108,
                reason: TailReason::BadLength { len }
            })
        );
    }
    // The maximum itself is a valid length: what fails is the CRC.
    let (bytes, h) = with_frame(MAX_RECORD_LEN, 0, MAX_RECORD_LEN as usize);
    let (_, tail) = read(&bytes).unwrap();
    let t = tail.unwrap();
    assert_eq!(t.last_good_offset, h);
    assert!(
        matches!(t.reason, TailReason::CrcMismatch { stored: 0, .. }),
        "{t}"
    );
}

#[test]
fn a_valid_crc_over_a_bad_payload_is_a_decode_report() {
    // The first variant index past the last (an unknown future topic).
    let unknown = u8::try_from(Record::TOPICS.len()).unwrap();
    let payload = [unknown, 0, 0];
    let (mut bytes, h) = with_frame(3, crc32fast::hash(&payload), 0);
    bytes.extend_from_slice(&payload);
    let (_, tail) = read(&bytes).unwrap();
    assert!(matches!(tail.unwrap().reason, TailReason::Decode(_)));
    // A valid record followed by a stray byte inside the same frame.
    let mut enc = RecordEncoder::new();
    let mut payload = enc.encode(&one_of_each(1)[0]).unwrap()[8..].to_vec();
    payload.push(0);
    let (mut bytes, _) = with_frame(payload.len() as u32, crc32fast::hash(&payload), 0);
    bytes.extend_from_slice(&payload);
    let (recs, tail) = read(&bytes).unwrap();
    assert!(recs.is_empty());
    let t = tail.unwrap();
    assert_eq!(t.reason, TailReason::TrailingBytes { extra: 1 });
    assert_eq!(t.last_good_offset, h);
}
