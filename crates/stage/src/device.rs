//! The driver loop over a real sensor (`sources.imu` or `sources.uwb` =
//! `"device"`, configured in `[devices.imu]` / `[devices.uwb]`): a
//! [`Link`] that reconnects, the protocol's [`AnyDecoder`], one
//! [`ClockFilter`] for the device's own clock, and the conversion of each
//! [`Reading`] into the sample the group expects (an [`ImuSample`] on topic
//! `imu`, a [`UwbFix`] on topic `uwb_fix`, with `[uwb] kind = "twr"` a
//! [`UwbRange`] on topic `uwb_range` and the fixes built from them). It owns
//! the driver's heartbeat while a device is the source.
//!
//! # Time stamps
//!
//! Bytes are handed to the decoder one at a time, so the byte that completes
//! a reading is known: the reading was sent at the host time of the read
//! minus the wire time ([`wire_time_ns`] at the configured baud; 0 over TCP)
//! of the bytes read after it and of the reading's own frames (two WitMotion
//! frames, the DWM1001 line as long as it was, one frame of the other
//! protocols). When the reading carries a
//! device time (MAVLink `time_usec`/`time_boot_ms`, NLink `system_time`,
//! Eliko Unix time), that pair feeds the [`ClockFilter`] and the sample is
//! stamped with the filter's mapping of the device time, which removes the
//! random read delay. A device clock that repeats its value for
//! [`CLOCK_REPEATS_MAX`] readings in a row is too coarse for the reading
//! rate: it is left for host times, with a warning.
//!
//! # Samples
//!
//! IMU: accelerations and rates are rotated from the sensor to the body
//! frame by `rotation_deg` = roll, pitch, yaw (degrees):
//! `v_body = Rz(yaw) Ry(pitch) Rx(roll) v_sensor`. UWB: position readings of
//! the configured tag (`tag_id`, 0 = any) become fixes with
//! `pos_cov = position_sigma_m^2 I`, `gdop` 1, `n_meas` 0. The velocity is
//! the device's own where it sends one (NLink), else the sliding-window
//! regression the TDOA fix builder uses (`insuwb_uwb::velocity`, settings
//! from the fusion config's `[fusion.fix.velocity]`); `vel_cov` is the
//! regression's in both cases, and [`UwbFix::FLAG_VEL_VALID`] is set once
//! the regression window is valid. The fix is the antenna's position; the
//! antenna lever arm (`lever_arm_m`) is applied by the loose filters in the
//! fusion stage (`[fusion.loose] lever_arm_m`, see `RobotConfig::fusion_config`).
//!
//! UWB with `[uwb] kind = "twr"` (DWM1001, NLink): the device's positions
//! are ignored and each range reading becomes a [`UwbRange`]. The ranges of
//! one round (one line or frame) share one stamp, the round's (its device
//! time through the clock filter once); the last carries
//! [`UwbRange::FLAG_EPOCH_END`], one with a device quality
//! [`UwbRange::FLAG_QUALITY`]. The anchor's position is the configured one
//! (`[[devices.uwb.anchors]]`), else the device's; a range to an anchor of
//! neither is dropped (`dropped_invalid`, a warning once per anchor naming
//! the key to add). Each range then takes the recorded sources' path
//! (`driver::uwb::take_range`: gate, range offset, fix builder with
//! `[fusion.fix]`); the fix it completes is published before it. A round
//! whose last range was dropped is closed all the same
//! ([`FixBuilder::flush`]).
//!
//! All drop and count samples with a NaN, infinite or out-of-range value
//! (`Health::dropped_invalid`: the IMU limits of [`crate::driver`]; a
//! position beyond [`MAX_POS_M`] or a device velocity beyond
//! [`MAX_VEL_MPS`]; a range the gate refuses for its values) and samples
//! whose time is not after the previous one (`Health::dropped_time`; for
//! ranges, a round's stamp, and the gate's time refusals).
//!
//! # Heartbeat
//!
//! State [`HealthState::Disconnected`] while the link is down,
//! [`HealthState::Ok`] while valid frames arrive, and
//! [`HealthState::Degraded`] when connected but no valid frame came for
//! [`SILENT_NS`] or the decoder has seen `wrong_baud_bytes` bytes without a
//! valid frame (then an error names the port, the baud rate and the
//! protocol, once per episode; the driver keeps reading: the device may be
//! fixed while it runs). A change of state is published at once, besides the
//! periodic heartbeat. Counters: `received` valid frames, `published`
//! samples (fixes and ranges with two-way ranging), `dropped_invalid`,
//! `dropped_time`, `seq_gaps` the device's own sequence gaps (Eliko), and
//! [`DeviceCounters`]: decoder resynchronisations plus checksum errors,
//! link reconnections (connections after the first), and the device
//! clock's offset (host minus device, ns) and drift (ppb), `None` while
//! unknown.
//!
//! The loop allocates nothing per sample: a fixed read buffer, decoders with
//! fixed buffers, a regression window and a fix builder's tables allocated
//! once (the range solver of `insuwb_uwb` allocates per fix).

use std::time::Duration;

use anyhow::Result;
use insuwb_devices::clock::{ClockConfig, ClockEvent, ClockFilter};
use insuwb_devices::frame::{wire_time_ns, AnyDecoder, DeviceTime, Protocol, Reading};
use insuwb_devices::link::{Link, LinkConfigError, LinkSpec, LinkState, Read, ReconnectPolicy};
use insuwb_devices::{eliko, witmotion};
use insuwb_msg::check::RangeGate;
use insuwb_msg::{
    topics, DeviceCounters, Header, HealthState, ImuSample, StageCounters, UwbFix, UwbKind,
    UwbRange,
};
use insuwb_runtime::{monotonic_ns, HealthCounters, Stage, Wake};
use insuwb_uwb::fix::{FixBuilder, FixConfig, FixConfigError, PushError};
use insuwb_uwb::velocity::{VelocityConfig, VelocityConfigError, VelocityEstimator};

use crate::driver::uwb::take_range;
use crate::driver::SKIP_LOG_PERIOD_NS;
use crate::source::Want;
use insuwb_group::robot::{DeviceConfig, RobotConfig};
use insuwb_msg::check::imu_values;

/// Connected without a valid frame for this long: state DEGRADED, ns.
pub const SILENT_NS: u64 = 1_000_000_000;

/// Largest plausible position coordinate of a UWB fix, m.
pub const MAX_POS_M: f64 = 100_000.0;

/// Largest plausible velocity component a UWB device reports, m/s.
pub const MAX_VEL_MPS: f64 = 100.0;

/// Readings in a row that repeat the previous reading's device time after
/// which the device clock is left for host times.
pub const CLOCK_REPEATS_MAX: u32 = 3;

/// Longest single read: bounds the delay of a heartbeat or a shutdown.
const READ_TIMEOUT: Duration = Duration::from_millis(20);

/// Bytes read at once.
const READ_BUF_LEN: usize = 4096;

/// Anchors without a position warned about one by one; more are counted
/// silently.
const MAX_WARNED_ANCHORS: usize = 64;

