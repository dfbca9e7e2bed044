//! The Qorvo (formerly Decawave) DWM1001 UART shell as a tag prints its
//! location engine's output (PANS firmware, 115200 baud, shell entered with
//! two `\r`): the streaming [`Decoder`] of `lec`, `les` and `lep` lines and
//! their encoders ([`encode_lec`], [`encode_les`], [`encode_lep`]) for the
//! emulators.
//!
//! Source: Qorvo (Decawave), "DWM1001 Firmware API Guide", the shell
//! commands `lec` (location engine output as CSV), `les` (the same as
//! text) and `lep` (the position alone, as CSV):
//!
//! ```text
//! DIST,4,AN0,0C2B,0.00,0.00,0.00,1.38,AN1,9825,3.00,0.00,0.00,2.26,...,POS,1.45,1.45,0.82,64
//! 1151[5.00,8.00,2.25]=6.48 0CA8[0.00,8.00,2.25]=6.51 ... le_us=2576 est[2.57,1.98,1.68,100]
//! POS,1.45,1.45,0.82,64
//! ```
//!
//! - `lec`: `DIST,<n>`, then `n` anchors `AN<i>,<id>,<x>,<y>,<z>,<d>` (`i`
//!   counting from 0), then optionally `POS,<x>,<y>,<z>,<qf>`.
//! - `les`: anchors `<id>[<x>,<y>,<z>]=<d>` separated by spaces, then
//!   optionally `le_us=<n>` (the engine's run time, ignored) and
//!   `est[<x>,<y>,<z>,<qf>]`.
//!
//! `id` is the anchor's 16-bit short address as four hex digits; `x y z d`
//! are metres; `qf` is the position's quality factor, 0 to 100. At most
//! [`MAX_ANCHORS`] anchors.
//!
//! Each report line gives one [`Reading::Range`] per anchor, in line order
//! (the anchor's position with it, no quality and no device time: the
//! shell prints neither), the last with `last_of_round`; then a
//! [`Reading::Position`] of the decoder's tag ([`Decoder::with_tag`]) when
//! the line has a position of quality factor above 0 (0: the engine has no
//! estimate). A report line that gives a reading counts in
//! [`DecoderStats::frames_ok`]; one that gives none (no anchor, no usable
//! position) in [`DecoderStats::no_fix`]. Other text (the `dwm> ` prompt,
//! the echoed command, help, blank lines) counts in
//! [`DecoderStats::unknown`]. There is no checksum: a line that starts like
//! a report but does not parse whole (a field missing, extra or not a
//! number, NaN, a count disagreeing with the anchors present, anchors out
//! of order, more than [`MAX_ANCHORS`]) counts in
//! [`DecoderStats::malformed`] and gives nothing. Lines end in `\n`
//! (`\r\n` too) and are at most [`MAX_LINE_LEN`] bytes; a longer one is
//! dropped whole ([`DecoderStats::oversize`]).
//!
//! Resynchronisation: a report may start inside a line (after garbage, a
//! cut line, the prompt); what came before it is dropped (skipped) before
//! `DIST,`; before `POS,` unless the line so far starts with `DIST,` or
//! ends in `,`; before four hex digits and `[` unless the line so far
//! starts like a `les` report or ends in a space (the prompt's excepted).
//! A `\r` not followed by `\n` (a lost `\n`) drops the line so far. So a
//! damaged byte inside a report (not turned into a line end) loses that
//! report whole rather than a part, and the next report comes through,
//! except after a cut `lec` line or garbage ending in `,` (a `lep` line),
//! and after a cut `les` line or garbage ending in a space (a `les` line).
//!
//! ```
//! use insuwb_devices::dwm1001::Decoder;
//! use insuwb_devices::frame::Reading;
//!
//! let mut decoder = Decoder::new();
//! let mut got = Vec::new();
//! decoder.push(b"dwm> lep\r\nPOS,1.45,1.45,0.82,64\r\n", &mut |r| got.push(r));
//! assert!(matches!(got[..], [Reading::Position { pos_m: [1.45, 1.45, 0.82], .. }]));
//! assert_eq!((decoder.stats().frames_ok, decoder.stats().unknown), (1, 1));
//! ```

