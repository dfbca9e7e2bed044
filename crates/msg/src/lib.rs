//! Every sample type exchanged between insuwb stages, and every service setting.
//!
//! This crate owns the wire vocabulary of the system: the fixed-layout
//! (`#[repr(C)]`, [`ZeroCopySend`]) samples that travel over iceoryx2 shared
//! memory, that the logger records (serde), that the simulator and dataset
//! readers produce and that `insuwb eval` consumes. One type per topic, used
//! everywhere, so the same input is the same bytes in process, in replay and
//! in the pipeline.
//!
//! Conventions:
//! - times are CLOCK_MONOTONIC nanoseconds (`_ns`); in logs and simulations
//!   they are nanoseconds since the start of the recording;
//! - the navigation frame is ENU (x east, y north, z up), yaw counter-clockwise
//!   from east; the body frame is x forward, y left, z up (FLU);
//! - quaternions are `[w, x, y, z]`, rotating body vectors into ENU;
//! - accelerometers report specific force (about +9.81 m/s^2 on body z at rest).
//!
//! ```
//! use insuwb_msg::{Header, ImuSample, LAYOUT_VERSION};
//! let s = ImuSample { header: Header::new(7, 1_000_000), accel_mps2: [0.0, 0.0, 9.81], gyro_rps: [0.0; 3] };
//! assert_eq!(s.header.layout_version, LAYOUT_VERSION);
//! ```
#![warn(missing_docs)]

pub mod check;
pub mod health;
pub mod qos;

pub use health::{
    CounterBlock, CounterKind, CounterValue, DeviceCounters, FoxgloveCounters, FusionCounters,
    Health, HealthState, InsCounters, LoggerCounters, Ros2BridgeCounters, Ros2SourceCounters,
    StageCounters, StateCode, UnknownCounterKind, UnknownState, UwbDriverCounters, ZenohCounters,
    COUNTER_WORDS, NO_VALUE,
};

use iceoryx2_bb_derive_macros::ZeroCopySend;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;
use serde::{Deserialize, Serialize};

/// Version of every sample layout in this crate (and of the log format's records).
/// Bump it whenever a field, its order or its meaning changes; a stage drops
/// samples of another version and a log reader refuses a file of another
/// version. Version 2: [`Health`] carries a [`StateCode`] and a
/// [`CounterBlock`] (kind-tagged named counters) instead of four untyped words.
pub const LAYOUT_VERSION: u16 = 2;

/// Header common to every sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
#[type_name("insuwb::Header")]
pub struct Header {
    /// [`LAYOUT_VERSION`] of the writer; a reader drops samples of another version.
    pub layout_version: u16,
    /// Identifier of the producing source (stage id, sensor id).
    pub source_id: u16,
    /// Type-specific flag bits (see each type's `FLAG_*` constants).
    pub flags: u32,
    /// Start generation of the publisher: a restarted publisher counts up.
    pub generation: u32,
    /// Reserved, zero.
    pub reserved: u32,
    /// Sequence number, per publisher and generation, counting up from 0.
    pub seq: u64,
    /// When the quantity was measured (CLOCK_MONOTONIC ns).
    pub meas_time_ns: u64,
    /// When the sample was published (CLOCK_MONOTONIC ns); 0 before publishing.
    pub pub_time_ns: u64,
}

impl Header {
    /// A header of the current layout version with the given sequence number and measurement time.
    #[must_use]
    pub fn new(seq: u64, meas_time_ns: u64) -> Self {
        Self {
            layout_version: LAYOUT_VERSION,
            seq,
            meas_time_ns,
            ..Self::default()
        }
    }
}

/// Raw inertial sample from the IMU driver (topic [`topics::IMU`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
#[type_name("insuwb::ImuSample")]
pub struct ImuSample {
    /// Common header.
    pub header: Header,
    /// Specific force in the body frame, m/s^2.
    pub accel_mps2: [f64; 3],
    /// Angular rate in the body frame, rad/s.
    pub gyro_rps: [f64; 3],
}

/// One UWB time-difference-of-arrival measurement (topic [`topics::UWB_TDOA`]).
///
/// `diff_m = |p - anchor_b| - |p - anchor_a|` (the UTIL / Crazyflie convention).
/// The anchor positions travel with the sample so every consumer uses the
/// same survey as the driver that stamped it.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
#[type_name("insuwb::UwbTdoa")]
pub struct UwbTdoa {
    /// Common header.
    pub header: Header,
    /// Id of anchor A.
    pub anchor_a: u32,
    /// Id of anchor B.
    pub anchor_b: u32,
    /// Range difference `|p - b| - |p - a|`, metres.
    pub diff_m: f64,
    /// Surveyed position of anchor A (ENU, m).
    pub anchor_a_pos_m: [f64; 3],
    /// Surveyed position of anchor B (ENU, m).
    pub anchor_b_pos_m: [f64; 3],
}