/// Why a device driver could not start.
#[derive(Debug, thiserror::Error)]
pub enum DeviceSetupError {
    /// The source is `device` but the config has no device table.
    #[error("DeviceSetupError::NoDevice: sources.{sensor} = \"device\" needs a [devices.{sensor}] table")]
    NoDevice {
        /// `imu` or `uwb`.
        sensor: &'static str,
    },
    /// The protocol is unknown or is not one of this sensor's.
    #[error("DeviceSetupError::Protocol: devices.{sensor}.protocol: {reason}")]
    Protocol {
        /// `imu` or `uwb`.
        sensor: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// The `source` is not `serial:PATH` or `tcp:HOST:PORT`.
    #[error("DeviceSetupError::Source: devices.{sensor}.source: {reason}")]
    Source {
        /// `imu` or `uwb`.
        sensor: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// The reconnection settings were refused.
    #[error("DeviceSetupError::Link: devices.{sensor}: {error}")]
    Link {
        /// `imu` or `uwb`.
        sensor: &'static str,
        /// The link's reason.
        error: LinkConfigError,
    },
    /// The velocity regression settings were refused.
    #[error("fusion.fix.{0}")]
    Velocity(VelocityConfigError),
    /// The fix builder's settings were refused.
    #[error("fusion.fix: {0}")]
    Fix(FixConfigError),
    /// The protocol does not report what `[uwb] kind` names.
    #[error("DeviceSetupError::Kind: devices.uwb.protocol = \"{protocol}\" reports {reports}, but [uwb] kind = \"{kind}\"")]
    Kind {
        /// The device protocol.
        protocol: Protocol,
        /// What it reports.
        reports: &'static str,
        /// The robot's `[uwb] kind`.
        kind: UwbKind,
    },
}

impl From<FixConfigError> for DeviceSetupError {
    fn from(e: FixConfigError) -> Self {
        Self::Fix(e)
    }
}

impl From<VelocityConfigError> for DeviceSetupError {
    fn from(e: VelocityConfigError) -> Self {
        Self::Velocity(e)
    }
}

/// What a device driver needs from its `[devices.*]` table, checked.
#[derive(Debug)]
struct Setup {
    protocol: Protocol,
    spec: LinkSpec,
    /// Baud rate of the wire-time correction (0 over TCP).
    wire_baud: u32,
    policy: ReconnectPolicy,
    on_connect: Vec<u8>,
}

impl Setup {
    fn new(want: Want, dev: &DeviceConfig) -> Result<Self, DeviceSetupError> {
        let sensor = sensor_name(want);
        let protocol: Protocol =
            dev.protocol
                .parse()
                .map_err(|e: insuwb_devices::frame::UnknownProtocol| {
                    DeviceSetupError::Protocol {
                        sensor,
                        reason: e.to_string(),
                    }
                })?;
        let fits = match want {
            Want::Imu => matches!(protocol, Protocol::WitMotion | Protocol::Mavlink),
            Want::Uwb => matches!(
                protocol,
                Protocol::Nlink | Protocol::Eliko | Protocol::Dwm1001
            ),
        };
        if !fits {
            return Err(DeviceSetupError::Protocol {
                sensor,
                reason: format!("{protocol} is not a protocol of this sensor"),
            });
        }
        let spec: LinkSpec =
            dev.source
                .parse()
                .map_err(
                    |e: insuwb_devices::link::LinkSpecError| DeviceSetupError::Source {
                        sensor,
                        reason: e.to_string(),
                    },
                )?;
        let wire_baud = match spec {
            LinkSpec::Serial { .. } => dev.baud,
            LinkSpec::Tcp { .. } => 0,
        };
        let policy = ReconnectPolicy {
            initial_backoff: Duration::from_millis(dev.reconnect_initial_ms),
            max_backoff: Duration::from_millis(dev.reconnect_max_ms),
            // A connect or a blocked write must never outlast the
            // launcher's heartbeat watchdog.
            connect_timeout: READ_TIMEOUT,
            write_timeout: Duration::from_millis(100),
        };
        let on_connect = match protocol {
            Protocol::Eliko => eliko::HANDSHAKE.concat().into_bytes(),
            _ => Vec::new(),
        };
        Ok(Self {
            protocol,
            spec,
            wire_baud,
            policy,
            on_connect,
        })
    }

    fn decoder(&self, tag_id: u32) -> AnyDecoder {
        match self.protocol {
            Protocol::Eliko if tag_id != 0 => {
                AnyDecoder::Eliko(eliko::Decoder::with_tags([tag_id]))
            }
            p => AnyDecoder::new(p),
        }
    }
}

fn sensor_name(want: Want) -> &'static str {
    want.role().name()
}

/// `[uwb] kind` against what a UWB protocol reports (Eliko positions,
/// DWM1001 ranges, NLink both).
fn check_kind(want: Want, protocol: Protocol, kind: UwbKind) -> Result<(), DeviceSetupError> {
    let reports = match (want, protocol) {
        (Want::Uwb, Protocol::Eliko) if kind == UwbKind::Twr => "positions, not ranges",
        (Want::Uwb, Protocol::Dwm1001) if kind == UwbKind::Tdoa => {
            "two-way ranges (set [uwb] kind = \"twr\")"
        }
        _ => return Ok(()),
    };
    Err(DeviceSetupError::Kind {
        protocol,
        reports,
        kind,
    })
}

/// Whether a reading's own bytes are one text line of varying length (its
/// wire time is the line's, not [`Protocol::nominal_frame_len`]'s).
fn per_line(protocol: Protocol) -> bool {
    matches!(protocol, Protocol::Dwm1001 | Protocol::Eliko)
}

/// Bytes on the wire of the frames that make one reading.
fn reading_len(protocol: Protocol) -> usize {
    match protocol {
        // 0x51 then 0x52.
        Protocol::WitMotion => 2 * witmotion::FRAME_LEN,
        p => p.nominal_frame_len(),
    }
}

/// `Rz(yaw) Ry(pitch) Rx(roll)` from degrees; `None` for no rotation.
fn mounting_rotation(rpy_deg: [f64; 3]) -> Option<[[f64; 3]; 3]> {
    if rpy_deg == [0.0; 3] {
        return None;
    }
    let [r, p, y] = rpy_deg.map(f64::to_radians);
    let (sr, cr) = r.sin_cos();
    let (sp, cp) = p.sin_cos();
    let (sy, cy) = y.sin_cos();
    Some([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])
}

fn rotate(m: Option<&[[f64; 3]; 3]>, v: [f64; 3]) -> [f64; 3] {
    match m {
        None => v,
        Some(m) => m.map(|row| row[0] * v[0] + row[1] * v[1] + row[2] * v[2]),
    }
}

/// Samples dropped, by reason.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
struct Drops {
    invalid: u64,
    time: u64,
}

/// The fields of a [`Reading::Range`] but its device time.
#[derive(Debug, Clone, Copy, PartialEq)]
struct RangeReading {
    anchor: u32,
    range_m: f64,
    anchor_pos_m: Option<[f64; 3]>,
    quality: Option<u8>,
    last_of_round: bool,
}

/// What one reading became.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Out {
    Imu(ImuSample),
    Fix(UwbFix),
    /// A two-way range, after the fix it completed (if any).
    Range {
        fix: Option<UwbFix>,
        range: UwbRange,
    },
    /// Dropped and counted.
    Dropped,
    /// Not for this driver (another kind of reading, another tag).
    Skipped,
}

/// A UWB device's two-way ranges (`[uwb] kind = "twr"`): the surveyed
/// anchors, the open round, and the path every range takes into the group
/// ([`take_range`]).
#[derive(Debug)]
struct Ranging {
    /// `[[devices.uwb.anchors]]`: id and position.
    anchors: Vec<(u32, [f64; 3])>,
    gate: RangeGate,
    fixes: FixBuilder,
    /// The open round: the send time its readings share and its stamp
    /// (`None`: the round is dropped for its time).
    round: Option<(u64, Option<u64>)>,
    /// Anchors warned about for having no position (capacity
    /// [`MAX_WARNED_ANCHORS`], allocated once).
    warned: Vec<u32>,
    /// The latest range the fix builder refused.
    last_refusal: Option<PushError>,
    /// Skipped epochs and refusals already logged, and when.
    logged: (u64, u64),
    logged_at: u64,
}

impl Ranging {
    /// The anchors of `dev` and a fix builder with `fix` (live stamps: the
    /// epoch windows are not aligned to any start epoch).
    fn new(dev: &DeviceConfig, fix: FixConfig) -> Result<Self, DeviceSetupError> {
        Ok(Self {
            anchors: dev.anchors.iter().map(|a| (a.id, a.pos_m)).collect(),
            gate: RangeGate::new(),
            fixes: FixBuilder::new(fix)?,
            round: None,
            warned: Vec::with_capacity(MAX_WARNED_ANCHORS),
            last_refusal: None,
            logged: (0, 0),
            logged_at: 0,
        })
    }

    /// The anchor's position: configured, else the device's.
    fn anchor_pos(&self, anchor: u32, reported: Option<[f64; 3]>) -> Option<[f64; 3]> {
        self.anchors
            .iter()
            .find(|(id, _)| *id == anchor)
            .map(|(_, p)| *p)
            .or(reported)
    }

