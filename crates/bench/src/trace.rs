//! The logger's receive trace: when each fused state reached the logger.
//!
//! A text file, one fused state per line: `seq pub_time_ns receive_ns`
//! (decimal, separated by spaces; `seq` and `pub_time_ns` from the sample's
//! header, `receive_ns` the logger's CLOCK_MONOTONIC time when it received
//! it). Lines starting with `#` and blank lines are ignored. The pipeline's
//! logger writes it when `INSUWB_LOGGER_FUSED_TRACE` names a file
//! (`insuwb_stage::logger::FUSED_TRACE_ENV`); the floor logger always writes
//! it into its trace folder ([`crate::floor::FUSED_TRACE_FILE`]).

use std::io::Write;
use std::path::Path;

/// One fused state as the logger received it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RecvStamp {
    /// Sequence number of the fused state (its header's `seq`).
    pub seq: u64,
    /// Its publish time (header `pub_time_ns`), ns.
    pub pub_time_ns: u64,
    /// When the logger received it, ns.
    pub receive_ns: u64,
}

/// Why a receive trace could not be read.
#[derive(Debug, thiserror::Error)]
pub enum TraceError {
    /// The file could not be read or written.
    #[error("receive trace {path}: {error}")]
    Io {
        /// The file.
        path: String,
        /// The I/O error.
        error: std::io::Error,
    },
    /// A line is not three unsigned integers.
    #[error("receive trace line {line}: expected `seq pub_time_ns receive_ns`, got {text:?}")]
    Line {
        /// 1-based line number.
        line: usize,
        /// The line.
        text: String,
    },
}

/// Parses a receive trace (see the module documentation).
pub fn parse(text: &str) -> Result<Vec<RecvStamp>, TraceError> {
    let mut out = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let bad = || TraceError::Line {
            line: i + 1,
            text: raw.chars().take(80).collect(),
        };
        let mut it = line.split_ascii_whitespace().map(str::parse::<u64>);
        let (Some(Ok(seq)), Some(Ok(pub_time_ns)), Some(Ok(receive_ns)), None) =
            (it.next(), it.next(), it.next(), it.next())
        else {
            return Err(bad());
        };
        out.push(RecvStamp {
            seq,
            pub_time_ns,
            receive_ns,
        });
    }
    Ok(out)
}

/// Reads and parses the receive trace at `path`.
pub fn read(path: &Path) -> Result<Vec<RecvStamp>, TraceError> {
    let text = std::fs::read_to_string(path).map_err(|source| TraceError::Io {
        path: path.display().to_string(),
        error: source,
    })?;
    parse(&text)
}

/// Writes `stamps` to `path` in the trace format (replacing the file).
pub fn write(path: &Path, stamps: &[RecvStamp]) -> Result<(), TraceError> {
    let io = |source| TraceError::Io {
        path: path.display().to_string(),
        error: source,
    };
    let file = std::fs::File::create(path).map_err(io)?;
    let mut w = std::io::BufWriter::new(file);
    writeln!(w, "# seq pub_time_ns receive_ns").map_err(io)?;
    for s in stamps {
        writeln!(w, "{} {} {}", s.seq, s.pub_time_ns, s.receive_ns).map_err(io)?;
    }
    w.flush().map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_lines_and_skips_comments() {
        let t = "# seq pub_time_ns receive_ns\n\n3 1000 1250\n 4  2000\t2100 \n";
        assert_eq!(
            parse(t).unwrap(),
            vec![
                RecvStamp {
                    seq: 3,
                    pub_time_ns: 1000,
                    receive_ns: 1250
                },
                RecvStamp {
                    seq: 4,
                    pub_time_ns: 2000,
                    receive_ns: 2100
                }
            ]
        );
    }

    #[test]
    fn refuses_short_long_and_negative_lines_naming_the_line() {
        for bad in ["1 2", "1 2 3 4", "1 -2 3", "a b c"] {
            let text = format!("# header\n{bad}\n");
            let e = parse(&text).unwrap_err().to_string();
            assert!(e.contains("line 2") && e.contains(bad), "{e}");
        }
    }

    #[test]
    fn write_then_read_round_trips() {
        let dir = std::env::temp_dir().join(format!("insuwb-bench-trace-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("t.txt");
        let s = vec![
            RecvStamp {
                seq: 0,
                pub_time_ns: u64::MAX - 1,
                receive_ns: u64::MAX,
            },
            RecvStamp {
                seq: 9,
                pub_time_ns: 5,
                receive_ns: 7,
            },
        ];
        write(&p, &s).unwrap();
        assert_eq!(read(&p).unwrap(), s);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