use std::io::Write;

use crate::frame::{DecoderStats, Reading, SkipCounter};

/// The shell's UART baud rate.
pub const DEFAULT_BAUD: u32 = 115_200;
/// The longest line kept, end of line included.
pub const MAX_LINE_LEN: usize = 1024;
/// A `lec` line of four anchors with a position, `\r\n` included.
pub const NOMINAL_LINE_LEN: usize = 146;
/// The most anchors a line may hold.
pub const MAX_ANCHORS: usize = 16;
/// The highest quality factor.
pub const MAX_QUALITY: u8 = 100;
/// The shell's prompt.
pub const PROMPT: &[u8] = b"dwm> ";
/// Hex digits of an anchor id.
const ID_DIGITS: usize = 4;
/// Largest coordinate or distance written (m); beyond it values saturate.
const MAX_COORD_M: f64 = 1e6;

/// One anchor of a report: its id, position and distance.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct AnchorRange {
    /// The anchor's 16-bit short address.
    pub id: u32,
    /// The anchor's position (m).
    pub pos_m: [f64; 3],
    /// Distance from the tag (m).
    pub range_m: f64,
}

/// A report line, parsed.
#[derive(Debug, Clone, Copy, Default)]
struct Report {
    anchors: [AnchorRange; MAX_ANCHORS],
    n: usize,
    /// Position and quality factor.
    pos: Option<([f64; 3], u8)>,
}

impl Report {
    /// Adds an anchor; `None` past [`MAX_ANCHORS`].
    fn push(&mut self, a: AnchorRange) -> Option<()> {
        *self.anchors.get_mut(self.n)? = a;
        self.n += 1;
        Some(())
    }
}

/// What a complete line turned out to be.
enum Line {
    /// A report, parsed into the caller's [`Report`].
    Report,
    /// Other text.
    Other,
    /// A report that does not parse.
    Malformed,
}