    /// Warns once about an anchor without a position.
    fn warn_unknown(&mut self, anchor: u32) {
        if self.warned.contains(&anchor) || self.warned.len() >= MAX_WARNED_ANCHORS {
            return;
        }
        self.warned.push(anchor);
        tracing::warn!(
            "uwb driver: ranges to anchor {anchor} (0x{anchor:04X}) are dropped: its position is unknown; add it to the robot config: [[devices.uwb.anchors]] id = {anchor}, pos_m = [x, y, z]"
        );
    }

    /// A range of the round was dropped: when it was the round's last, the
    /// epoch is closed all the same and its fix returned.
    fn dropped(&mut self, last_of_round: bool) -> Out {
        match last_of_round.then(|| self.fixes.flush()).flatten() {
            Some(f) => Out::Fix(f),
            None => Out::Dropped,
        }
    }

    /// Logs, at most every [`SKIP_LOG_PERIOD_NS`], the epochs the fix
    /// builder skipped and the ranges it refused since the last log.
    fn log(&mut self, now_ns: u64) {
        let s = self.fixes.stats();
        let skipped = s.skipped_too_few_pairs
            + s.skipped_too_few_anchors
            + s.skipped_degenerate
            + s.skipped_no_convergence
            + s.skipped_runaway
            + s.skipped_other;
        let refused = s.dropped_impossible
            + s.dropped_capacity
            + s.dropped_non_finite
            + s.dropped_same_anchor
            + s.dropped_time_backwards;
        if (skipped, refused) == self.logged || now_ns < self.logged_at + SKIP_LOG_PERIOD_NS {
            return;
        }
        tracing::warn!(
            "uwb driver: {} ranging epochs without a fix (last: {}), {} ranges refused by the fix builder (last: {})",
            skipped - self.logged.0,
            self.fixes
                .last_skip()
                .map_or_else(|| "-".to_owned(), ToString::to_string),
            refused - self.logged.1,
            self.last_refusal
                .map_or_else(|| "-".to_owned(), |e| e.to_string())
        );
        self.logged = (skipped, refused);
        self.logged_at = now_ns;
    }
}

/// Turns readings into samples: times, rotation, checks, velocity; with
/// two-way ranging, ranges and their fixes. Pure.
#[derive(Debug)]
struct Converter {
    want: Want,
    rotation: Option<[[f64; 3]; 3]>,
    tag_id: u32,
    pos_var_m2: f64,
    /// The clock filter and the (tick, wrap) it was made for.
    clock: Option<(ClockFilter, u64, Option<u64>)>,
    last_ticks: Option<u64>,
    clock_repeats: u32,
    clock_off: bool,
    last_t: Option<u64>,
    velocity: VelocityEstimator,
    /// With `[uwb] kind = "twr"`.
    ranging: Option<Ranging>,
    drops: Drops,
    other_tags: u64,
}

impl Converter {
    fn new(
        want: Want,
        dev: &DeviceConfig,
        velocity: VelocityConfig,
    ) -> Result<Self, DeviceSetupError> {
        Ok(Self {
            want,
            rotation: mounting_rotation(dev.rotation_deg),
            tag_id: dev.tag_id,
            pos_var_m2: dev.position_sigma_m * dev.position_sigma_m,
            clock: None,
            last_ticks: None,
            clock_repeats: 0,
            clock_off: false,
            last_t: None,
            velocity: VelocityEstimator::new(velocity)?,
            ranging: None,
            drops: Drops::default(),
            other_tags: 0,
        })
    }

    /// Turns range readings into [`UwbRange`]s (and ignores positions).
    fn with_ranging(mut self, ranging: Ranging) -> Self {
        self.ranging = Some(ranging);
        self
    }

    /// Samples dropped for their values, by the converter or the range gate.
    fn dropped_invalid(&self) -> u64 {
        self.drops.invalid
            + self
                .ranging
                .as_ref()
                .map_or(0, |r| r.gate.refusals().invalid())
    }

    /// Samples dropped for their time, by the converter or the range gate.
    fn dropped_time(&self) -> u64 {
        self.drops.time
            + self
                .ranging
                .as_ref()
                .map_or(0, |r| r.gate.refusals().time())
    }

    /// The host time of a reading sent at `sent_ns` with `device_time`.
    fn time(&mut self, device_time: Option<DeviceTime>, sent_ns: u64) -> u64 {
        let Some(dt) = device_time else {
            return sent_ns;
        };
        if self.clock_off {
            return sent_ns;
        }
        if self.last_ticks != Some(dt.ticks) {
            self.clock_repeats = 0;
        } else {
            self.clock_repeats = self.clock_repeats.saturating_add(1);
            if self.clock_repeats >= CLOCK_REPEATS_MAX {
                self.clock_off = true;
                tracing::warn!(
                    "the device clock repeated its value {} times: too coarse for the reading rate, using host receive times",
                    self.clock_repeats
                );
            }
            return sent_ns;
        }
        if !matches!(self.clock, Some((_, tick, wrap)) if tick == dt.tick_ns && wrap == dt.wrap) {
            match ClockFilter::new(dt.tick_ns, dt.wrap, ClockConfig::default()) {
                Ok(f) => self.clock = Some((f, dt.tick_ns, dt.wrap)),
                Err(e) => {
                    tracing::warn!("device clock unusable ({e}): using host receive times");
                    self.clock_off = true;
                    return sent_ns;
                }
            }
        }
        let Some((filter, _, _)) = self.clock.as_mut() else {
            return sent_ns;
        };
        match filter.update(dt.ticks, sent_ns) {
            Ok(ClockEvent::Reset(cause)) => {
                tracing::warn!("device clock filter reset: {cause:?}");
            }
            Ok(_) => {}
            Err(_) => return sent_ns,
        }
        self.last_ticks = Some(dt.ticks);
        filter.to_host(dt.ticks).unwrap_or(sent_ns)
    }

    /// Takes time `t` if it is after the previous sample's.
    fn take_time(&mut self, t: u64) -> bool {
        if self.last_t.is_some_and(|l| t <= l) {
            self.drops.time += 1;
            return false;
        }
        self.last_t = Some(t);
        true
    }

    fn convert(&mut self, reading: &Reading, sent_ns: u64) -> Out {
        match (self.want, reading) {
            (
                Want::Imu,
                Reading::Imu {
                    accel_mps2,
                    gyro_rps,
                    device_time,
                },
            ) => {
                let t = self.time(*device_time, sent_ns);
                let s = ImuSample {
                    header: Header::new(0, t),
                    accel_mps2: rotate(self.rotation.as_ref(), *accel_mps2),
                    gyro_rps: rotate(self.rotation.as_ref(), *gyro_rps),
                };
                if imu_values(&s).is_err() {
                    self.drops.invalid += 1;
                    return Out::Dropped;
                }
                if !self.take_time(t) {
                    return Out::Dropped;
                }
                Out::Imu(s)
            }
            (
                Want::Uwb,
                Reading::Range {
                    anchor,
                    range_m,
                    anchor_pos_m,
                    quality,
                    last_of_round,
                    device_time,
                },
            ) if self.ranging.is_some() => {
                let r = RangeReading {
                    anchor: *anchor,
                    range_m: *range_m,
                    anchor_pos_m: *anchor_pos_m,
                    quality: *quality,
                    last_of_round: *last_of_round,
                };
                self.range(&r, *device_time, sent_ns)
            }
            // Two-way ranging: the device's own positions are not used.
            (Want::Uwb, Reading::Position { .. }) if self.ranging.is_some() => Out::Skipped,
            (
                Want::Uwb,
                Reading::Position {
                    tag,
                    pos_m,
                    vel_mps,
                    device_time,
                    ..
                },
            ) => {
                if self.tag_id != 0 && *tag != self.tag_id {
                    self.other_tags += 1;
                    return Out::Skipped;
                }
                let t = self.time(*device_time, sent_ns);
                let pos_ok = pos_m.iter().all(|v| v.is_finite() && v.abs() < MAX_POS_M);
                let vel_ok = vel_mps
                    .is_none_or(|v| v.iter().all(|x| x.is_finite() && x.abs() < MAX_VEL_MPS));
                if !(pos_ok && vel_ok) {
                    self.drops.invalid += 1;
                    return Out::Dropped;
                }
                if !self.take_time(t) {
                    return Out::Dropped;
                }
                let v = self.pos_var_m2;
                let cov = [[v, 0.0, 0.0], [0.0, v, 0.0], [0.0, 0.0, v]];
                let mut fix = UwbFix {
                    header: Header::new(0, t),
                    pos_m: *pos_m,
                    pos_cov_m2: cov,
                    gdop: 1.0,
                    ..UwbFix::default()
                };
                if let Ok(est) = self.velocity.push(t, *pos_m, cov) {
                    if est.valid {
                        fix.vel_mps = vel_mps.unwrap_or(est.vel_mps);
                        fix.vel_cov = est.cov_mps2;
                        fix.header.flags |= UwbFix::FLAG_VEL_VALID;
                    }
                }
                Out::Fix(fix)
            }
            _ => Out::Skipped,
        }
    }

