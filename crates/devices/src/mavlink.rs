//! MAVLink v1 and v2 framing and the two IMU messages drivers read from a
//! flight controller: the streaming [`Decoder`] and the encoders the
//! emulator uses. Written here rather than taken from the `mavlink` crate,
//! whose code generation is too heavy for the 2-core CI.
//!
//! Frames (all little-endian):
//!
//! | version | header                                                       | then |
//! |---------|--------------------------------------------------------------|------|
//! | v1      | `0xFE` len seq sysid compid msgid(1)                          | payload, CRC(2) |
//! | v2      | `0xFD` len incompat compat seq sysid compid msgid(3)          | payload, CRC(2), signature(13) if incompat & 0x01 |
//!
//! The CRC is CRC-16/MCRF4XX (the X.25 CRC MAVLink uses) over the frame
//! from the byte after the magic to the end of the payload, then over the
//! message's CRC_EXTRA byte. A v2 sender drops the payload's trailing zero
//! bytes; the decoder puts them back. Signatures are skipped, not checked.
//!
//! Decoded messages, in MAVLink wire order (fields sorted by type size,
//! largest first, extensions last):
//!
//! - HIGHRES_IMU (id 105, CRC_EXTRA 93, 62 bytes + 1 extension):
//!   `time_usec u64` @0, `xacc yacc zacc f32` @8 (m/s^2), `xgyro ygyro zgyro
//!   f32` @20 (rad/s), `xmag ymag zmag abs_pressure diff_pressure
//!   pressure_alt temperature f32` @32, `fields_updated u16` @60, extension
//!   `id u8` @62.
//! - SCALED_IMU (id 26, CRC_EXTRA 170, 22 bytes + 2 extension):
//!   `time_boot_ms u32` @0, `xacc yacc zacc i16` @4 (mG), `xgyro ygyro zgyro
//!   i16` @10 (mrad/s), `xmag ymag zmag i16` @16, extension `temperature i16`
//!   @22.
//!
//! SCALED_IMU is a fallback: it is decoded only while no HIGHRES_IMU has
//! been seen, then counted in [`DecoderStats::filtered`]. Only the IMU whose
//! HIGHRES_IMU `id` matches the decoder's (default 0) is decoded.
//!
//! A frame's CRC can be checked only for messages whose CRC_EXTRA we know
//! ([`crc_extra`]); a header announcing any other message is treated as
//! noise (its bytes are skipped and scanned for the next magic), so a frame
//! of an unknown message can never hide a frame we decode.
//!
//! ```
//! use insuwb_devices::mavlink::{encode_highres_imu, Decoder, Header, MAX_FRAME_LEN};
//! use insuwb_devices::frame::Reading;
//!
//! let mut buf = [0u8; MAX_FRAME_LEN];
//! let n = encode_highres_imu(&Header::v2(0), 1_000, [0.0, 0.0, -9.81], [0.1, 0.0, 0.0], 0, &mut buf);
//! let mut decoder = Decoder::new();
//! let mut got = Vec::new();
//! decoder.push(&buf[..n], &mut |r| got.push(r));
//! assert!(matches!(got.as_slice(), [Reading::Imu { .. }]));
//! ```

use crate::frame::{
    le_f32, le_i16, le_u32, le_u64, DecoderStats, DeviceTime, FrameFormat, Framer, Outcome,
    Reading, Scan, STANDARD_GRAVITY,
};

/// Magic byte of a MAVLink v1 frame.
pub const STX_V1: u8 = 0xFE;
/// Magic byte of a MAVLink v2 frame.
pub const STX_V2: u8 = 0xFD;
/// The largest frame: v2 header 10, payload 255, CRC 2, signature 13.
pub const MAX_FRAME_LEN: usize = 280;
/// Bytes of a v1 header (magic to msgid).
pub const V1_HEADER_LEN: usize = 6;
/// Bytes of a v2 header (magic to msgid).
pub const V2_HEADER_LEN: usize = 10;
/// Bytes of a v2 signature.
pub const SIGNATURE_LEN: usize = 13;
/// v2 incompatibility flag: the frame is signed.
pub const INCOMPAT_SIGNED: u8 = 0x01;