impl UwbTdoa {
    /// Last measurement of a group taken at the same instant (a TDOA system
    /// that measures all pairs at once, as the simulator does): the fix
    /// builder may close the epoch without waiting for the next one.
    pub const FLAG_EPOCH_END: u32 = 1;
    /// `diff_m` has been corrected by a site calibration (its learnt
    /// per-pair bias removed): a measurement so flagged is never corrected
    /// again (`insuwb_uwb::calibration`).
    pub const FLAG_CALIBRATED: u32 = 2;
}

/// One UWB two-way-ranging measurement (topic [`topics::UWB_RANGE`]): the
/// distance from the tag's antenna to one anchor, as a DWM1001 tag, a
/// LinkTrack tag or a Crazyflie Loco deck in TWR mode reports it.
///
/// `range_m = |p - anchor|`. The anchor's surveyed position travels with
/// the sample, as a TDOA measurement's do. A device that reports a quality
/// per range (the DWM1001's quality factor, 0-100) sets
/// [`UwbRange::FLAG_QUALITY`] and `quality`; otherwise both are zero.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
#[type_name("insuwb::UwbRange")]
pub struct UwbRange {
    /// Common header.
    pub header: Header,
    /// Id of the anchor.
    pub anchor: u32,
    /// The device's quality of this range, 0-100 (valid with
    /// [`UwbRange::FLAG_QUALITY`]).
    pub quality: u32,
    /// Distance from the tag to the anchor, metres.
    pub range_m: f64,
    /// Surveyed position of the anchor (ENU, m).
    pub anchor_pos_m: [f64; 3],
}

impl UwbRange {
    /// Last range of a group taken at the same instant (every anchor of a
    /// ranging round stamped at once): the fix builder may close the epoch.
    pub const FLAG_EPOCH_END: u32 = 1;
    /// `quality` holds the device's quality figure.
    pub const FLAG_QUALITY: u32 = 2;
    /// `range_m` has had the tag's common range offset (its antenna
    /// delay, estimated by the fix builder) removed: a range so flagged is
    /// never corrected again (`insuwb_uwb::fix`).
    pub const FLAG_OFFSET_REMOVED: u32 = 4;
}

/// A velocity measured in the body frame (topic [`topics::BODY_VEL`]): a
/// wheeled base's odometry (the twist of `nav_msgs/Odometry`), or optical
/// flow scaled by the height above the floor (a flow deck).
///
/// The frame is the body's, FLU (x forward, y left, z up), the IMU's: a
/// source whose sensor frame differs rotates into it before publishing. An
/// axis the sensor does not measure has `sigma_mps` 0 (flow measures x and
/// y, odometry of a differential drive x alone, or x and y with its
/// non-holonomic zero).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
#[type_name("insuwb::BodyVelocity")]
pub struct BodyVelocity {
    /// Common header; `meas_time_ns` is the middle of the interval the
    /// velocity was measured over.
    pub header: Header,
    /// Velocity of the body in its own frame, m/s.
    pub vel_mps: [f64; 3],
    /// Standard deviation of each axis, m/s; 0: the axis is not measured.
    pub sigma_mps: [f64; 3],
    /// What measured it: [`BodyVelocity::SOURCE_ODOMETRY`] or
    /// [`BodyVelocity::SOURCE_FLOW`].
    pub source: u32,
    /// The range finder's distance to the ground along body z that scaled
    /// a flow velocity, mm (the time-of-flight sensor's own unit, so never
    /// negative or NaN); 0: none (odometry, or flow without it). A record
    /// of what the velocity was scaled with: the filters take their height
    /// from the range finder's own readings ([`Height`]).
    pub range_mm: u32,
}

impl BodyVelocity {
    /// Wheel odometry.
    pub const SOURCE_ODOMETRY: u32 = 1;
    /// Optical flow with a range finder.
    pub const SOURCE_FLOW: u32 = 2;

    /// A range in the whole millimetres `range_mm` holds (negative or NaN:
    /// 0, none).
    #[must_use]
    pub fn range_mm_from_m(range_m: f64) -> u32 {
        // `as` saturates and maps NaN to 0.
        (range_m * 1000.0).round().max(0.0) as u32
    }

    /// The range the sample carries, m (`None`: none).
    #[must_use]
    pub fn range_m(&self) -> Option<f64> {
        (self.range_mm > 0).then(|| f64::from(self.range_mm) * 1e-3)
    }
}

