#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
//! Fuzzing of the five decoders with proptest (stable Rust): arbitrary
//! bytes and mutated valid streams, pushed in arbitrary chunks. For every
//! input: no panic; every byte accounted for (framed, skipped or buffered);
//! the buffer never exceeds the protocol's largest frame; the same readings
//! and counts whatever the chunking; readings consistent with the counts and
//! within the protocol's value ranges. DWM1001 shell lines also go through
//! garbage and cut lines: every whole line after them still decodes.
//!
//! 4096 cases per target by default; `PROPTEST_CASES=1000000` for a long
//! run.
//! The seed streams are `tests/corpus/*`, written by
//! `cargo test -p insuwb-devices --test devices -- fuzz:: --ignored write_corpus`
//! and checked against the generator by `corpus_matches_the_generator`.

use std::path::PathBuf;

use insuwb_devices::frame::{AnyDecoder, DecoderStats, Protocol, Reading, STANDARD_GRAVITY};
use insuwb_devices::{dwm1001, eliko, mavlink, nlink, witmotion};
use proptest::prelude::*;
use proptest::sample::Index;
use rand::SeedableRng as _;
use rand_xoshiro::Xoshiro256StarStar;

// ------------------------------------------------------------------ corpus

fn corpus_path(protocol: Protocol) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/corpus")
        .join(format!("{}.bin", protocol.name()))
}

const CORPUS: [(Protocol, &[u8]); 5] = [
    (
        Protocol::WitMotion,
        include_bytes!("../corpus/witmotion.bin"),
    ),
    (Protocol::Mavlink, include_bytes!("../corpus/mavlink.bin")),
    (Protocol::Nlink, include_bytes!("../corpus/nlink.bin")),
    (Protocol::Eliko, include_bytes!("../corpus/eliko.bin")),
    (Protocol::Dwm1001, include_bytes!("../corpus/dwm1001.bin")),
];

fn corpus(protocol: Protocol) -> &'static [u8] {
    CORPUS
        .iter()
        .find(|(p, _)| *p == protocol)
        .map(|(_, bytes)| *bytes)
        .unwrap()
}

/// A valid stream of each protocol, exercising every decoded frame type.
fn generate(protocol: Protocol) -> Vec<u8> {
    let mut out = Vec::new();
    match protocol {
        Protocol::WitMotion => {
            for k in 0..12 {
                let x = f64::from(k);
                out.extend_from_slice(&witmotion::encode_imu(
                    [x * 0.5, -1.0, 9.8],
                    [0.1, 0.0, -x * 0.02],
                    21.5,
                ));
                out.extend_from_slice(&witmotion::encode_attitude([0.1, -0.2, x * 0.1], 0x0102));
                out.extend_from_slice(&witmotion::encode_quaternion([1.0, 0.0, 0.0, 0.0]));
            }
        }
        Protocol::Mavlink => {
            let mut buf = [0u8; mavlink::MAX_FRAME_LEN];
            let heartbeat = [0, 0, 0, 0, 2, 3, 81, 4, 3];
            let n = mavlink::encode_frame(&mavlink::Header::v2(0), 0, 50, &heartbeat, &mut buf);
            out.extend_from_slice(&buf[..n]);
            for k in 0..4u8 {
                let t = u32::from(k) * 10;
                let n = mavlink::encode_scaled_imu(
                    &mavlink::Header::v1(1 + k),
                    t,
                    [0.1, 0.2, -9.8],
                    [0.01, 0.0, 0.0],
                    &mut buf,
                );
                out.extend_from_slice(&buf[..n]);
            }
            for k in 0..8u8 {
                let header = if k % 2 == 0 {
                    mavlink::Header::v2(5 + k)
                } else {
                    mavlink::Header::v1(5 + k)
                };
                let n = mavlink::encode_highres_imu(
                    &header,
                    u64::from(k) * 10_000,
                    [f64::from(k), 0.2, -9.8],
                    [0.0, 0.01, 0.02],
                    0,
                    &mut buf,
                );
                out.extend_from_slice(&buf[..n]);
            }
        }
        Protocol::Nlink => {
            for k in 0..6u32 {
                let x = f64::from(k);
                let frame = nlink::TagFrame {
                    id: 2,
                    role: 2,
                    pos_m: [x * 0.1, 3.0, 1.2],
                    vel_mps: [0.1, 0.0, 0.0],
                    ranges_m: [4.0, 5.0 + x, 6.0, 7.0, 0.0, 0.0, 0.0, 0.0],
                    local_time_ms: k * 20,
                    system_time_ms: 1_000 + k * 20,
                    voltage_v: 4.1,
                };
                out.extend_from_slice(&frame.encode());
            }
        }
        Protocol::Eliko => {
            let mut line = [0u8; eliko::MAX_LINE_LEN];
            out.extend_from_slice(b"$PEKIO,EULA,ACCEPTED\r\n");
            for k in 0..16u8 {
                let pos = (k % 5 != 4).then(|| [f64::from(k) * 0.25, 1.5, 0.9]);
                let tag = if k % 3 == 0 { 0x2A } else { 0x2B };
                let t = 1_700_000_000_000_000 + u64::from(k) * 100_000;
                let n = eliko::encode_coord(k, tag, pos, t, &mut line).unwrap();
                out.extend_from_slice(&line[..n]);
            }
        }
        Protocol::Dwm1001 => {
            // lec, les and lep lines in turn, 1 to 4 anchors, every fifth
            // position of quality 0 (none), between shell prompts.
            out.extend_from_slice(b"dwm> lec\r\n");
            for k in 0..12u32 {
                let x = f64::from(k);
                let anchors: Vec<dwm1001::AnchorRange> = (0..1 + k % 4)
                    .map(|i| dwm1001::AnchorRange {
                        id: 0x1150 + i * 0x0101,
                        pos_m: [5.0 * f64::from(i % 2), 8.0 * f64::from(i / 2), 2.25],
                        range_m: 3.0 + x * 0.1 + f64::from(i),
                    })
                    .collect();
                let quality = if k % 5 == 4 { 0 } else { 100 - k as u8 };
                let pos = ([x * 0.25, 1.98, 1.68], quality);
                match k % 3 {
                    0 => dwm1001::encode_lec(&anchors, Some(pos), &mut out),
                    1 => dwm1001::encode_les(&anchors, Some(pos), Some(2000 + k), &mut out),
                    _ => dwm1001::encode_lep(pos.0, pos.1, &mut out),
                }
                .unwrap();
                if k == 5 {
                    out.extend_from_slice(b"\r\ndwm> les\r\n");
                }
            }
            out.extend_from_slice(b"dwm> ");
        }
    }
    out
}

