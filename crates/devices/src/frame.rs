//! What every protocol codec shares: the [`Reading`] a decoder emits, the
//! raw [`DeviceTime`] it carries, the [`DecoderStats`] a decoder counts, the
//! [`Protocol`] names and [`AnyDecoder`] that picks a decoder by name, the
//! time a frame spends on a serial wire ([`wire_time_ns`]), and the
//! fixed-buffer framer the binary protocols resynchronise with.
//!
//! ```
//! use insuwb_devices::frame::{AnyDecoder, Protocol, Reading};
//! use insuwb_devices::witmotion;
//!
//! let protocol: Protocol = "witmotion".parse()?;
//! let mut decoder = AnyDecoder::new(protocol);
//! let frames = witmotion::encode_imu([0.0, 0.0, 9.80665], [0.0; 3], 25.0);
//! let mut readings = Vec::new();
//! decoder.push(&frames, &mut |r| readings.push(r));
//! assert!(matches!(readings.as_slice(), [Reading::Imu { .. }]));
//! assert_eq!(decoder.stats().frames_ok, 2);
//! # Ok::<(), insuwb_devices::frame::UnknownProtocol>(())
//! ```
//!
//! Decoders never allocate per frame: each holds a fixed-size buffer of its
//! protocol's largest frame. Every byte pushed ends up in exactly one of
//! three places, which the fuzz tests check:
//! `bytes_in == bytes_framed + bytes_skipped + buffered()`.

use std::fmt;
use std::str::FromStr;

use crate::{dwm1001, eliko, mavlink, nlink, witmotion};

/// Standard gravity (m/s^2) used to turn g and mG into m/s^2.
pub const STANDARD_GRAVITY: f64 = 9.80665;

/// A raw device counter as the device sent it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct DeviceTime {
    /// The counter value, in the device's ticks.
    pub ticks: u64,
    /// Nanoseconds per tick.
    pub tick_ns: u64,
    /// Where the counter wraps back to zero, in ticks (`None`: never).
    pub wrap: Option<u64>,
}

/// One measurement decoded from a device.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub enum Reading {
    /// Specific force and angular rate from an IMU, body frame.
    Imu {
        /// Specific force (m/s^2).
        accel_mps2: [f64; 3],
        /// Angular rate (rad/s).
        gyro_rps: [f64; 3],
        /// The device's own time stamp, if the protocol carries one.
        device_time: Option<DeviceTime>,
    },
    /// A position fix of a UWB tag.
    Position {
        /// The tag's identifier.
        tag: u32,
        /// Position in the positioning system's frame (m).
        pos_m: [f64; 3],
        /// Velocity, if the system reports one (m/s).
        vel_mps: Option<[f64; 3]>,
        /// The system's own time stamp, if the protocol carries one.
        device_time: Option<DeviceTime>,
        /// The system's sequence number, if the protocol carries one.
        seq: Option<u32>,
    },
    /// Ranges from a UWB tag to the anchors of its network.
    Ranges {
        /// The tag's identifier.
        tag: u32,
        /// Range to anchor `i` (m); 0 where the anchor is not heard.
        ranges_m: [f64; 8],
        /// The system's own time stamp, if the protocol carries one.
        device_time: Option<DeviceTime>,
    },
    /// One two-way range from a UWB tag to one anchor, as the tag reported
    /// it: the anchors of one ranging round come one after the other, the
    /// last with `last_of_round`.
    Range {
        /// The anchor's identifier (DWM1001: its 16-bit short address;
        /// NLink: its index 0..7).
        anchor: u32,
        /// Distance from the tag to the anchor (m).
        range_m: f64,
        /// The anchor's position as the system knows it (m), if the
        /// protocol carries it.
        anchor_pos_m: Option<[f64; 3]>,
        /// The device's quality figure of this range, 0-100, if the
        /// protocol carries one.
        quality: Option<u8>,
        /// The last range of its round (its line or frame).
        last_of_round: bool,
        /// The system's own time stamp, if the protocol carries one.
        device_time: Option<DeviceTime>,
    },
    /// Euler angles an IMU computed on board.
    Attitude {
        /// Roll, pitch, yaw (rad).
        rpy_rad: [f64; 3],
        /// The device's own time stamp, if the protocol carries one.
        device_time: Option<DeviceTime>,
    },
    /// An attitude quaternion an IMU computed on board.
    Quaternion {
        /// `[w, x, y, z]`, as the device sent it (not renormalised).
        wxyz: [f64; 4],
        /// The device's own time stamp, if the protocol carries one.
        device_time: Option<DeviceTime>,
    },
}