/// Streaming decoder of a DWM1001 shell byte stream. Its line buffer is
/// allocated once, when it is made.
#[derive(Debug, Clone)]
pub struct Decoder {
    buf: Box<[u8; MAX_LINE_LEN]>,
    len: usize,
    /// Dropping the rest of an over-long line, up to its `\n`.
    discarding: bool,
    sync: SkipCounter,
    since_valid: u64,
    stats: DecoderStats,
    /// Tag id of the positions.
    tag: u32,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder {
    /// A decoder whose positions are tag 0's.
    pub fn new() -> Self {
        Self::with_tag(0)
    }

    /// A decoder whose positions are `tag`'s (the shell does not print the
    /// tag's own id).
    pub fn with_tag(tag: u32) -> Self {
        Decoder {
            buf: Box::new([0; MAX_LINE_LEN]),
            len: 0,
            discarding: false,
            sync: SkipCounter::new(),
            since_valid: 0,
            stats: DecoderStats::default(),
            tag,
        }
    }

    /// Feeds bytes as they came off the port; calls `out` with the ranges
    /// then the position of each report line.
    pub fn push(&mut self, bytes: &[u8], out: &mut impl FnMut(Reading)) {
        for &byte in bytes {
            self.stats.bytes_in = self.stats.bytes_in.saturating_add(1);
            self.since_valid = self.since_valid.saturating_add(1);
            if self.discarding {
                self.count_skipped(1);
                self.discarding = byte != b'\n';
                continue;
            }
            if byte != b'\n' && self.len > 0 && self.buf.get(self.len - 1) == Some(&b'\r') {
                // The line's `\n` was lost: drop it.
                self.count_skipped(self.len as u64);
                self.len = 0;
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
                continue;
            }
            if let Some(start) = self.restart_at() {
                self.buf.copy_within(start..self.len, 0);
                self.len -= start;
                self.count_skipped(start as u64);
            }
            if self.len == MAX_LINE_LEN {
                self.overflow();
            }
        }
    }

    /// Where a report starts inside the line, after other bytes, judged
    /// from the byte just kept (see the module doc).
    fn restart_at(&self) -> Option<usize> {
        let buf = self.buf.get(..self.len)?;
        match buf.last()? {
            b',' => {
                let dist = buf.len().checked_sub(5).filter(|&s| s > 0);
                if let Some(start) = dist.filter(|&s| buf.get(s..) == Some(b"DIST,".as_slice())) {
                    return Some(start);
                }
                let start = buf.len().checked_sub(4).filter(|&s| s > 0)?;
                if buf.get(start..) != Some(b"POS,".as_slice()) {
                    return None;
                }
                let stub = buf.get(..start)?;
                let inside = stub.starts_with(b"DIST,") || stub.ends_with(b",");
                (!inside).then_some(start)
            }
            b'[' => {
                let start = buf.len().checked_sub(ID_DIGITS + 1).filter(|&s| s > 0)?;
                if !starts_les_anchor(buf.get(start..)?) {
                    return None;
                }
                let stub = buf.get(..start)?;
                let inside = starts_les(stub) || (stub.ends_with(b" ") && !stub.ends_with(PROMPT));
                (!inside).then_some(start)
            }
            _ => None,
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
        let s = &mut self.stats;
        s.bytes_framed = s.bytes_framed.saturating_add(len as u64);
        let mut report = Report::default();
        match parse_line(self.buf.get(..len).unwrap_or(&[]), &mut report) {
            Line::Malformed => s.malformed = s.malformed.saturating_add(1),
            Line::Other => s.unknown = s.unknown.saturating_add(1),
            Line::Report => {
                self.since_valid = 0;
                if emit(&report, self.tag, out) {
                    s.frames_ok = s.frames_ok.saturating_add(1);
                } else {
                    s.no_fix = s.no_fix.saturating_add(1);
                }
            }
        }
    }

    /// What the decoder has counted.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Bytes received since the end of the last report line that parsed
    /// (other text does not count: noise at the wrong baud rate has line
    /// ends too).
    pub fn bytes_since_last_valid_frame(&self) -> u64 {
        self.since_valid
    }

    /// Bytes held waiting for the end of a line.
    pub fn buffered(&self) -> usize {
        self.len
    }

    /// Forgets a partial line (after a reconnect); keeps counts.
    pub fn clear(&mut self) {
        self.count_skipped(self.len as u64);
        self.len = 0;
        self.discarding = false;
        self.sync.kept();
    }
}

/// Calls `out` with a report's readings; whether there was any.
fn emit(report: &Report, tag: u32, out: &mut impl FnMut(Reading)) -> bool {
    let anchors = report.anchors.get(..report.n).unwrap_or(&[]);
    let last = anchors.len().checked_sub(1);
    for (i, a) in anchors.iter().enumerate() {
        out(Reading::Range {
            anchor: a.id,
            range_m: a.range_m,
            anchor_pos_m: Some(a.pos_m),
            quality: None,
            last_of_round: Some(i) == last,
            device_time: None,
        });
    }
    let pos = report.pos.filter(|(_, quality)| *quality > 0);
    if let Some((pos_m, _)) = pos {
        out(Reading::Position {
            tag,
            pos_m,
            vel_mps: None,
            device_time: None,
            seq: None,
        });
    }
    !anchors.is_empty() || pos.is_some()
}

/// Whether `bytes` start like a `les` report.
fn starts_les(bytes: &[u8]) -> bool {
    starts_les_anchor(bytes) || bytes.starts_with(b"le_us=") || bytes.starts_with(b"est[")
}

/// Whether `bytes` start with a `les` anchor: four hex digits and `[`.
fn starts_les_anchor(bytes: &[u8]) -> bool {
    bytes.get(ID_DIGITS) == Some(&b'[')
        && bytes
            .get(..ID_DIGITS)
            .is_some_and(|id| id.iter().all(u8::is_ascii_hexdigit))
}

/// Parses a line (with its end of line), a report into `report`.
fn parse_line(line: &[u8], report: &mut Report) -> Line {
    let line = line.strip_suffix(b"\n").unwrap_or(line);
    let line = line.strip_suffix(b"\r").unwrap_or(line);
    let parse: fn(&str) -> Option<Report> = if line.starts_with(b"DIST,") {
        parse_lec
    } else if line.starts_with(b"POS,") {
        parse_lep
    } else if starts_les(line) {
        parse_les
    } else {
        return Line::Other;
    };
    match std::str::from_utf8(line).ok().and_then(parse) {
        Some(parsed) => {
            *report = parsed;
            Line::Report
        }
        None => Line::Malformed,
    }
}

/// `DIST,<n>,AN0,<id>,<x>,<y>,<z>,<d>,...[,POS,<x>,<y>,<z>,<qf>]`.
fn parse_lec(line: &str) -> Option<Report> {
    let mut f = line.split(',');
    if f.next()? != "DIST" {
        return None;
    }
    let count = parse_decimal(f.next()?)?;
    if count > MAX_ANCHORS as u64 {
        return None;
    }
    let mut report = Report::default();
    for i in 0..count {
        if parse_decimal(f.next()?.strip_prefix("AN")?)? != i {
            return None;
        }
        let id = parse_id(f.next()?)?;
        let pos_m = parse_xyz(&mut f)?;
        let range_m = parse_metres(f.next()?)?;
        report.push(AnchorRange { id, pos_m, range_m })?;
    }
    match f.next() {
        None => return Some(report),
        Some("POS") => report.pos = Some(parse_estimate(&mut f)?),
        Some(_) => return None,
    }
    f.next().is_none().then_some(report)
}

/// `POS,<x>,<y>,<z>,<qf>`.
fn parse_lep(line: &str) -> Option<Report> {
    let mut f = line.split(',');
    if f.next()? != "POS" {
        return None;
    }
    let pos = parse_estimate(&mut f)?;
    f.next().is_none().then_some(Report {
        pos: Some(pos),
        ..Report::default()
    })
}

/// `<id>[<x>,<y>,<z>]=<d> ... [le_us=<n>] [est[<x>,<y>,<z>,<qf>]]`.
fn parse_les(line: &str) -> Option<Report> {
    /// What may still come: anchors, then le_us, then est.
    #[derive(PartialEq, PartialOrd)]
    enum Next {
        Anchor,
        LeUs,
        Est,
        Nothing,
    }
    let mut report = Report::default();
    let mut next = Next::Anchor;
    for token in line.split(' ').filter(|t| !t.is_empty()) {
        if let Some(us) = token.strip_prefix("le_us=") {
            if next > Next::LeUs {
                return None;
            }
            parse_decimal(us)?;
            next = Next::Est;
        } else if let Some(est) = token.strip_prefix("est[") {
            if next > Next::Est {
                return None;
            }
            let mut f = est.strip_suffix(']')?.split(',');
            report.pos = Some(parse_estimate(&mut f)?);
            if f.next().is_some() {
                return None;
            }
            next = Next::Nothing;
        } else {
            if next > Next::Anchor {
                return None;
            }
            let (id, rest) = token.split_once('[')?;
            let (xyz, range) = rest.split_once("]=")?;
            let mut f = xyz.split(',');
            let pos_m = parse_xyz(&mut f)?;
            if f.next().is_some() {
                return None;
            }
            report.push(AnchorRange {
                id: parse_id(id)?,
                pos_m,
                range_m: parse_metres(range)?,
            })?;
        }
    }
    Some(report)
}

/// Three coordinates in metres.
fn parse_xyz<'a>(f: &mut impl Iterator<Item = &'a str>) -> Option<[f64; 3]> {
    Some([
        parse_metres(f.next()?)?,
        parse_metres(f.next()?)?,
        parse_metres(f.next()?)?,
    ])
}

/// A position and its quality factor.
fn parse_estimate<'a>(f: &mut impl Iterator<Item = &'a str>) -> Option<([f64; 3], u8)> {
    let pos = parse_xyz(f)?;
    let quality = u8::try_from(parse_decimal(f.next()?)?).ok()?;
    (quality <= MAX_QUALITY).then_some((pos, quality))
}

