//! The checks of a sensor sample before anything uses it: one path for a
//! measurement, whoever reads it.
//!
//! A sample from a source (simulation, replay, a device) passes a gate
//! before it is published or used: [`ImuGate`] for the IMU stream,
//! [`TdoaGate`] for the UWB TDOA stream, [`RangeGate`] for UWB two-way
//! ranges, [`VelocityGate`] for body-frame velocities (odometry, flow),
//! [`HeightGate`] for heights (a range finder). A gate refuses a sample whose
//! values cannot be a measurement ([`imu_values`], [`tdoa_values`]) or whose
//! time does not follow the stream's, counts every refusal by reason
//! ([`ImuRefusals`], [`TdoaRefusals`]) and says why ([`ImuRefusal`],
//! [`TdoaRefusal`]). The IMU and UWB drivers and the lockstep runner of
//! `insuwb eval` (`insuwb_fusion::runner`) hold the same gates, so eval
//! refuses exactly the samples a replay through the stages refuses. The
//! live IMU sources (a device, `ros2:/TOPIC`) call [`imu_values`] and keep
//! the time order of their host stamps themselves; the INS engine and the
//! fix builder call the value checks again on what reaches them from other
//! callers, with the same limits. The checks are pure and allocate nothing.
//!
//! ```
//! use insuwb_msg::check::{ImuGate, ImuRefusal};
//! use insuwb_msg::{Header, ImuSample};
//! let mut gate = ImuGate::new();
//! let at = |t_ns| ImuSample {
//!     header: Header::new(0, t_ns),
//!     accel_mps2: [0.0, 0.0, 9.81],
//!     gyro_rps: [0.0; 3],
//! };
//! assert_eq!(gate.check(&at(10)), Ok(()));
//! assert_eq!(gate.check(&at(10)), Err(ImuRefusal::TimeRepeated { time_ns: 10 }));
//! let mut nan = at(20);
//! nan.gyro_rps[2] = f64::NAN;
//! assert!(gate.check(&nan).is_err());
//! assert_eq!(gate.check(&at(20)), Ok(()));
//! assert_eq!((gate.refusals().invalid(), gate.refusals().time()), (1, 1));
//! ```
//!
//! # What is refused
//!
//! - IMU: a NaN or infinite value; an accelerometer axis at or above
//!   [`MAX_ACCEL_MPS2`] or a gyro axis at or above [`MAX_RATE_RPS`] in
//!   magnitude; a time before the previous accepted sample's, or equal to
//!   it (a repeat).
//! - TDOA: a NaN or infinite difference or anchor coordinate; anchor A and
//!   B with one id; a difference longer than the distance between its two
//!   anchors (the triangle inequality allows at most that: a corrupted or
//!   multipath-wrapped measurement); a time before the previous accepted
//!   measurement's; the same unordered anchor pair again at the time of an
//!   accepted measurement (several pairs of one epoch share a time, one
//!   pair does not), checked for the first [`MAX_PAIRS_PER_TIME`] pairs of
//!   a time.
//!
//! - Range: a NaN or infinite range or anchor coordinate; a negative range,
//!   or one at or above [`MAX_RANGE_M`]; a quality above 100; a time before
//!   the previous accepted range's; the same anchor again at the time of an
//!   accepted range, checked for the first [`MAX_PAIRS_PER_TIME`] anchors
//!   of a time.
//!
//! - Body velocity: a NaN or infinite velocity or sigma; a negative sigma;
//!   no axis measured (every sigma 0); a measured axis at or above
//!   [`MAX_BODY_SPEED_MPS`]; an unknown source; a time before the previous
//!   accepted measurement's, or equal to it.
//!
//! - Height: a NaN or infinite range; a range at or below 0 or at or above
//!   [`MAX_HEIGHT_RANGE_M`]; an unknown source; a time before the previous
//!   accepted measurement's, or equal to it.
//!
//! The value refusals (`Invalid`) are what a driver's heartbeat counts in
//! `Health::dropped_invalid`, the time refusals in `Health::dropped_time`.
//! A refused sample changes nothing in its gate but the counts. A new
//! sample type gets its value check, its gate, its refusal enum and its
//! counts the same way: a stream whose times strictly increase (the IMU,
//! body velocities, heights) implements [`Ordered`] and its gate is an
//! [`OrderedGate`].

use crate::{BodyVelocity, Height, ImuSample, UwbRange, UwbTdoa};
use serde::{Deserialize, Serialize};

/// Largest plausible accelerometer magnitude per axis, m/s^2 (excluded).
pub const MAX_ACCEL_MPS2: f64 = 400.0;
/// Largest plausible gyro magnitude per axis, rad/s (excluded).
pub const MAX_RATE_RPS: f64 = 70.0;
/// Largest plausible body-frame speed per axis, m/s (excluded).
pub const MAX_BODY_SPEED_MPS: f64 = 50.0;
/// Longest plausible range finder distance, m (excluded): downward lidars
/// reach tens of metres, the flow deck's VL53L1x 4 m.
pub const MAX_HEIGHT_RANGE_M: f64 = 100.0;
/// Longest plausible UWB range, m (excluded): the radios reach a few
/// hundred metres line of sight.
pub const MAX_RANGE_M: f64 = 1000.0;
/// Largest quality figure a range may carry (percent).
pub const MAX_RANGE_QUALITY: u32 = 100;
/// Anchor pairs a [`TdoaGate`] remembers at one time to find repeats;
/// further pairs of that time are not checked.
pub const MAX_PAIRS_PER_TIME: usize = 64;

/// Why an IMU sample's values cannot be a measurement.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum InvalidImu {
    /// A value is NaN or infinite.
    #[error("imu {field}[{axis}] is not finite ({value})")]
    NonFinite {
        /// `accel_mps2` or `gyro_rps`.
        field: &'static str,
        /// The axis, 0 to 2.
        axis: usize,
        /// The offending value.
        value: f64,
    },
    /// A value's magnitude is not below its limit.
    #[error("imu {field}[{axis}] = {value} is out of range (|value| < {limit})")]
    OutOfRange {
        /// `accel_mps2` or `gyro_rps`.
        field: &'static str,
        /// The axis, 0 to 2.
        axis: usize,
        /// The offending value.
        value: f64,
        /// [`MAX_ACCEL_MPS2`] or [`MAX_RATE_RPS`].
        limit: f64,
    },
}