/// What a decoder has counted since it was made.
///
/// `bytes_in == bytes_framed + bytes_skipped + buffered()` holds after every
/// `push`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DecoderStats {
    /// Bytes pushed into the decoder.
    pub bytes_in: u64,
    /// Bytes that belonged to frames whose checksum held (decoded or not).
    pub bytes_framed: u64,
    /// Bytes dropped while looking for the next frame.
    pub bytes_skipped: u64,
    /// Frames whose checksum held and whose content was decoded.
    pub frames_ok: u64,
    /// Frames whose checksum held but whose type this decoder does not use
    /// (text protocols: lines that are not reports).
    pub unknown: u64,
    /// Frames dropped because their checksum failed.
    pub checksum_errors: u64,
    /// Times the decoder lost the frame boundary and had to search for it.
    pub resyncs: u64,
    /// Frames or lines longer than the protocol allows (dropped).
    pub oversize: u64,
    /// Frames whose checksum held but whose content made no sense.
    pub malformed: u64,
    /// Readings that needed two frames of which only one arrived (WitMotion
    /// 0x51/0x52 cycles).
    pub incomplete: u64,
    /// Frames missing according to the device's sequence numbers.
    pub seq_gaps: u64,
    /// Valid frames left out on purpose (another tag or IMU, a fallback
    /// message while the preferred one flows).
    pub filtered: u64,
    /// Valid position reports that carried no position (tag not located;
    /// DWM1001: a line with no range and no position of quality above 0).
    pub no_fix: u64,
}

/// The protocols this crate speaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Protocol {
    /// WitMotion 0x55 serial protocol (IMU).
    WitMotion,
    /// MAVLink v1/v2, HIGHRES_IMU and SCALED_IMU (IMU).
    Mavlink,
    /// Nooploop LinkTrack NLink Tag_Frame0 (UWB).
    Nlink,
    /// Eliko RTLS text protocol over TCP (UWB).
    Eliko,
    /// Qorvo (Decawave) DWM1001 UART shell, `lec`/`les`/`lep` lines (UWB).
    Dwm1001,
}

/// The name given to [`Protocol::from_str`] is not one we know.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown device protocol {name:?}; known: {}", Protocol::NAMES.join(", "))]
pub struct UnknownProtocol {
    /// The name that was given.
    pub name: String,
}

impl Protocol {
    /// Every protocol, in the order of [`Protocol::NAMES`].
    pub const ALL: [Protocol; 5] = [
        Protocol::WitMotion,
        Protocol::Mavlink,
        Protocol::Nlink,
        Protocol::Eliko,
        Protocol::Dwm1001,
    ];

    /// The names [`Protocol::from_str`] accepts.
    pub const NAMES: [&'static str; 5] = ["witmotion", "mavlink", "nlink", "eliko", "dwm1001"];

    /// The protocol's name as [`Protocol::from_str`] accepts it.
    pub fn name(self) -> &'static str {
        match self {
            Protocol::WitMotion => "witmotion",
            Protocol::Mavlink => "mavlink",
            Protocol::Nlink => "nlink",
            Protocol::Eliko => "eliko",
            Protocol::Dwm1001 => "dwm1001",
        }
    }