/// A height measurement (topic [`topics::HEIGHT`]): a range finder's
/// distance to the floor along the body's z axis (the Crazyflie flow
/// deck's VL53L1x, a downward lidar or sonar), from which a filter takes
/// the height above a flat floor as `range_m * R33` (the body z axis's
/// vertical component) plus its mounting offset.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
#[type_name("insuwb::Height")]
pub struct Height {
    /// Common header; `meas_time_ns` is the reading's time.
    pub header: Header,
    /// The distance measured along the body z axis down to the floor, m.
    pub range_m: f64,
    /// What measured it: [`Height::SOURCE_RANGE_FINDER`].
    pub source: u32,
}

impl Height {
    /// A range finder looking down along the body z axis.
    pub const SOURCE_RANGE_FINDER: u32 = 1;
}

/// A UWB position (and velocity) fix from multilateration (topic [`topics::UWB_FIX`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
#[type_name("insuwb::UwbFix")]
pub struct UwbFix {
    /// Common header; `meas_time_ns` is the fix epoch.
    pub header: Header,
    /// Position, ENU, m.
    pub pos_m: [f64; 3],
    /// Velocity, ENU, m/s (valid when [`UwbFix::FLAG_VEL_VALID`] is set).
    pub vel_mps: [f64; 3],
    /// Position covariance, m^2 (row-major 3 x 3).
    pub pos_cov_m2: [[f64; 3]; 3],
    /// Velocity covariance, (m/s)^2 (row-major 3 x 3).
    pub vel_cov: [[f64; 3]; 3],
    /// Geometric dilution of precision of this fix.
    pub gdop: f64,
    /// Number of TDOA measurements used.
    pub n_meas: u32,
    /// Solver iterations used.
    pub iterations: u32,
}

impl UwbFix {
    /// The velocity fields hold a valid estimate.
    pub const FLAG_VEL_VALID: u32 = 1;
    /// The fix is two-dimensional (height held fixed).
    pub const FLAG_2D: u32 = 2;
}

/// Output of INS mechanisation for one IMU sample (topic [`topics::NAV`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
#[type_name("insuwb::NavState")]
pub struct NavState {
    /// Common header: `meas_time_ns` is that of the IMU sample integrated last.
    pub header: Header,
    /// Id of the last correction folded into this state (0: none).
    pub correction_id: u64,
    /// Sequence number of the IMU sample integrated last (corrections name it).
    pub imu_seq: u64,
    /// Generation of the IMU driver whose samples were integrated.
    pub imu_generation: u32,
    /// Reserved, zero.
    pub reserved: u32,
    /// Position, ENU, m.
    pub pos_m: [f64; 3],
    /// Velocity, ENU, m/s.
    pub vel_mps: [f64; 3],
    /// Attitude quaternion `[w, x, y, z]`, body to ENU.
    pub quat: [f64; 4],
    /// Kinematic acceleration in ENU (gravity removed, biases compensated), m/s^2.
    pub accel_nav_mps2: [f64; 3],
    /// Angular rate in ENU (biases compensated), rad/s.
    pub omega_nav_rps: [f64; 3],
    /// Estimated accelerometer bias (body), m/s^2.
    pub accel_bias_mps2: [f64; 3],
    /// Estimated gyro bias (body), rad/s.
    pub gyro_bias_rps: [f64; 3],
}

impl NavState {
    /// The INS is aligned and integrating.
    pub const FLAG_ALIGNED: u32 = 1;
    /// The INS was re-initialised from a fused state (after a restart).
    pub const FLAG_REINIT: u32 = 2;
    /// IMU samples were missing before this state (a dropout or a restarted
    /// IMU driver): the INS coasted over the gap and its error grew.
    pub const FLAG_GAP: u32 = 4;
    /// A multirotor INS handed over to the free model at run time (its
    /// accelerometer's horizontal channels follow the motion): every axis
    /// is integrated, and the filters model it so.
    pub const FLAG_FREE: u32 = 8;
}

/// Correction from fusion to INS (topic [`topics::CORRECTION`]).
///
/// A correction names the INS sample (`apply_at_seq` of generation
/// `imu_generation`) after which it applies: the INS applies it to its state
/// at that sample and re-propagates the samples after it, so the result does
/// not depend on when the correction arrives. Ids count up; an INS applies
/// each id once.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
#[type_name("insuwb::InsCorrection")]
pub struct InsCorrection {
    /// Common header.
    pub header: Header,
    /// Correction id, counting up from 1.
    pub correction_id: u64,
    /// INS (IMU) sequence number after which the correction applies.
    pub apply_at_seq: u64,
    /// IMU generation that `apply_at_seq` refers to.
    pub imu_generation: u32,
    /// Reserved, zero.
    pub reserved: u32,
    /// Position error to remove (INS minus truth), ENU, m.
    pub d_pos_m: [f64; 3],
    /// Velocity error to remove, ENU, m/s.
    pub d_vel_mps: [f64; 3],
    /// Attitude error to remove, small-angle rotation vector in ENU, rad.
    pub d_att_rad: [f64; 3],
    /// Accelerometer bias increment (body), m/s^2.
    pub d_accel_bias_mps2: [f64; 3],
    /// Gyro bias increment (body), rad/s.
    pub d_gyro_bias_rps: [f64; 3],
    /// With [`InsCorrection::FLAG_RESET`]: full state to take (pos, vel, quat).
    pub reset_pos_m: [f64; 3],
    /// Reset velocity, ENU, m/s.
    pub reset_vel_mps: [f64; 3],
    /// Reset attitude `[w, x, y, z]`.
    pub reset_quat: [f64; 4],
}