/// HIGHRES_IMU message id.
pub const HIGHRES_IMU_ID: u32 = 105;
/// HIGHRES_IMU CRC_EXTRA.
pub const HIGHRES_IMU_CRC_EXTRA: u8 = 93;
/// HIGHRES_IMU payload without extensions (what v1 sends).
pub const HIGHRES_IMU_BASE_LEN: usize = 62;
/// HIGHRES_IMU payload with the `id` extension.
pub const HIGHRES_IMU_LEN: usize = 63;
/// A full (untruncated) v2 HIGHRES_IMU frame.
pub const HIGHRES_IMU_V2_FRAME_LEN: usize = V2_HEADER_LEN + HIGHRES_IMU_LEN + 2;
/// SCALED_IMU message id.
pub const SCALED_IMU_ID: u32 = 26;
/// SCALED_IMU CRC_EXTRA.
pub const SCALED_IMU_CRC_EXTRA: u8 = 170;
/// SCALED_IMU payload without extensions (what v1 sends).
pub const SCALED_IMU_BASE_LEN: usize = 22;
/// SCALED_IMU payload with the `temperature` extension.
pub const SCALED_IMU_LEN: usize = 24;

/// CRC_EXTRA of the messages whose frames we can check: the two we decode
/// and common ones a flight controller interleaves with them (their frames
/// are checked, then counted in [`DecoderStats::unknown`]). Source:
/// `MAVLINK_MESSAGE_CRCS` of the generated C headers, common.xml.
const KNOWN_CRC_EXTRA: [(u32, u8); 11] = [
    (0, 50),  // HEARTBEAT
    (1, 124), // SYS_STATUS
    (2, 137), // SYSTEM_TIME
    (26, SCALED_IMU_CRC_EXTRA),
    (27, 144), // RAW_IMU
    (30, 39),  // ATTITUDE
    (31, 246), // ATTITUDE_QUATERNION
    (33, 104), // GLOBAL_POSITION_INT
    (105, HIGHRES_IMU_CRC_EXTRA),
    (116, 76), // SCALED_IMU2
    (129, 46), // SCALED_IMU3
];

/// The CRC_EXTRA of message `msgid`, if this codec knows the message.
pub fn crc_extra(msgid: u32) -> Option<u8> {
    KNOWN_CRC_EXTRA
        .iter()
        .find(|(id, _)| *id == msgid)
        .map(|(_, extra)| *extra)
}

/// Folds `bytes` into a CRC-16/MCRF4XX (X.25 as MAVLink computes it;
/// start from `0xFFFF`).
pub fn crc_accumulate(mut crc: u16, bytes: &[u8]) -> u16 {
    for &b in bytes {
        let mut tmp = b ^ (crc & 0xFF) as u8;
        tmp ^= tmp << 4;
        let t = u16::from(tmp);
        crc = (crc >> 8) ^ (t << 8) ^ (t << 3) ^ (t >> 4);
    }
    crc
}

/// The frame CRC: over `covered` (frame after the magic, up to the end of
/// the payload), then the message's CRC_EXTRA.
pub fn frame_crc(covered: &[u8], crc_extra: u8) -> u16 {
    crc_accumulate(crc_accumulate(0xFFFF, covered), &[crc_extra])
}

/// The parts of a frame's header the decoder reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct FrameInfo {
    header_len: usize,
    payload_len: usize,
    msgid: u32,
    signed: bool,
}