    /// Bytes of the frame that carries one reading: a WitMotion 0x51 or
    /// 0x52 frame, a MAVLink v2 HIGHRES_IMU, an NLink Tag_Frame0, a typical
    /// Eliko COORD line, a DWM1001 `lec` line of four anchors.
    pub fn nominal_frame_len(self) -> usize {
        match self {
            Protocol::WitMotion => witmotion::FRAME_LEN,
            Protocol::Mavlink => mavlink::HIGHRES_IMU_V2_FRAME_LEN,
            Protocol::Nlink => nlink::FRAME_LEN,
            Protocol::Eliko => eliko::NOMINAL_LINE_LEN,
            Protocol::Dwm1001 => dwm1001::NOMINAL_LINE_LEN,
        }
    }

    /// The largest frame the decoder buffers; a link that sees this many
    /// bytes without one valid frame is not hearing this protocol.
    pub fn max_frame_len(self) -> usize {
        match self {
            Protocol::WitMotion => witmotion::FRAME_LEN,
            Protocol::Mavlink => mavlink::MAX_FRAME_LEN,
            Protocol::Nlink => nlink::FRAME_LEN,
            Protocol::Eliko => eliko::MAX_LINE_LEN,
            Protocol::Dwm1001 => dwm1001::MAX_LINE_LEN,
        }
    }
}

impl fmt::Display for Protocol {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Protocol {
    type Err = UnknownProtocol;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        Protocol::ALL
            .into_iter()
            .find(|p| p.name().eq_ignore_ascii_case(name.trim()))
            .ok_or_else(|| UnknownProtocol {
                name: name.to_owned(),
            })
    }
}

/// Nanoseconds `frame_len` bytes take on a serial line at `baud` (8N1: ten
/// bits a byte). `baud == 0` means no serial line (TCP): 0 ns.
pub fn wire_time_ns(frame_len: usize, baud: u32) -> u64 {
    if baud == 0 {
        return 0;
    }
    let bits = (frame_len as u128).saturating_mul(10);
    let ns = bits.saturating_mul(1_000_000_000) / u128::from(baud);
    u64::try_from(ns).unwrap_or(u64::MAX)
}

/// A decoder of one of the [`Protocol`]s, chosen at run time.
#[derive(Debug, Clone)]
pub enum AnyDecoder {
    /// See [`witmotion::Decoder`].
    WitMotion(witmotion::Decoder),
    /// See [`mavlink::Decoder`].
    Mavlink(mavlink::Decoder),
    /// See [`nlink::Decoder`].
    Nlink(nlink::Decoder),
    /// See [`eliko::Decoder`].
    Eliko(eliko::Decoder),
    /// See [`dwm1001::Decoder`].
    Dwm1001(dwm1001::Decoder),
}

impl AnyDecoder {
    /// The protocol's decoder with its default settings (MAVLink IMU id 0,
    /// every Eliko tag, DWM1001 positions as tag 0).
    pub fn new(protocol: Protocol) -> Self {
        match protocol {
            Protocol::WitMotion => AnyDecoder::WitMotion(witmotion::Decoder::new()),
            Protocol::Mavlink => AnyDecoder::Mavlink(mavlink::Decoder::new()),
            Protocol::Nlink => AnyDecoder::Nlink(nlink::Decoder::new()),
            Protocol::Eliko => AnyDecoder::Eliko(eliko::Decoder::new()),
            Protocol::Dwm1001 => AnyDecoder::Dwm1001(dwm1001::Decoder::new()),
        }
    }

    /// The protocol this decoder speaks.
    pub fn protocol(&self) -> Protocol {
        match self {
            AnyDecoder::WitMotion(_) => Protocol::WitMotion,
            AnyDecoder::Mavlink(_) => Protocol::Mavlink,
            AnyDecoder::Nlink(_) => Protocol::Nlink,
            AnyDecoder::Eliko(_) => Protocol::Eliko,
            AnyDecoder::Dwm1001(_) => Protocol::Dwm1001,
        }
    }