/// Why an [`ImuGate`] refused an IMU sample.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum ImuRefusal {
    /// Its values cannot be a measurement.
    #[error(transparent)]
    Invalid(#[from] InvalidImu),
    /// Its time is before the previous accepted sample's.
    #[error("imu time {time_ns} ns is before the previous sample's {last_ns} ns")]
    TimeBackwards {
        /// Time of the refused sample, ns.
        time_ns: u64,
        /// Time of the previous accepted sample, ns.
        last_ns: u64,
    },
    /// Its time is the previous accepted sample's.
    #[error("imu time {time_ns} ns repeats the previous sample's")]
    TimeRepeated {
        /// Time of both samples, ns.
        time_ns: u64,
    },
}

impl ImuRefusal {
    /// Whether the sample was refused for its time (`Health::dropped_time`),
    /// not its values (`Health::dropped_invalid`).
    #[must_use]
    pub fn is_time(&self) -> bool {
        !matches!(self, Self::Invalid(_))
    }
}

/// Why a TDOA measurement's values cannot be a measurement.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum InvalidTdoa {
    /// A value is NaN or infinite.
    #[error("tdoa {field} is not finite ({value})")]
    NonFinite {
        /// `diff_m`, `anchor_a_pos_m` or `anchor_b_pos_m`.
        field: &'static str,
        /// The offending value.
        value: f64,
    },
    /// Anchor A and anchor B have the same id.
    #[error("tdoa pairs anchor {id} with itself")]
    SameAnchor {
        /// The anchor id.
        id: u32,
    },
    /// The range difference is longer than the distance between its anchors.
    #[error(
        "tdoa range difference {diff_m} m is longer than the {baseline_m} m between anchors {a} and {b}"
    )]
    Impossible {
        /// The measured difference, m.
        diff_m: f64,
        /// Distance between the two anchors, m.
        baseline_m: f64,
        /// Anchor A id.
        a: u32,
        /// Anchor B id.
        b: u32,
    },
}

/// Why a [`TdoaGate`] refused a TDOA measurement.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum TdoaRefusal {
    /// Its values cannot be a measurement.
    #[error(transparent)]
    Invalid(#[from] InvalidTdoa),
    /// Its time is before the previous accepted measurement's.
    #[error("tdoa time {time_ns} ns is before the previous measurement's {last_ns} ns")]
    TimeBackwards {
        /// Time of the refused measurement, ns.
        time_ns: u64,
        /// Time of the previous accepted measurement, ns.
        last_ns: u64,
    },
    /// Its anchor pair was measured already at this time.
    #[error("tdoa pair ({a}, {b}) repeated at {time_ns} ns")]
    PairRepeated {
        /// The lower anchor id.
        a: u32,
        /// The higher anchor id.
        b: u32,
        /// The time of both measurements, ns.
        time_ns: u64,
    },
}

impl TdoaRefusal {
    /// Whether the measurement was refused for its time or as a repeat
    /// (`Health::dropped_time`), not its values (`Health::dropped_invalid`).
    #[must_use]
    pub fn is_time(&self) -> bool {
        !matches!(self, Self::Invalid(_))
    }
}

/// IMU samples refused, by reason.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct ImuRefusals {
    /// A NaN or infinite value ([`InvalidImu::NonFinite`]).
    pub non_finite: u64,
    /// A value out of range ([`InvalidImu::OutOfRange`]).
    pub out_of_range: u64,
    /// A time before the previous sample's ([`ImuRefusal::TimeBackwards`]).
    pub time_backwards: u64,
    /// The previous sample's time again ([`ImuRefusal::TimeRepeated`]).
    pub time_repeated: u64,
}

impl ImuRefusals {
    /// Counts `r` under its reason.
    pub fn count(&mut self, r: &ImuRefusal) {
        let n = match r {
            ImuRefusal::Invalid(InvalidImu::NonFinite { .. }) => &mut self.non_finite,
            ImuRefusal::Invalid(InvalidImu::OutOfRange { .. }) => &mut self.out_of_range,
            ImuRefusal::TimeBackwards { .. } => &mut self.time_backwards,
            ImuRefusal::TimeRepeated { .. } => &mut self.time_repeated,
        };
        *n += 1;
    }
}

/// TDOA measurements refused, by reason.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct TdoaRefusals {
    /// A NaN or infinite value ([`InvalidTdoa::NonFinite`]).
    pub non_finite: u64,
    /// One anchor id twice ([`InvalidTdoa::SameAnchor`]).
    pub same_anchor: u64,
    /// A difference longer than the anchors' distance ([`InvalidTdoa::Impossible`]).
    pub impossible: u64,
    /// A time before the previous measurement's ([`TdoaRefusal::TimeBackwards`]).
    pub time_backwards: u64,
    /// A pair again at one time ([`TdoaRefusal::PairRepeated`]).
    pub pair_repeated: u64,
}

impl TdoaRefusals {
    /// Counts `r` under its reason.
    pub fn count(&mut self, r: &TdoaRefusal) {
        let n = match r {
            TdoaRefusal::Invalid(InvalidTdoa::NonFinite { .. }) => &mut self.non_finite,
            TdoaRefusal::Invalid(InvalidTdoa::SameAnchor { .. }) => &mut self.same_anchor,
            TdoaRefusal::Invalid(InvalidTdoa::Impossible { .. }) => &mut self.impossible,
            TdoaRefusal::TimeBackwards { .. } => &mut self.time_backwards,
            TdoaRefusal::PairRepeated { .. } => &mut self.pair_repeated,
        };
        *n += 1;
    }
}

/// Why a range measurement's values cannot be a measurement.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum InvalidRange {
    /// A value is NaN or infinite.
    #[error("range {field} is not finite ({value})")]
    NonFinite {
        /// `range_m` or `anchor_pos_m`.
        field: &'static str,
        /// The offending value.
        value: f64,
    },
    /// The range is negative or not below [`MAX_RANGE_M`].
    #[error("range to anchor {anchor} = {range_m} m is out of range (0 <= range < {limit_m} m)")]
    OutOfRange {
        /// The anchor id.
        anchor: u32,
        /// The measured range, m.
        range_m: f64,
        /// [`MAX_RANGE_M`].
        limit_m: f64,
    },
    /// The quality figure is above [`MAX_RANGE_QUALITY`].
    #[error("range to anchor {anchor}: quality {quality} is above {MAX_RANGE_QUALITY}")]
    Quality {
        /// The anchor id.
        anchor: u32,
        /// The quality given.
        quality: u32,
    },
}