impl InsCorrection {
    /// Replace the INS state by the `reset_*` fields instead of adding the deltas.
    pub const FLAG_RESET: u32 = 1;
}

/// The fused navigation solution (topic [`topics::FUSED`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
#[type_name("insuwb::FusedState")]
pub struct FusedState {
    /// Common header: `meas_time_ns` is the epoch of the estimate.
    pub header: Header,
    /// Position, ENU, m.
    pub pos_m: [f64; 3],
    /// Velocity, ENU, m/s.
    pub vel_mps: [f64; 3],
    /// Attitude `[w, x, y, z]`, body to ENU.
    pub quat: [f64; 4],
    /// Heading (yaw counter-clockwise from east), rad.
    pub yaw_rad: f64,
    /// Covariance of `[pos e, n, u, vel e, n, u]` (row-major 6 x 6).
    pub cov: [[f64; 6]; 6],
    /// Frame id of `pos_m`/`vel_mps`, NUL-padded ASCII (e.g. `map`).
    pub frame_id: [u8; 16],
    /// Sequence number of the UWB sample that triggered this output.
    pub uwb_seq: u64,
    /// Measurement time of that UWB sample.
    pub uwb_meas_time_ns: u64,
    /// Publish time of that UWB sample.
    pub uwb_pub_time_ns: u64,
    /// Sequence number of the INS state used.
    pub ins_seq: u64,
    /// Measurement time of that INS state.
    pub ins_meas_time_ns: u64,
    /// Publish time of that INS state.
    pub ins_pub_time_ns: u64,
    /// Filter that produced it (see [`FilterKind`] codes).
    pub filter_kind: u32,
    /// Reserved, zero.
    pub reserved: u32,
}

impl FusedState {
    /// The pose is valid (aligned INS, converged filter, inputs fresh).
    pub const FLAG_VALID: u32 = 1;
    /// No UWB update for longer than the configured timeout: INS-only coasting.
    pub const FLAG_DEGRADED: u32 = 2;
    /// The INS input is stale: the pose is not built on fresh inertial data.
    pub const FLAG_STALE: u32 = 4;
    /// The state was restored from a checkpoint after a restart.
    pub const FLAG_RESUMED: u32 = 8;
    /// The filter was reset from UWB after divergence.
    pub const FLAG_RESET: u32 = 16;
    /// Built on the UWB fix alone while the INS input is stale: position
    /// and its covariance from the fix, attitude from the last fused state
    /// (see `insuwb_fusion::output`).
    pub const FLAG_UWB_ONLY: u32 = 32;
}

/// The filters, with their codes in [`FusedState::filter_kind`] and
/// [`FilterDiag::filter_kind`] and their one name (configuration, command
/// line, JSON keys): `kf`, `shaf`, `stf`, `iakf`, `iakf_tdoa`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[repr(u32)]
pub enum FilterKind {
    /// Plain Kalman filter.
    Kf = 1,
    /// Simplified Sage-Husa adaptive filter.
    Shaf = 2,
    /// Strong tracking filter.
    Stf = 3,
    /// Improved adaptive Kalman filter (the paper's).
    Iakf = 4,
    /// Tightly coupled TDOA filter.
    IakfTdoa = 5,
}

impl FilterKind {
    /// Every filter, in code order.
    pub const ALL: [Self; 5] = [Self::Kf, Self::Shaf, Self::Stf, Self::Iakf, Self::IakfTdoa];

    /// Its name: `kf`, `shaf`, `stf`, `iakf` or `iakf_tdoa`.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Kf => "kf",
            Self::Shaf => "shaf",
            Self::Stf => "stf",
            Self::Iakf => "iakf",
            Self::IakfTdoa => "iakf_tdoa",
        }
    }

    /// The filter of a sample's `filter_kind` code, if it is one.
    #[must_use]
    pub fn from_code(code: u32) -> Option<Self> {
        Self::ALL.into_iter().find(|k| *k as u32 == code)
    }
}

/// What a UWB system measures, one per robot (robot.toml `[uwb] kind`, a
/// scenario's `[sim.uwb] kind`, a log's header entry `uwb_kind`): `tdoa` or
/// `twr`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum UwbKind {
    /// Time differences of arrival between anchor pairs ([`UwbTdoa`] on
    /// [`topics::UWB_TDOA`]).
    #[default]
    Tdoa,
    /// Two-way ranging: one distance per anchor ([`UwbRange`] on
    /// [`topics::UWB_RANGE`]).
    Twr,
}