/// A finite number of metres.
fn parse_metres(s: &str) -> Option<f64> {
    s.parse::<f64>().ok().filter(|v| v.is_finite())
}

/// An unsigned decimal integer: digits only, at most 19.
fn parse_decimal(s: &str) -> Option<u64> {
    if s.is_empty() || s.len() > 19 || !s.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    s.parse().ok()
}

/// An anchor id: exactly four hex digits.
fn parse_id(s: &str) -> Option<u32> {
    if s.len() != ID_DIGITS || !s.bytes().all(|b| b.is_ascii_hexdigit()) {
        return None;
    }
    u32::from_str_radix(s, 16).ok()
}

/// What the encoders cannot write.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    /// More anchors than a line holds.
    #[error("dwm1001::EncodeError::TooManyAnchors: {0} anchors, at most 16")]
    TooManyAnchors(usize),
    /// The shell prints 16-bit short addresses.
    #[error("dwm1001::EncodeError::AnchorId: anchor id {0:#x} is not a 16-bit short address")]
    AnchorId(u32),
    /// A coordinate or a distance is NaN or infinite.
    #[error("dwm1001::EncodeError::NotFinite: a coordinate or distance is not finite")]
    NotFinite,
    /// Quality factors are 0 to 100.
    #[error("dwm1001::EncodeError::Quality: quality factor {0} is above 100")]
    Quality(u8),
    /// A `les` line needs an anchor, `le_us` or a position.
    #[error("dwm1001::EncodeError::Empty: a les line needs an anchor, le_us or a position")]
    Empty,
    /// The line would exceed [`MAX_LINE_LEN`].
    #[error("dwm1001::EncodeError::LineTooLong: the line exceeds 1024 bytes")]
    LineTooLong,
}