#[test]
#[ignore = "writes tests/corpus; run by hand after changing the generator"]
fn write_corpus() {
    for protocol in Protocol::ALL {
        let path = corpus_path(protocol);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, generate(protocol)).unwrap();
    }
}

#[test]
fn corpus_matches_the_generator() {
    for protocol in Protocol::ALL {
        assert_eq!(
            corpus(protocol),
            generate(protocol),
            "{protocol}: rerun write_corpus"
        );
        let (readings, stats) = run(protocol, corpus(protocol), &[usize::MAX]);
        assert_eq!(stats.bytes_skipped, 0, "{protocol}");
        assert_eq!(stats.checksum_errors, 0, "{protocol}");
        let expected = match protocol {
            Protocol::WitMotion => 36,
            Protocol::Mavlink => 12,
            Protocol::Nlink => 36,
            Protocol::Eliko => 13,
            Protocol::Dwm1001 => 30,
        };
        assert_eq!(readings.len(), expected, "{protocol}");
    }
}

// -------------------------------------------------------------- invariants

/// Decodes `bytes` pushed in chunks of the given sizes (cycled; 0 counts
/// as 1); checks the invariants that hold after every push.
fn run(protocol: Protocol, bytes: &[u8], chunks: &[usize]) -> (Vec<Reading>, DecoderStats) {
    let mut decoder = AnyDecoder::new(protocol);
    let mut readings = Vec::new();
    let mut rest = bytes;
    let mut sizes = chunks.iter().cycle();
    while !rest.is_empty() {
        let size = sizes.next().copied().unwrap_or(1).clamp(1, rest.len());
        let (chunk, tail) = rest.split_at(size);
        decoder.push(chunk, &mut |r| readings.push(r));
        rest = tail;
        let s = decoder.stats();
        assert!(
            decoder.buffered() <= protocol.max_frame_len(),
            "{protocol}: {s:?}"
        );
        assert_eq!(
            s.bytes_in,
            s.bytes_framed + s.bytes_skipped + decoder.buffered() as u64,
            "{protocol}: {s:?}"
        );
        assert!(decoder.bytes_since_last_valid_frame() <= s.bytes_in);
    }
    let stats = decoder.stats();
    assert_eq!(stats.bytes_in, bytes.len() as u64);
    check_readings(protocol, &readings, &stats);
    (readings, stats)
}