impl UwbKind {
    /// Both kinds.
    pub const ALL: [Self; 2] = [Self::Tdoa, Self::Twr];

    /// Its name: `tdoa` or `twr`.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Tdoa => "tdoa",
            Self::Twr => "twr",
        }
    }
}

/// A name that is not one of [`UwbKind::ALL`]'s.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown UWB kind '{0}' (known: tdoa, twr)")]
pub struct UnknownUwbKind(pub String);

/// A name that is not one of [`FilterKind::ALL`]'s.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown filter '{0}' (known: kf, shaf, stf, iakf, iakf_tdoa)")]
pub struct UnknownFilterKind(pub String);

/// The processes of a group, each one stage of the pipeline, with their one
/// name (configuration `stages`, binaries, health, locks, logs): `imu`,
/// `uwb`, `ins`, `fusion`, `ros2`, `foxglove`, `zenoh`, `logger`. A group
/// runs [`StageRole::DEFAULT`] unless its `stages` lists others: the ROS 2
/// bridge, the Foxglove live view and the Zenoh bridge run only where they
/// are listed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StageRole {
    /// The IMU driver.
    Imu,
    /// The UWB driver (and fix builder).
    Uwb,
    /// The strapdown INS.
    Ins,
    /// The fusion filter.
    Fusion,
    /// The ROS 2 bridge (binary `insuwb-stage-ros2`, library `insuwb-ros2`):
    /// optional.
    Ros2,
    /// The Foxglove live view (binary `insuwb-stage-foxglove`, library
    /// `insuwb-foxglove`): optional.
    Foxglove,
    /// The Zenoh bridge to the fleet's station (binary
    /// `insuwb-stage-zenoh`, library `insuwb-zenoh`): optional.
    Zenoh,
    /// The logger.
    Logger,
}

impl StageRole {
    /// Every role, in start order.
    pub const ALL: [Self; 8] = [
        Self::Imu,
        Self::Uwb,
        Self::Ins,
        Self::Fusion,
        Self::Ros2,
        Self::Foxglove,
        Self::Zenoh,
        Self::Logger,
    ];

    /// The roles a group runs when its `stages` lists none: every role but
    /// the ROS 2 bridge, the Foxglove live view and the Zenoh bridge
    /// (nothing is opened on the network unless asked).
    pub const DEFAULT: [Self; 5] = [Self::Imu, Self::Uwb, Self::Ins, Self::Fusion, Self::Logger];

    /// Their names, in start order, which is also the shutdown order of a
    /// group: the sources first, so that nothing new enters, the ROS 2
    /// bridge, the Foxglove live view and the Zenoh bridge after fusion, the
    /// logger last, so that it records the end.
    pub const NAMES: [&'static str; 8] = [
        Self::Imu.name(),
        Self::Uwb.name(),
        Self::Ins.name(),
        Self::Fusion.name(),
        Self::Ros2.name(),
        Self::Foxglove.name(),
        Self::Zenoh.name(),
        Self::Logger.name(),
    ];

    /// Its name: `imu`, `uwb`, `ins`, `fusion`, `ros2`, `foxglove`,
    /// `zenoh` or `logger`.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Imu => "imu",
            Self::Uwb => "uwb",
            Self::Ins => "ins",
            Self::Fusion => "fusion",
            Self::Ros2 => "ros2",
            Self::Foxglove => "foxglove",
            Self::Zenoh => "zenoh",
            Self::Logger => "logger",
        }
    }

    /// The program of its process, in the folder of the `insuwb`
    /// executable (and of its cargo package): `insuwb-stage-imu`,
    /// `insuwb-stage-uwb`, `insuwb-stage-ins`, `insuwb-stage-fusion`,
    /// `insuwb-stage-ros2`, `insuwb-stage-foxglove`, `insuwb-stage-zenoh`,
    /// `insuwb-stage-logger`.
    #[must_use]
    pub const fn program(self) -> &'static str {
        match self {
            Self::Imu => "insuwb-stage-imu",
            Self::Uwb => "insuwb-stage-uwb",
            Self::Ins => "insuwb-stage-ins",
            Self::Fusion => "insuwb-stage-fusion",
            Self::Ros2 => "insuwb-stage-ros2",
            Self::Foxglove => "insuwb-stage-foxglove",
            Self::Zenoh => "insuwb-stage-zenoh",
            Self::Logger => "insuwb-stage-logger",
        }
    }

    /// The name the kernel gives its process (`/proc/PID/comm`, `ps`,
    /// `top`): the program's name cut to 15 bytes, e.g. `insuwb-stage-fu`,
    /// distinct for every role.
    #[must_use]
    pub fn process_name(self) -> &'static str {
        let p = self.program();
        p.get(..COMM_LEN).unwrap_or(p)
    }

    /// The role whose process the kernel names `comm`
    /// ([`StageRole::process_name`]).
    #[must_use]
    pub fn from_process_name(comm: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|r| r.process_name() == comm)
    }
}

