//! What a device emulator sends: IMU samples, UWB position fixes and UWB
//! two-way ranges turned into timed byte chunks of a device protocol
//! ([`imu_chunks`], [`uwb_chunks`], [`range_chunks`]) for
//! [`crate::emulator::Player`]; `insuwb emulate` and `insuwb demo
//! --via-devices` use it with the recordings of `insuwb_group::recording`.
//!
//! ```
//! use insuwb_devices::play::{imu_chunks, Encoding};
//! use insuwb_devices::Protocol;
//! use insuwb_msg::{Header, ImuSample};
//!
//! let imu: Vec<ImuSample> = (0..10)
//!     .map(|k| ImuSample {
//!         header: Header::new(0, k * 10_000_000),
//!         accel_mps2: [0.0, 0.0, 9.81],
//!         gyro_rps: [0.0; 3],
//!     })
//!     .collect();
//! let chunks = imu_chunks(&imu, &Encoding::new(Protocol::WitMotion))?;
//! // One 0x51 + 0x52 cycle per IMU sample, due when its last byte is in.
//! assert_eq!(chunks.len(), imu.len());
//! assert_eq!(chunks[0].1.len(), 22);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! # The device model
//!
//! - **When bytes leave.** A sample measured at recording time `t` (ns
//!   since the start) is played at `t / speed` after the epoch. On a serial
//!   line of `baud` bauds (8N1) the frame starts then and its last byte
//!   arrives `wire_time_ns(len, baud)` later: the chunk is due then, so a
//!   driver that stamps a frame with "read time minus wire time" (at the
//!   same baud) gets the measurement time back. `baud = 0` (TCP): due at
//!   `t / speed`.
//! - **Device clocks.** MAVLink `time_usec`, NLink `system_time` (ms, wraps
//!   at 2^32) and the Eliko server's Unix time come from a [`DeviceClock`]:
//!   a start value plus the time played since the epoch, scaled by a drift
//!   in ppm. The clock runs in host time (it follows `t / speed`, not `t`),
//!   as a real device's would. WitMotion frames and DWM1001 lines carry no
//!   clock.
//! - **Ranging rounds.** A tag ranges to its anchors in rounds and reports
//!   a round at once: the ranges of one round ([`range_rounds`]) share
//!   their measurement time and become one chunk (a DWM1001 `lec` line on
//!   its 115200-baud UART, an NLink Tag_Frame0), due when its last byte
//!   arrives, as above.
//!
//! Pure and deterministic: the same samples and encoding give the same
//! bytes.

use crate::frame::wire_time_ns;
use crate::{dwm1001, eliko, mavlink, nlink, witmotion, Protocol};
use insuwb_msg::{ImuSample, UwbFix, UwbRange};

/// Temperature written in WitMotion frames, C.
pub const WITMOTION_TEMPERATURE_C: f64 = 25.0;

/// Default device-clock start of MAVLink (`time_usec`, since boot) and
/// NLink (`system_time`): 10 s, ns.
pub const DEFAULT_BOOT_CLOCK_START_NS: u64 = 10_000_000_000;

/// Default Eliko server Unix time at the epoch: 2023-11-14 22:13:20 UTC,
/// ns (fixed, so that runs are reproducible).
pub const DEFAULT_UNIX_CLOCK_START_NS: u64 = 1_700_000_000_000_000_000;

/// Default baud rate of the serial line modelled for serial protocols.
pub const DEFAULT_SERIAL_BAUD: u32 = 115_200;

/// A device's own clock: `start_ns` at the epoch, then running with the
/// host's clock `1 + drift_ppm * 1e-6` times as fast.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceClock {
    /// Device time at the epoch, ns.
    pub start_ns: u64,
    /// How much faster than the host the device clock runs, ppm (negative:
    /// slower).
    pub drift_ppm: f64,
}

impl DeviceClock {
    /// The protocol's default clock: 10 s since boot (MAVLink, NLink; also
    /// WitMotion and DWM1001, which send none), a fixed Unix time (Eliko),
    /// no drift.
    #[must_use]
    pub fn default_for(protocol: Protocol) -> Self {
        let start_ns = match protocol {
            Protocol::Eliko => DEFAULT_UNIX_CLOCK_START_NS,
            Protocol::WitMotion | Protocol::Mavlink | Protocol::Nlink | Protocol::Dwm1001 => {
                DEFAULT_BOOT_CLOCK_START_NS
            }
        };
        Self {
            start_ns,
            drift_ppm: 0.0,
        }
    }