/// Readings agree with the counts and lie within the protocol's ranges.
fn check_readings(protocol: Protocol, readings: &[Reading], s: &DecoderStats) {
    let frames = s.frames_ok + s.unknown + s.malformed + s.filtered + s.no_fix;
    let min_frame: u64 = match protocol {
        Protocol::WitMotion => 11,
        Protocol::Mavlink => 8,
        Protocol::Nlink => 128,
        Protocol::Eliko => 2,
        Protocol::Dwm1001 => 1,
    };
    assert!(frames * min_frame <= s.bytes_framed, "{protocol}: {s:?}");
    let n = readings.len() as u64;
    match protocol {
        Protocol::WitMotion => {
            let imus = readings
                .iter()
                .filter(|r| matches!(r, Reading::Imu { .. }))
                .count() as u64;
            assert!(n - imus + 2 * imus <= s.frames_ok, "{s:?}");
        }
        Protocol::Mavlink | Protocol::Eliko => assert_eq!(n, s.frames_ok, "{protocol}: {s:?}"),
        Protocol::Nlink => {
            let ranges = count(readings, |r| matches!(r, Reading::Range { .. }));
            assert_eq!(n - ranges, 2 * s.frames_ok, "{s:?}");
            assert!(ranges <= 8 * s.frames_ok, "{s:?}");
        }
        Protocol::Dwm1001 => {
            // A decoded line ends a round of ranges, has a position, or both.
            let ends = count(readings, |r| {
                matches!(
                    r,
                    Reading::Range {
                        last_of_round: true,
                        ..
                    }
                )
            });
            let positions = count(readings, |r| matches!(r, Reading::Position { .. }));
            assert!(ends <= s.frames_ok && positions <= s.frames_ok, "{s:?}");
            assert!(s.frames_ok <= ends + positions, "{s:?}");
            assert!(
                n <= s.frames_ok * (dwm1001::MAX_ANCHORS as u64 + 1),
                "{s:?}"
            );
        }
    }
    for r in readings {
        let ok = match (protocol, r) {
            (
                Protocol::WitMotion,
                Reading::Imu {
                    accel_mps2,
                    gyro_rps,
                    ..
                },
            ) => {
                accel_mps2
                    .iter()
                    .all(|a| a.abs() <= 16.0 * STANDARD_GRAVITY)
                    && gyro_rps.iter().all(|w| w.abs() <= 2000f64.to_radians())
            }
            (Protocol::WitMotion, Reading::Attitude { rpy_rad, .. }) => {
                rpy_rad.iter().all(|a| a.abs() <= std::f64::consts::PI)
            }
            (Protocol::WitMotion, Reading::Quaternion { wxyz, .. }) => {
                wxyz.iter().all(|q| q.abs() <= 1.0)
            }
            (
                Protocol::Mavlink,
                Reading::Imu {
                    accel_mps2,
                    gyro_rps,
                    device_time: Some(_),
                },
            ) => accel_mps2.iter().chain(gyro_rps).all(|v| v.is_finite()),
            (
                Protocol::Nlink,
                Reading::Position {
                    pos_m,
                    vel_mps: Some(vel),
                    device_time: Some(_),
                    ..
                },
            ) => {
                pos_m.iter().all(|p| p.abs() <= 8388.608) && vel.iter().all(|v| v.abs() <= 838.8608)
            }
            (Protocol::Nlink, Reading::Ranges { ranges_m, .. }) => {
                ranges_m.iter().all(|d| d.abs() <= 8388.608)
            }
            (
                Protocol::Nlink,
                Reading::Range {
                    anchor,
                    range_m,
                    anchor_pos_m: None,
                    quality: None,
                    device_time: Some(_),
                    ..
                },
            ) => *anchor < 8 && *range_m != 0.0 && range_m.abs() <= 8388.608,
            (
                Protocol::Dwm1001,
                Reading::Range {
                    anchor,
                    range_m,
                    anchor_pos_m: Some(pos),
                    quality: None,
                    device_time: None,
                    ..
                },
            ) => *anchor <= 0xFFFF && range_m.is_finite() && pos.iter().all(|p| p.is_finite()),
            (
                Protocol::Dwm1001,
                Reading::Position {
                    pos_m,
                    vel_mps: None,
                    device_time: None,
                    seq: None,
                    ..
                },
            ) => pos_m.iter().all(|p| p.is_finite()),
            (
                Protocol::Eliko,
                Reading::Position {
                    pos_m,
                    vel_mps: None,
                    seq: Some(seq),
                    ..
                },
            ) => pos_m.iter().all(|p| p.is_finite()) && *seq < 256,
            _ => false,
        };
        assert!(ok, "{protocol}: {r:?}");
    }
}