/// The longest process name the kernel keeps (`TASK_COMM_LEN` less its nul).
const COMM_LEN: usize = 15;

/// A name that is not one of [`StageRole::ALL`]'s.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown stage '{0}' (known: imu, uwb, ins, fusion, ros2, foxglove, zenoh, logger)")]
pub struct UnknownStageRole(pub String);

/// `Display` as the enum's `name()`, and `FromStr` from it (`$err` for any
/// other text).
macro_rules! named_enum {
    ($ty:ident, $err:ident) => {
        impl core::fmt::Display for $ty {
            fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
                f.write_str(self.name())
            }
        }

        impl core::str::FromStr for $ty {
            type Err = $err;

            fn from_str(s: &str) -> Result<Self, Self::Err> {
                Self::ALL
                    .into_iter()
                    .find(|k| k.name() == s)
                    .ok_or_else(|| $err(s.to_owned()))
            }
        }
    };
}

named_enum!(FilterKind, UnknownFilterKind);
named_enum!(StageRole, UnknownStageRole);
named_enum!(UwbKind, UnknownUwbKind);

/// Filter diagnostics after each update (topic [`topics::DIAG`]).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
#[type_name("insuwb::FilterDiag")]
pub struct FilterDiag {
    /// Common header.
    pub header: Header,
    /// Innovation (measurement minus prediction); unused entries zero.
    pub innovation: [f64; 8],
    /// Innovation variance `S_ii`.
    pub innovation_var: [f64; 8],
    /// Outlier weight per component (1: accepted as is).
    pub lambda: [f64; 8],
    /// Measurement noise diagonal in use.
    pub r_diag: [f64; 8],
    /// Normalised innovation squared of this update.
    pub nis: f64,
    /// Fading factor applied (1: none).
    pub fading: f64,
    /// Number of valid entries in the arrays.
    pub dim: u32,
    /// Filter code ([`FilterKind`]).
    pub filter_kind: u32,
}

impl FilterDiag {
    /// The divergence test fired on this update.
    pub const FLAG_DIVERGENCE: u32 = 1;
    /// At least one component was weighted as an outlier.
    pub const FLAG_OUTLIER: u32 = 2;
    /// The filter was reset.
    pub const FLAG_RESET: u32 = 4;
}

/// Ground truth (topic [`topics::TRUTH`]); published only by the simulator and
/// replay sources, for evaluation and the log. Fusion never reads it.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
#[type_name("insuwb::GroundTruth")]
pub struct GroundTruth {
    /// Common header.
    pub header: Header,
    /// Position, ENU, m.
    pub pos_m: [f64; 3],
    /// Velocity, ENU, m/s (zero when the source has none).
    pub vel_mps: [f64; 3],
    /// Attitude `[w, x, y, z]`, body to ENU.
    pub quat: [f64; 4],
}

impl GroundTruth {
    /// `vel_mps` is valid.
    pub const FLAG_VEL_VALID: u32 = 1;
}

/// Copies an ASCII name into a NUL-padded fixed field (truncating).
#[must_use]
pub fn fixed_name<const N: usize>(name: &str) -> [u8; N] {
    let mut out = [0u8; N];
    for (o, b) in out.iter_mut().zip(name.bytes()) {
        *o = b;
    }
    out
}

/// Reads a NUL-padded fixed field back as a string (lossy).
#[must_use]
pub fn name_str(field: &[u8]) -> String {
    let end = field.iter().position(|&b| b == 0).unwrap_or(field.len());
    String::from_utf8_lossy(&field[..end]).into_owned()
}

/// Topic names (relative to the deployment's service prefix).
pub mod topics {
    /// Raw IMU samples ([`crate::ImuSample`]).
    pub const IMU: &str = "imu";
    /// Raw UWB TDOA measurements ([`crate::UwbTdoa`]).
    pub const UWB_TDOA: &str = "uwb_tdoa";
    /// UWB fixes ([`crate::UwbFix`]).
    pub const UWB_FIX: &str = "uwb_fix";
    /// INS navigation states ([`crate::NavState`]).
    pub const NAV: &str = "nav";
    /// Fused states ([`crate::FusedState`]).
    pub const FUSED: &str = "fused";
    /// Filter diagnostics ([`crate::FilterDiag`]).
    pub const DIAG: &str = "diag";
    /// INS corrections ([`crate::InsCorrection`]).
    pub const CORRECTION: &str = "correction";
    /// Stage health ([`crate::Health`]).
    pub const HEALTH: &str = "health";
    /// Ground truth ([`crate::GroundTruth`]).
    pub const TRUTH: &str = "truth";
    /// Body-frame velocity measurements ([`crate::BodyVelocity`]).
    pub const BODY_VEL: &str = "body_vel";
    /// Raw UWB two-way ranges ([`crate::UwbRange`]).
    pub const UWB_RANGE: &str = "uwb_range";
    /// Height measurements ([`crate::Height`]).
    pub const HEIGHT: &str = "height";
}