/// Why a [`RangeGate`] refused a range measurement.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum RangeRefusal {
    /// Its values cannot be a measurement.
    #[error(transparent)]
    Invalid(#[from] InvalidRange),
    /// Its time is before the previous accepted measurement's.
    #[error("range time {time_ns} ns is before the previous measurement's {last_ns} ns")]
    TimeBackwards {
        /// Time of the refused measurement, ns.
        time_ns: u64,
        /// Time of the previous accepted measurement, ns.
        last_ns: u64,
    },
    /// Its anchor was measured already at this time.
    #[error("range to anchor {anchor} repeated at {time_ns} ns")]
    AnchorRepeated {
        /// The anchor id.
        anchor: u32,
        /// The time of both measurements, ns.
        time_ns: u64,
    },
}

impl RangeRefusal {
    /// Whether the measurement was refused for its time or as a repeat
    /// (`Health::dropped_time`), not its values (`Health::dropped_invalid`).
    #[must_use]
    pub fn is_time(&self) -> bool {
        !matches!(self, Self::Invalid(_))
    }
}

/// Range measurements refused, by reason.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct RangeRefusals {
    /// A NaN or infinite value ([`InvalidRange::NonFinite`]).
    pub non_finite: u64,
    /// A negative or too long range ([`InvalidRange::OutOfRange`]).
    pub out_of_range: u64,
    /// A quality above 100 ([`InvalidRange::Quality`]).
    pub quality: u64,
    /// A time before the previous measurement's ([`RangeRefusal::TimeBackwards`]).
    pub time_backwards: u64,
    /// An anchor again at one time ([`RangeRefusal::AnchorRepeated`]).
    pub anchor_repeated: u64,
}

impl RangeRefusals {
    /// Counts `r` under its reason.
    pub fn count(&mut self, r: &RangeRefusal) {
        let n = match r {
            RangeRefusal::Invalid(InvalidRange::NonFinite { .. }) => &mut self.non_finite,
            RangeRefusal::Invalid(InvalidRange::OutOfRange { .. }) => &mut self.out_of_range,
            RangeRefusal::Invalid(InvalidRange::Quality { .. }) => &mut self.quality,
            RangeRefusal::TimeBackwards { .. } => &mut self.time_backwards,
            RangeRefusal::AnchorRepeated { .. } => &mut self.anchor_repeated,
        };
        *n += 1;
    }
}

/// Why a body-velocity measurement's values cannot be a measurement.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum InvalidVelocity {
    /// A value is NaN or infinite.
    #[error("body velocity {field} is not finite ({value})")]
    NonFinite {
        /// `vel_mps` or `sigma_mps`.
        field: &'static str,
        /// The offending value.
        value: f64,
    },
    /// A standard deviation is negative, or every one is 0 (nothing measured).
    #[error("body velocity sigma_mps {sigma:?} m/s: each must be >= 0 and one > 0")]
    Sigma {
        /// The standard deviations, m/s.
        sigma: [f64; 3],
    },
    /// A measured axis at or above [`MAX_BODY_SPEED_MPS`] in magnitude.
    #[error("body velocity axis {axis} is {value} m/s, at or beyond the {limit} m/s limit")]
    OutOfRange {
        /// The axis (0 x, 1 y, 2 z).
        axis: usize,
        /// The value, m/s.
        value: f64,
        /// The limit, m/s.
        limit: f64,
    },
    /// The source is none of `BodyVelocity::SOURCE_*`.
    #[error("body velocity source {0} is unknown")]
    Source(u32),
}

/// Why a [`VelocityGate`] refused a body-velocity measurement.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum VelocityRefusal {
    /// Its values cannot be a measurement.
    #[error(transparent)]
    Invalid(#[from] InvalidVelocity),
    /// Its time is before the previous accepted measurement's.
    #[error("body velocity time {time_ns} ns is before the previous measurement's {last_ns} ns")]
    TimeBackwards {
        /// Time of the refused measurement, ns.
        time_ns: u64,
        /// Time of the previous accepted measurement, ns.
        last_ns: u64,
    },
    /// Its time is the previous accepted measurement's (a repeat).
    #[error("body velocity time {time_ns} ns repeats the previous measurement's")]
    TimeRepeated {
        /// The time of both, ns.
        time_ns: u64,
    },
}

impl VelocityRefusal {
    /// Whether the measurement was refused for its time, not its values.
    #[must_use]
    pub fn is_time(&self) -> bool {
        !matches!(self, Self::Invalid(_))
    }
}

/// Body-velocity measurements refused, by reason.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct VelocityRefusals {
    /// A NaN or infinite value ([`InvalidVelocity::NonFinite`]).
    pub non_finite: u64,
    /// A negative sigma, or none measured ([`InvalidVelocity::Sigma`]).
    pub sigma: u64,
    /// A speed out of range ([`InvalidVelocity::OutOfRange`]).
    pub out_of_range: u64,
    /// An unknown source ([`InvalidVelocity::Source`]).
    pub source: u64,
    /// A time before the previous measurement's ([`VelocityRefusal::TimeBackwards`]).
    pub time_backwards: u64,
    /// The previous measurement's time again ([`VelocityRefusal::TimeRepeated`]).
    pub time_repeated: u64,
}

impl VelocityRefusals {
    /// Counts `r` under its reason.
    pub fn count(&mut self, r: &VelocityRefusal) {
        let n = match r {
            VelocityRefusal::Invalid(InvalidVelocity::NonFinite { .. }) => &mut self.non_finite,
            VelocityRefusal::Invalid(InvalidVelocity::Sigma { .. }) => &mut self.sigma,
            VelocityRefusal::Invalid(InvalidVelocity::OutOfRange { .. }) => &mut self.out_of_range,
            VelocityRefusal::Invalid(InvalidVelocity::Source(_)) => &mut self.source,
            VelocityRefusal::TimeBackwards { .. } => &mut self.time_backwards,
            VelocityRefusal::TimeRepeated { .. } => &mut self.time_repeated,
        };
        *n += 1;
    }
}

/// Why a height measurement's values cannot be a measurement.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum InvalidHeight {
    /// The range is NaN or infinite.
    #[error("height range_m is not finite ({0})")]
    NonFinite(f64),
    /// The range is at or below 0 or at or above [`MAX_HEIGHT_RANGE_M`].
    #[error("height range_m is {value} m, outside (0, {limit}) m")]
    OutOfRange {
        /// The range, m.
        value: f64,
        /// The limit, m.
        limit: f64,
    },
    /// The source is none of `Height::SOURCE_*`.
    #[error("height source {0} is unknown")]
    Source(u32),
}

