//! Seed-corpus fuzzing of the TOML loader (stable Rust, proptest): the
//! project's own files in `tests/corpus/` (copies of `config/robot.toml`,
//! `config/util.toml` and a scenario) load, then are edited line by line
//! (lines dropped, repeated, swapped, cut; values replaced by hostile ones:
//! NaN, infinities, huge numbers, empty or unterminated strings and arrays,
//! deep nesting; stray characters) and loaded again. The loader must never
//! panic, and every error must name the file and a key.
//!
//! Cases: 20,000 per run (0.8 s in release), more with `PROPTEST_CASES`.
//! The seed is random per run unless `PROPTEST_RNG_SEED` is set; a failing
//! case is saved, shrunk, in `proptest-regressions/corpus.txt` (commit it:
//! it runs first from then on). Longer campaigns: docs/RELIABILITY.md.
#![allow(clippy::unwrap_used, clippy::panic)]

use std::path::PathBuf;
use std::sync::OnceLock;

use proptest::prelude::*;
use proptest::sample::Index;

/// The seed files as (name, lines), read once.
fn seeds() -> &'static [(String, Vec<String>)] {
    static SEEDS: OnceLock<Vec<(String, Vec<String>)>> = OnceLock::new();
    SEEDS.get_or_init(|| {
        let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/corpus");
        let mut v: Vec<(String, Vec<String>)> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| {
                let p = e.unwrap().path();
                let text = std::fs::read_to_string(&p).unwrap();
                let name = p.file_name().unwrap().to_string_lossy().into_owned();
                (name, text.lines().map(str::to_owned).collect())
            })
            .collect();
        v.sort();
        v
    })
}

/// Loads `text` as a generic table; checks what an error says.
fn load_checked(text: &str, origin: &str) -> Option<toml::Table> {
    match insuwb_config::load_str::<toml::Table>(text, origin) {
        Ok(t) => Some(t),
        Err(e) => {
            let msg = e.to_string();
            assert!(msg.starts_with(origin) && msg.contains("key '"), "{msg}");
            None
        }
    }
}

#[test]
fn every_seed_loads() {
    let seeds = seeds();
    assert!(seeds.len() >= 3);
    for (name, lines) in seeds {
        let t = load_checked(&lines.join("\n"), name).unwrap();
        assert!(!t.is_empty(), "{name}");
    }
}

/// Values that have broken parsers and loaders.
const HOSTILE: [&str; 14] = [
    "nan",
    "-inf",
    "1e400",
    "-9223372036854775809",
    "\"\"",
    "\"unterminated",
    "[",
    "[[[[[[[[[[[[[[[[1]]]]]]]]]]]]]]]]",
    "{ a = { b = { c = 1 } } }",
    "'''",
    "0x",
    "1979-05-27T07:32:00Z",
    "\"\\u0000\"",
    "true false",
];

/// One edit of a seed's lines.
#[derive(Debug, Clone)]
enum LineEdit {
    Drop(Index),
    Repeat(Index),
    Swap(Index, Index),
    /// The text after the line's first `=` becomes a hostile value.
    Value(Index, Index),
    /// A character put in at a byte position of the line (on a boundary).
    Stray(Index, Index, char),
    /// The line cut at a byte position (on a boundary).
    Cut(Index, Index),
}

fn line_edit() -> impl Strategy<Value = LineEdit> {
    let i = any::<Index>;
    prop_oneof![
        i().prop_map(LineEdit::Drop),
        i().prop_map(LineEdit::Repeat),
        (i(), i()).prop_map(|(a, b)| LineEdit::Swap(a, b)),
        (i(), i()).prop_map(|(a, b)| LineEdit::Value(a, b)),
        (
            i(),
            i(),
            prop_oneof![Just('['), Just('"'), Just('='), Just('.'), any::<char>()]
        )
            .prop_map(|(a, b, c)| LineEdit::Stray(a, b, c)),
        (i(), i()).prop_map(|(a, b)| LineEdit::Cut(a, b)),
    ]
}

/// The char boundary of `s` nearest below the byte `at`.
fn boundary(s: &str, at: usize) -> usize {
    (0..=at.min(s.len()))
        .rev()
        .find(|&k| s.is_char_boundary(k))
        .unwrap_or(0)
}

fn edit_lines(lines: &mut Vec<String>, e: &LineEdit) {
    if lines.is_empty() {
        return;
    }
    let n = lines.len();
    match e {
        LineEdit::Drop(i) => {
            lines.remove(i.index(n));
        }
        LineEdit::Repeat(i) => {
            let l = lines[i.index(n)].clone();
            lines.insert(i.index(n), l);
        }
        LineEdit::Swap(a, b) => lines.swap(a.index(n), b.index(n)),
        LineEdit::Value(i, v) => {
            let l = &mut lines[i.index(n)];
            if let Some(eq) = l.find('=') {
                l.truncate(eq + 1);
                l.push(' ');
                l.push_str(HOSTILE[v.index(HOSTILE.len())]);
            }
        }
        LineEdit::Stray(i, at, c) => {
            let l = &mut lines[i.index(n)];
            let k = boundary(l, at.index(l.len() + 1));
            l.insert(k, *c);
        }
        LineEdit::Cut(i, at) => {
            let l = &mut lines[i.index(n)];
            let k = boundary(l, at.index(l.len() + 1));
            l.truncate(k);
        }
    }
}

proptest! {
    // At least 20,000 cases; more with PROPTEST_CASES.
    #![proptest_config(ProptestConfig::with_cases(ProptestConfig::default().cases.max(20_000)))]

    #[test]
    fn edited_seeds_load_or_name_file_and_key(
        (seed, edits) in (any::<Index>(), proptest::collection::vec(line_edit(), 1..6))
    ) {
        let (name, lines) = &seeds()[seed.index(seeds().len())];
        let mut lines = lines.clone();
        for e in &edits {
            edit_lines(&mut lines, e);
        }
        let _ = load_checked(&lines.join("\n"), name);
    }
}