impl FrameInfo {
    /// Reads the header at the start of `buf`; `Err(scan)` when it is not
    /// (yet) a header of a frame we can check.
    fn parse(buf: &[u8]) -> Result<Self, Scan> {
        let (header_len, msgid, signed) = match buf.first() {
            Some(&STX_V1) => {
                let msgid = buf.get(5).ok_or(Scan::NeedMore)?;
                (V1_HEADER_LEN, u32::from(*msgid), false)
            }
            Some(&STX_V2) => {
                let h = buf.get(..V2_HEADER_LEN).ok_or(Scan::NeedMore)?;
                let incompat = h.get(2).copied().unwrap_or(0xFF);
                if incompat & !INCOMPAT_SIGNED != 0 {
                    // Unknown incompatibility flags: the spec says drop it.
                    return Err(Scan::Invalid);
                }
                let id = |i: usize| u32::from(h.get(i).copied().unwrap_or(0));
                let msgid = id(7) | id(8) << 8 | id(9) << 16;
                (V2_HEADER_LEN, msgid, incompat & INCOMPAT_SIGNED != 0)
            }
            _ => return Err(Scan::Invalid),
        };
        if crc_extra(msgid).is_none() {
            return Err(Scan::Invalid);
        }
        let payload_len = usize::from(buf.get(1).copied().unwrap_or(0));
        Ok(FrameInfo {
            header_len,
            payload_len,
            msgid,
            signed,
        })
    }

    fn crc_at(&self) -> usize {
        self.header_len + self.payload_len
    }

    fn frame_len(&self) -> usize {
        self.crc_at() + 2 + if self.signed { SIGNATURE_LEN } else { 0 }
    }
}

#[derive(Debug, Clone, Copy)]
struct Format;

impl FrameFormat for Format {
    fn is_start(&self, byte: u8) -> bool {
        byte == STX_V1 || byte == STX_V2
    }

    fn scan(&self, buf: &[u8]) -> Scan {
        match FrameInfo::parse(buf) {
            Ok(info) => Scan::Frame(info.frame_len()),
            Err(scan) => scan,
        }
    }

    fn checksum_ok(&self, frame: &[u8]) -> bool {
        let Ok(info) = FrameInfo::parse(frame) else {
            return false;
        };
        let (Some(covered), Some(extra), Some(lo), Some(hi)) = (
            frame.get(1..info.crc_at()),
            crc_extra(info.msgid),
            frame.get(info.crc_at()),
            frame.get(info.crc_at() + 1),
        ) else {
            return false;
        };
        frame_crc(covered, extra) == u16::from_le_bytes([*lo, *hi])
    }
}