/// Why a [`HeightGate`] refused a height measurement.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum HeightRefusal {
    /// Its values cannot be a measurement.
    #[error(transparent)]
    Invalid(#[from] InvalidHeight),
    /// Its time is before the previous accepted measurement's.
    #[error("height time {time_ns} ns is before the previous measurement's {last_ns} ns")]
    TimeBackwards {
        /// Time of the refused measurement, ns.
        time_ns: u64,
        /// Time of the previous accepted measurement, ns.
        last_ns: u64,
    },
    /// Its time equals the previous accepted measurement's.
    #[error("height time {time_ns} ns repeats the previous measurement's")]
    TimeRepeated {
        /// The time of both, ns.
        time_ns: u64,
    },
}

/// Height measurements refused, by reason.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct HeightRefusals {
    /// A NaN or infinite range ([`InvalidHeight::NonFinite`]).
    pub non_finite: u64,
    /// A range out of range ([`InvalidHeight::OutOfRange`]).
    pub out_of_range: u64,
    /// An unknown source ([`InvalidHeight::Source`]).
    pub source: u64,
    /// A time before the previous measurement's ([`HeightRefusal::TimeBackwards`]).
    pub time_backwards: u64,
    /// The previous measurement's time again ([`HeightRefusal::TimeRepeated`]).
    pub time_repeated: u64,
}

impl HeightRefusals {
    /// Counts `r` under its reason.
    pub fn count(&mut self, r: &HeightRefusal) {
        let n = match r {
            HeightRefusal::Invalid(InvalidHeight::NonFinite(_)) => &mut self.non_finite,
            HeightRefusal::Invalid(InvalidHeight::OutOfRange { .. }) => &mut self.out_of_range,
            HeightRefusal::Invalid(InvalidHeight::Source(_)) => &mut self.source,
            HeightRefusal::TimeBackwards { .. } => &mut self.time_backwards,
            HeightRefusal::TimeRepeated { .. } => &mut self.time_repeated,
        };
        *n += 1;
    }
}

/// The sums every refusal count has: `invalid` (refused for their
/// values, `Health::dropped_invalid`), `time` (refused for their time or
/// as repeats, `Health::dropped_time`) and `total`.
macro_rules! refusal_sums {
    ($t:ty; invalid: $($i:ident),+; time: $($k:ident),+) => {
        impl $t {
            /// Refused for their values (`Health::dropped_invalid`).
            #[must_use]
            pub fn invalid(&self) -> u64 {
                0 $(+ self.$i)+
            }

            /// Refused for their time or as repeats (`Health::dropped_time`).
            #[must_use]
            pub fn time(&self) -> u64 {
                0 $(+ self.$k)+
            }

            /// Refused in all.
            #[must_use]
            pub fn total(&self) -> u64 {
                self.invalid() + self.time()
            }
        }
    };
}
refusal_sums!(ImuRefusals; invalid: non_finite, out_of_range; time: time_backwards, time_repeated);
refusal_sums!(TdoaRefusals; invalid: non_finite, same_anchor, impossible; time: time_backwards, pair_repeated);
refusal_sums!(RangeRefusals; invalid: non_finite, out_of_range, quality; time: time_backwards, anchor_repeated);
refusal_sums!(VelocityRefusals; invalid: non_finite, sigma, out_of_range, source; time: time_backwards, time_repeated);
refusal_sums!(HeightRefusals; invalid: non_finite, out_of_range, source; time: time_backwards, time_repeated);

/// Samples refused, by sample type and reason (what `insuwb eval` reports).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Refusals {
    /// IMU samples.
    pub imu: ImuRefusals,
    /// TDOA measurements.
    pub tdoa: TdoaRefusals,
    /// Body-velocity measurements (odometry, flow).
    #[serde(default)]
    pub velocity: VelocityRefusals,
    /// UWB two-way ranges.
    #[serde(default)]
    pub range: RangeRefusals,
    /// Heights (a range finder).
    #[serde(default)]
    pub height: HeightRefusals,
}

/// Checks a range measurement's values: finite, `0 <= range_m <`
/// [`MAX_RANGE_M`], a quality (when flagged) of at most
/// [`MAX_RANGE_QUALITY`].
///
/// # Errors
/// The first failed check, in that order.
pub fn range_values(m: &UwbRange) -> Result<(), InvalidRange> {
    if !m.range_m.is_finite() {
        return Err(InvalidRange::NonFinite {
            field: "range_m",
            value: m.range_m,
        });
    }
    if let Some(&value) = m.anchor_pos_m.iter().find(|v| !v.is_finite()) {
        return Err(InvalidRange::NonFinite {
            field: "anchor_pos_m",
            value,
        });
    }
    if !(0.0..MAX_RANGE_M).contains(&m.range_m) {
        return Err(InvalidRange::OutOfRange {
            anchor: m.anchor,
            range_m: m.range_m,
            limit_m: MAX_RANGE_M,
        });
    }
    if m.header.flags & UwbRange::FLAG_QUALITY != 0 && m.quality > MAX_RANGE_QUALITY {
        return Err(InvalidRange::Quality {
            anchor: m.anchor,
            quality: m.quality,
        });
    }
    Ok(())
}

/// Checks a body-velocity measurement's values: finite, sigmas >= 0 with
/// one > 0, each measured axis below [`MAX_BODY_SPEED_MPS`], a known source.
///
/// # Errors
/// The first failed check, in that order.
pub fn velocity_values(m: &BodyVelocity) -> Result<(), InvalidVelocity> {
    for (field, values) in [("vel_mps", &m.vel_mps), ("sigma_mps", &m.sigma_mps)] {
        if let Some(&value) = values.iter().find(|v| !v.is_finite()) {
            return Err(InvalidVelocity::NonFinite { field, value });
        }
    }
    if m.sigma_mps.iter().any(|&s| s < 0.0) || m.sigma_mps.iter().all(|&s| s == 0.0) {
        return Err(InvalidVelocity::Sigma { sigma: m.sigma_mps });
    }
    for (axis, (&value, &sigma)) in m.vel_mps.iter().zip(&m.sigma_mps).enumerate() {
        if sigma > 0.0 && value.abs() >= MAX_BODY_SPEED_MPS {
            return Err(InvalidVelocity::OutOfRange {
                axis,
                value,
                limit: MAX_BODY_SPEED_MPS,
            });
        }
    }
    if !matches!(
        m.source,
        BodyVelocity::SOURCE_ODOMETRY | BodyVelocity::SOURCE_FLOW
    ) {
        return Err(InvalidVelocity::Source(m.source));
    }
    Ok(())
}

