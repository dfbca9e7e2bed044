//! The Eliko RTLS text protocol (the positioning server's TCP interface,
//! port 25025 by default): the client [`HANDSHAKE`], the streaming
//! [`Decoder`] of `$PEKIO,COORD` lines, and the line encoder the emulator
//! uses.
//!
//! After the client sends `$PEKIO,EULA,ACCEPT\r\n` and
//! `$PEKIO,SET_REPORT_LIST,COORD\r\n`, the server sends one line per
//! computed tag position:
//!
//! ```text
//! $PEKIO,COORD,<seq>,<tag>,<x>,<y>,<z>,<info>,<unix_s>\r\n
//! ```
//!
//! `seq` is an 8-bit counter (gaps counted per tag, modulo 256), `tag` the
//! tag's serial number (decimal, or hexadecimal with `0x`), `x y z` metres
//! (empty when the tag could not be located: counted in
//! [`DecoderStats::no_fix`]), `info` ignored, `unix_s` the server's Unix time
//! in seconds with an optional fraction (kept as microseconds in the
//! reading's [`DeviceTime`]). Other `$PEKIO` lines (RR_L, COORD_E, replies)
//! are counted in [`DecoderStats::unknown`]. Lines are at most
//! [`MAX_LINE_LEN`] bytes; a longer one is dropped whole and counted in
//! [`DecoderStats::oversize`]. There is no checksum: a line must have
//! exactly nine fields that all parse, or it is counted in
//! [`DecoderStats::malformed`].
//!
//! ```
//! use insuwb_devices::eliko::Decoder;
//! use insuwb_devices::frame::Reading;
//!
//! let mut decoder = Decoder::with_tags([0x1A2B]);
//! let mut got = Vec::new();
//! decoder.push(b"$PEKIO,COORD,7,0x001A2B,1.50,-2.25,0.80,,1700000000.25\r\n", &mut |r| got.push(r));
//! assert!(matches!(got[0], Reading::Position { tag: 0x1A2B, seq: Some(7), .. }));
//! ```

use std::io::Write;

use crate::frame::{DecoderStats, DeviceTime, Reading, SkipCounter};

/// The server's default TCP port.
pub const DEFAULT_PORT: u16 = 25025;
/// Lines the client sends after connecting, in order.
pub const HANDSHAKE: [&str; 2] = ["$PEKIO,EULA,ACCEPT\r\n", "$PEKIO,SET_REPORT_LIST,COORD\r\n"];
/// The longest line kept, end of line included.
pub const MAX_LINE_LEN: usize = 256;
/// A typical COORD line's length.
pub const NOMINAL_LINE_LEN: usize = 64;
/// Tick of the readings' device time (ns): microseconds of Unix time.
pub const TIME_TICK_NS: u64 = 1_000;
/// Tags whose sequence numbers are followed for gap counting.
const SEQ_SLOTS: usize = 16;

/// Streaming decoder of an Eliko RTLS byte stream.
#[derive(Debug, Clone)]
pub struct Decoder {
    buf: [u8; MAX_LINE_LEN],
    len: usize,
    /// Dropping the rest of an over-long line, up to its `\n`.
    discarding: bool,
    sync: SkipCounter,
    since_valid: u64,
    stats: DecoderStats,
    /// Tags to report; empty: all.
    tags: Vec<u32>,
    /// Last sequence number per tag, for the first [`SEQ_SLOTS`] tags seen.
    last_seq: [Option<(u32, u8)>; SEQ_SLOTS],
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

/// What a complete line turned out to be.
enum Line {
    Coord {
        seq: u8,
        tag: u32,
        pos_m: Option<[f64; 3]>,
        unix_us: Option<u64>,
    },
    Other,
}

impl Decoder {
    /// A decoder that reports every tag.
    pub fn new() -> Self {
        Self::with_tags([])
    }