/// Streaming decoder of a MAVLink byte stream (HIGHRES_IMU, SCALED_IMU).
#[derive(Debug, Clone)]
pub struct Decoder {
    framer: Framer<MAX_FRAME_LEN>,
    imu_id: u8,
    highres_seen: bool,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder {
    /// A decoder of IMU 0 (HIGHRES_IMU `id` 0).
    pub fn new() -> Self {
        Self::with_imu_id(0)
    }

    /// A decoder of the IMU whose HIGHRES_IMU `id` is `imu_id`.
    pub fn with_imu_id(imu_id: u8) -> Self {
        Decoder {
            framer: Framer::new(),
            imu_id,
            highres_seen: false,
        }
    }

    /// Feeds bytes as they came off the link; calls `out` for each reading.
    pub fn push(&mut self, bytes: &[u8], out: &mut impl FnMut(Reading)) {
        let Decoder {
            framer,
            imu_id,
            highres_seen,
        } = self;
        framer.push(&Format, bytes, &mut |frame, _gap| {
            decode_frame(frame, *imu_id, highres_seen, out)
        });
    }

    /// What the decoder has counted.
    pub fn stats(&self) -> DecoderStats {
        self.framer.stats
    }

    crate::frame::framer_accessors!();

    /// Forgets a partial frame (after a reconnect); keeps counts.
    pub fn clear(&mut self) {
        self.framer.clear();
    }

    /// Whether a HIGHRES_IMU of our IMU has been decoded (SCALED_IMU is
    /// then ignored).
    pub fn highres_seen(&self) -> bool {
        self.highres_seen
    }
}

fn decode_frame(
    frame: &[u8],
    imu_id: u8,
    highres_seen: &mut bool,
    out: &mut impl FnMut(Reading),
) -> Outcome {
    let Ok(info) = FrameInfo::parse(frame) else {
        return Outcome::Malformed;
    };
    // Put back the zeros a v2 sender truncated; ignore bytes past 255.
    let mut payload = [0u8; 255];
    let got = frame.get(info.header_len..info.crc_at()).unwrap_or(&[]);
    if let Some(dst) = payload.get_mut(..got.len()) {
        dst.copy_from_slice(got);
    }
    match info.msgid {
        HIGHRES_IMU_ID => {
            if payload.get(62).copied() != Some(imu_id) {
                return Outcome::Filtered;
            }
            let f = |at: usize| f64::from(le_f32(&payload, at).unwrap_or(f32::NAN));
            let accel_mps2 = [f(8), f(12), f(16)];
            let gyro_rps = [f(20), f(24), f(28)];
            if !accel_mps2.iter().chain(&gyro_rps).all(|v| v.is_finite()) {
                return Outcome::Malformed;
            }
            *highres_seen = true;
            out(Reading::Imu {
                accel_mps2,
                gyro_rps,
                device_time: le_u64(&payload, 0).map(|ticks| DeviceTime {
                    ticks,
                    tick_ns: 1_000,
                    wrap: None,
                }),
            });
            Outcome::Decoded
        }
        SCALED_IMU_ID => {
            if *highres_seen {
                return Outcome::Filtered;
            }
            let i = |at: usize| f64::from(le_i16(&payload, at).unwrap_or(0));
            out(Reading::Imu {
                accel_mps2: [i(4), i(6), i(8)].map(|mg| mg * STANDARD_GRAVITY / 1000.0),
                gyro_rps: [i(10), i(12), i(14)].map(|mrad| mrad / 1000.0),
                device_time: le_u32(&payload, 0).map(|ms| DeviceTime {
                    ticks: u64::from(ms),
                    tick_ns: 1_000_000,
                    wrap: Some(1 << 32),
                }),
            });
            Outcome::Decoded
        }
        _ => Outcome::Unknown,
    }
}

/// Which framing an encoder writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Version {
    /// MAVLink 1 (`0xFE`): no extensions, no truncation.
    V1,
    /// MAVLink 2 (`0xFD`): extensions, trailing zeros truncated, unsigned.
    V2,
}

/// The header fields an encoder writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// Framing.
    pub version: Version,
    /// Sequence number.
    pub seq: u8,
    /// Sender's system id.
    pub sysid: u8,
    /// Sender's component id.
    pub compid: u8,
}

impl Header {
    /// A v2 header from system 1, component 1 (autopilot).
    pub fn v2(seq: u8) -> Self {
        Header {
            version: Version::V2,
            seq,
            sysid: 1,
            compid: 1,
        }
    }

    /// A v1 header from system 1, component 1 (autopilot).
    pub fn v1(seq: u8) -> Self {
        Header {
            version: Version::V1,
            ..Self::v2(seq)
        }
    }
}