    /// A range reading sent at `sent_ns`: stamped with its round's time,
    /// given its anchor's position and flags, through [`take_range`].
    fn range(&mut self, r: &RangeReading, device_time: Option<DeviceTime>, sent_ns: u64) -> Out {
        // Readings of one line or frame come out of one byte: one send time.
        let open = match self.ranging.as_ref().and_then(|g| g.round) {
            Some((sent, stamp)) if sent == sent_ns => Some(stamp),
            _ => None,
        };
        let stamp = match open {
            Some(stamp) => stamp,
            None => {
                let t = self.time(device_time, sent_ns);
                self.take_time(t).then_some(t)
            }
        };
        let Some(g) = self.ranging.as_mut() else {
            return Out::Skipped;
        };
        g.round = (!r.last_of_round).then_some((sent_ns, stamp));
        let Some(t) = stamp else {
            // The round's first range was counted by `take_time`.
            if open.is_some() {
                self.drops.time += 1;
            }
            return Out::Dropped;
        };
        let Some(anchor_pos_m) = g.anchor_pos(r.anchor, r.anchor_pos_m) else {
            self.drops.invalid += 1;
            g.warn_unknown(r.anchor);
            return g.dropped(r.last_of_round);
        };
        let mut header = Header::new(0, t);
        if r.last_of_round {
            header.flags |= UwbRange::FLAG_EPOCH_END;
        }
        if r.quality.is_some() {
            header.flags |= UwbRange::FLAG_QUALITY;
        }
        let m = UwbRange {
            header,
            anchor: r.anchor,
            quality: r.quality.map_or(0, u32::from),
            range_m: r.range_m,
            anchor_pos_m,
        };
        // Refused by the gate: counted there.
        let Some((pushed, range)) = take_range(&mut g.gate, &mut g.fixes, &m) else {
            return g.dropped(r.last_of_round);
        };
        let fix = match pushed {
            Ok(f) => f,
            Err(e) => {
                g.last_refusal = Some(e);
                r.last_of_round.then(|| g.fixes.flush()).flatten()
            }
        };
        Out::Range { fix, range }
    }

    fn clock_offset_ns(&self) -> Option<i64> {
        self.clock.as_ref().and_then(|(f, _, _)| f.offset_ns())
    }

    fn clock_drift_ppb(&self) -> Option<i64> {
        let ppm = self.clock.as_ref().and_then(|(f, _, _)| f.drift_ppm())?;
        // `as` saturates; the filter clamps the drift to +-1000 ppm anyway.
        Some((ppm * 1e3).round() as i64)
    }
}

/// The driver's state from the link and what the decoder saw.
fn device_state(
    link: LinkState,
    wrong_baud: bool,
    last_frame_ns: Option<u64>,
    now_ns: u64,
) -> HealthState {
    match link {
        LinkState::Disconnected { .. } => HealthState::Disconnected,
        LinkState::Connected { since_ns } => {
            let fresh = last_frame_ns
                .is_some_and(|t| t >= since_ns && now_ns.saturating_sub(t) < SILENT_NS);
            if fresh && !wrong_baud {
                HealthState::Ok
            } else {
                HealthState::Degraded
            }
        }
    }
}

/// When the bytes of one read were on the wire.
#[derive(Debug, Clone, Copy)]
struct Wire {
    /// CLOCK_MONOTONIC when the read returned.
    host_time_ns: u64,
    /// Serial baud rate (0: TCP, no wire time).
    baud: u32,
    /// Wire time of the frames of one reading, ns.
    reading_ns: u64,
    /// A reading is a text line: its wire time is its line's.
    per_line: bool,
}

/// Hands the `bytes` of one read to the decoder one at a time and gives
/// `out` what each reading became, stamped with the time it was sent: the
/// read time minus the wire time of the bytes after the reading's last one
/// and of the reading's own frames (or line).
fn on_bytes(
    decoder: &mut AnyDecoder,
    conv: &mut Converter,
    bytes: &[u8],
    wire: &Wire,
    out: &mut impl FnMut(Out),
) {
    let n = bytes.len();
    for (i, byte) in bytes.iter().enumerate() {
        let after = wire_time_ns(n - 1 - i, wire.baud);
        let own = if wire.per_line {
            wire_time_ns(decoder.buffered() + 1, wire.baud)
        } else {
            wire.reading_ns
        };
        let sent_ns = wire.host_time_ns.saturating_sub(after).saturating_sub(own);
        decoder.push(std::slice::from_ref(byte), &mut |r| {
            out(conv.convert(&r, sent_ns))
        });
    }
}