/// Checks what the encoders write.
fn check(ranges: &[AnchorRange], pos: Option<([f64; 3], u8)>) -> Result<(), EncodeError> {
    if ranges.len() > MAX_ANCHORS {
        return Err(EncodeError::TooManyAnchors(ranges.len()));
    }
    for a in ranges {
        if a.id > 0xFFFF {
            return Err(EncodeError::AnchorId(a.id));
        }
        if !(a.pos_m.iter().all(|v| v.is_finite()) && a.range_m.is_finite()) {
            return Err(EncodeError::NotFinite);
        }
    }
    if let Some((p, quality)) = pos {
        if !p.iter().all(|v| v.is_finite()) {
            return Err(EncodeError::NotFinite);
        }
        if quality > MAX_QUALITY {
            return Err(EncodeError::Quality(quality));
        }
    }
    Ok(())
}

/// Metres with two decimals, saturated at +-1000 km.
struct M(f64);

impl std::fmt::Display for M {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:.2}", self.0.clamp(-MAX_COORD_M, MAX_COORD_M))
    }
}

/// Writes a line with `body` into a fixed buffer, appends it to `out`;
/// returns its length.
fn write_line(
    out: &mut Vec<u8>,
    body: impl FnOnce(&mut &mut [u8]) -> std::io::Result<()>,
) -> Result<usize, EncodeError> {
    let mut line = [0_u8; MAX_LINE_LEN];
    let mut w: &mut [u8] = &mut line;
    body(&mut w)
        .and_then(|()| w.write_all(b"\r\n"))
        .map_err(|_| EncodeError::LineTooLong)?;
    let n = MAX_LINE_LEN - w.len();
    out.extend_from_slice(line.get(..n).ok_or(EncodeError::LineTooLong)?);
    Ok(n)
}