/// Checks a height measurement's values: a finite range in `(0,`
/// [`MAX_HEIGHT_RANGE_M`]`)`, a known source.
///
/// # Errors
/// The first failed check, in that order.
pub fn height_values(m: &Height) -> Result<(), InvalidHeight> {
    if !m.range_m.is_finite() {
        return Err(InvalidHeight::NonFinite(m.range_m));
    }
    if m.range_m <= 0.0 || m.range_m >= MAX_HEIGHT_RANGE_M {
        return Err(InvalidHeight::OutOfRange {
            value: m.range_m,
            limit: MAX_HEIGHT_RANGE_M,
        });
    }
    if m.source != Height::SOURCE_RANGE_FINDER {
        return Err(InvalidHeight::Source(m.source));
    }
    Ok(())
}

/// Checks an IMU sample's values: finite, and each axis below
/// [`MAX_ACCEL_MPS2`] (accelerometer) or [`MAX_RATE_RPS`] (gyro).
///
/// # Errors
/// The first offending value, accelerometer axes first.
pub fn imu_values(s: &ImuSample) -> Result<(), InvalidImu> {
    for (field, values, limit) in [
        ("accel_mps2", &s.accel_mps2, MAX_ACCEL_MPS2),
        ("gyro_rps", &s.gyro_rps, MAX_RATE_RPS),
    ] {
        for (axis, &value) in values.iter().enumerate() {
            if !value.is_finite() {
                return Err(InvalidImu::NonFinite { field, axis, value });
            }
            if value.abs() >= limit {
                return Err(InvalidImu::OutOfRange {
                    field,
                    axis,
                    value,
                    limit,
                });
            }
        }
    }
    Ok(())
}

/// Checks a TDOA measurement's values: finite, two distinct anchors, a
/// difference no longer than the distance between them.
///
/// # Errors
/// The first failed check, in that order.
pub fn tdoa_values(m: &UwbTdoa) -> Result<(), InvalidTdoa> {
    if !m.diff_m.is_finite() {
        return Err(InvalidTdoa::NonFinite {
            field: "diff_m",
            value: m.diff_m,
        });
    }
    for (field, p) in [
        ("anchor_a_pos_m", &m.anchor_a_pos_m),
        ("anchor_b_pos_m", &m.anchor_b_pos_m),
    ] {
        if let Some(&value) = p.iter().find(|v| !v.is_finite()) {
            return Err(InvalidTdoa::NonFinite { field, value });
        }
    }
    if m.anchor_a == m.anchor_b {
        return Err(InvalidTdoa::SameAnchor { id: m.anchor_a });
    }
    let baseline_m = m
        .anchor_a_pos_m
        .iter()
        .zip(&m.anchor_b_pos_m)
        .map(|(a, b)| (a - b) * (a - b))
        .sum::<f64>()
        .sqrt();
    if m.diff_m.abs() > baseline_m {
        return Err(InvalidTdoa::Impossible {
            diff_m: m.diff_m,
            baseline_m,
            a: m.anchor_a,
            b: m.anchor_b,
        });
    }
    Ok(())
}

/// The time rule of a stream whose samples each have a time of their own
/// (IMU, body velocity): strictly after the previous accepted sample's.
/// `Err(Some(last))`: before it; `Err(None)`: equal to it (a repeat).
fn strictly_after(last_ns: Option<u64>, time_ns: u64) -> Result<(), Option<u64>> {
    match last_ns {
        Some(last) if time_ns < last => Err(Some(last)),
        Some(last) if time_ns == last => Err(None),
        _ => Ok(()),
    }
}

/// The gate of a TDOA stream: values ([`tdoa_values`]), then a time not
/// before the previous accepted measurement's and no pair twice at one
/// time (see the module doc). Holds its pair table inline: no allocation.
#[derive(Debug, Clone)]
pub struct TdoaGate {
    last_ns: Option<u64>,
    /// Unordered pairs `(min id, max id)` accepted at `last_ns`.
    pairs: [(u32, u32); MAX_PAIRS_PER_TIME],
    n_pairs: usize,
    refusals: TdoaRefusals,
}

impl Default for TdoaGate {
    fn default() -> Self {
        Self {
            last_ns: None,
            pairs: [(0, 0); MAX_PAIRS_PER_TIME],
            n_pairs: 0,
            refusals: TdoaRefusals::default(),
        }
    }
}

impl TdoaGate {
    /// A gate that has seen nothing.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// Checks `m` (its time is `header.meas_time_ns`); an accepted
    /// measurement's time and pair are what the next is compared with.
    ///
    /// # Errors
    /// Why `m` is refused (also counted in [`TdoaGate::refusals`]).
    pub fn check(&mut self, m: &UwbTdoa) -> Result<(), TdoaRefusal> {
        let pair = (m.anchor_a.min(m.anchor_b), m.anchor_a.max(m.anchor_b));
        let r = self.verdict(m, pair);
        match &r {
            Ok(()) => {
                let t = m.header.meas_time_ns;
                if self.last_ns != Some(t) {
                    self.last_ns = Some(t);
                    self.n_pairs = 0;
                }
                if let Some(slot) = self.pairs.get_mut(self.n_pairs) {
                    *slot = pair;
                    self.n_pairs += 1;
                }
            }
            Err(e) => self.refusals.count(e),
        }
        r
    }

    fn verdict(&self, m: &UwbTdoa, (a, b): (u32, u32)) -> Result<(), TdoaRefusal> {
        tdoa_values(m)?;
        let time_ns = m.header.meas_time_ns;
        match self.last_ns {
            Some(last_ns) if time_ns < last_ns => {
                Err(TdoaRefusal::TimeBackwards { time_ns, last_ns })
            }
            Some(last_ns)
                if time_ns == last_ns
                    && self
                        .pairs
                        .get(..self.n_pairs)
                        .is_some_and(|p| p.contains(&(a, b))) =>
            {
                Err(TdoaRefusal::PairRepeated { a, b, time_ns })
            }
            _ => Ok(()),
        }
    }

    /// The measurements refused so far, by reason.
    #[must_use]
    pub fn refusals(&self) -> &TdoaRefusals {
        &self.refusals
    }
}

/// The gate of a range stream: values ([`range_values`]), then a time not
/// before the previous accepted measurement's and no anchor twice at one
/// time (a ranging round stamps its anchors at once). Holds its anchor
/// table inline: no allocation.
#[derive(Debug, Clone)]
pub struct RangeGate {
    last_ns: Option<u64>,
    anchors: [u32; MAX_PAIRS_PER_TIME],
    n_anchors: usize,
    refusals: RangeRefusals,
}

impl Default for RangeGate {
    fn default() -> Self {
        Self {
            last_ns: None,
            anchors: [0; MAX_PAIRS_PER_TIME],
            n_anchors: 0,
            refusals: RangeRefusals::default(),
        }
    }
}