    /// A decoder that reports only `tags` (all tags if empty); positions of
    /// other tags are counted in [`DecoderStats::filtered`].
    pub fn with_tags(tags: impl IntoIterator<Item = u32>) -> Self {
        Decoder {
            buf: [0; MAX_LINE_LEN],
            len: 0,
            discarding: false,
            sync: SkipCounter::new(),
            since_valid: 0,
            stats: DecoderStats::default(),
            tags: tags.into_iter().collect(),
            last_seq: [None; SEQ_SLOTS],
        }
    }

    /// Feeds bytes as they came off the socket; calls `out` for each
    /// position of a reported tag.
    pub fn push(&mut self, bytes: &[u8], out: &mut impl FnMut(Reading)) {
        for &byte in bytes {
            self.stats.bytes_in = self.stats.bytes_in.saturating_add(1);
            self.since_valid = self.since_valid.saturating_add(1);
            if self.discarding {
                self.count_skipped(1);
                self.discarding = byte != b'\n';
                continue;
            }
            if byte == b'$' && self.len > 0 {
                // A line starts before the last one ended: drop the stub.
                self.count_skipped(self.len as u64);
                self.len = 0;
            }
            if self.len == 0 && byte != b'$' {
                self.count_skipped(1);
                continue;
            }
            let Some(slot) = self.buf.get_mut(self.len) else {
                self.overflow();
                continue;
            };
            *slot = byte;
            self.len += 1;
            self.sync.kept();
            if byte == b'\n' {
                self.line(out);
            } else if self.len == MAX_LINE_LEN {
                self.overflow();
            }
        }
    }

    /// Drops an over-long line: what is buffered now, the rest up to `\n`.
    fn overflow(&mut self) {
        self.stats.oversize = self.stats.oversize.saturating_add(1);
        self.count_skipped(self.len as u64);
        self.len = 0;
        self.discarding = true;
    }

    fn count_skipped(&mut self, n: u64) {
        self.sync.skipped(&mut self.stats, n);
    }

    /// Handles the complete line in the buffer.
    fn line(&mut self, out: &mut impl FnMut(Reading)) {
        let len = std::mem::take(&mut self.len);
        self.stats.bytes_framed = self.stats.bytes_framed.saturating_add(len as u64);
        let parsed = self.buf.get(..len).and_then(parse_line);
        let s = &mut self.stats;
        match parsed {
            None => {
                s.malformed = s.malformed.saturating_add(1);
                return;
            }
            Some(Line::Other) => s.unknown = s.unknown.saturating_add(1),
            Some(Line::Coord {
                seq,
                tag,
                pos_m,
                unix_us,
            }) => {
                if !self.tags.is_empty() && !self.tags.contains(&tag) {
                    s.filtered = s.filtered.saturating_add(1);
                } else {
                    let gap = follow_seq(&mut self.last_seq, tag, seq);
                    s.seq_gaps = s.seq_gaps.saturating_add(u64::from(gap));
                    match pos_m {
                        None => s.no_fix = s.no_fix.saturating_add(1),
                        Some(pos_m) => {
                            s.frames_ok = s.frames_ok.saturating_add(1);
                            out(Reading::Position {
                                tag,
                                pos_m,
                                vel_mps: None,
                                device_time: unix_us.map(|ticks| DeviceTime {
                                    ticks,
                                    tick_ns: TIME_TICK_NS,
                                    wrap: None,
                                }),
                                seq: Some(u32::from(seq)),
                            });
                        }
                    }
                }
            }
        }
        self.since_valid = 0;
    }

    /// What the decoder has counted.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Bytes received since the end of the last well-formed line.
    pub fn bytes_since_last_valid_frame(&self) -> u64 {
        self.since_valid
    }

    /// Bytes held waiting for the end of a line.
    pub fn buffered(&self) -> usize {
        self.len
    }

