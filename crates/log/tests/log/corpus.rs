//! Seed-corpus fuzzing of the log reader (stable Rust, proptest): the files
//! in `tests/corpus/` are read whole, then mutated (bit flips, byte writes,
//! cuts, insertions, removals, copied chunks, length fields set to extreme
//! values) and read again. The reader must never panic, account for every
//! byte (records read, then a tail report whose offset and ignored bytes add
//! up to the input's length) and never claim more records than the bytes
//! can hold.
//!
//! Cases: 20,000 per run (0.1 s in release), more with `PROPTEST_CASES`.
//! The seed is random per run unless `PROPTEST_RNG_SEED` is set; a failing
//! case is saved, shrunk, in `proptest-regressions/corpus.txt` (commit it:
//! it runs first from then on). Longer campaigns: docs/RELIABILITY.md.
//! The corpus is made by
//! `cargo test -p insuwb-log --test log -- corpus:: --ignored`.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use crate::common;

use std::path::PathBuf;
use std::sync::OnceLock;

use insuwb_log::{encode_header, LogReader, Metadata, Record, RecordEncoder};
use proptest::prelude::*;
use proptest::sample::Index;

/// Smallest frame on disk: u32 length, u32 CRC, a record tag.
const MIN_FRAME: u64 = 9;

fn corpus_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/corpus")
}

/// The seed files, sorted by name (read once).
fn seeds() -> &'static [(String, Vec<u8>)] {
    static SEEDS: OnceLock<Vec<(String, Vec<u8>)>> = OnceLock::new();
    SEEDS.get_or_init(|| {
        let mut out: Vec<(String, Vec<u8>)> = std::fs::read_dir(corpus_dir())
            .unwrap()
            .map(|e| {
                let p = e.unwrap().path();
                let name = p.file_name().unwrap().to_string_lossy().into_owned();
                (name, std::fs::read(&p).unwrap())
            })
            .collect();
        out.sort();
        out
    })
}

/// Reads `bytes` whole and checks the accounting; returns the records read.
fn read_checked(bytes: &[u8]) -> Option<u64> {
    let mut r = LogReader::from_reader(bytes).ok()?;
    for item in r.by_ref() {
        // In-memory input: no I/O error, corruption ends in a tail report.
        assert!(item.is_ok(), "{item:?}");
    }
    let len = bytes.len() as u64;
    let n = r.records_read();
    match r.tail() {
        Some(t) => {
            assert_eq!(t.last_good_offset + t.bytes_ignored, len, "{t}");
            assert!(t.last_good_offset >= n * MIN_FRAME, "{t}");
        }
        None => assert_eq!(r.offset(), len),
    }
    assert!(n * MIN_FRAME <= len);
    Some(n)
}

#[test]
fn every_seed_reads_whole() {
    let seeds = seeds();
    assert!(seeds.len() >= 3, "{seeds:?}");
    for (name, bytes) in seeds {
        let mut r = LogReader::from_reader(bytes.as_slice()).unwrap();
        let n = r.by_ref().filter(Result::is_ok).count();
        assert!(r.tail().is_none(), "{name}: {:?}", r.tail());
        assert_eq!(read_checked(bytes), Some(n as u64), "{name}");
    }
}

/// `before-body-vel.iulog` is a seed written before the `BodyVel` variant
/// was appended (one record of each of the nine types then, as
/// `one_of_each(3)` made them), kept as it was: a log of that time reads
/// whole, to the same records. `regenerate_corpus` leaves it alone.
#[test]
fn a_log_written_before_body_velocity_reads_the_same() {
    let bytes = std::fs::read(corpus_dir().join("before-body-vel.iulog")).unwrap();
    let mut r = LogReader::from_reader(bytes.as_slice()).unwrap();
    let recs: Vec<Record> = r.by_ref().map(Result::unwrap).collect();
    assert!(r.tail().is_none(), "{:?}", r.tail());
    assert_eq!(recs[..], common::one_of_each(3)[..9]);
    assert!(recs
        .iter()
        .all(|rec| rec.topic() != insuwb_msg::topics::BODY_VEL));
}