    /// Feeds bytes as they came off the link; calls `out` for each reading.
    pub fn push(&mut self, bytes: &[u8], out: &mut impl FnMut(Reading)) {
        match self {
            AnyDecoder::WitMotion(d) => d.push(bytes, out),
            AnyDecoder::Mavlink(d) => d.push(bytes, out),
            AnyDecoder::Nlink(d) => d.push(bytes, out),
            AnyDecoder::Eliko(d) => d.push(bytes, out),
            AnyDecoder::Dwm1001(d) => d.push(bytes, out),
        }
    }

    /// What the decoder has counted.
    pub fn stats(&self) -> DecoderStats {
        match self {
            AnyDecoder::WitMotion(d) => d.stats(),
            AnyDecoder::Mavlink(d) => d.stats(),
            AnyDecoder::Nlink(d) => d.stats(),
            AnyDecoder::Eliko(d) => d.stats(),
            AnyDecoder::Dwm1001(d) => d.stats(),
        }
    }

    /// Bytes received since the end of the last frame whose checksum held
    /// (all bytes, if none yet). Many times [`Protocol::max_frame_len`]
    /// suggests the wrong baud rate or the wrong protocol.
    pub fn bytes_since_last_valid_frame(&self) -> u64 {
        match self {
            AnyDecoder::WitMotion(d) => d.bytes_since_last_valid_frame(),
            AnyDecoder::Mavlink(d) => d.bytes_since_last_valid_frame(),
            AnyDecoder::Nlink(d) => d.bytes_since_last_valid_frame(),
            AnyDecoder::Eliko(d) => d.bytes_since_last_valid_frame(),
            AnyDecoder::Dwm1001(d) => d.bytes_since_last_valid_frame(),
        }
    }

    /// Bytes held waiting for the rest of a frame.
    pub fn buffered(&self) -> usize {
        match self {
            AnyDecoder::WitMotion(d) => d.buffered(),
            AnyDecoder::Mavlink(d) => d.buffered(),
            AnyDecoder::Nlink(d) => d.buffered(),
            AnyDecoder::Eliko(d) => d.buffered(),
            AnyDecoder::Dwm1001(d) => d.buffered(),
        }
    }

    /// Forgets a partial frame (after the link reconnected); keeps counts.
    pub fn clear(&mut self) {
        match self {
            AnyDecoder::WitMotion(d) => d.clear(),
            AnyDecoder::Mavlink(d) => d.clear(),
            AnyDecoder::Nlink(d) => d.clear(),
            AnyDecoder::Eliko(d) => d.clear(),
            AnyDecoder::Dwm1001(d) => d.clear(),
        }
    }
}

/// Reads a little-endian `i16` at `at`; `None` past the end.
pub(crate) fn le_i16(bytes: &[u8], at: usize) -> Option<i16> {
    let b = bytes.get(at..at.checked_add(2)?)?;
    Some(i16::from_le_bytes([*b.first()?, *b.get(1)?]))
}

/// Reads a little-endian `u16` at `at`; `None` past the end.
pub(crate) fn le_u16(bytes: &[u8], at: usize) -> Option<u16> {
    let b = bytes.get(at..at.checked_add(2)?)?;
    Some(u16::from_le_bytes([*b.first()?, *b.get(1)?]))
}

/// Reads a little-endian `u32` at `at`; `None` past the end.
pub(crate) fn le_u32(bytes: &[u8], at: usize) -> Option<u32> {
    let b: [u8; 4] = bytes.get(at..at.checked_add(4)?)?.try_into().ok()?;
    Some(u32::from_le_bytes(b))
}

/// Reads a little-endian `u64` at `at`; `None` past the end.
pub(crate) fn le_u64(bytes: &[u8], at: usize) -> Option<u64> {
    let b: [u8; 8] = bytes.get(at..at.checked_add(8)?)?.try_into().ok()?;
    Some(u64::from_le_bytes(b))
}

/// Reads a little-endian `f32` at `at`; `None` past the end.
pub(crate) fn le_f32(bytes: &[u8], at: usize) -> Option<f32> {
    le_u32(bytes, at).map(f32::from_bits)
}