/// Appends a `lec` line (`\r\n` ended) to `out`: ids as four hex digits,
/// metres with two decimals saturated at +-1000 km, the position if given;
/// returns its length. Nothing is written on error.
///
/// # Errors
/// [`EncodeError::TooManyAnchors`], [`EncodeError::AnchorId`],
/// [`EncodeError::NotFinite`], [`EncodeError::Quality`].
pub fn encode_lec(
    ranges: &[AnchorRange],
    pos: Option<([f64; 3], u8)>,
    out: &mut Vec<u8>,
) -> Result<usize, EncodeError> {
    check(ranges, pos)?;
    write_line(out, |w| {
        write!(w, "DIST,{}", ranges.len())?;
        for (i, a) in ranges.iter().enumerate() {
            let [x, y, z] = a.pos_m.map(M);
            write!(w, ",AN{i},{:04X},{x},{y},{z},{}", a.id, M(a.range_m))?;
        }
        if let Some((p, quality)) = pos {
            let [x, y, z] = p.map(M);
            write!(w, ",POS,{x},{y},{z},{quality}")?;
        }
        Ok(())
    })
}

/// Appends a `les` line (`\r\n` ended) to `out`: the anchors, `le_us` and
/// the position where given, formatted as [`encode_lec`] does; returns its
/// length. Nothing is written on error.
///
/// # Errors
/// As [`encode_lec`], and [`EncodeError::Empty`] for a line with nothing.
pub fn encode_les(
    ranges: &[AnchorRange],
    pos: Option<([f64; 3], u8)>,
    le_us: Option<u32>,
    out: &mut Vec<u8>,
) -> Result<usize, EncodeError> {
    check(ranges, pos)?;
    if ranges.is_empty() && le_us.is_none() && pos.is_none() {
        return Err(EncodeError::Empty);
    }
    write_line(out, |w| {
        let mut sep = "";
        for a in ranges {
            let [x, y, z] = a.pos_m.map(M);
            write!(w, "{sep}{:04X}[{x},{y},{z}]={}", a.id, M(a.range_m))?;
            sep = " ";
        }
        if let Some(us) = le_us {
            write!(w, "{sep}le_us={us}")?;
            sep = " ";
        }
        if let Some((p, quality)) = pos {
            let [x, y, z] = p.map(M);
            write!(w, "{sep}est[{x},{y},{z},{quality}]")?;
        }
        Ok(())
    })
}