    /// The device time when the host is `since_epoch_ns` past the epoch, ns.
    #[must_use]
    pub fn at(&self, since_epoch_ns: u64) -> u64 {
        #[allow(clippy::cast_precision_loss, clippy::cast_possible_truncation)]
        let extra = (since_epoch_ns as f64 * self.drift_ppm * 1e-6).round() as i64;
        self.start_ns
            .saturating_add(since_epoch_ns)
            .saturating_add_signed(extra)
    }
}

/// How samples become bytes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Encoding {
    /// The device protocol.
    pub protocol: Protocol,
    /// The device's clock (ignored by WitMotion and DWM1001).
    pub clock: DeviceClock,
    /// Serial line modelled for the wire time (0: none, as over TCP).
    pub baud: u32,
    /// UWB tag id (NLink: 0 to 255; not sent by DWM1001).
    pub tag: u32,
    /// Play speed (1: real time); finite and > 0.
    pub speed: f64,
}

impl Encoding {
    /// The protocol with its default clock, tag 1, real time, and a
    /// [`DEFAULT_SERIAL_BAUD`] line for the serial protocols (none for
    /// Eliko, which is TCP).
    #[must_use]
    pub fn new(protocol: Protocol) -> Self {
        Self {
            protocol,
            clock: DeviceClock::default_for(protocol),
            baud: if protocol == Protocol::Eliko {
                0
            } else {
                DEFAULT_SERIAL_BAUD
            },
            tag: 1,
            speed: 1.0,
        }
    }

    /// Host time since the epoch at which a sample of recording time `t_ns`
    /// is measured: `t / speed`.
    #[must_use]
    pub fn played_at(&self, t_ns: u64) -> u64 {
        #[allow(
            clippy::cast_precision_loss,
            clippy::cast_possible_truncation,
            clippy::cast_sign_loss
        )]
        let ns = (t_ns as f64 / self.speed).round() as u64;
        ns
    }
}