/// Anything carrying a [`Header`].
pub trait HasHeader {
    /// The sample's header.
    fn header(&self) -> &Header;
    /// The sample's header, mutable.
    fn header_mut(&mut self) -> &mut Header;
}

macro_rules! impl_has_header {
    ($($t:ty),*) => {$(
        impl HasHeader for $t {
            fn header(&self) -> &Header { &self.header }
            fn header_mut(&mut self) -> &mut Header { &mut self.header }
        }
    )*};
}
impl_has_header!(
    ImuSample,
    UwbTdoa,
    UwbRange,
    BodyVelocity,
    Height,
    UwbFix,
    NavState,
    InsCorrection,
    FusedState,
    FilterDiag,
    GroundTruth,
    Health
);

#[cfg(test)]
mod name_tests {
    use super::*;

    #[test]
    fn every_name_parses_back_and_codes_round_trip() {
        for k in FilterKind::ALL {
            assert_eq!(k.name().parse::<FilterKind>(), Ok(k));
            assert_eq!(FilterKind::from_code(k as u32), Some(k));
            assert_eq!(k.to_string(), k.name());
        }
        assert_eq!(FilterKind::from_code(0), None);
        let e = "ekf".parse::<FilterKind>().unwrap_err();
        assert_eq!(
            e.to_string(),
            "unknown filter 'ekf' (known: kf, shaf, stf, iakf, iakf_tdoa)"
        );
        for k in UwbKind::ALL {
            assert_eq!(k.name().parse::<UwbKind>(), Ok(k));
            assert_eq!(k.to_string(), k.name());
        }
        assert_eq!(
            "aoa".parse::<UwbKind>().unwrap_err().to_string(),
            "unknown UWB kind 'aoa' (known: tdoa, twr)"
        );
        for r in StageRole::ALL {
            assert_eq!(r.name().parse::<StageRole>(), Ok(r));
            assert_eq!(r.to_string(), r.name());
        }
        assert!("gps"
            .parse::<StageRole>()
            .unwrap_err()
            .to_string()
            .contains("imu, uwb, ins, fusion, ros2, foxglove, zenoh, logger"));
        assert_eq!(
            StageRole::NAMES.join(", "),
            "imu, uwb, ins, fusion, ros2, foxglove, zenoh, logger"
        );
        assert!(!StageRole::DEFAULT.contains(&StageRole::Ros2));
        assert!(!StageRole::DEFAULT.contains(&StageRole::Foxglove));
        assert!(!StageRole::DEFAULT.contains(&StageRole::Zenoh));
        assert!(StageRole::DEFAULT
            .iter()
            .all(|r| StageRole::ALL.contains(r)));
    }

    #[test]
    fn every_stage_process_has_its_own_kernel_name() {
        for r in StageRole::ALL {
            assert_eq!(r.program(), format!("insuwb-stage-{}", r.name()));
            assert!(r.process_name().len() <= 15);
            assert_eq!(StageRole::from_process_name(r.process_name()), Some(r));
        }
        assert_eq!(StageRole::Fusion.process_name(), "insuwb-stage-fu");
        assert_eq!(StageRole::Foxglove.process_name(), "insuwb-stage-fo");
        assert_eq!(StageRole::Zenoh.process_name(), "insuwb-stage-ze");
        assert_eq!(StageRole::from_process_name("insuwb-stage-fusion"), None);
        assert_eq!(StageRole::from_process_name("insuwb"), None);
    }
}

#[cfg(test)]
mod layout_tests {
    use super::*;
    use core::mem::{align_of, offset_of, size_of};

    /// A body velocity's range in whole mm: rounded, nothing below zero,
    /// and read back as metres only where there is one.
    #[test]
    fn a_body_velocitys_range_is_whole_millimetres() {
        assert_eq!(BodyVelocity::range_mm_from_m(1.2344), 1234);
        assert_eq!(BodyVelocity::range_mm_from_m(1.2346), 1235);
        for none in [-0.1, f64::NAN, f64::NEG_INFINITY] {
            assert_eq!(BodyVelocity::range_mm_from_m(none), 0, "{none}");
        }
        assert_eq!(BodyVelocity::range_mm_from_m(1e12), u32::MAX);
        let mut v = BodyVelocity::default();
        assert_eq!(v.range_m(), None);
        v.range_mm = 1500;
        assert_eq!(v.range_m(), Some(1.5));
    }