/// One edit of a seed.
#[derive(Debug, Clone)]
enum Edit {
    FlipBit(Index, u8),
    SetByte(Index, u8),
    Cut(Index),
    Insert(Index, Vec<u8>),
    Remove(Index, usize),
    CopyChunk(Index, Index, usize),
    /// A little-endian u32 written over 4 bytes (frame lengths, counts).
    SetU32(Index, u32),
}

fn edit() -> impl Strategy<Value = Edit> {
    let big = prop_oneof![
        Just(0u32),
        Just(1),
        Just(u32::MAX),
        Just(1 << 24),
        any::<u32>()
    ];
    prop_oneof![
        (any::<Index>(), 0u8..8).prop_map(|(i, b)| Edit::FlipBit(i, b)),
        (any::<Index>(), any::<u8>()).prop_map(|(i, b)| Edit::SetByte(i, b)),
        any::<Index>().prop_map(Edit::Cut),
        (
            any::<Index>(),
            proptest::collection::vec(any::<u8>(), 1..16)
        )
            .prop_map(|(i, v)| Edit::Insert(i, v)),
        (any::<Index>(), 1usize..64).prop_map(|(i, n)| Edit::Remove(i, n)),
        (any::<Index>(), any::<Index>(), 1usize..128)
            .prop_map(|(a, b, n)| Edit::CopyChunk(a, b, n)),
        (any::<Index>(), big).prop_map(|(i, v)| Edit::SetU32(i, v)),
    ]
}

fn apply(bytes: &mut Vec<u8>, e: &Edit) {
    let len = bytes.len();
    if len == 0 {
        return;
    }
    match e {
        Edit::FlipBit(i, b) => bytes[i.index(len)] ^= 1 << b,
        Edit::SetByte(i, v) => bytes[i.index(len)] = *v,
        Edit::Cut(i) => bytes.truncate(i.index(len)),
        Edit::Insert(i, v) => {
            let at = i.index(len);
            bytes.splice(at..at, v.iter().copied());
        }
        Edit::Remove(i, n) => {
            let at = i.index(len);
            bytes.drain(at..(at + n).min(len));
        }
        Edit::CopyChunk(from, to, n) => {
            let a = from.index(len);
            let chunk = bytes[a..(a + n).min(len)].to_vec();
            let b = to.index(len);
            bytes.splice(b..b, chunk);
        }
        Edit::SetU32(i, v) => {
            let at = i.index(len);
            for (k, byte) in v.to_le_bytes().into_iter().enumerate() {
                if let Some(slot) = bytes.get_mut(at + k) {
                    *slot = byte;
                }
            }
        }
    }
}

proptest! {
    // At least 20,000 cases; more with PROPTEST_CASES.
    #![proptest_config(ProptestConfig::with_cases(ProptestConfig::default().cases.max(20_000)))]

    #[test]
    fn mutated_seeds_are_read_without_panic(
        seed in any::<Index>(),
        edits in proptest::collection::vec(edit(), 1..6),
    ) {
        let seeds = seeds();
        let mut bytes = seeds[seed.index(seeds.len())].1.clone();
        for e in &edits {
            apply(&mut bytes, e);
        }
        let _ = read_checked(&bytes);
    }
}

/// Writes the seed files (tiny: a header with metadata only, one record of
/// every type, and a mixed stream); `before-body-vel.iulog` is not
/// rewritten.
#[test]
#[ignore = "regenerates tests/corpus"]
fn regenerate_corpus() {
    let dir = corpus_dir();
    std::fs::create_dir_all(&dir).unwrap();
    let meta = Metadata::new("insuwb corpus")
        .with("fusion_config", "[fusion]\nfilter = \"iakf\"\n")
        .with("note", "seed of the log reader fuzz target");
    let header = encode_header(1_000_000_000, &meta).unwrap();
    let mut enc = RecordEncoder::new();
    let mut write = |name: &str, records: &[insuwb_log::Record]| {
        let mut bytes = header.clone();
        for r in records {
            bytes.extend_from_slice(enc.encode(r).unwrap());
        }
        std::fs::write(dir.join(name), bytes).unwrap();
    };
    write("header-only.iulog", &[]);
    write("one-of-each.iulog", &common::one_of_each(3));
    write("mixed-40.iulog", &common::mixed(40));
}