/// Sum of the bytes modulo 256 (WitMotion, NLink checksums).
pub(crate) fn sum8(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0u8, |s, b| s.wrapping_add(*b))
}

/// `x / scale` rounded to the nearest integer and saturated into `i16`
/// (NaN gives 0).
pub(crate) fn saturate_i16(x: f64, scale: f64) -> i16 {
    // `as` saturates at the bounds and maps NaN to 0.
    (x / scale).round() as i16
}

/// Counts skipped bytes, and a resync each time skipping starts after
/// bytes that were kept.
#[derive(Debug, Clone, Copy)]
pub(crate) struct SkipCounter {
    /// False while skipping.
    in_sync: bool,
}

impl SkipCounter {
    pub(crate) fn new() -> Self {
        SkipCounter { in_sync: true }
    }

    /// A byte was kept: the next skip starts a new resync.
    pub(crate) fn kept(&mut self) {
        self.in_sync = true;
    }

    /// `n` bytes were dropped.
    pub(crate) fn skipped(&mut self, stats: &mut DecoderStats, n: u64) {
        if n == 0 {
            return;
        }
        if self.in_sync {
            stats.resyncs = stats.resyncs.saturating_add(1);
            self.in_sync = false;
        }
        stats.bytes_skipped = stats.bytes_skipped.saturating_add(n);
    }
}

/// The accessors every [`Framer`]-based decoder forwards.
macro_rules! framer_accessors {
    () => {
        /// Bytes received since the end of the last checksum-valid frame.
        pub fn bytes_since_last_valid_frame(&self) -> u64 {
            self.framer.bytes_since_last_valid_frame()
        }

        /// Bytes held waiting for the rest of a frame.
        pub fn buffered(&self) -> usize {
            self.framer.buffered()
        }
    };
}
pub(crate) use framer_accessors;

/// What [`FrameFormat::scan`] learned from the start of the buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Scan {
    /// Not enough bytes yet to know the frame's length.
    NeedMore,
    /// The header cannot start a frame: drop the start byte.
    Invalid,
    /// A frame of this many bytes (header, body and checksum).
    Frame(usize),
}

/// How a binary protocol delimits and checks its frames.
pub(crate) trait FrameFormat {
    /// Whether `byte` can be a frame's first byte.
    fn is_start(&self, byte: u8) -> bool;
    /// Reads the header at the start of `buf` (which begins with a start
    /// byte).
    fn scan(&self, buf: &[u8]) -> Scan;
    /// Whether the complete frame's checksum holds.
    fn checksum_ok(&self, frame: &[u8]) -> bool;
}

/// What happened on the link since the previous valid frame, for decoders
/// that pair frames.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct Gap {
    /// Bytes skipped since the previous valid frame.
    pub skipped: u64,
    /// Checksum failures since the previous valid frame.
    pub checksum_errors: u64,
}

/// What a decoder made of a frame whose checksum held.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Outcome {
    /// Decoded (counted in `frames_ok`).
    Decoded,
    /// A type the decoder does not use (counted in `unknown`).
    Unknown,
    /// Content out of range (counted in `malformed`).
    Malformed,
    /// Left out on purpose (counted in `filtered`).
    Filtered,
}

/// Splits a byte stream into checksum-valid frames with a fixed buffer of
/// `N` bytes, resynchronising byte by byte after anything that is not one.
#[derive(Debug, Clone)]
pub(crate) struct Framer<const N: usize> {
    buf: [u8; N],
    len: usize,
    sync: SkipCounter,
    since_valid: u64,
    gap: Gap,
    pub(crate) stats: DecoderStats,
}

impl<const N: usize> Framer<N> {
    pub(crate) fn new() -> Self {
        Framer {
            buf: [0; N],
            len: 0,
            sync: SkipCounter::new(),
            since_valid: 0,
            gap: Gap::default(),
            stats: DecoderStats::default(),
        }
    }

    pub(crate) fn buffered(&self) -> usize {
        self.len
    }

    pub(crate) fn bytes_since_last_valid_frame(&self) -> u64 {
        self.since_valid
    }