    #[test]
    fn header_layout_is_pinned() {
        assert_eq!(size_of::<Header>(), 40);
        assert_eq!(align_of::<Header>(), 8);
        assert_eq!(offset_of!(Header, layout_version), 0);
        assert_eq!(offset_of!(Header, source_id), 2);
        assert_eq!(offset_of!(Header, flags), 4);
        assert_eq!(offset_of!(Header, generation), 8);
        assert_eq!(offset_of!(Header, seq), 16);
        assert_eq!(offset_of!(Header, meas_time_ns), 24);
        assert_eq!(offset_of!(Header, pub_time_ns), 32);
    }

    #[test]
    fn sample_layouts_are_pinned() {
        assert_eq!(size_of::<ImuSample>(), 88);
        assert_eq!(offset_of!(ImuSample, accel_mps2), 40);
        assert_eq!(offset_of!(ImuSample, gyro_rps), 64);

        assert_eq!(size_of::<UwbTdoa>(), 104);
        assert_eq!(offset_of!(UwbTdoa, anchor_a), 40);
        assert_eq!(offset_of!(UwbTdoa, anchor_b), 44);
        assert_eq!(offset_of!(UwbTdoa, diff_m), 48);
        assert_eq!(offset_of!(UwbTdoa, anchor_a_pos_m), 56);
        assert_eq!(offset_of!(UwbTdoa, anchor_b_pos_m), 80);

        assert_eq!(size_of::<UwbRange>(), 80);
        assert_eq!(offset_of!(UwbRange, anchor), 40);
        assert_eq!(offset_of!(UwbRange, quality), 44);
        assert_eq!(offset_of!(UwbRange, range_m), 48);
        assert_eq!(offset_of!(UwbRange, anchor_pos_m), 56);

        assert_eq!(size_of::<UwbFix>(), 248);
        assert_eq!(offset_of!(UwbFix, pos_m), 40);
        assert_eq!(offset_of!(UwbFix, vel_mps), 64);
        assert_eq!(offset_of!(UwbFix, pos_cov_m2), 88);
        assert_eq!(offset_of!(UwbFix, vel_cov), 160);
        assert_eq!(offset_of!(UwbFix, gdop), 232);
        assert_eq!(offset_of!(UwbFix, n_meas), 240);

        assert_eq!(size_of::<NavState>(), 240);
        assert_eq!(offset_of!(NavState, correction_id), 40);
        assert_eq!(offset_of!(NavState, imu_seq), 48);
        assert_eq!(offset_of!(NavState, pos_m), 64);
        assert_eq!(offset_of!(NavState, quat), 112);
        assert_eq!(offset_of!(NavState, gyro_bias_rps), 216);

        assert_eq!(size_of::<InsCorrection>(), 264);
        assert_eq!(offset_of!(InsCorrection, apply_at_seq), 48);
        assert_eq!(offset_of!(InsCorrection, d_pos_m), 64);
        assert_eq!(offset_of!(InsCorrection, reset_quat), 232);

        assert_eq!(size_of::<FusedState>(), 488);
        assert_eq!(offset_of!(FusedState, cov), 128);
        assert_eq!(offset_of!(FusedState, frame_id), 416);
        assert_eq!(offset_of!(FusedState, uwb_seq), 432);
        assert_eq!(offset_of!(FusedState, filter_kind), 480);

        assert_eq!(size_of::<FilterDiag>(), 320);
        assert_eq!(offset_of!(FilterDiag, lambda), 168);
        assert_eq!(offset_of!(FilterDiag, dim), 312);

        assert_eq!(size_of::<GroundTruth>(), 120);
        // Health: pinned field by field in its module.
        assert_eq!(size_of::<Health>(), 168);
        for a in [
            align_of::<ImuSample>(),
            align_of::<UwbTdoa>(),
            align_of::<UwbRange>(),
            align_of::<UwbFix>(),
            align_of::<NavState>(),
            align_of::<InsCorrection>(),
            align_of::<FusedState>(),
            align_of::<FilterDiag>(),
            align_of::<GroundTruth>(),
            align_of::<Health>(),
        ] {
            assert_eq!(a, 8);
        }
    }

    #[test]
    fn samples_round_trip_through_postcard() {
        let mut f = FusedState {
            header: Header::new(3, 42),
            ..FusedState::default()
        };
        f.cov[5][4] = 1.5;
        f.frame_id = fixed_name("map");
        let bytes = postcard::to_stdvec(&f).unwrap();
        let back: FusedState = postcard::from_bytes(&bytes).unwrap();
        assert_eq!(back, f);
        assert_eq!(name_str(&back.frame_id), "map");
    }
}