impl RangeGate {
    /// A gate that has seen nothing.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// Checks `m`; an accepted measurement's time and anchor are what the
    /// next is compared with.
    ///
    /// # Errors
    /// Why `m` is refused (also counted in [`RangeGate::refusals`]).
    pub fn check(&mut self, m: &UwbRange) -> Result<(), RangeRefusal> {
        let r = self.verdict(m);
        match &r {
            Ok(()) => {
                let t = m.header.meas_time_ns;
                if self.last_ns != Some(t) {
                    self.last_ns = Some(t);
                    self.n_anchors = 0;
                }
                if let Some(slot) = self.anchors.get_mut(self.n_anchors) {
                    *slot = m.anchor;
                    self.n_anchors += 1;
                }
            }
            Err(e) => self.refusals.count(e),
        }
        r
    }

    fn verdict(&self, m: &UwbRange) -> Result<(), RangeRefusal> {
        range_values(m)?;
        let time_ns = m.header.meas_time_ns;
        match self.last_ns {
            Some(last_ns) if time_ns < last_ns => {
                Err(RangeRefusal::TimeBackwards { time_ns, last_ns })
            }
            Some(last_ns)
                if time_ns == last_ns
                    && self
                        .anchors
                        .get(..self.n_anchors)
                        .is_some_and(|a| a.contains(&m.anchor)) =>
            {
                Err(RangeRefusal::AnchorRepeated {
                    anchor: m.anchor,
                    time_ns,
                })
            }
            _ => Ok(()),
        }
    }

    /// The measurements refused so far, by reason.
    #[must_use]
    pub fn refusals(&self) -> &RangeRefusals {
        &self.refusals
    }
}

/// A sample whose stream's gate refuses values that cannot be a
/// measurement and any time not strictly after the previous accepted
/// sample's ([`OrderedGate`]): the IMU, body velocities, heights.
pub trait Ordered {
    /// Why its values cannot be a measurement.
    type Invalid;
    /// Why a gate refused it.
    type Refusal: From<Self::Invalid>;
    /// Its refusals, by reason.
    type Refusals: Default + Clone + std::fmt::Debug;
    /// Its measurement time, ns.
    fn time_ns(&self) -> u64;
    /// Its value check.
    ///
    /// # Errors
    /// The first failed check.
    fn values(&self) -> Result<(), Self::Invalid>;
    /// The refusal of a time before the previous accepted one, `last_ns`.
    fn backwards(time_ns: u64, last_ns: u64) -> Self::Refusal;
    /// The refusal of the previous accepted time again.
    fn repeated(time_ns: u64) -> Self::Refusal;
    /// Counts `r` under its reason.
    fn count(counts: &mut Self::Refusals, r: &Self::Refusal);
}

/// The gate of a stream of [`Ordered`] samples: values, then a time
/// strictly after the previous accepted sample's (see the module doc).
#[derive(Debug, Clone)]
pub struct OrderedGate<T: Ordered> {
    last_ns: Option<u64>,
    refusals: T::Refusals,
}

impl<T: Ordered> Default for OrderedGate<T> {
    fn default() -> Self {
        Self {
            last_ns: None,
            refusals: T::Refusals::default(),
        }
    }
}

impl<T: Ordered> OrderedGate<T> {
    /// A gate that has seen nothing.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// Checks `s`; an accepted sample's time becomes the one the next must
    /// follow.
    ///
    /// # Errors
    /// Why `s` is refused (also counted in [`OrderedGate::refusals`]).
    pub fn check(&mut self, s: &T) -> Result<(), T::Refusal> {
        let r = self.verdict(s);
        match &r {
            Ok(()) => self.last_ns = Some(s.time_ns()),
            Err(e) => T::count(&mut self.refusals, e),
        }
        r
    }

    fn verdict(&self, s: &T) -> Result<(), T::Refusal> {
        s.values()?;
        let time_ns = s.time_ns();
        strictly_after(self.last_ns, time_ns).map_err(|last| match last {
            Some(last_ns) => T::backwards(time_ns, last_ns),
            None => T::repeated(time_ns),
        })
    }

    /// The samples refused so far, by reason.
    #[must_use]
    pub fn refusals(&self) -> &T::Refusals {
        &self.refusals
    }
}

/// Implements [`Ordered`] for a sample type with its value check, its
/// refusal and its counts.
macro_rules! ordered {
    ($t:ty, $values:ident, $invalid:ty, $refusal:ident, $refusals:ty) => {
        impl Ordered for $t {
            type Invalid = $invalid;
            type Refusal = $refusal;
            type Refusals = $refusals;
            fn time_ns(&self) -> u64 {
                self.header.meas_time_ns
            }
            fn values(&self) -> Result<(), $invalid> {
                $values(self)
            }
            fn backwards(time_ns: u64, last_ns: u64) -> $refusal {
                $refusal::TimeBackwards { time_ns, last_ns }
            }
            fn repeated(time_ns: u64) -> $refusal {
                $refusal::TimeRepeated { time_ns }
            }
            fn count(counts: &mut $refusals, r: &$refusal) {
                counts.count(r);
            }
        }
    };
}
ordered!(ImuSample, imu_values, InvalidImu, ImuRefusal, ImuRefusals);
ordered!(
    BodyVelocity,
    velocity_values,
    InvalidVelocity,
    VelocityRefusal,
    VelocityRefusals
);
ordered!(
    Height,
    height_values,
    InvalidHeight,
    HeightRefusal,
    HeightRefusals
);

/// The gate of an IMU stream: values ([`imu_values`]), then a time strictly
/// after the previous accepted sample's.
pub type ImuGate = OrderedGate<ImuSample>;

/// The gate of a body-velocity stream: values ([`velocity_values`]), then a
/// time strictly after the previous accepted measurement's.
pub type VelocityGate = OrderedGate<BodyVelocity>;

