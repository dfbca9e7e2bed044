//! Seed-corpus fuzzing of the dataset readers (stable Rust, proptest): the
//! Crazyflie event-log parser (with and without the CRC check, then the
//! UTIL import of what it accepts) and the anchor-file parser. Seeds in
//! `tests/corpus/`: the first records of two real UTIL flights (CRC
//! recomputed) and two real anchor files. Each case damages one seed
//! (flipped bytes, a u16 count or id overwritten, a chunk repeated or
//! dropped, a cut) and parses it: no panic, and every error that points
//! into the file names a byte offset inside it.
//!
//! Cases: 20,000 per run (0.4 s in release), more with `PROPTEST_CASES`.
//! The seed is random per run unless `PROPTEST_RNG_SEED` is set; a failing
//! case is saved, shrunk, in `proptest-regressions/corpus.txt` (commit it:
//! it runs first from then on). Longer campaigns: docs/RELIABILITY.md.
//! The corpus is made by
//! `cargo test -p insuwb-data --test data -- corpus:: --ignored` (needs the UTIL
//! data in ../shared/data/util).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::PathBuf;
use std::sync::OnceLock;

use insuwb_data::{Anchors, CfLog, ParseOptions, UtilFlight};
use proptest::prelude::*;
use proptest::sample::Index;

fn corpus() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/corpus")
}

/// Seed logs and anchor files, by name (read once).
struct Seeds {
    logs: Vec<(String, Vec<u8>)>,
    anchors: Vec<(String, String)>,
}

fn seeds() -> &'static Seeds {
    static SEEDS: OnceLock<Seeds> = OnceLock::new();
    SEEDS.get_or_init(|| {
        let mut s = Seeds {
            logs: Vec::new(),
            anchors: Vec::new(),
        };
        let mut paths: Vec<PathBuf> = std::fs::read_dir(corpus())
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        paths.sort();
        for p in paths {
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            if name.ends_with(".txt") {
                s.anchors.push((name, std::fs::read_to_string(&p).unwrap()));
            } else {
                s.logs.push((name, std::fs::read(&p).unwrap()));
            }
        }
        s
    })
}

/// The anchors every imported seed uses.
fn anchors() -> Anchors {
    let (name, text) = &seeds().anchors[0];
    Anchors::parse(text, name).unwrap()
}

#[test]
fn every_seed_is_read_and_imported() {
    let s = seeds();
    assert!(s.logs.len() >= 2 && s.anchors.len() >= 2);
    for (name, text) in &s.anchors {
        assert!(Anchors::parse(text, name).unwrap().len() >= 8, "{name}");
    }
    for (name, bytes) in &s.logs {
        let log = CfLog::parse(bytes, &ParseOptions::default()).unwrap();
        assert!(log.crc_ok() && log.len() >= 100, "{name}");
        let flight = UtilFlight::from_cflog(&log, &anchors()).unwrap();
        assert!(!flight.imu.is_empty() && !flight.tdoa.is_empty(), "{name}");
    }
}

/// The damage done to one seed.
#[derive(Debug, Clone)]
struct Damage {
    /// Bytes XORed with a non-zero mask.
    flips: Vec<(Index, u8)>,
    /// A little-endian u16 written over two bytes (counts, ids, lengths).
    word: Option<(Index, u16)>,
    /// A chunk `[at, at + len)` repeated right after itself, or removed.
    chunk: Option<(Index, usize, bool)>,
    /// Cut the file here.
    cut: Option<Index>,
}

fn damage() -> impl Strategy<Value = Damage> {
    let word = prop_oneof![Just(0u16), Just(u16::MAX), Just(1), any::<u16>()];
    (
        proptest::collection::vec((any::<Index>(), 1u8..=255), 0..4),
        proptest::option::of((any::<Index>(), word)),
        proptest::option::of((any::<Index>(), 1usize..200, any::<bool>())),
        proptest::option::weighted(0.2, any::<Index>()),
    )
        .prop_map(|(flips, word, chunk, cut)| Damage {
            flips,
            word,
            chunk,
            cut,
        })
}

fn damaged(seed: &[u8], d: &Damage) -> Vec<u8> {
    let mut b = seed.to_vec();
    for (i, mask) in &d.flips {
        let k = i.index(b.len());
        b[k] ^= mask;
    }
    if let Some((i, v)) = d.word {
        let k = i.index(b.len() - 1);
        b[k..k + 2].copy_from_slice(&v.to_le_bytes());
    }
    if let Some((i, len, repeat)) = d.chunk {
        let a = i.index(b.len());
        let end = (a + len).min(b.len());
        if repeat {
            let c = b[a..end].to_vec();
            b.splice(end..end, c);
        } else {
            b.drain(a..end);
        }
    }
    if let Some(i) = d.cut {
        b.truncate(i.index(b.len()));
    }
    b
}

/// The offset an error message names after "byte ", if any.
fn named_offset(msg: &str) -> Option<usize> {
    let rest = &msg[msg.find("byte ")? + 5..];
    let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
    digits.parse().ok()
}

proptest! {
    // At least 20,000 cases; more with PROPTEST_CASES.
    #![proptest_config(ProptestConfig::with_cases(ProptestConfig::default().cases.max(20_000)))]

    #[test]
    fn damaged_logs_parse_or_name_the_offset(seed in any::<Index>(), d in damage()) {
        let logs = &seeds().logs;
        let bytes = damaged(&logs[seed.index(logs.len())].1, &d);
        let _ = insuwb_data::is_cflog(&bytes);
        for ignore_crc in [false, true] {
            match CfLog::parse(&bytes, &ParseOptions { ignore_crc }) {
                Ok(log) => {
                    prop_assert!(log.records().all(|r| r.offset < bytes.len()));
                    let _ = UtilFlight::from_cflog(&log, &anchors());
                }
                Err(e) => {
                    let msg = e.to_string();
                    if let Some(at) = named_offset(&msg) {
                        prop_assert!(at <= bytes.len(), "{msg} (len {})", bytes.len());
                    }
                }
            }
        }
    }

    #[test]
    fn damaged_anchor_files_parse_or_name_the_line(seed in any::<Index>(), d in damage()) {
        let files = &seeds().anchors;
        let (name, text) = &files[seed.index(files.len())];
        let text = String::from_utf8_lossy(&damaged(text.as_bytes(), &d)).into_owned();
        if let Err(e) = Anchors::parse(&text, name) {
            prop_assert!(e.to_string().starts_with(name.as_str()), "{e}");
        }
    }
}

/// Writes the seeds: the first 400 records of two UTIL flights (CRC-32
/// recomputed over the cut) and their anchor files.
#[test]
#[ignore = "regenerates tests/corpus from ../shared/data/util"]
fn regenerate_corpus() {
    let util = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/util");
    let out = corpus();
    std::fs::create_dir_all(&out).unwrap();
    for (log, seed) in [
        ("0426-traj3", "util-0426-traj3-head.cflog"),
        ("cfBolt-log00", "util-cfBolt-log00-head.cflog"),
    ] {
        let bytes = std::fs::read(util.join(log)).unwrap();
        let parsed = CfLog::parse(&bytes, &ParseOptions::default()).unwrap();
        let end = parsed.record(400).unwrap().offset;
        let mut head = bytes[..end].to_vec();
        let crc = crc32fast::hash(&head);
        head.extend_from_slice(&crc.to_le_bytes());
        std::fs::write(out.join(seed), head).unwrap();
    }
    for a in ["anchors-0426.txt", "anchors-const3.txt"] {
        std::fs::copy(util.join(a), out.join(a)).unwrap();
    }
}