/// Runs the driver of `want` over its configured device until SIGINT/SIGTERM.
pub fn run(want: Want, cfg: &RobotConfig) -> Result<()> {
    let name = sensor_name(want);
    let dev = match want {
        Want::Imu => cfg.devices.imu.as_ref(),
        Want::Uwb => cfg.devices.uwb.as_ref(),
    }
    .ok_or(DeviceSetupError::NoDevice { sensor: name })?;
    let setup = Setup::new(want, dev)?;
    check_kind(want, setup.protocol, cfg.uwb.kind)?;
    let ranging = want == Want::Uwb && cfg.uwb.kind == UwbKind::Twr;
    let (velocity, fix) = match want {
        Want::Uwb => {
            let fix = cfg.fusion_config()?.fix;
            (fix.velocity.clone(), Some(fix))
        }
        Want::Imu => (VelocityConfig::default(), None),
    };
    let mut conv = Converter::new(want, dev, velocity)?;
    if let (true, Some(fix)) = (ranging, fix) {
        conv = conv.with_ranging(Ranging::new(dev, fix)?);
    }
    let stage = Stage::new(cfg.runtime(name))?;
    let (mut imu_pub, mut fix_pub) = match want {
        Want::Imu => (Some(stage.publisher::<ImuSample>(topics::IMU)?), None),
        Want::Uwb => (None, Some(stage.publisher::<UwbFix>(topics::UWB_FIX)?)),
    };
    let mut range_pub = if ranging {
        Some(stage.publisher::<UwbRange>(topics::UWB_RANGE)?)
    } else {
        None
    };
    let mut health = stage.health_reporter()?;
    let waiter = stage.waiter()?;
    let hb = waiter.attach_interval(health.period())?;
    let mut link = Link::new(
        setup.spec.clone(),
        setup.wire_baud,
        setup.policy,
        setup.on_connect.clone(),
        monotonic_ns,
    )
    .map_err(|source| DeviceSetupError::Link {
        sensor: name,
        error: source,
    })?;
    let mut decoder = setup.decoder(dev.tag_id);
    let baud = setup.wire_baud;
    let reading_wire_ns = wire_time_ns(reading_len(setup.protocol), baud);
    tracing::info!(
        "{name} driver: device {} ({}, {} baud{}), generation {}",
        setup.spec,
        setup.protocol,
        dev.baud,
        if ranging {
            format!(", two-way ranges, {} surveyed anchors", dev.anchors.len())
        } else {
            String::new()
        },
        stage.generation()
    );
    let mut buf = [0u8; READ_BUF_LEN];
    let mut counters = HealthCounters::default();
    let mut connects_seen = 0u64;
    let mut frames_seen = 0u64;
    let mut last_frame_ns: Option<u64> = None;
    let mut wrong_baud = false;
    let mut last_state: Option<HealthState> = None;
    loop {
        let beat = match waiter.wait_timeout(Duration::ZERO)? {
            Wake::Shutdown => break,
            Wake::Fired(f) => f.contains(&hb),
            Wake::Timeout => false,
        };
        if let Read::Data { n, host_time_ns } = link.read(&mut buf, READ_TIMEOUT)? {
            let connects = link.stats().connects;
            if connects != connects_seen {
                // A partial frame from before the device went away is junk.
                decoder.clear();
                connects_seen = connects;
            }
            let bytes = buf.get(..n).unwrap_or(&[]);
            let mut err = None;
            let wire = Wire {
                host_time_ns,
                baud,
                reading_ns: reading_wire_ns,
                per_line: per_line(setup.protocol),
            };
            on_bytes(&mut decoder, &mut conv, bytes, &wire, &mut |out| {
                let published = match out {
                    Out::Imu(s) => imu_pub.as_mut().map(|p| p.publish(s)),
                    Out::Fix(f) => fix_pub.as_mut().map(|p| p.publish(f)),
                    // The fix the range completed goes out before it.
                    Out::Range { fix, range } => {
                        match fix.and_then(|f| fix_pub.as_mut().map(|p| p.publish(f))) {
                            Some(Err(e)) => Some(Err(e)),
                            _ => range_pub.as_mut().map(|p| p.publish(range)),
                        }
                    }
                    Out::Dropped | Out::Skipped => None,
                };
                if let Some(Err(e)) = published {
                    err = Some(e);
                }
            });
            if let Some(e) = err {
                return Err(e.into());
            }
            let stats = decoder.stats();
            if stats.frames_ok != frames_seen {
                frames_seen = stats.frames_ok;
                last_frame_ns = Some(host_time_ns);
            }
            let since = decoder.bytes_since_last_valid_frame();
            let wrong = since >= dev.wrong_baud_bytes;
            if wrong && !wrong_baud {
                match setup.spec {
                    LinkSpec::Serial { .. } => tracing::error!(
                        "{name} driver: {}: no valid {} frame in {since} bytes at {} baud: wrong baud rate or protocol?",
                        setup.spec,
                        setup.protocol,
                        dev.baud
                    ),
                    LinkSpec::Tcp { .. } => tracing::error!(
                        "{name} driver: {}: no valid {} frame in {since} bytes: wrong protocol or port?",
                        setup.spec,
                        setup.protocol
                    ),
                }
            } else if !wrong && wrong_baud {
                tracing::info!(
                    "{name} driver: {}: valid {} frames again",
                    setup.spec,
                    setup.protocol
                );
            }
            wrong_baud = wrong;
        }
        let state = device_state(link.state(), wrong_baud, last_frame_ns, monotonic_ns());
        if last_state != Some(state) {
            match state {
                HealthState::Disconnected => tracing::warn!(
                    "{name} driver: {} disconnected ({}); retrying",
                    setup.spec,
                    link.stats().last_error.as_deref().unwrap_or("not found")
                ),
                HealthState::Ok => {
                    tracing::info!("{name} driver: {}: receiving", setup.spec);
                }
                HealthState::Degraded | HealthState::Stopping => {}
            }
        }
        if beat || last_state != Some(state) {
            let stats = decoder.stats();
            counters.received = stats.frames_ok;
            counters.published = imu_pub
                .as_ref()
                .map_or(0, |p| p.published())
                .saturating_add(fix_pub.as_ref().map_or(0, |p| p.published()))
                .saturating_add(range_pub.as_ref().map_or(0, |p| p.published()));
            counters.dropped_invalid = conv.dropped_invalid();
            counters.dropped_time = conv.dropped_time();
            if let Some(r) = conv.ranging.as_mut() {
                r.log(monotonic_ns());
            }
            counters.seq_gaps = stats.seq_gaps;
            counters.stage = StageCounters::Device(DeviceCounters {
                decoder_errors: stats.resyncs.saturating_add(stats.checksum_errors),
                reconnects: link.stats().connects.saturating_sub(1),
                clock_offset_ns: conv.clock_offset_ns(),
                clock_drift_ppb: conv.clock_drift_ppb(),
            });
            health.report(&counters, state)?;
            last_state = Some(state);
            // Late subscribers get history only when the publisher acts.
            for p in imu_pub.iter() {
                p.update_connections()?;
            }
            for p in fix_pub.iter() {
                p.update_connections()?;
            }
            for p in range_pub.iter() {
                p.update_connections()?;
            }
        }
    }
    health.report(&counters, HealthState::Stopping)?;
    tracing::info!(
        "{name} driver: stopped after {} samples",
        counters.published
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

    use super::*;
    use insuwb_group::robot::AnchorConfig;

    fn dev(protocol: &str, source: &str) -> DeviceConfig {
        DeviceConfig {
            source: source.to_owned(),
            protocol: protocol.to_owned(),
            ..DeviceConfig::default()
        }
    }

    fn imu(accel: [f64; 3], gyro: [f64; 3], ticks: Option<u64>) -> Reading {
        Reading::Imu {
            accel_mps2: accel,
            gyro_rps: gyro,
            device_time: ticks.map(|ticks| DeviceTime {
                ticks,
                tick_ns: 1_000,
                wrap: None,
            }),
        }
    }

    fn position(tag: u32, pos: [f64; 3], vel: Option<[f64; 3]>) -> Reading {
        Reading::Position {
            tag,
            pos_m: pos,
            vel_mps: vel,
            device_time: None,
            seq: None,
        }
    }

    #[test]
    fn yaw_90_turns_sensor_x_into_body_y() {
        let m = mounting_rotation([0.0, 0.0, 90.0]);
        let v = rotate(m.as_ref(), [1.0, 0.0, 0.0]);
        assert!(v[0].abs() < 1e-12 && (v[1] - 1.0).abs() < 1e-12 && v[2].abs() < 1e-12);
        // Roll 180 (sensor mounted upside down): z flips, y flips.
        let m = mounting_rotation([180.0, 0.0, 0.0]);
        let v = rotate(m.as_ref(), [0.0, 1.0, 9.81]);
        assert!(v[0].abs() < 1e-12 && (v[1] + 1.0).abs() < 1e-12 && (v[2] + 9.81).abs() < 1e-12);
        // Pitch 90: sensor x points down in the body (nose-up convention).
        let m = mounting_rotation([0.0, 90.0, 0.0]);
        let v = rotate(m.as_ref(), [1.0, 0.0, 0.0]);
        assert!((v[2] + 1.0).abs() < 1e-12, "{v:?}");
        assert_eq!(mounting_rotation([0.0; 3]), None);
        assert_eq!(rotate(None, [1.0, 2.0, 3.0]), [1.0, 2.0, 3.0]);
    }

    #[test]
    fn imu_readings_are_rotated_checked_and_kept_in_time_order() {
        let mut d = dev("witmotion", "serial:/dev/null");
        d.rotation_deg = [0.0, 0.0, 90.0];
        let mut c = Converter::new(Want::Imu, &d, VelocityConfig::default()).unwrap();
        let Out::Imu(s) = c.convert(&imu([1.0, 0.0, 9.8], [0.1, 0.0, 0.0], None), 1_000) else {
            panic!("not published")
        };
        assert_eq!(s.header.meas_time_ns, 1_000);
        assert!((s.accel_mps2[1] - 1.0).abs() < 1e-12 && (s.gyro_rps[1] - 0.1).abs() < 1e-12);
        // Same time again, earlier time: dropped for time.
        assert_eq!(
            c.convert(&imu([0.0; 3], [0.0; 3], None), 1_000),
            Out::Dropped
        );
        assert_eq!(c.convert(&imu([0.0; 3], [0.0; 3], None), 999), Out::Dropped);
        // NaN, out of range: dropped as invalid.
        assert_eq!(
            c.convert(&imu([f64::NAN, 0.0, 0.0], [0.0; 3], None), 2_000),
            Out::Dropped
        );
        assert_eq!(
            c.convert(&imu([0.0; 3], [80.0, 0.0, 0.0], None), 3_000),
            Out::Dropped
        );
        assert_eq!(
            c.drops,
            Drops {
                invalid: 2,
                time: 2
            }
        );
        // A UWB reading is not for the IMU driver.
        assert_eq!(c.convert(&position(1, [0.0; 3], None), 4_000), Out::Skipped);
        assert!(matches!(
            c.convert(&imu([0.0; 3], [0.0; 3], None), 4_000),
            Out::Imu(_)
        ));
    }

    #[test]
    fn device_times_go_through_the_clock_filter() {
        let d = dev("mavlink", "serial:/dev/null");
        let mut c = Converter::new(Want::Imu, &d, VelocityConfig::default()).unwrap();
        // Device us counter 5 s behind the host; reads late by 0 to 0.9 ms.
        let mut times = Vec::new();
        for k in 0..200u64 {
            let device_us = 1_000_000 + k * 10_000;
            let host = 6_000_000_000 + k * 10_000_000 + (k * 7919 % 10) * 100_000;
            match c.convert(&imu([0.0; 3], [0.0; 3], Some(device_us)), host) {
                Out::Imu(s) => times.push(s.header.meas_time_ns),
                o => panic!("{o:?}"),
            }
        }
        // Late in the run the mapped times follow the device clock within 0.1 ms.
        let last = *times.last().unwrap();
        let want = 6_000_000_000 + 199 * 10_000_000;
        assert!(last.abs_diff(want) < 100_000, "{last} vs {want}");
        let offset = c.clock_offset_ns().unwrap();
        assert!((offset - 5_000_000_000).abs() < 100_000, "{offset}");
        assert!(c.clock_drift_ppb().is_some());
    }

    #[test]
    fn a_coarse_device_clock_is_left_for_host_times() {
        let d = dev("eliko", "tcp:127.0.0.1:9");
        let mut c = Converter::new(Want::Uwb, &d, VelocityConfig::default()).unwrap();
        let at = |s: u64| Reading::Position {
            tag: 1,
            pos_m: [0.0; 3],
            vel_mps: None,
            device_time: Some(DeviceTime {
                ticks: s * 1_000_000,
                tick_ns: 1_000,
                wrap: None,
            }),
            seq: None,
        };
        let mut published = 0;
        // Whole-second Unix times, ten fixes a second for 2 s.
        for k in 0..20u64 {
            if let Out::Fix(_) =
                c.convert(&at(1_700_000_000 + k / 10), 1_000_000_000 + k * 100_000_000)
            {
                published += 1;
            }
        }
        assert!(c.clock_off);
        assert!(published >= 15, "{published} of 20 fixes published");
    }

    #[test]
    fn fixes_take_the_tag_the_variance_and_a_velocity() {
        let mut d = dev("nlink", "serial:/dev/null");
        d.tag_id = 3;
        d.position_sigma_m = 0.2;
        let mut c = Converter::new(Want::Uwb, &d, VelocityConfig::default()).unwrap();
        assert_eq!(c.convert(&position(4, [0.0; 3], None), 1), Out::Skipped);
        assert_eq!(c.other_tags, 1);
        let mut last = None;
        for k in 0..10u64 {
            let p = [0.5 * k as f64 * 0.1, 1.0, 0.3];
            match c.convert(&position(3, p, None), k * 100_000_000) {
                Out::Fix(f) => last = Some(f),
                o => panic!("{o:?}"),
            }
        }
        let f = last.unwrap();
        assert!((f.pos_cov_m2[0][0] - 0.04).abs() < 1e-12 && f.pos_cov_m2[0][1] == 0.0);
        assert_eq!(f.gdop, 1.0);
        assert_ne!(f.header.flags & UwbFix::FLAG_VEL_VALID, 0);
        assert!((f.vel_mps[0] - 0.5).abs() < 1e-9, "{:?}", f.vel_mps);
        assert!(f.vel_cov[0][0] > 0.0);
        // The device's own velocity wins; the covariance stays the regression's.
        let Out::Fix(g) = c.convert(
            &position(3, [0.5, 1.0, 0.3], Some([0.4, 0.0, 0.0])),
            1_000_000_000,
        ) else {
            panic!()
        };
        assert_eq!(g.vel_mps, [0.4, 0.0, 0.0]);
        assert!(g.vel_cov[0][0] > 0.0);
        // Absurd values are dropped.
        assert_eq!(
            c.convert(&position(3, [1e9, 0.0, 0.0], None), 2_000_000_000),
            Out::Dropped
        );
        assert_eq!(
            c.convert(
                &position(3, [0.0; 3], Some([f64::INFINITY, 0.0, 0.0])),
                2_100_000_000
            ),
            Out::Dropped
        );
        // The first fixes have no valid velocity yet.
        let mut c = Converter::new(Want::Uwb, &d, VelocityConfig::default()).unwrap();
        let Out::Fix(first) = c.convert(&position(3, [0.0; 3], Some([1.0, 0.0, 0.0])), 5) else {
            panic!()
        };
        assert_eq!(first.header.flags & UwbFix::FLAG_VEL_VALID, 0);
    }

    #[test]
    fn state_follows_link_and_frames() {
        let up = LinkState::Connected { since_ns: 100 };
        let down = LinkState::Disconnected {
            since_ns: 0,
            attempts: 1,
        };
        assert_eq!(
            device_state(down, false, Some(50), 60),
            HealthState::Disconnected
        );
        assert_eq!(device_state(up, false, None, 200), HealthState::Degraded);
        // A frame of the previous connection does not count.
        assert_eq!(
            device_state(up, false, Some(50), 200),
            HealthState::Degraded
        );
        assert_eq!(device_state(up, false, Some(150), 200), HealthState::Ok);
        assert_eq!(
            device_state(up, true, Some(150), 200),
            HealthState::Degraded
        );
        assert_eq!(
            device_state(up, false, Some(150), 150 + SILENT_NS),
            HealthState::Degraded
        );
    }

    #[test]
    fn setup_checks_protocol_and_source() {
        assert!(matches!(
            Setup::new(Want::Imu, &dev("nlink", "serial:/dev/ttyUSB0")),
            Err(DeviceSetupError::Protocol { sensor: "imu", .. })
        ));
        assert!(matches!(
            Setup::new(Want::Uwb, &dev("morse", "serial:/dev/ttyUSB0")),
            Err(DeviceSetupError::Protocol { sensor: "uwb", .. })
        ));
        assert!(matches!(
            Setup::new(Want::Uwb, &dev("eliko", "udp:1")),
            Err(DeviceSetupError::Source { .. })
        ));
        let s = Setup::new(Want::Uwb, &dev("eliko", "tcp:127.0.0.1:25025")).unwrap();
        assert_eq!(s.wire_baud, 0);
        assert_eq!(s.on_connect, eliko::HANDSHAKE.concat().into_bytes());
        let s = Setup::new(Want::Imu, &dev("witmotion", "serial:/dev/ttyUSB0")).unwrap();
        assert_eq!(s.wire_baud, 115_200);
        assert!(s.on_connect.is_empty());
        // 22 bytes at 115200 baud, 8N1.
        assert_eq!(
            wire_time_ns(reading_len(Protocol::WitMotion), 115_200),
            1_909_722
        );
    }
    /// Counts the allocations of the threads that set `COUNTING`.
    mod counting {
        use std::alloc::{GlobalAlloc, Layout, System};
        use std::cell::Cell;
        use std::sync::atomic::{AtomicU64, Ordering};

        pub static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);

        thread_local! {
            pub static COUNTING: Cell<bool> = const { Cell::new(false) };
        }

        pub struct Counting;

        // SAFETY: every call is forwarded unchanged to the system allocator;
        // the counting touches only an atomic and a const thread local.
        #[allow(unsafe_code)]
        unsafe impl GlobalAlloc for Counting {
            unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
                if COUNTING.try_with(Cell::get).unwrap_or(false) {
                    ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
                }
                // SAFETY: the caller's contract is passed through.
                unsafe { System.alloc(layout) }
            }
            unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
                // SAFETY: the caller's contract is passed through.
                unsafe { System.dealloc(ptr, layout) }
            }
            unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
                if COUNTING.try_with(Cell::get).unwrap_or(false) {
                    ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
                }
                // SAFETY: the caller's contract is passed through.
                unsafe { System.realloc(ptr, layout, new_size) }
            }
        }

        #[global_allocator]
        static GLOBAL: Counting = Counting;
    }

    /// Reads `protocol` chunks played on a real pseudo-terminal through a
    /// real link for 1.5 s; returns (samples, allocations) of the reading
    /// thread after the first 0.3 s (connection and first readings are
    /// allowed to allocate).
    fn steady_state_allocations(
        want: Want,
        protocol: &str,
        chunks: Vec<(u64, Vec<u8>)>,
    ) -> (u64, u64) {
        steady_state_allocations_of(want, protocol, chunks, None)
    }

    /// [`steady_state_allocations`], with `[uwb] kind = "twr"` when
    /// `ranging` gives the anchors and the fix builder's settings.
    fn steady_state_allocations_of(
        want: Want,
        protocol: &str,
        chunks: Vec<(u64, Vec<u8>)>,
        ranging: Option<(Vec<AnchorConfig>, FixConfig)>,
    ) -> (u64, u64) {
        use insuwb_devices::emulator::{Faults, Player, PtyEmulator};
        use std::sync::atomic::Ordering;

        let pty = PtyEmulator::open().unwrap();
        let path = pty.driver_path().unwrap().to_owned();
        let mut d = dev(protocol, &format!("serial:{}", path.display()));
        let setup = Setup::new(want, &d).unwrap();
        let mut link = Link::new(
            setup.spec.clone(),
            115_200,
            setup.policy,
            Vec::new(),
            monotonic_ns,
        )
        .unwrap();
        let mut decoder = setup.decoder(0);
        let mut conv = Converter::new(want, &d, VelocityConfig::default()).unwrap();
        if let Some((anchors, fix)) = ranging {
            d.anchors = anchors;
            conv = conv.with_ranging(Ranging::new(&d, fix).unwrap());
        }
        let mut buf = [0u8; READ_BUF_LEN];
        // Connect before the player starts: a pty loses what nobody reads.
        let _ = link.read(&mut buf, Duration::from_millis(1)).unwrap();
        let start = monotonic_ns() + 50_000_000;
        let player = Player::start(pty, chunks, start, monotonic_ns, Faults::none()).unwrap();
        let reading_ns = wire_time_ns(reading_len(setup.protocol), 115_200);
        let mut samples = 0u64;
        let mut counted_from = None;
        while monotonic_ns() < start + 1_500_000_000 {
            if counted_from.is_none() && monotonic_ns() > start + 300_000_000 {
                counted_from = Some((samples, counting::ALLOCATIONS.load(Ordering::Relaxed)));
                counting::COUNTING.with(|c| c.set(true));
            }
            if let Read::Data { n, host_time_ns } = link.read(&mut buf, READ_TIMEOUT).unwrap() {
                let wire = Wire {
                    host_time_ns,
                    baud: 115_200,
                    reading_ns,
                    per_line: per_line(setup.protocol),
                };
                on_bytes(
                    &mut decoder,
                    &mut conv,
                    buf.get(..n).unwrap(),
                    &wire,
                    &mut |out| {
                        if matches!(out, Out::Imu(_) | Out::Fix(_) | Out::Range { .. }) {
                            samples += 1;
                        }
                    },
                );
            }
            // What the loop asks each time round.
            let _ = device_state(link.state(), false, None, monotonic_ns());
            let _ = (
                conv.clock_offset_ns(),
                conv.clock_drift_ppb(),
                conv.dropped_invalid(),
                conv.dropped_time(),
                decoder.stats(),
            );
        }
        counting::COUNTING.with(|c| c.set(false));
        let (s0, a0) = counted_from.unwrap();
        player.stop();
        let _ = player.join().unwrap();
        (
            samples - s0,
            counting::ALLOCATIONS.load(Ordering::Relaxed) - a0,
        )
    }

    #[test]
    fn the_read_decode_convert_path_allocates_nothing_per_sample() {
        use insuwb_devices::play::{self, Encoding};
        use insuwb_group::recording;
        let rec = recording::from_scenario("nlos-long", 1).unwrap();
        // MAVLink: a device clock through the clock filter; 100 Hz.
        let imu = play::imu_chunks(&rec.imu, &Encoding::new(Protocol::Mavlink)).unwrap();
        let (samples, allocations) = steady_state_allocations(Want::Imu, "mavlink", imu);
        eprintln!("mavlink IMU: {samples} samples, {allocations} allocations");
        assert!(samples >= 80, "{samples} samples");
        assert_eq!(allocations, 0, "over {samples} samples");
        // NLink fixes played 10 times faster (100 Hz): clock filter and
        // velocity regression.
        let enc = Encoding {
            speed: 10.0,
            ..Encoding::new(Protocol::Nlink)
        };
        let fixes = play::uwb_chunks(&rec.fixes, &enc).unwrap();
        let (samples, allocations) = steady_state_allocations(Want::Uwb, "nlink", fixes);
        eprintln!("nlink UWB: {samples} fixes, {allocations} allocations");
        assert!(samples >= 80, "{samples} fixes");
        assert_eq!(allocations, 0, "over {samples} fixes");
    }

    #[test]
    fn the_range_path_allocates_nothing_per_range() {
        use insuwb_devices::play::{self, Encoding};
        let (ranges, solving) = twr_ranges();
        // First without the solver (rounds of 4 anchors never reach it):
        // the driver's own path (read, decode, stamp, gate, offset, epoch
        // tables); then with it.
        let fix = FixConfig {
            max_pairs: 8,
            min_pairs: 8,
            ..solving.clone()
        };
        // DWM1001 `lec` lines, 100 rounds a second of 4 anchors, positions
        // printed by the device.
        let lec = play::range_chunks(&ranges, &Encoding::new(Protocol::Dwm1001)).unwrap();
        let (samples, allocations) = steady_state_allocations_of(
            Want::Uwb,
            "dwm1001",
            lec.clone(),
            Some((Vec::new(), fix.clone())),
        );
        eprintln!("dwm1001 ranges: {samples} ranges, {allocations} allocations");
        assert!(samples >= 300, "{samples} ranges");
        assert_eq!(allocations, 0, "over {samples} ranges");
        // NLink tag frames: device clock, anchors from the config.
        let frames = play::range_chunks(&ranges, &Encoding::new(Protocol::Nlink)).unwrap();
        let (samples, allocations) =
            steady_state_allocations_of(Want::Uwb, "nlink", frames, Some((twr_anchors(), fix)));
        eprintln!("nlink ranges: {samples} ranges, {allocations} allocations");
        assert!(samples >= 300, "{samples} ranges");
        assert_eq!(allocations, 0, "over {samples} ranges");
        // With the solver (`insuwb_uwb::range`, a fix per round of 4, the
        // range offset estimated too): nothing allocated per range either.
        let (samples, allocations) =
            steady_state_allocations_of(Want::Uwb, "dwm1001", lec, Some((Vec::new(), solving)));
        eprintln!("dwm1001 ranges with the solver: {samples} ranges, {allocations} allocations");
        assert!(samples >= 300, "{samples} ranges");
        assert_eq!(allocations, 0, "over {samples} ranges with the solver");
    }

    /// The `twr-3.4` scenario's ranges (seed 1) and its fix settings.
    fn twr_ranges() -> (Vec<UwbRange>, FixConfig) {
        let sc = insuwb_fusion::scenario::ScenarioFile::load("twr-3.4").unwrap();
        let fix = sc.fusion_for_seed(1).unwrap().fix;
        (sc.simulate(1).unwrap().range, fix)
    }

    /// The `twr-3.4` anchors: ids 0 to 3 at the corners of a 10 m square.
    fn twr_anchors() -> Vec<AnchorConfig> {
        [[-5.0, -5.0], [5.0, -5.0], [-5.0, 5.0], [5.0, 5.0]]
            .iter()
            .enumerate()
            .map(|(i, p)| AnchorConfig {
                id: i as u32,
                pos_m: [p[0], p[1], 0.0],
            })
            .collect()
    }

    fn range(anchor: u32, range_m: f64, pos: Option<[f64; 3]>, last: bool) -> Reading {
        Reading::Range {
            anchor,
            range_m,
            anchor_pos_m: pos,
            quality: None,
            last_of_round: last,
            device_time: None,
        }
    }

    /// A converter of two-way ranges from `protocol` with the configured
    /// `anchors` and `twr-3.4`'s fix settings.
    fn ranging(protocol: &str, anchors: Vec<AnchorConfig>) -> Converter {
        let mut d = dev(protocol, "serial:/dev/null");
        d.anchors = anchors;
        let (_, fix) = twr_ranges();
        Converter::new(Want::Uwb, &d, VelocityConfig::default())
            .unwrap()
            .with_ranging(Ranging::new(&d, fix).unwrap())
    }

    fn range_of(out: Out) -> UwbRange {
        match out {
            Out::Range { range, .. } => range,
            o => panic!("not a range: {o:?}"),
        }
    }

    #[test]
    fn a_configured_anchor_position_wins_over_the_devices() {
        let surveyed = [1.0, 2.0, 0.5];
        let mut c = ranging(
            "dwm1001",
            vec![AnchorConfig {
                id: 0x0C2B,
                pos_m: surveyed,
            }],
        );
        let r = range_of(c.convert(&range(0x0C2B, 3.0, Some([0.0; 3]), false), 1_000));
        assert_eq!(
            (r.anchor, r.range_m, r.anchor_pos_m),
            (0x0C2B, 3.0, surveyed)
        );
        // Not configured: the device's position.
        let r = range_of(c.convert(&range(0x9825, 2.0, Some([3.0, 0.0, 0.0]), true), 1_000));
        assert_eq!(r.anchor_pos_m, [3.0, 0.0, 0.0]);
        assert_eq!(c.dropped_invalid(), 0);
    }

    #[test]
    fn a_range_to_an_anchor_without_a_position_is_dropped_and_counted() {
        let mut c = ranging("nlink", twr_anchors()[..2].to_vec());
        assert!(matches!(
            c.convert(&range(0, 7.0, None, false), 1_000),
            Out::Range { .. }
        ));
        assert_eq!(c.convert(&range(5, 7.0, None, false), 1_000), Out::Dropped);
        assert_eq!(c.convert(&range(5, 7.0, None, false), 2_000), Out::Dropped);
        assert_eq!(c.convert(&range(6, 7.0, None, false), 3_000), Out::Dropped);
        assert_eq!(c.dropped_invalid(), 3);
        assert_eq!(c.drops.time, 0);
        // One warning per anchor.
        assert_eq!(c.ranging.as_ref().unwrap().warned, vec![5, 6]);
    }

    #[test]
    fn the_ranges_of_a_round_share_its_stamp_and_flags() {
        let mut c = ranging("nlink", twr_anchors());
        let mut q = range(2, 4.0, None, false);
        if let Reading::Range { quality, .. } = &mut q {
            *quality = Some(87);
        }
        // One round: one send time (one frame); the next: another.
        let a = range_of(c.convert(&range(0, 5.0, None, false), 1_000_000));
        let b = range_of(c.convert(&q, 1_000_000));
        let z = range_of(c.convert(&range(3, 6.0, None, true), 1_000_000));
        let next = range_of(c.convert(&range(0, 5.1, None, false), 11_000_000));
        for r in [a, b, z] {
            assert_eq!(r.header.meas_time_ns, 1_000_000);
        }
        assert_eq!(next.header.meas_time_ns, 11_000_000);
        assert_eq!(a.header.flags, 0);
        assert_eq!(b.header.flags, UwbRange::FLAG_QUALITY);
        assert_eq!(b.quality, 87);
        assert_eq!(z.header.flags, UwbRange::FLAG_EPOCH_END);
        assert_eq!(a.anchor_pos_m, [-5.0, -5.0, 0.0]);
        // A round stamped at or before the previous one's is dropped whole.
        let mut c = ranging("nlink", twr_anchors());
        let _ = c.convert(&range(0, 5.0, None, true), 2_000);
        assert_eq!(c.convert(&range(0, 5.0, None, false), 2_000), Out::Dropped);
        assert_eq!(c.convert(&range(1, 5.0, None, true), 2_000), Out::Dropped);
        assert_eq!(c.dropped_time(), 2);
    }

    #[test]
    fn rounds_give_fixes_and_a_dropped_last_range_still_closes_the_round() {
        let mut c = ranging("nlink", twr_anchors());
        let p = [1.0, 2.0];
        let to =
            |a: &AnchorConfig| ((p[0] - a.pos_m[0]).powi(2) + (p[1] - a.pos_m[1]).powi(2)).sqrt();
        let anchors = twr_anchors();
        let mut fixes = Vec::new();
        for k in 1..=5u64 {
            let t = k * 10_000_000;
            for (i, a) in anchors.iter().enumerate() {
                match c.convert(&range(a.id, to(a), None, i == 3), t) {
                    Out::Range { fix, range } => {
                        assert_eq!(fix.is_some(), i == 3, "round {k}, anchor {i}");
                        fixes.extend(fix.map(|f| (f, range)));
                    }
                    o => panic!("{o:?}"),
                }
            }
        }
        assert_eq!(fixes.len(), 5);
        for (f, r) in &fixes {
            assert_eq!(f.header.meas_time_ns, r.header.meas_time_ns);
            assert!(
                (f.pos_m[0] - 1.0).abs() < 1e-3 && (f.pos_m[1] - 2.0).abs() < 1e-3,
                "{f:?}"
            );
        }
        // The round's last range is to an anchor without a position: the
        // round is closed all the same.
        let t = 60_000_000;
        for a in &anchors {
            assert!(matches!(
                c.convert(&range(a.id, to(a), None, false), t),
                Out::Range { fix: None, .. }
            ));
        }
        match c.convert(&range(9, 3.0, None, true), t) {
            Out::Fix(f) => assert_eq!(f.header.meas_time_ns, t),
            o => panic!("{o:?}"),
        }
        assert_eq!(c.dropped_invalid(), 1);
    }

    #[test]
    fn positions_or_ranges_by_kind() {
        let pos = Reading::Position {
            tag: 1,
            pos_m: [1.0, 2.0, 0.0],
            vel_mps: None,
            device_time: None,
            seq: None,
        };
        // TWR: ranges used, the device's positions ignored.
        let mut c = ranging("nlink", twr_anchors());
        assert_eq!(c.convert(&pos, 1_000), Out::Skipped);
        assert!(matches!(
            c.convert(&range(0, 5.0, None, true), 1_000),
            Out::Range { .. }
        ));
        // TDOA: positions used, ranges ignored.
        let mut c = Converter::new(
            Want::Uwb,
            &dev("nlink", "serial:/dev/null"),
            VelocityConfig::default(),
        )
        .unwrap();
        assert_eq!(c.convert(&range(0, 5.0, None, true), 1_000), Out::Skipped);
        assert!(matches!(c.convert(&pos, 2_000), Out::Fix(_)));
        // The protocols that report one kind refuse the other.
        assert!(check_kind(Want::Uwb, Protocol::Dwm1001, UwbKind::Twr).is_ok());
        assert!(check_kind(Want::Uwb, Protocol::Nlink, UwbKind::Twr).is_ok());
        assert!(check_kind(Want::Uwb, Protocol::Nlink, UwbKind::Tdoa).is_ok());
        let e = check_kind(Want::Uwb, Protocol::Dwm1001, UwbKind::Tdoa).unwrap_err();
        assert!(e.to_string().contains("kind = \"twr\""), "{e}");
        assert!(check_kind(Want::Uwb, Protocol::Eliko, UwbKind::Twr).is_err());
    }

    #[test]
    fn a_dwm1001_line_is_stamped_by_its_own_length() {
        // A `lec` line read whole at 1 s: sent its own wire time earlier.
        let line = b"DIST,2,AN0,0001,0.00,0.00,0.00,1.00,AN1,0002,3.00,0.00,0.00,2.00\r\n";
        let mut c = ranging("dwm1001", Vec::new());
        let mut decoder = AnyDecoder::new(Protocol::Dwm1001);
        let wire = Wire {
            host_time_ns: 1_000_000_000,
            baud: 115_200,
            reading_ns: wire_time_ns(reading_len(Protocol::Dwm1001), 115_200),
            per_line: per_line(Protocol::Dwm1001),
        };
        let mut got = Vec::new();
        on_bytes(&mut decoder, &mut c, line, &wire, &mut |o| got.push(o));
        let want = 1_000_000_000 - wire_time_ns(line.len(), 115_200);
        assert_eq!(got.len(), 2, "{got:?}");
        for o in got {
            assert_eq!(range_of(o).header.meas_time_ns, want);
        }
    }
}