/// Appends a `lep` line (`POS,<x>,<y>,<z>,<qf>\r\n`) to `out`; returns its
/// length. Nothing is written on error.
///
/// # Errors
/// [`EncodeError::NotFinite`], [`EncodeError::Quality`].
pub fn encode_lep(pos_m: [f64; 3], quality: u8, out: &mut Vec<u8>) -> Result<usize, EncodeError> {
    check(&[], Some((pos_m, quality)))?;
    write_line(out, |w| {
        let [x, y, z] = pos_m.map(M);
        write!(w, "POS,{x},{y},{z},{quality}")
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode(bytes: &[u8]) -> (Vec<Reading>, DecoderStats) {
        let mut d = Decoder::new();
        let mut got = Vec::new();
        d.push(bytes, &mut |r| got.push(r));
        (got, d.stats())
    }

    #[test]
    fn fields_parse_strictly() {
        assert_eq!(parse_id("0C2B"), Some(0x0C2B));
        assert_eq!(parse_id("c2b"), None);
        assert_eq!(parse_id("10C2B"), None);
        assert_eq!(parse_id("0x2B"), None);
        assert_eq!(parse_decimal("16"), Some(16));
        assert_eq!(parse_decimal("+1"), None);
        assert_eq!(parse_decimal(""), None);
        assert_eq!(parse_decimal("99999999999999999999"), None);
        assert_eq!(parse_metres("-1.25"), Some(-1.25));
        assert_eq!(parse_metres("nan"), None);
        assert_eq!(parse_metres("inf"), None);
        assert_eq!(parse_metres(""), None);
    }

    #[test]
    fn a_report_restarts_a_line_only_where_it_cannot_continue_one() {
        // After the prompt, garbage, a cut line, a line without its \n.
        for stream in [
            &b"dwm> DIST,1,AN0,0001,1.00,2.00,3.00,4.00\n"[..],
            b"dwm> 0001[1.00,2.00,3.00]=4.00\n",
            b"x\x99POS,1.00,2.00,3.00,50\n",
            b"DIST,2,AN0,0001,1.0DIST,1,AN0,0001,1.00,2.00,3.00,4.00\n",
            b"DIST,2,AN0,00010001[1.00,2.00,3.00]=4.00\n",
            b"0001[1.00,2.00,3.00]=4POS,1.00,2.00,3.00,50\n",
            b"0001[1.00,2.00,3.00]=4.00\r0001[1.00,2.00,3.00]=4.00\n",
        ] {
            let (got, s) = decode(stream);
            assert_eq!(got.len(), 1, "{}", String::from_utf8_lossy(stream));
            assert_eq!((s.frames_ok, s.resyncs), (1, 1), "{s:?}");
        }
        // Inside a report, or where one may go on: no restart, and a
        // damaged report gives nothing.
        for (stream, readings) in [
            (&b"DIST,0,POS,1.00,2.00,3.00,50\n"[..], 1),
            (b"0001[1.00,2.00,3.00]=4.00 0002[1.00,2.00,3.00]=4.00\n", 2),
            (b"DIST,0,x POS,1.00,2.00,3.00,50\n", 0),
            (b"\xBBIST,0,POS,1.00,2.00,3.00,50\n", 0),
            (b"0001[1.00,2.00,3.00]=4.000002[1.00,2.00,3.00]=4.00\n", 0),
            (
                b"\xCF001[1.00,2.00,3.00]=4.00 0002[1.00,2.00,3.00]=4.00\n",
                0,
            ),
        ] {
            let (got, s) = decode(stream);
            assert_eq!(got.len(), readings, "{}", String::from_utf8_lossy(stream));
            assert_eq!(s.resyncs, 0, "{s:?}");
        }
    }

    #[test]
    fn quality_zero_gives_no_position() {
        let (got, s) = decode(b"POS,1.00,2.00,3.00,0\r\nDIST,0\r\n");
        assert!(got.is_empty());
        assert_eq!((s.frames_ok, s.no_fix, s.malformed), (0, 2, 0));
        let (got, s) = decode(b"DIST,1,AN0,0001,1.00,2.00,3.00,4.00,POS,1.00,2.00,3.00,0\r\n");
        assert!(matches!(
            got[..],
            [Reading::Range {
                last_of_round: true,
                ..
            }]
        ));
        assert_eq!((s.frames_ok, s.no_fix), (1, 0));
    }

    #[test]
    fn encoders_refuse_what_the_shell_cannot_print_and_saturate() {
        let a = |id, range_m| AnchorRange {
            id,
            pos_m: [0.0; 3],
            range_m,
        };
        let mut out = Vec::new();
        assert_eq!(
            encode_lec(&[a(0x1_0000, 1.0)], None, &mut out),
            Err(EncodeError::AnchorId(0x1_0000))
        );
        assert_eq!(
            encode_lec(&[a(1, f64::NAN)], None, &mut out),
            Err(EncodeError::NotFinite)
        );
        assert_eq!(
            encode_lec(&[a(1, 1.0); 17], None, &mut out),
            Err(EncodeError::TooManyAnchors(17))
        );
        assert_eq!(
            encode_lep([0.0; 3], 101, &mut out),
            Err(EncodeError::Quality(101))
        );
        assert_eq!(
            encode_les(&[], None, None, &mut out),
            Err(EncodeError::Empty)
        );
        assert!(out.is_empty());
        // The widest line there is still fits.
        let wide = AnchorRange {
            id: 0xFFFF,
            pos_m: [-1e9; 3],
            range_m: -1e9,
        };
        let n = encode_lec(&[wide; 16], Some(([-1e9; 3], 100)), &mut out).unwrap();
        assert!(n <= MAX_LINE_LEN, "{n}");
        assert!(out.starts_with(b"DIST,16,AN0,FFFF,-1000000.00,"));
        out.clear();
        let n = encode_les(
            &[wide; 16],
            Some(([-1e9; 3], 100)),
            Some(u32::MAX),
            &mut out,
        )
        .unwrap();
        assert!(n <= MAX_LINE_LEN, "{n}");
        let (got, s) = decode(&out);
        assert_eq!((got.len(), s.frames_ok), (17, 1));
    }
}