/// Writes one frame of message `msgid` with `payload` (v1: sent as is; v2:
/// trailing zeros dropped, at least one byte kept) into `out`; returns its
/// length. `msgid` above 255 cannot go in a v1 frame: it is truncated to its
/// low byte, as is a payload over 255 bytes.
pub fn encode_frame(
    header: &Header,
    msgid: u32,
    crc_extra: u8,
    payload: &[u8],
    out: &mut [u8; MAX_FRAME_LEN],
) -> usize {
    let payload = payload.get(..payload.len().min(255)).unwrap_or(&[]);
    let (header_len, payload) = match header.version {
        Version::V1 => {
            out[..V1_HEADER_LEN].copy_from_slice(&[
                STX_V1,
                payload.len() as u8,
                header.seq,
                header.sysid,
                header.compid,
                msgid.to_le_bytes()[0],
            ]);
            (V1_HEADER_LEN, payload)
        }
        Version::V2 => {
            let keep = payload.iter().rposition(|b| *b != 0).map_or(1, |i| i + 1);
            let payload = payload.get(..keep.min(payload.len())).unwrap_or(&[]);
            let [id0, id1, id2, _] = msgid.to_le_bytes();
            out[..V2_HEADER_LEN].copy_from_slice(&[
                STX_V2,
                payload.len() as u8,
                0,
                0,
                header.seq,
                header.sysid,
                header.compid,
                id0,
                id1,
                id2,
            ]);
            (V2_HEADER_LEN, payload)
        }
    };
    let crc_at = header_len + payload.len();
    out[header_len..crc_at].copy_from_slice(payload);
    let crc = frame_crc(&out[1..crc_at], crc_extra);
    out[crc_at..crc_at + 2].copy_from_slice(&crc.to_le_bytes());
    crc_at + 2
}

/// `x` as an `f32`, saturated at the largest finite `f32` (NaN stays NaN).
fn saturate_f32(x: f64) -> f32 {
    x.clamp(f64::from(f32::MIN), f64::from(f32::MAX)) as f32
}

/// `x / lsb` rounded and saturated into `i16`.
fn saturate_i16(x: f64, lsb: f64) -> i16 {
    crate::frame::saturate_i16(x, lsb)
}

/// Writes a HIGHRES_IMU frame (accel and gyro marked updated; magnetometer,
/// pressure and temperature zero); returns its length.
pub fn encode_highres_imu(
    header: &Header,
    time_usec: u64,
    accel_mps2: [f64; 3],
    gyro_rps: [f64; 3],
    imu_id: u8,
    out: &mut [u8; MAX_FRAME_LEN],
) -> usize {
    let mut p = [0u8; HIGHRES_IMU_LEN];
    p[..8].copy_from_slice(&time_usec.to_le_bytes());
    for (i, v) in accel_mps2.iter().chain(&gyro_rps).enumerate() {
        let at = 8 + 4 * i;
        p[at..at + 4].copy_from_slice(&saturate_f32(*v).to_le_bytes());
    }
    p[60..62].copy_from_slice(&0x003Fu16.to_le_bytes());
    p[62] = imu_id;
    let len = match header.version {
        Version::V1 => HIGHRES_IMU_BASE_LEN,
        Version::V2 => HIGHRES_IMU_LEN,
    };
    encode_frame(
        header,
        HIGHRES_IMU_ID,
        HIGHRES_IMU_CRC_EXTRA,
        &p[..len],
        out,
    )
}

/// Writes a SCALED_IMU frame (accel in mG and gyro in mrad/s, saturated into
/// `i16`; magnetometer and temperature zero); returns its length.
pub fn encode_scaled_imu(
    header: &Header,
    time_boot_ms: u32,
    accel_mps2: [f64; 3],
    gyro_rps: [f64; 3],
    out: &mut [u8; MAX_FRAME_LEN],
) -> usize {
    let mut p = [0u8; SCALED_IMU_LEN];
    p[..4].copy_from_slice(&time_boot_ms.to_le_bytes());
    let accel = accel_mps2.map(|a| saturate_i16(a, STANDARD_GRAVITY / 1000.0));
    let gyro = gyro_rps.map(|w| saturate_i16(w, 1.0 / 1000.0));
    for (i, v) in accel.iter().chain(&gyro).enumerate() {
        let at = 4 + 2 * i;
        p[at..at + 2].copy_from_slice(&v.to_le_bytes());
    }
    let len = match header.version {
        Version::V1 => SCALED_IMU_BASE_LEN,
        Version::V2 => SCALED_IMU_LEN,
    };
    encode_frame(header, SCALED_IMU_ID, SCALED_IMU_CRC_EXTRA, &p[..len], out)
}