fn count(readings: &[Reading], pred: impl Fn(&Reading) -> bool) -> u64 {
    readings.iter().filter(|r| pred(r)).count() as u64
}

/// Decodes with the given chunking and in one push: the results must agree.
fn check(protocol: Protocol, bytes: &[u8], chunks: &[usize]) {
    let chunked = run(protocol, bytes, chunks);
    let whole = run(protocol, bytes, &[usize::MAX]);
    assert_eq!(chunked, whole, "{protocol}: chunking changed the result");
}

// --------------------------------------------------------------- mutations

#[derive(Debug, Clone)]
enum Mutation {
    Flip(Index, u8),
    Insert(Index, Vec<u8>),
    Delete(Index, usize),
    Duplicate(Index, usize),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        (any::<Index>(), 1..=255u8).prop_map(|(i, m)| Mutation::Flip(i, m)),
        (any::<Index>(), prop::collection::vec(any::<u8>(), 1..40))
            .prop_map(|(i, b)| Mutation::Insert(i, b)),
        (any::<Index>(), 1..40usize).prop_map(|(i, n)| Mutation::Delete(i, n)),
        (any::<Index>(), 1..300usize).prop_map(|(i, n)| Mutation::Duplicate(i, n)),
    ]
}

fn mutate(seed: &[u8], mutations: &[Mutation]) -> Vec<u8> {
    let mut bytes = seed.to_vec();
    for m in mutations {
        if bytes.is_empty() {
            break;
        }
        match m {
            Mutation::Flip(i, mask) => {
                let at = i.index(bytes.len());
                bytes[at] ^= mask;
            }
            Mutation::Insert(i, new) => {
                let at = i.index(bytes.len() + 1);
                bytes.splice(at..at, new.iter().copied());
            }
            Mutation::Delete(i, n) => {
                let at = i.index(bytes.len());
                let end = (at + n).min(bytes.len());
                bytes.drain(at..end);
            }
            Mutation::Duplicate(i, n) => {
                let at = i.index(bytes.len());
                let end = (at + n).min(bytes.len());
                let copy = bytes[at..end].to_vec();
                bytes.splice(end..end, copy);
            }
        }
    }
    bytes
}

fn chunks() -> impl Strategy<Value = Vec<usize>> {
    prop::collection::vec(1..300usize, 1..16)
}

fn arbitrary_bytes() -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(any::<u8>(), 0..4096)
}

fn mutations() -> impl Strategy<Value = Vec<Mutation>> {
    prop::collection::vec(mutation(), 0..8)
}

/// Cases per target: `PROPTEST_CASES`, else 4096 (the whole file then runs
/// in well under a second in release on one core).
fn cases() -> u32 {
    std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(4096)
}

/// Two targets per protocol: arbitrary bytes, and the corpus mutated.
macro_rules! fuzz_targets {
    ($($protocol:expr => $arbitrary:ident, $mutated:ident;)*) => {
        proptest! {
            // Failures print the minimal input; nothing is written to disk.
            #![proptest_config(ProptestConfig {
                cases: cases(),
                failure_persistence: None,
                ..ProptestConfig::default()
            })]
            $(
                #[test]
                fn $arbitrary(bytes in arbitrary_bytes(), c in chunks()) {
                    check($protocol, &bytes, &c);
                }

                #[test]
                fn $mutated(m in mutations(), c in chunks()) {
                    check($protocol, &mutate(corpus($protocol), &m), &c);
                }
            )*
        }
    };
}

fuzz_targets! {
    Protocol::WitMotion => witmotion_arbitrary_bytes, witmotion_mutated_stream;
    Protocol::Mavlink => mavlink_arbitrary_bytes, mavlink_mutated_stream;
    Protocol::Nlink => nlink_arbitrary_bytes, nlink_mutated_stream;
    Protocol::Eliko => eliko_arbitrary_bytes, eliko_mutated_stream;
    Protocol::Dwm1001 => dwm1001_arbitrary_bytes, dwm1001_mutated_stream;
}

// ------------------------------------------- DWM1001 lines after garbage