/// The gate of a height stream: values ([`height_values`]), then a time
/// strictly after the previous accepted measurement's.
pub type HeightGate = OrderedGate<Height>;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Header;

    fn vel(t_ns: u64, v: [f64; 3], sigma: [f64; 3]) -> BodyVelocity {
        BodyVelocity {
            header: Header::new(0, t_ns),
            vel_mps: v,
            sigma_mps: sigma,
            source: BodyVelocity::SOURCE_FLOW,
            range_mm: 0,
        }
    }

    #[test]
    fn range_gate_refuses_each_bad_value_and_time_with_its_counter() {
        let r = |t_ns: u64, anchor: u32, range_m: f64| UwbRange {
            header: Header::new(0, t_ns),
            anchor,
            range_m,
            anchor_pos_m: [1.0, 2.0, 3.0],
            ..UwbRange::default()
        };
        let mut g = RangeGate::new();
        assert_eq!(g.check(&r(10, 1, 3.0)), Ok(()));
        assert_eq!(g.check(&r(10, 2, 4.0)), Ok(()));
        let mut bad_pos = r(20, 3, 1.0);
        bad_pos.anchor_pos_m[1] = f64::INFINITY;
        let mut bad_quality = r(20, 3, 1.0);
        bad_quality.header.flags = UwbRange::FLAG_QUALITY;
        bad_quality.quality = 101;
        let cases = [
            r(20, 3, f64::NAN),
            bad_pos,
            r(20, 3, -0.01),
            r(20, 3, MAX_RANGE_M),
            bad_quality,
            r(5, 3, 1.0),
            r(10, 2, 4.0),
        ];
        for c in &cases {
            assert!(g.check(c).is_err(), "{c:?}");
        }
        // A quality that is not flagged is not read; 0 m is a range.
        let mut unflagged = r(20, 3, 0.0);
        unflagged.quality = 500;
        assert_eq!(g.check(&unflagged), Ok(()));
        let n = g.refusals();
        assert_eq!((n.non_finite, n.out_of_range, n.quality), (2, 2, 1));
        assert_eq!((n.time_backwards, n.anchor_repeated), (1, 1));
        assert_eq!((n.invalid(), n.time(), n.total()), (5, 2, 7));
        assert!(RangeRefusal::AnchorRepeated {
            anchor: 1,
            time_ns: 1
        }
        .is_time());
    }

    #[test]
    fn velocity_gate_refuses_each_bad_value_and_time_with_its_counter() {
        let mut g = VelocityGate::new();
        let s = [0.1, 0.1, 0.0];
        assert_eq!(g.check(&vel(10, [0.5, -0.2, 0.0], s)), Ok(()));
        let cases = [
            vel(20, [f64::NAN, 0.0, 0.0], s),
            vel(20, [0.0; 3], [-0.1, 0.1, 0.0]),
            vel(20, [0.0; 3], [0.0; 3]),
            vel(20, [60.0, 0.0, 0.0], s),
            BodyVelocity {
                source: 7,
                ..vel(20, [0.0; 3], s)
            },
            vel(5, [0.0; 3], s),
            vel(10, [0.0; 3], s),
        ];
        for c in &cases {
            assert!(g.check(c).is_err(), "{c:?}");
        }
        // An unmeasured axis may hold anything finite.
        assert_eq!(g.check(&vel(20, [0.0, 0.0, 99.0], s)), Ok(()));
        let r = g.refusals();
        assert_eq!(
            (r.non_finite, r.sigma, r.out_of_range, r.source),
            (1, 2, 1, 1)
        );
        assert_eq!((r.time_backwards, r.time_repeated), (1, 1));
        assert_eq!((r.invalid(), r.time(), r.total()), (5, 2, 7));
    }

    #[test]
    fn height_gate_refuses_each_bad_value_and_time_with_its_counter() {
        let h = |t_ns, range_m| Height {
            header: Header::new(0, t_ns),
            range_m,
            source: Height::SOURCE_RANGE_FINDER,
        };
        let mut g = HeightGate::new();
        assert_eq!(g.check(&h(10, 1.2)), Ok(()));
        let cases = [
            (h(20, f64::NAN), "non-finite"),
            (h(20, f64::INFINITY), "non-finite"),
            (h(20, -0.3), "negative"),
            (h(20, 0.0), "zero"),
            (h(20, MAX_HEIGHT_RANGE_M), "too long"),
            (
                Height {
                    source: 9,
                    ..h(20, 1.0)
                },
                "source",
            ),
            (h(5, 1.0), "backwards"),
            (h(10, 1.0), "repeated"),
        ];
        for (c, why) in &cases {
            assert!(g.check(c).is_err(), "{why}: {c:?}");
        }
        assert_eq!(g.check(&h(20, 1.25)), Ok(()));
        let r = g.refusals();
        assert_eq!((r.non_finite, r.out_of_range, r.source), (2, 3, 1));
        assert_eq!((r.time_backwards, r.time_repeated), (1, 1));
        assert_eq!((r.invalid(), r.time(), r.total()), (6, 2, 8));
        assert_eq!(
            g.check(&h(30, -1.0)).map_err(|e| e.to_string()),
            Err("height range_m is -1 m, outside (0, 100) m".to_string())
        );
    }

    fn imu(t_ns: u64) -> ImuSample {
        ImuSample {
            header: Header::new(0, t_ns),
            accel_mps2: [0.1, -0.2, 9.81],
            gyro_rps: [0.01, 0.0, -0.02],
        }
    }

    /// Anchors 0 at the origin, 1 at 10 m east, 2 at 10 m north.
    fn tdoa(t_ns: u64, a: u32, b: u32, diff_m: f64) -> UwbTdoa {
        let pos = |id: u32| match id {
            1 => [10.0, 0.0, 0.0],
            2 => [0.0, 10.0, 0.0],
            _ => [0.0; 3],
        };
        UwbTdoa {
            header: Header::new(0, t_ns),
            anchor_a: a,
            anchor_b: b,
            diff_m,
            anchor_a_pos_m: pos(a),
            anchor_b_pos_m: pos(b),
        }
    }

    #[test]
    fn imu_values_refuse_each_bad_value_by_field_and_axis() {
        assert_eq!(imu_values(&imu(0)), Ok(()));
        let mut s = imu(0);
        s.accel_mps2[1] = f64::INFINITY;
        assert_eq!(
            imu_values(&s),
            Err(InvalidImu::NonFinite {
                field: "accel_mps2",
                axis: 1,
                value: f64::INFINITY
            })
        );
        let mut s = imu(0);
        s.gyro_rps[2] = f64::NAN;
        assert!(matches!(
            imu_values(&s),
            Err(InvalidImu::NonFinite { field: "gyro_rps", axis: 2, value }) if value.is_nan()
        ));
        let mut s = imu(0);
        s.accel_mps2[0] = -MAX_ACCEL_MPS2;
        assert_eq!(
            imu_values(&s),
            Err(InvalidImu::OutOfRange {
                field: "accel_mps2",
                axis: 0,
                value: -MAX_ACCEL_MPS2,
                limit: MAX_ACCEL_MPS2
            })
        );
        s.accel_mps2[0] = 399.9;
        assert_eq!(imu_values(&s), Ok(()));
        s.gyro_rps[1] = MAX_RATE_RPS;
        assert_eq!(
            imu_values(&s),
            Err(InvalidImu::OutOfRange {
                field: "gyro_rps",
                axis: 1,
                value: MAX_RATE_RPS,
                limit: MAX_RATE_RPS
            })
        );
    }

    #[test]
    fn the_imu_gate_refuses_and_counts_each_reason() {
        let mut g = ImuGate::new();
        assert_eq!(g.check(&imu(100)), Ok(()));
        assert_eq!(
            g.check(&imu(100)),
            Err(ImuRefusal::TimeRepeated { time_ns: 100 })
        );
        assert_eq!(
            g.check(&imu(50)),
            Err(ImuRefusal::TimeBackwards {
                time_ns: 50,
                last_ns: 100
            })
        );
        let mut bad = imu(200);
        bad.gyro_rps[0] = 100.0;
        let r = g.check(&bad);
        assert!(matches!(
            r,
            Err(ImuRefusal::Invalid(InvalidImu::OutOfRange { .. }))
        ));
        assert!(!r.is_err_and(|e| e.is_time()));
        bad = imu(200);
        bad.accel_mps2[2] = f64::NAN;
        assert!(g.check(&bad).is_err());
        // A refused sample moved nothing: 200 is still after 100.
        assert_eq!(g.check(&imu(200)), Ok(()));
        // A bad value at a bad time is refused for its value.
        let mut both = imu(10);
        both.accel_mps2[0] = f64::NEG_INFINITY;
        assert!(matches!(g.check(&both), Err(ImuRefusal::Invalid(_))));
        assert_eq!(
            *g.refusals(),
            ImuRefusals {
                non_finite: 2,
                out_of_range: 1,
                time_backwards: 1,
                time_repeated: 1,
            }
        );
        assert_eq!(
            (
                g.refusals().invalid(),
                g.refusals().time(),
                g.refusals().total()
            ),
            (3, 2, 5)
        );
    }

    #[test]
    fn tdoa_values_refuse_each_bad_value() {
        assert_eq!(tdoa_values(&tdoa(0, 0, 1, 9.0)), Ok(()));
        // At the baseline exactly: a tag on the line beyond an anchor.
        assert_eq!(tdoa_values(&tdoa(0, 0, 1, -10.0)), Ok(()));
        assert!(matches!(
            tdoa_values(&tdoa(0, 0, 1, f64::NAN)),
            Err(InvalidTdoa::NonFinite {
                field: "diff_m",
                ..
            })
        ));
        let mut m = tdoa(0, 0, 1, 1.0);
        m.anchor_b_pos_m[2] = f64::INFINITY;
        assert_eq!(
            tdoa_values(&m),
            Err(InvalidTdoa::NonFinite {
                field: "anchor_b_pos_m",
                value: f64::INFINITY
            })
        );
        assert_eq!(
            tdoa_values(&tdoa(0, 2, 2, 0.0)),
            Err(InvalidTdoa::SameAnchor { id: 2 })
        );
        assert_eq!(
            tdoa_values(&tdoa(0, 0, 1, 10.5)),
            Err(InvalidTdoa::Impossible {
                diff_m: 10.5,
                baseline_m: 10.0,
                a: 0,
                b: 1
            })
        );
    }

    #[test]
    fn the_tdoa_gate_refuses_and_counts_each_reason() {
        let mut g = TdoaGate::new();
        assert_eq!(g.check(&tdoa(100, 0, 1, 1.0)), Ok(()));
        // Another pair at the same time: an epoch of several pairs.
        assert_eq!(g.check(&tdoa(100, 0, 2, 1.0)), Ok(()));
        // The same unordered pair again at that time.
        assert_eq!(
            g.check(&tdoa(100, 1, 0, -1.0)),
            Err(TdoaRefusal::PairRepeated {
                a: 0,
                b: 1,
                time_ns: 100
            })
        );
        assert_eq!(
            g.check(&tdoa(90, 1, 2, 0.0)),
            Err(TdoaRefusal::TimeBackwards {
                time_ns: 90,
                last_ns: 100
            })
        );
        assert!(g.check(&tdoa(110, 1, 1, 0.0)).is_err());
        assert!(g.check(&tdoa(110, 0, 1, 11.0)).is_err());
        assert!(g.check(&tdoa(110, 0, 1, f64::INFINITY)).is_err());
        // The refusals moved nothing; a new time forgets the pairs.
        assert_eq!(g.check(&tdoa(100, 1, 2, 0.0)), Ok(()));
        assert_eq!(g.check(&tdoa(120, 0, 1, 1.0)), Ok(()));
        assert_eq!(
            *g.refusals(),
            TdoaRefusals {
                non_finite: 1,
                same_anchor: 1,
                impossible: 1,
                time_backwards: 1,
                pair_repeated: 1,
            }
        );
        assert_eq!((g.refusals().invalid(), g.refusals().time()), (3, 2));
        assert!(TdoaRefusal::PairRepeated {
            a: 0,
            b: 1,
            time_ns: 0
        }
        .is_time());
    }

    /// Beyond [`MAX_PAIRS_PER_TIME`] pairs at one time, further pairs are
    /// accepted unchecked (the table is bounded); the first ones are still
    /// caught.
    #[test]
    fn the_tdoa_gate_checks_the_first_pairs_of_a_crowded_time() {
        let mut g = TdoaGate::new();
        let at = |a: u32, b: u32| tdoa(5, a, b, 0.0);
        let pairs: Vec<(u32, u32)> = (3..40)
            .flat_map(|a| (a + 1..a + 3).map(move |b| (a, b)))
            .take(MAX_PAIRS_PER_TIME + 2)
            .collect();
        for &(a, b) in &pairs {
            assert_eq!(g.check(&at(a, b)), Ok(()));
        }
        let (a, b) = pairs[0];
        assert!(g.check(&at(b, a)).is_err());
        let (a, b) = pairs[MAX_PAIRS_PER_TIME + 1];
        assert_eq!(g.check(&at(a, b)), Ok(()));
    }

    #[test]
    fn refusals_say_what_and_why() {
        let r = TdoaRefusal::from(InvalidTdoa::Impossible {
            diff_m: 12.5,
            baseline_m: 10.0,
            a: 3,
            b: 4,
        });
        assert_eq!(
            r.to_string(),
            "tdoa range difference 12.5 m is longer than the 10 m between anchors 3 and 4"
        );
        assert!(std::error::Error::source(&r).is_none());
        assert_eq!(
            ImuRefusal::TimeRepeated { time_ns: 7 }.to_string(),
            "imu time 7 ns repeats the previous sample's"
        );
    }
}