/// What [`encode`] cannot do.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    /// Only IMU readings have a MAVLink message here.
    #[error("mavlink::EncodeError::Unsupported: only IMU readings are encoded")]
    Unsupported,
}

/// Writes an IMU reading as HIGHRES_IMU of IMU 0; `time_usec` from its
/// device time (0 without one). Returns the frame length.
pub fn encode(
    reading: &Reading,
    header: &Header,
    out: &mut [u8; MAX_FRAME_LEN],
) -> Result<usize, EncodeError> {
    let Reading::Imu {
        accel_mps2,
        gyro_rps,
        device_time,
    } = reading
    else {
        return Err(EncodeError::Unsupported);
    };
    let time_usec = device_time.map_or(0, |t| {
        u64::try_from(u128::from(t.ticks) * u128::from(t.tick_ns) / 1_000).unwrap_or(u64::MAX)
    });
    Ok(encode_highres_imu(
        header,
        time_usec,
        *accel_mps2,
        *gyro_rps,
        0,
        out,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_matches_the_catalogue_check_value() {
        // CRC-16/MCRF4XX of "123456789" is 0x6F91 (CRC catalogue check).
        assert_eq!(crc_accumulate(0xFFFF, b"123456789"), 0x6F91);
    }

    #[test]
    fn v2_truncates_trailing_zeros_and_the_decoder_restores_them() {
        let mut buf = [0u8; MAX_FRAME_LEN];
        // fields_updated 0x003F is sent as 3F 00 and imu id 0 follows: the
        // last two payload bytes are zero, 61 bytes are sent.
        let n = encode_highres_imu(&Header::v2(3), 7, [1.0; 3], [0.5; 3], 0, &mut buf);
        assert_eq!(buf[1], 61);
        assert_eq!(n, V2_HEADER_LEN + 61 + 2);
        let mut d = Decoder::new();
        let mut got = Vec::new();
        d.push(&buf[..n], &mut |r| got.push(r));
        assert_eq!(got.len(), 1);
    }

    #[test]
    fn scaled_imu_is_a_fallback_until_highres_arrives() {
        let mut buf = [0u8; MAX_FRAME_LEN];
        let mut stream = Vec::new();
        let n = encode_scaled_imu(&Header::v2(0), 10, [0.0; 3], [0.0; 3], &mut buf);
        stream.extend_from_slice(&buf[..n]);
        let n = encode_highres_imu(&Header::v2(1), 20, [0.0; 3], [0.0; 3], 0, &mut buf);
        stream.extend_from_slice(&buf[..n]);
        let n = encode_scaled_imu(&Header::v2(2), 30, [0.0; 3], [0.0; 3], &mut buf);
        stream.extend_from_slice(&buf[..n]);
        let mut d = Decoder::new();
        let mut got = Vec::new();
        d.push(&stream, &mut |r| got.push(r));
        assert_eq!(got.len(), 2);
        assert_eq!(d.stats().filtered, 1);
        assert!(d.highres_seen());
    }

    #[test]
    fn other_imu_ids_are_filtered_and_unknown_flags_rejected() {
        let mut buf = [0u8; MAX_FRAME_LEN];
        let n = encode_highres_imu(&Header::v2(0), 1, [0.0; 3], [0.0; 3], 2, &mut buf);
        let mut d = Decoder::new();
        d.push(&buf[..n], &mut |_| panic!("IMU 2 must be filtered"));
        assert_eq!(d.stats().filtered, 1);
        buf[2] = 0x02; // an incompatibility flag we do not know
        let mut d = Decoder::with_imu_id(2);
        d.push(&buf[..n], &mut |_| panic!("unknown flags must be dropped"));
        assert_eq!(d.stats().bytes_skipped, n as u64);
    }
}