/// The corpus's report lines, each with what it decodes to alone.
fn dwm1001_lines() -> Vec<(Vec<u8>, Vec<Reading>)> {
    corpus(Protocol::Dwm1001)
        .split_inclusive(|b| *b == b'\n')
        .filter(|l| l.ends_with(b"\n"))
        .map(|l| (l.to_vec(), run(Protocol::Dwm1001, l, &[usize::MAX]).0))
        .filter(|(_, readings)| !readings.is_empty())
        .collect()
}

/// Whether `next` restarts a line that holds `cut` (the start of another
/// report); see the resynchronisation rules of `dwm1001`.
fn restarts(cut: &[u8], next: &[u8]) -> bool {
    let starts_les = |b: &[u8]| {
        b.get(4) == Some(&b'[') && b.len() > 4 && b[..4].iter().all(u8::is_ascii_hexdigit)
    };
    if cut.ends_with(b"\r") || next.starts_with(b"DIST,") {
        true
    } else if next.starts_with(b"POS,") {
        !cut.starts_with(b"DIST,") && !cut.ends_with(b",")
    } else {
        !starts_les(cut) && !cut.ends_with(b" ")
    }
}

/// Garbage without the bytes a report continues with (`,` `[` space `=`).
fn dwm1001_garbage() -> impl Strategy<Value = Vec<u8>> {
    prop::collection::vec(
        any::<u8>().prop_map(|b| if b",[ =".contains(&b) { b'x' } else { b }),
        0..40,
    )
}

proptest! {
    #![proptest_config(ProptestConfig {
        cases: cases(),
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    /// Report lines after garbage, after the start of another report cut
    /// anywhere (where the rules can tell the two apart), pushed in
    /// arbitrary chunks, byte by byte and whole: each gives exactly what it
    /// gives alone.
    #[test]
    fn dwm1001_lines_survive_garbage_and_cut_lines(
        items in prop::collection::vec(
            (any::<Index>(), dwm1001_garbage(), any::<Option<(Index, Index)>>()),
            1..12,
        ),
        c in chunks(),
    ) {
        let lines = dwm1001_lines();
        let mut stream = Vec::new();
        let mut expected = Vec::new();
        for (line, garbage, cut) in &items {
            let (line, readings) = &lines[line.index(lines.len())];
            stream.extend_from_slice(garbage);
            if let Some((cut_line, cut_len)) = cut {
                let cut_line = &lines[cut_line.index(lines.len())].0;
                let cut = &cut_line[..1 + cut_len.index(cut_line.len() - 1)];
                if restarts(cut, line) {
                    stream.extend_from_slice(cut);
                }
            }
            stream.extend_from_slice(line);
            expected.extend_from_slice(readings);
        }
        for chunking in [&c[..], &[1], &[usize::MAX]] {
            let (readings, _) = run(Protocol::Dwm1001, &stream, chunking);
            prop_assert_eq!(&readings, &expected);
        }
    }
}

// --------------------------------------------------- recovery after damage

/// One flipped byte in every fourth copy of the corpus, 400 copies: the
/// frames the flips did not touch must nearly all come through (a flip may
/// also make a false frame whose checksum passes and that swallows a
/// neighbour, at odds of about 1 in 256 for the 8-bit checksums).
#[test]
fn frames_untouched_by_damage_come_through() {
    for protocol in Protocol::ALL {
        let copies = 400;
        let mut stream = corpus(protocol).repeat(copies);
        // Clean, the stream gives this many (MAVLink: SCALED_IMU only in the
        // first copy, before HIGHRES_IMU is seen).
        let expected = run(protocol, &stream, &[usize::MAX]).0.len();
        // Seeded, so the statistic is the same on every run.
        let mut rng = Xoshiro256StarStar::seed_from_u64(0x5EED);
        let flips = copies / 4;
        for _ in 0..flips {
            let at = rng.random_range(0..stream.len());
            stream[at] ^= rng.random_range(1..=255_u8);
        }
        let (readings, stats) = run(protocol, &stream, &[4096]);
        // A flip costs the readings of the frame it hits (NLink: 2 and a
        // range per heard anchor, 4 in the corpus; a DWM1001 line: up to 4
        // ranges and a position; the others 1); allow 10 % more for false
        // frames that pass a checksum.
        let per_frame = match protocol {
            Protocol::Nlink => 6,
            Protocol::Dwm1001 => 5,
            _ => 1,
        };
        let floor = expected - per_frame * flips * 11 / 10;
        println!(
            "{protocol}: {} of {expected} readings after {flips} flips ({:?} checksum errors)",
            readings.len(),
            stats.checksum_errors
        );
        assert!(
            readings.len() >= floor,
            "{protocol}: {} < {floor}",
            readings.len()
        );
    }
}