    /// Forgets a partial line (after a reconnect); keeps counts and
    /// sequence numbers.
    pub fn clear(&mut self) {
        self.count_skipped(self.len as u64);
        self.len = 0;
        self.discarding = false;
        self.sync.kept();
    }
}

/// Records `seq` for `tag`; returns how many lines are missing before it.
fn follow_seq(slots: &mut [Option<(u32, u8)>; SEQ_SLOTS], tag: u32, seq: u8) -> u8 {
    if let Some(last) = slots.iter_mut().flatten().find(|(t, _)| *t == tag) {
        let gap = seq.wrapping_sub(last.1).wrapping_sub(1);
        last.1 = seq;
        return gap;
    }
    if let Some(free) = slots.iter_mut().find(|s| s.is_none()) {
        *free = Some((tag, seq));
    }
    0
}

/// Parses a line (with its end of line); `None` if malformed.
fn parse_line(line: &[u8]) -> Option<Line> {
    let line = std::str::from_utf8(line).ok()?;
    let line = line.strip_suffix('\n')?;
    let line = line.strip_suffix('\r').unwrap_or(line);
    let mut fields = line.split(',');
    if fields.next()? != "$PEKIO" {
        return None;
    }
    if fields.next()? != "COORD" {
        return Some(Line::Other);
    }
    let mut f: [&str; 7] = [""; 7];
    for slot in &mut f {
        *slot = fields.next()?;
    }
    if fields.next().is_some() {
        return None;
    }
    let [seq, tag, x, y, z, _info, time] = f;
    let pos_m = if x.is_empty() && y.is_empty() && z.is_empty() {
        None
    } else {
        let p = [parse_metres(x)?, parse_metres(y)?, parse_metres(z)?];
        Some(p)
    };
    Some(Line::Coord {
        seq: seq.parse().ok()?,
        tag: parse_tag(tag)?,
        pos_m,
        unix_us: if time.is_empty() {
            None
        } else {
            Some(parse_unix_us(time)?)
        },
    })
}

fn parse_metres(s: &str) -> Option<f64> {
    s.parse::<f64>().ok().filter(|v| v.is_finite())
}

/// A tag serial number: decimal, or hexadecimal after `0x`.
fn parse_tag(s: &str) -> Option<u32> {
    match s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
        Some(hex) if !hex.is_empty() && hex.bytes().all(|b| b.is_ascii_hexdigit()) => {
            u32::from_str_radix(hex, 16).ok()
        }
        Some(_) => None,
        None if !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit()) => s.parse().ok(),
        None => None,
    }
}

/// `seconds[.fraction]` to microseconds, exactly (digits past the sixth
/// decimal are dropped).
fn parse_unix_us(s: &str) -> Option<u64> {
    let (whole, frac) = s.split_once('.').unwrap_or((s, ""));
    if whole.is_empty() || !whole.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    if !frac.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let mut us: u64 = 0;
    for i in 0..6 {
        let digit = frac.as_bytes().get(i).map_or(0, |b| u64::from(b - b'0'));
        us = us * 10 + digit;
    }
    whole
        .parse::<u64>()
        .ok()?
        .checked_mul(1_000_000)?
        .checked_add(us)
}

/// What [`encode_coord`] and [`encode`] cannot do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    /// Only position readings have a COORD line.
    #[error("eliko::EncodeError::Unsupported: only position readings are encoded")]
    Unsupported,
    /// The output buffer is shorter than the line.
    #[error("eliko::EncodeError::BufferTooSmall: the line does not fit")]
    BufferTooSmall,
}

/// Largest coordinate written (m); beyond it values saturate.
const MAX_COORD_M: f64 = 1e6;