    /// Drops a partial frame; what it held counts as skipped.
    pub(crate) fn clear(&mut self) {
        self.skip(self.len);
        self.sync.kept();
    }

    /// Feeds `bytes`; calls `on_frame` with each checksum-valid frame and
    /// the gap before it.
    pub(crate) fn push<F: FrameFormat>(
        &mut self,
        format: &F,
        bytes: &[u8],
        on_frame: &mut impl FnMut(&[u8], Gap) -> Outcome,
    ) {
        for &byte in bytes {
            self.stats.bytes_in = self.stats.bytes_in.saturating_add(1);
            self.since_valid = self.since_valid.saturating_add(1);
            if self.len == 0 && !format.is_start(byte) {
                self.count_skipped(1);
                continue;
            }
            if let Some(slot) = self.buf.get_mut(self.len) {
                *slot = byte;
                self.len += 1;
            } else {
                // Unreachable with a format whose frames fit in N: scan()
                // reports a length before the buffer fills. Drop the byte.
                self.count_skipped(1);
                continue;
            }
            self.sync.kept();
            self.drain(format, on_frame);
        }
    }

    /// Takes frames off the front of the buffer while it holds any.
    fn drain<F: FrameFormat>(
        &mut self,
        format: &F,
        on_frame: &mut impl FnMut(&[u8], Gap) -> Outcome,
    ) {
        while self.len > 0 {
            if !self.buf.first().is_some_and(|b| format.is_start(*b)) {
                self.skip_to_start(format, 0);
                continue;
            }
            let held = self.buf.get(..self.len).unwrap_or(&[]);
            match format.scan(held) {
                Scan::NeedMore => return,
                Scan::Invalid => self.drop_start(format),
                Scan::Frame(n) if n > N || n == 0 => {
                    self.stats.oversize = self.stats.oversize.saturating_add(1);
                    self.drop_start(format);
                }
                Scan::Frame(n) if n > self.len => return,
                Scan::Frame(n) => {
                    let frame = self.buf.get(..n).unwrap_or(&[]);
                    if format.checksum_ok(frame) {
                        let outcome = on_frame(frame, self.gap);
                        let s = &mut self.stats;
                        match outcome {
                            Outcome::Decoded => s.frames_ok = s.frames_ok.saturating_add(1),
                            Outcome::Unknown => s.unknown = s.unknown.saturating_add(1),
                            Outcome::Malformed => s.malformed = s.malformed.saturating_add(1),
                            Outcome::Filtered => s.filtered = s.filtered.saturating_add(1),
                        }
                        s.bytes_framed = s.bytes_framed.saturating_add(n as u64);
                        self.gap = Gap::default();
                        self.consume(n);
                        self.since_valid = self.len as u64;
                    } else {
                        self.stats.checksum_errors = self.stats.checksum_errors.saturating_add(1);
                        self.gap.checksum_errors = self.gap.checksum_errors.saturating_add(1);
                        self.drop_start(format);
                    }
                }
            }
        }
    }

    /// Drops the start byte and everything up to the next possible start.
    fn drop_start<F: FrameFormat>(&mut self, format: &F) {
        self.skip_to_start(format, 1);
    }

    /// Drops the buffer up to the first possible start at or after `from`.
    fn skip_to_start<F: FrameFormat>(&mut self, format: &F, from: usize) {
        let next = self
            .buf
            .get(from..self.len)
            .and_then(|rest| rest.iter().position(|b| format.is_start(*b)))
            .map_or(self.len, |at| at + from);
        self.skip(next);
    }

    fn consume(&mut self, n: usize) {
        let n = n.min(self.len);
        self.buf.copy_within(n..self.len, 0);
        self.len -= n;
    }

    fn skip(&mut self, n: usize) {
        self.consume(n);
        self.count_skipped(n as u64);
    }

    fn count_skipped(&mut self, n: u64) {
        self.sync.skipped(&mut self.stats, n);
        self.gap.skipped = self.gap.skipped.saturating_add(n);
    }
}
