//! A log's header read alone ([`read_header_file`]): the records after it
//! are neither read nor checked, and errors name the file.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)] // tests may unwrap

use crate::common;

use std::io::Write;

use common::{one_of_each, Scratch};
use insuwb_log::{read_header_file, HeaderError, LogWriter, Metadata, OpenError};

fn meta() -> Metadata {
    Metadata::new("header test")
        .with("fusion_config", "[fusion]\nfilter = \"iakf\"\n")
        .with("seed", "7")
}

/// Bytes this thread has read through system calls so far
/// (`/proc/thread-self/io`), where the kernel says.
fn thread_bytes_read() -> Option<u64> {
    let io = std::fs::read_to_string("/proc/thread-self/io").ok()?;
    io.lines()
        .find_map(|l| l.strip_prefix("rchar:"))
        .and_then(|v| v.trim().parse().ok())
}

#[test]
fn the_header_of_a_large_log_is_read_without_its_body() {
    let dir = Scratch::new("header-large");
    let path = dir.join("large.iulog");
    let mut w = LogWriter::create(&path, &meta(), 42).unwrap();
    let records = one_of_each(1);
    for _ in 0..20_000 {
        for r in &records {
            w.append(r).unwrap();
        }
    }
    w.finish().unwrap();
    let size = std::fs::metadata(&path).unwrap().len();
    assert!(size > 8 << 20, "{size} bytes");
    // Reading the proc file counts too: measure its own cost first.
    let before = thread_bytes_read();
    let between = thread_bytes_read();
    let header = read_header_file(&path).unwrap();
    let after = thread_bytes_read();
    assert_eq!(header.meta, meta());
    assert_eq!(header.created_ns, 42);
    if let (Some(b), Some(m), Some(a)) = (before, between, after) {
        let proc_read = m - b;
        let read = a - m - proc_read;
        assert!(
            read <= header.header_len + 64,
            "read {read} bytes of a {size}-byte log whose header is {} bytes",
            header.header_len
        );
    }
}

#[test]
fn a_damaged_or_cut_body_still_gives_the_header() {
    let dir = Scratch::new("header-damaged");
    let path = dir.join("damaged.iulog");
    let mut w = LogWriter::create(&path, &meta(), 7).unwrap();
    for r in one_of_each(1) {
        w.append(&r).unwrap();
    }
    w.finish().unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let header_len = usize::try_from(read_header_file(&path).unwrap().header_len).unwrap();
    // Garbage after the header.
    let garbage = dir.join("garbage.iulog");
    let mut f = std::fs::File::create(&garbage).unwrap();
    f.write_all(&bytes[..header_len]).unwrap();
    f.write_all(&[0xff; 4096]).unwrap();
    drop(f);
    assert_eq!(read_header_file(&garbage).unwrap().meta, meta());
    // Cut inside the first record, and right after the header.
    for cut in [header_len + 3, header_len] {
        let p = dir.join(&format!("cut-{cut}.iulog"));
        std::fs::write(&p, &bytes[..cut]).unwrap();
        assert_eq!(read_header_file(&p).unwrap().meta, meta(), "cut at {cut}");
    }
}

#[test]
fn header_errors_name_the_file() {
    let dir = Scratch::new("header-errors");
    let path = dir.join("whole.iulog");
    LogWriter::create(&path, &meta(), 0)
        .unwrap()
        .finish()
        .unwrap();
    let bytes = std::fs::read(&path).unwrap();
    // Cut inside the metadata.
    let cut = dir.join("cut.iulog");
    std::fs::write(&cut, &bytes[..bytes.len() - 5]).unwrap();
    let e = read_header_file(&cut).unwrap_err();
    assert!(
        matches!(
            &e,
            OpenError::Header {
                error: HeaderError::Truncated { .. },
                ..
            }
        ),
        "{e}"
    );
    let msg = e.to_string();
    assert!(
        msg.contains("cut.iulog") && msg.contains("truncated"),
        "{msg}"
    );
    // Not a log, missing, a directory.
    let other = dir.join("other.txt");
    std::fs::write(&other, b"hello").unwrap();
    let msg = read_header_file(&other).unwrap_err().to_string();
    assert!(msg.contains("other.txt") && msg.contains("magic"), "{msg}");
    let msg = read_header_file(dir.join("missing.iulog"))
        .unwrap_err()
        .to_string();
    assert!(msg.contains("missing.iulog"), "{msg}");
    let e = read_header_file(dir.path()).unwrap_err();
    assert!(matches!(e, OpenError::BadPath { .. }), "{e}");
}