/// Writes a COORD line into `out` (tag as `0x` and six hex digits, metres
/// with three decimals saturated at +-1000 km, no fix as empty fields,
/// time as seconds with six decimals); returns its length.
pub fn encode_coord(
    seq: u8,
    tag: u32,
    pos_m: Option<[f64; 3]>,
    unix_us: u64,
    out: &mut [u8],
) -> Result<usize, EncodeError> {
    let capacity = out.len();
    let mut w: &mut [u8] = out;
    let coords = |w: &mut &mut [u8]| -> std::io::Result<()> {
        match pos_m.filter(|p| p.iter().all(|v| v.is_finite())) {
            Some(p) => {
                let [x, y, z] = p.map(|v| v.clamp(-MAX_COORD_M, MAX_COORD_M));
                write!(w, "{x:.3},{y:.3},{z:.3}")
            }
            None => write!(w, ",,"),
        }
    };
    (|| -> std::io::Result<()> {
        write!(w, "$PEKIO,COORD,{seq},0x{tag:06X},")?;
        coords(&mut w)?;
        write!(
            w,
            ",,{}.{:06}\r\n",
            unix_us / 1_000_000,
            unix_us % 1_000_000
        )
    })()
    .map_err(|_| EncodeError::BufferTooSmall)?;
    Ok(capacity - w.len())
}

/// Writes a position reading as a COORD line (seq modulo 256, time from its
/// device time, 0 without one); returns its length.
pub fn encode(reading: &Reading, out: &mut [u8]) -> Result<usize, EncodeError> {
    let Reading::Position {
        tag,
        pos_m,
        device_time,
        seq,
        ..
    } = reading
    else {
        return Err(EncodeError::Unsupported);
    };
    let unix_us = device_time.map_or(0, |t| {
        let us = u128::from(t.ticks) * u128::from(t.tick_ns) / u128::from(TIME_TICK_NS);
        u64::try_from(us).unwrap_or(u64::MAX)
    });
    encode_coord(
        seq.map_or(0, |s| s.to_le_bytes()[0]),
        *tag,
        Some(*pos_m),
        unix_us,
        out,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn times_parse_exactly() {
        assert_eq!(parse_unix_us("1700000000"), Some(1_700_000_000_000_000));
        assert_eq!(parse_unix_us("1.5"), Some(1_500_000));
        assert_eq!(parse_unix_us("1.1234567"), Some(1_123_456));
        assert_eq!(parse_unix_us("-1"), None);
        assert_eq!(parse_unix_us(".5"), None);
        assert_eq!(parse_unix_us("99999999999999999999"), None);
    }

    #[test]
    fn tags_parse_in_decimal_and_hex() {
        assert_eq!(parse_tag("42"), Some(42));
        assert_eq!(parse_tag("0x00002A"), Some(42));
        assert_eq!(parse_tag("0x"), None);
        assert_eq!(parse_tag("+42"), None);
        assert_eq!(parse_tag(""), None);
    }

    #[test]
    fn encoder_saturates_and_writes_no_fix_as_empty_fields() {
        let mut buf = [0u8; MAX_LINE_LEN];
        let n = encode_coord(1, 2, Some([1e12, -1e12, 0.0]), 3_000_001, &mut buf).unwrap();
        assert_eq!(
            &buf[..n],
            b"$PEKIO,COORD,1,0x000002,1000000.000,-1000000.000,0.000,,3.000001\r\n"
        );
        let n = encode_coord(1, 2, None, 0, &mut buf).unwrap();
        assert_eq!(&buf[..n], b"$PEKIO,COORD,1,0x000002,,,,,0.000000\r\n");
        assert_eq!(
            encode_coord(1, 2, None, 0, &mut buf[..10]),
            Err(EncodeError::BufferTooSmall)
        );
    }

    #[test]
    fn seq_gaps_wrap_at_256_per_tag() {
        let mut d = Decoder::new();
        let mut buf = [0u8; MAX_LINE_LEN];
        let mut stream = Vec::new();
        for (seq, tag) in [(254u8, 1u32), (9, 2), (0, 1), (10, 2), (1, 1)] {
            let n = encode_coord(seq, tag, Some([0.0; 3]), 0, &mut buf).unwrap();
            stream.extend_from_slice(&buf[..n]);
        }
        let mut count = 0;
        d.push(&stream, &mut |_| count += 1);
        assert_eq!(count, 5);
        // tag 1: 254 -> 0 misses 255 (one line); 0 -> 1 none. tag 2: none.
        assert_eq!(d.stats().seq_gaps, 1);
    }
}