/// Why samples could not be encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    /// The protocol does not carry this kind of sample (IMU samples:
    /// witmotion or mavlink; UWB positions: nlink, eliko or dwm1001; UWB
    /// ranges: nlink or dwm1001).
    #[error("EncodeError::WrongProtocol: {protocol} does not carry {what}")]
    WrongProtocol {
        /// The protocol asked for.
        protocol: Protocol,
        /// `IMU samples`, `UWB positions` or `UWB ranges`.
        what: &'static str,
    },
    /// An anchor id the protocol cannot carry (NLink: 0 to 7, its `dis`
    /// slots; DWM1001: a 16-bit short address).
    #[error("EncodeError::AnchorTooLarge: {protocol} anchor ids are 0 to {max}, got {anchor}")]
    AnchorTooLarge {
        /// The protocol asked for.
        protocol: Protocol,
        /// The anchor id refused.
        anchor: u32,
        /// The largest id the protocol carries.
        max: u32,
    },
    /// One round has two ranges to the same anchor (NLink has one slot per
    /// anchor).
    #[error("EncodeError::DuplicateAnchor: {protocol} carries one range per anchor in a round, anchor {anchor} has two")]
    DuplicateAnchor {
        /// The protocol asked for.
        protocol: Protocol,
        /// The anchor ranged twice.
        anchor: u32,
    },
    /// A round has more anchors than one DWM1001 line holds.
    #[error("EncodeError::TooManyAnchors: {protocol} carries at most {max} anchors a round, got {count}")]
    TooManyAnchors {
        /// The protocol asked for.
        protocol: Protocol,
        /// Ranges in the round.
        count: usize,
        /// The most the protocol carries.
        max: usize,
    },
    /// A position, range or anchor position is NaN or infinite.
    #[error("EncodeError::NotFinite: {0} is not finite")]
    NotFinite(&'static str),
    /// The speed is not a finite number > 0.
    #[error("EncodeError::BadSpeed: the speed must be a finite number > 0")]
    BadSpeed,
    /// An NLink tag id is 8 bits.
    #[error("EncodeError::TagTooLarge: NLink tag ids are 0 to 255, got {0}")]
    TagTooLarge(u32),
    /// An encoder refused a sample (a buffer too small: a bug).
    #[error("EncodeError::Encoder: {0}")]
    Encoder(&'static str),
}

fn check_speed(enc: &Encoding) -> Result<(), EncodeError> {
    if enc.speed.is_finite() && enc.speed > 0.0 {
        Ok(())
    } else {
        Err(EncodeError::BadSpeed)
    }
}

/// One chunk per IMU sample: a WitMotion 0x51 + 0x52 cycle or a MAVLink v2
/// HIGHRES_IMU (IMU id 0, `time_usec` from the device clock, sequence
/// numbers counting up). Each is due, in ns after the epoch, when its last
/// byte arrives (see the module doc).
///
/// # Errors
/// [`EncodeError::WrongProtocol`], [`EncodeError::BadSpeed`].
pub fn imu_chunks(
    samples: &[ImuSample],
    enc: &Encoding,
) -> Result<Vec<(u64, Vec<u8>)>, EncodeError> {
    check_speed(enc)?;
    let mut out = Vec::with_capacity(samples.len());
    let mut buf = [0_u8; mavlink::MAX_FRAME_LEN];
    let mut seq = 0_u8;
    for s in samples {
        let at = enc.played_at(s.header.meas_time_ns);
        let bytes: Vec<u8> = match enc.protocol {
            Protocol::WitMotion => {
                witmotion::encode_imu(s.accel_mps2, s.gyro_rps, WITMOTION_TEMPERATURE_C).to_vec()
            }
            Protocol::Mavlink => {
                let time_usec = enc.clock.at(at) / 1_000;
                let n = mavlink::encode_highres_imu(
                    &mavlink::Header::v2(seq),
                    time_usec,
                    s.accel_mps2,
                    s.gyro_rps,
                    0,
                    &mut buf,
                );
                seq = seq.wrapping_add(1);
                buf.get(..n)
                    .ok_or(EncodeError::Encoder("mavlink frame length"))?
                    .to_vec()
            }
            protocol @ (Protocol::Nlink | Protocol::Eliko | Protocol::Dwm1001) => {
                return Err(EncodeError::WrongProtocol {
                    protocol,
                    what: "IMU samples",
                })
            }
        };
        let due = at.saturating_add(wire_time_ns(bytes.len(), enc.baud));
        out.push((due, bytes));
    }
    Ok(out)
}

/// One chunk per fix: an NLink Tag_Frame0 (tag id, role 2 (tag), position,
/// velocity when the fix has one (else zero), no anchor ranges, both clocks
/// from the device clock in ms), an Eliko COORD line (8-bit sequence
/// counting up, the tag, position, the server's Unix time) or a DWM1001
/// `lep` line (position, quality factor 100). Each is due, in ns after the
/// epoch, when its last byte arrives (see the module doc).
///
/// # Errors
/// [`EncodeError::WrongProtocol`], [`EncodeError::BadSpeed`],
/// [`EncodeError::TagTooLarge`], [`EncodeError::NotFinite`] (DWM1001).
pub fn uwb_chunks(fixes: &[UwbFix], enc: &Encoding) -> Result<Vec<(u64, Vec<u8>)>, EncodeError> {
    check_speed(enc)?;
    let mut out = Vec::with_capacity(fixes.len());
    let mut line = [0_u8; eliko::MAX_LINE_LEN];
    let mut seq = 0_u8;
    for f in fixes {
        let at = enc.played_at(f.header.meas_time_ns);
        let device_ns = enc.clock.at(at);
        let bytes: Vec<u8> = match enc.protocol {
            Protocol::Nlink => {
                let id = u8::try_from(enc.tag).map_err(|_| EncodeError::TagTooLarge(enc.tag))?;
                // The counter wraps at 2^32 ms: keep the low 32 bits.
                let ms = (device_ns / 1_000_000).to_le_bytes();
                let ms = u32::from_le_bytes([ms[0], ms[1], ms[2], ms[3]]);
                let vel_valid = f.header.flags & UwbFix::FLAG_VEL_VALID != 0;
                nlink::TagFrame {
                    id,
                    role: 2,
                    pos_m: f.pos_m,
                    vel_mps: if vel_valid { f.vel_mps } else { [0.0; 3] },
                    ranges_m: [0.0; 8],
                    local_time_ms: ms,
                    system_time_ms: ms,
                    voltage_v: 5.0,
                }
                .encode()
                .to_vec()
            }
            Protocol::Eliko => {
                let n =
                    eliko::encode_coord(seq, enc.tag, Some(f.pos_m), device_ns / 1_000, &mut line)
                        .map_err(|_| EncodeError::Encoder("eliko line length"))?;
                seq = seq.wrapping_add(1);
                line.get(..n)
                    .ok_or(EncodeError::Encoder("eliko line length"))?
                    .to_vec()
            }
            Protocol::Dwm1001 => {
                let mut bytes = Vec::with_capacity(64);
                dwm1001::encode_lep(f.pos_m, dwm1001::MAX_QUALITY, &mut bytes)
                    .map_err(|_| EncodeError::NotFinite("a UWB position"))?;
                bytes
            }
            protocol @ (Protocol::WitMotion | Protocol::Mavlink) => {
                return Err(EncodeError::WrongProtocol {
                    protocol,
                    what: "UWB positions",
                })
            }
        };
        let due = at.saturating_add(wire_time_ns(bytes.len(), enc.baud));
        out.push((due, bytes));
    }
    Ok(out)
}

/// The ranging rounds of `ranges`, in order: a round is a run of ranges
/// with equal `meas_time_ns`, ended early by one with
/// [`UwbRange::FLAG_EPOCH_END`].
#[must_use]
pub fn range_rounds(ranges: &[UwbRange]) -> Vec<&[UwbRange]> {
    let mut rounds = Vec::new();
    let mut rest = ranges;
    while let Some(first) = rest.first() {
        let t = first.header.meas_time_ns;
        let len = rest
            .iter()
            .position(|r| r.header.flags & UwbRange::FLAG_EPOCH_END != 0)
            .map_or(rest.len(), |end| end + 1);
        let len = rest
            .iter()
            .take(len)
            .position(|r| r.header.meas_time_ns != t)
            .unwrap_or(len);
        let (round, tail) = rest.split_at(len);
        rounds.push(round);
        rest = tail;
    }
    rounds
}

/// One chunk per ranging round ([`range_rounds`]), measured at its ranges'
/// time: a DWM1001 `lec` line (the anchors in order, with their ids as
/// 16-bit short addresses, positions and ranges, no position estimate) or
/// an NLink Tag_Frame0 (tag id, role 2, the ranges in `dis[anchor]` for
/// anchors 0 to 7, the other slots 0, position and velocity 0, both clocks
/// from the device clock in ms). A range of 0 m is sent, but NLink's 0
/// means "not heard". Each chunk is due, in ns after the epoch, when its
/// last byte arrives (see the module doc).
///
/// # Errors
/// [`EncodeError::WrongProtocol`] (protocols that carry no ranges),
/// [`EncodeError::BadSpeed`], [`EncodeError::TagTooLarge`] (NLink),
/// [`EncodeError::AnchorTooLarge`], [`EncodeError::DuplicateAnchor`]
/// (NLink), [`EncodeError::TooManyAnchors`] (DWM1001),
/// [`EncodeError::NotFinite`].
pub fn range_chunks(
    ranges: &[UwbRange],
    enc: &Encoding,
) -> Result<Vec<(u64, Vec<u8>)>, EncodeError> {
    check_speed(enc)?;
    let protocol = enc.protocol;
    if !matches!(protocol, Protocol::Nlink | Protocol::Dwm1001) {
        return Err(EncodeError::WrongProtocol {
            protocol,
            what: "UWB ranges",
        });
    }
    let rounds = range_rounds(ranges);
    let mut out = Vec::with_capacity(rounds.len());
    for round in rounds {
        let t = round.first().map_or(0, |r| r.header.meas_time_ns);
        let at = enc.played_at(t);
        let bytes = if protocol == Protocol::Nlink {
            nlink_round(round, enc, at)?
        } else {
            dwm1001_round(round)?
        };
        let due = at.saturating_add(wire_time_ns(bytes.len(), enc.baud));
        out.push((due, bytes));
    }
    Ok(out)
}

/// A Tag_Frame0 with the round's ranges in `dis[anchor]`.
fn nlink_round(round: &[UwbRange], enc: &Encoding, at: u64) -> Result<Vec<u8>, EncodeError> {
    const PROTOCOL: Protocol = Protocol::Nlink;
    let id = u8::try_from(enc.tag).map_err(|_| EncodeError::TagTooLarge(enc.tag))?;
    let mut ranges_m = [0.0; 8];
    let mut seen = [false; 8];
    for r in round {
        let too_large = EncodeError::AnchorTooLarge {
            protocol: PROTOCOL,
            anchor: r.anchor,
            max: 7,
        };
        let slot = usize::try_from(r.anchor).map_err(|_| too_large)?;
        let (Some(d), Some(seen)) = (ranges_m.get_mut(slot), seen.get_mut(slot)) else {
            return Err(too_large);
        };
        if std::mem::replace(seen, true) {
            return Err(EncodeError::DuplicateAnchor {
                protocol: PROTOCOL,
                anchor: r.anchor,
            });
        }
        if !r.range_m.is_finite() {
            return Err(EncodeError::NotFinite("a UWB range"));
        }
        *d = r.range_m;
    }
    // The counter wraps at 2^32 ms: keep the low 32 bits.
    let ms = (enc.clock.at(at) / 1_000_000).to_le_bytes();
    let ms = u32::from_le_bytes([ms[0], ms[1], ms[2], ms[3]]);
    Ok(nlink::TagFrame {
        id,
        role: 2,
        ranges_m,
        local_time_ms: ms,
        system_time_ms: ms,
        voltage_v: 5.0,
        ..nlink::TagFrame::default()
    }
    .encode()
    .to_vec())
}

/// A `lec` line of the round.
fn dwm1001_round(round: &[UwbRange]) -> Result<Vec<u8>, EncodeError> {
    const PROTOCOL: Protocol = Protocol::Dwm1001;
    if round.len() > dwm1001::MAX_ANCHORS {
        return Err(EncodeError::TooManyAnchors {
            protocol: PROTOCOL,
            count: round.len(),
            max: dwm1001::MAX_ANCHORS,
        });
    }
    let mut anchors = [dwm1001::AnchorRange::default(); dwm1001::MAX_ANCHORS];
    for (slot, r) in anchors.iter_mut().zip(round) {
        if r.anchor > 0xFFFF {
            return Err(EncodeError::AnchorTooLarge {
                protocol: PROTOCOL,
                anchor: r.anchor,
                max: 0xFFFF,
            });
        }
        *slot = dwm1001::AnchorRange {
            id: r.anchor,
            pos_m: r.anchor_pos_m,
            range_m: r.range_m,
        };
    }
    let mut bytes = Vec::with_capacity(dwm1001::NOMINAL_LINE_LEN);
    let anchors = anchors.get(..round.len()).unwrap_or(&[]);
    dwm1001::encode_lec(anchors, None, &mut bytes).map_err(|e| match e {
        dwm1001::EncodeError::NotFinite => EncodeError::NotFinite("a UWB range or anchor position"),
        _ => EncodeError::Encoder("dwm1001 lec line"),
    })?;
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

    use super::*;
    use crate::frame::{AnyDecoder, Reading};
    use insuwb_msg::Header;

    fn imu(t_ns: u64, a: f64) -> ImuSample {
        ImuSample {
            header: Header::new(0, t_ns),
            accel_mps2: [a, -a, 9.81],
            gyro_rps: [0.01, -0.02, a / 10.0],
        }
    }

    fn fix(t_ns: u64, x: f64, vel: bool) -> UwbFix {
        let mut f = UwbFix {
            header: Header::new(0, t_ns),
            pos_m: [x, -x, 0.3],
            vel_mps: [0.5, -0.25, 0.0],
            ..UwbFix::default()
        };
        if vel {
            f.header.flags |= UwbFix::FLAG_VEL_VALID;
        }
        f
    }

    fn decode(protocol: Protocol, chunks: &[(u64, Vec<u8>)]) -> Vec<Reading> {
        let mut d = AnyDecoder::new(protocol);
        let mut out = Vec::new();
        for (_, b) in chunks {
            d.push(b, &mut |r| out.push(r));
        }
        out
    }

    #[test]
    fn device_clock_adds_drift_in_ppm() {
        let c = DeviceClock {
            start_ns: 5,
            drift_ppm: 100.0,
        };
        assert_eq!(c.at(0), 5);
        assert_eq!(c.at(10_000_000_000), 5 + 10_000_000_000 + 1_000_000);
        let slow = DeviceClock {
            start_ns: 0,
            drift_ppm: -50.0,
        };
        assert_eq!(slow.at(1_000_000_000), 1_000_000_000 - 50_000);
    }

    #[test]
    fn witmotion_chunks_are_due_after_their_wire_time_and_decode_back() {
        let samples: Vec<ImuSample> = (0..5)
            .map(|k| imu(10_000_000 * (k + 1), k as f64))
            .collect();
        let enc = Encoding::new(Protocol::WitMotion);
        let chunks = imu_chunks(&samples, &enc).unwrap();
        // 22 bytes at 115200 baud, 8N1: 220 bits = 1_909_722 ns.
        assert_eq!(chunks[0].0, 10_000_000 + 1_909_722);
        assert_eq!(chunks[4].0, 50_000_000 + 1_909_722);
        let got = decode(Protocol::WitMotion, &chunks);
        assert_eq!(got.len(), 5);
        for (r, s) in got.iter().zip(&samples) {
            let Reading::Imu {
                accel_mps2,
                gyro_rps,
                device_time: None,
            } = r
            else {
                panic!("{r:?}")
            };
            for i in 0..3 {
                // Half an LSB: 16 g / 32768 / 2 and 2000 deg/s / 32768 / 2.
                assert!((accel_mps2[i] - s.accel_mps2[i]).abs() <= 0.0024, "{r:?}");
                assert!((gyro_rps[i] - s.gyro_rps[i]).abs() <= 5.4e-4, "{r:?}");
            }
        }
    }

    #[test]
    fn mavlink_time_usec_follows_the_device_clock_at_the_play_speed() {
        let samples = [imu(1_000_000_000, 0.0), imu(3_000_000_000, 1.0)];
        let enc = Encoding {
            clock: DeviceClock {
                start_ns: 7_000_000_000,
                drift_ppm: 100.0,
            },
            baud: 0,
            speed: 2.0,
            ..Encoding::new(Protocol::Mavlink)
        };
        let chunks = imu_chunks(&samples, &enc).unwrap();
        assert_eq!(chunks[0].0, 500_000_000);
        assert_eq!(chunks[1].0, 1_500_000_000);
        let got = decode(Protocol::Mavlink, &chunks);
        let times: Vec<u64> = got
            .iter()
            .map(|r| match r {
                Reading::Imu {
                    device_time: Some(t),
                    ..
                } => t.ticks * t.tick_ns,
                _ => panic!("{r:?}"),
            })
            .collect();
        // 7 s + 0.5 s * (1 + 100e-6) and 7 s + 1.5 s * (1 + 100e-6).
        assert_eq!(times, vec![7_500_050_000, 8_500_150_000]);
    }

    #[test]
    fn nlink_frames_carry_position_velocity_tag_and_wrapping_ms() {
        let fixes = [fix(100_000_000, 1.25, true), fix(200_000_000, 2.5, false)];
        let enc = Encoding {
            clock: DeviceClock {
                start_ns: (u64::from(u32::MAX) - 50) * 1_000_000,
                drift_ppm: 0.0,
            },
            tag: 7,
            ..Encoding::new(Protocol::Nlink)
        };
        let chunks = uwb_chunks(&fixes, &enc).unwrap();
        // 128 bytes at 115200 baud: 11_111_111 ns on the wire.
        assert_eq!(chunks[0].0, 100_000_000 + 11_111_111);
        let positions: Vec<Reading> = decode(Protocol::Nlink, &chunks)
            .into_iter()
            .filter(|r| matches!(r, Reading::Position { .. }))
            .collect();
        assert_eq!(positions.len(), 2);
        let Reading::Position {
            tag: 7,
            pos_m,
            vel_mps: Some(v),
            device_time: Some(t),
            ..
        } = positions[0]
        else {
            panic!("{:?}", positions[0])
        };
        assert!((pos_m[0] - 1.25).abs() < 1e-9 && (v[0] - 0.5).abs() < 1e-9);
        // 2^32 - 50 ms + 100 ms wraps to 49 ms.
        assert_eq!(t.ticks, 49);
        let Reading::Position {
            vel_mps: Some(v2), ..
        } = positions[1]
        else {
            panic!()
        };
        assert_eq!(v2, [0.0; 3]);
        let too_big = Encoding { tag: 256, ..enc };
        assert_eq!(
            uwb_chunks(&fixes, &too_big),
            Err(EncodeError::TagTooLarge(256))
        );
    }

    #[test]
    fn eliko_lines_carry_seq_tag_and_unix_time_without_wire_time() {
        let fixes: Vec<UwbFix> = (1..=300).map(|k| fix(k * 100_000_000, 0.5, true)).collect();
        let enc = Encoding {
            tag: 0x1A2B,
            ..Encoding::new(Protocol::Eliko)
        };
        let chunks = uwb_chunks(&fixes, &enc).unwrap();
        assert_eq!(chunks[0].0, 100_000_000);
        let text = String::from_utf8(chunks[0].1.clone()).unwrap();
        assert_eq!(
            text,
            "$PEKIO,COORD,0,0x001A2B,0.500,-0.500,0.300,,1700000000.100000\r\n"
        );
        let mut d = crate::eliko::Decoder::with_tags([0x1A2B]);
        let mut n = 0;
        for (_, b) in &chunks {
            d.push(b, &mut |_| n += 1);
        }
        // 300 lines, sequence wrapping at 256 without a gap.
        assert_eq!(n, 300);
        assert_eq!(d.stats().seq_gaps, 0);
    }

    fn range(t_ns: u64, anchor: u32, range_m: f64, end: bool) -> UwbRange {
        let mut r = UwbRange {
            header: Header::new(0, t_ns),
            anchor,
            range_m,
            anchor_pos_m: [f64::from(anchor % 7), -1.25, 2.5],
            ..UwbRange::default()
        };
        if end {
            r.header.flags |= UwbRange::FLAG_EPOCH_END;
        }
        r
    }

    /// Four anchors ranged at each of `times`, the last flagged.
    fn rounds(times: &[u64], ids: [u32; 4]) -> Vec<UwbRange> {
        times
            .iter()
            .flat_map(|&t| {
                ids.iter()
                    .enumerate()
                    .map(move |(i, &id)| range(t, id, 1.0 + i as f64 + t as f64 * 1e-9, i == 3))
            })
            .collect()
    }

    #[test]
    fn rounds_end_at_the_flag_or_a_new_time() {
        let ranges = [
            range(1, 0, 1.0, false),
            range(1, 1, 1.0, false),
            range(1, 2, 1.0, true),
            range(1, 3, 1.0, false),
            range(2, 0, 1.0, false),
            range(2, 1, 1.0, false),
            range(3, 0, 1.0, true),
        ];
        let sizes: Vec<usize> = range_rounds(&ranges).iter().map(|r| r.len()).collect();
        assert_eq!(sizes, vec![3, 1, 2, 1]);
        assert!(range_rounds(&[]).is_empty());
    }

    #[test]
    fn dwm1001_rounds_are_lec_lines_that_decode_back() {
        let ids = [0x0C2B, 0x9825, 0x14D0, 0x18A9];
        let ranges = rounds(&[100_000_000, 200_000_000], ids);
        let enc = Encoding::new(Protocol::Dwm1001);
        let chunks = range_chunks(&ranges, &enc).unwrap();
        assert_eq!(chunks.len(), 2);
        let line = String::from_utf8(chunks[0].1.clone()).unwrap();
        assert_eq!(
            line,
            "DIST,4,AN0,0C2B,0.00,-1.25,2.50,1.10,AN1,9825,1.00,-1.25,2.50,2.10,\
             AN2,14D0,1.00,-1.25,2.50,3.10,AN3,18A9,6.00,-1.25,2.50,4.10\r\n"
        );
        // On a 115200-baud line: due when the last byte is in.
        assert_eq!(chunks[0].0, 100_000_000 + wire_time_ns(line.len(), 115_200));
        let got = decode(Protocol::Dwm1001, &chunks);
        assert_eq!(got.len(), 8);
        for (r, want) in got.iter().zip(&ranges) {
            let Reading::Range {
                anchor,
                range_m,
                anchor_pos_m: Some(pos),
                quality: None,
                last_of_round,
                device_time: None,
            } = *r
            else {
                panic!("{r:?}")
            };
            assert_eq!(anchor, want.anchor);
            assert!((range_m - want.range_m).abs() <= 0.005, "{r:?}");
            assert_eq!(pos, want.anchor_pos_m);
            assert_eq!(
                last_of_round,
                want.header.flags & UwbRange::FLAG_EPOCH_END != 0
            );
        }
        let too_many: Vec<UwbRange> = (0..17).map(|a| range(0, a, 1.0, false)).collect();
        assert_eq!(
            range_chunks(&too_many, &enc),
            Err(EncodeError::TooManyAnchors {
                protocol: Protocol::Dwm1001,
                count: 17,
                max: 16
            })
        );
        let wide = [range(0, 0x1_0000, 1.0, true)];
        assert!(matches!(
            range_chunks(&wide, &enc),
            Err(EncodeError::AnchorTooLarge {
                anchor: 0x1_0000,
                max: 0xFFFF,
                ..
            })
        ));
    }

    #[test]
    fn nlink_rounds_fill_dis_by_anchor_and_refuse_other_anchors() {
        let ranges = rounds(&[100_000_000, 200_000_000], [3, 0, 5, 1]);
        let enc = Encoding {
            tag: 9,
            ..Encoding::new(Protocol::Nlink)
        };
        let chunks = range_chunks(&ranges, &enc).unwrap();
        assert_eq!(chunks.len(), 2);
        assert_eq!(chunks[1].0, 200_000_000 + 11_111_111);
        let got: Vec<Reading> = decode(Protocol::Nlink, &chunks)
            .into_iter()
            .filter(|r| matches!(r, Reading::Range { .. }))
            .collect();
        // Decoded in anchor order; the last heard anchor closes the round.
        let mut want: Vec<&UwbRange> = ranges[..4].iter().collect();
        want.sort_by_key(|r| r.anchor);
        for (r, w) in got[..4].iter().zip(want) {
            let Reading::Range {
                anchor,
                range_m,
                anchor_pos_m: None,
                last_of_round,
                device_time: Some(t),
                ..
            } = *r
            else {
                panic!("{r:?}")
            };
            assert_eq!(anchor, w.anchor);
            assert!((range_m - w.range_m).abs() <= 0.0005, "{r:?}");
            assert_eq!(last_of_round, anchor == 5);
            // 10 s at the epoch plus 100 ms.
            assert_eq!(t.ticks, 10_100);
        }
        let err = range_chunks(&[range(0, 8, 1.0, true)], &enc).unwrap_err();
        assert_eq!(
            err,
            EncodeError::AnchorTooLarge {
                protocol: Protocol::Nlink,
                anchor: 8,
                max: 7
            }
        );
        assert_eq!(
            err.to_string(),
            "EncodeError::AnchorTooLarge: nlink anchor ids are 0 to 7, got 8"
        );
        let twice = [range(0, 2, 1.0, false), range(0, 2, 2.0, true)];
        assert_eq!(
            range_chunks(&twice, &enc),
            Err(EncodeError::DuplicateAnchor {
                protocol: Protocol::Nlink,
                anchor: 2
            })
        );
        assert_eq!(
            range_chunks(&[range(0, 2, f64::NAN, true)], &enc),
            Err(EncodeError::NotFinite("a UWB range"))
        );
    }

    #[test]
    fn dwm1001_fixes_are_lep_lines() {
        let fixes = [fix(100_000_000, 1.25, true)];
        let chunks = uwb_chunks(&fixes, &Encoding::new(Protocol::Dwm1001)).unwrap();
        assert_eq!(chunks[0].1, b"POS,1.25,-1.25,0.30,100\r\n");
        assert_eq!(
            decode(Protocol::Dwm1001, &chunks),
            vec![Reading::Position {
                tag: 0,
                pos_m: [1.25, -1.25, 0.3],
                vel_mps: None,
                device_time: None,
                seq: None,
            }]
        );
    }

    #[test]
    fn protocols_refuse_the_other_kind_of_sample_and_bad_speeds() {
        for protocol in [Protocol::WitMotion, Protocol::Mavlink, Protocol::Eliko] {
            let err = range_chunks(&[range(0, 0, 1.0, true)], &Encoding::new(protocol));
            assert_eq!(
                err,
                Err(EncodeError::WrongProtocol {
                    protocol,
                    what: "UWB ranges"
                })
            );
        }
        assert_eq!(
            imu_chunks(&[imu(0, 0.0)], &Encoding::new(Protocol::Dwm1001))
                .unwrap_err()
                .to_string(),
            "EncodeError::WrongProtocol: dwm1001 does not carry IMU samples"
        );
        let imu_enc = Encoding::new(Protocol::Eliko);
        assert!(matches!(
            imu_chunks(&[imu(0, 0.0)], &imu_enc),
            Err(EncodeError::WrongProtocol { .. })
        ));
        let uwb_enc = Encoding::new(Protocol::WitMotion);
        assert!(matches!(
            uwb_chunks(&[fix(0, 0.0, false)], &uwb_enc),
            Err(EncodeError::WrongProtocol { .. })
        ));
        for speed in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let enc = Encoding {
                speed,
                ..Encoding::new(Protocol::WitMotion)
            };
            assert_eq!(imu_chunks(&[], &enc), Err(EncodeError::BadSpeed));
        }
    }
}
