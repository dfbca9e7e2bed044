//! The payloads of the fleet, version [`VERSION`]: what a robot publishes
//! under `insuwb/<robot>/<kind>`, encoded so that a subscriber in any
//! language decodes it without insuwb's code (the text of
//! `docs/ZENOH.md` follows).
//!
//! | kind | payload | Zenoh encoding |
//! |---|---|---|
//! | `pose` | ROS 2 CDR of `nav_msgs/msg/Odometry` ([`Pose`]) | [`POSE_ENCODING`] |
//! | `health` | JSON, [`HealthPayload`] | [`HEALTH_ENCODING`] |
//! | `fix` | JSON, [`FixPayload`] | [`FIX_ENCODING`] |
//! | `diag` | JSON, [`DiagPayload`] | [`DIAG_ENCODING`] |
//!
//! Every sample carries an attachment, the JSON object [`Meta`]
//! (`{"v":1,"seq":N,"flags":F}`): the version, the publisher's count of
//! that key's samples and the sample's insuwb flags. The JSON payloads
//! carry `"version": 1` too. A decoder refuses another version
//! ([`DecodeError::Version`]) and ignores fields it does not know.
//! It refuses a payload over [`MAX_PAYLOAD_BYTES`] or an attachment over
//! [`MAX_ATTACHMENT_BYTES`] before reading it ([`DecodeError::TooLarge`]),
//! and JSON nested deeper than `serde_json`'s limit (128 levels).
//!
//! ```
//! use insuwb_fleet::keys::Kind;
//! use insuwb_msg::{FusedState, Header};
//! use insuwb_report::clock::ClockOffset;
//! use insuwb_zenoh::payload::{self, Payload};
//! let mut s = FusedState { header: Header::new(7, 2_000_000_000), quat: [1.0, 0.0, 0.0, 0.0], ..Default::default() };
//! s.pos_m = [1.0, 2.0, 0.5];
//! s.header.flags = FusedState::FLAG_VALID;
//! let (bytes, meta) = payload::encode_pose(&s, 0, &ClockOffset::ZERO).unwrap();
//! let got = payload::decode("insuwb/r1/pose", payload::POSE_ENCODING, &bytes, Some(&meta.to_attachment())).unwrap();
//! assert_eq!(got.key.kind(), Kind::Pose);
//! let Payload::Pose(pose) = got.payload else { unreachable!() };
//! assert_eq!(pose.sample().pos_m, [1.0, 2.0, 0.5]);
//! assert_eq!(pose.meta.flags, FusedState::FLAG_VALID);
//! ```
#![doc = include_str!("../../../docs/ZENOH.md")]

use std::collections::BTreeMap;

use insuwb_fleet::keys::{Key, KeyError, Kind};
use insuwb_fleet::station::{HealthSample, PoseSample, StageHealth, StageState};
use insuwb_msg::{CounterValue, FilterDiag, FilterKind, FusedState, UwbFix};
use insuwb_report::clock::ClockOffset;
use insuwb_report::health::{GroupSeen, StageCondition};
use insuwb_ros2::cdr;
use insuwb_ros2::convert::{self, ConvertError, Frames, RosStamp};
use insuwb_ros2::msgs::{Odometry, RosMessage, Time};
use serde::{Deserialize, Serialize};

/// The version of every payload and attachment this crate writes and
/// reads.
pub const VERSION: u32 = 1;

/// The pose's Zenoh encoding: CDR, schema the ROS 2 type name.
pub const POSE_ENCODING: &str = "application/cdr;nav_msgs/msg/Odometry";
/// The health's Zenoh encoding: JSON, schema [`HEALTH_SCHEMA`].
pub const HEALTH_ENCODING: &str = "application/json;insuwb/health";
/// The fixes' Zenoh encoding: JSON, schema `insuwb/fix`.
pub const FIX_ENCODING: &str = "application/json;insuwb/fix";
/// The diagnostics' Zenoh encoding: JSON, schema `insuwb/diag`.
pub const DIAG_ENCODING: &str = "application/json;insuwb/diag";
/// The schema name of the health payload.
pub const HEALTH_SCHEMA: &str = "insuwb/health";

/// The largest payload a decoder reads, bytes: every payload of this
/// version is a few KiB at most (a pose about 750 bytes, a group's health
/// a few hundred bytes a stage).
pub const MAX_PAYLOAD_BYTES: usize = 64 * 1024;

/// The largest attachment a decoder reads, bytes (the [`Meta`] JSON is
/// about 30).
pub const MAX_ATTACHMENT_BYTES: usize = 1024;

/// The frame of the pose (`header.frame_id`).
pub const FRAME_ID: &str = "map";
/// The robot's body frame (`child_frame_id`).
pub const CHILD_FRAME_ID: &str = "base_link";

/// The Zenoh encoding of `kind`'s payload (as Zenoh writes it as text:
/// `MIME;schema`).
#[must_use]
pub const fn encoding(kind: Kind) -> &'static str {
    match kind {
        Kind::Pose => POSE_ENCODING,
        Kind::Health => HEALTH_ENCODING,
        Kind::Fix => FIX_ENCODING,
        Kind::Diag => DIAG_ENCODING,
    }
}

/// A sample that cannot be encoded.
#[derive(Debug, thiserror::Error)]
pub enum EncodeError {
    /// A value that no message holds (NaN, a stamp out of range).
    #[error("EncodeError::Convert: {0}")]
    Convert(#[from] ConvertError),
    /// The CDR serializer refused the message.
    #[error("EncodeError::Cdr: {0}")]
    Cdr(#[from] cdr::EncodeError),
    /// The JSON serializer refused the value.
    #[error("EncodeError::Json: {0}")]
    Json(String),
}

/// A received sample that is not a payload of this version.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DecodeError {
    /// The key is not `insuwb/<robot>/<kind>`.
    #[error("DecodeError::Key: {0}")]
    Key(#[from] KeyError),
    /// The sample's encoding is not its kind's.
    #[error("DecodeError::Encoding: {key}: encoding {got:?}, expected {want:?}")]
    Encoding {
        /// The key.
        key: String,
        /// The sample's encoding.
        got: String,
        /// The kind's ([`encoding`]).
        want: &'static str,
    },
    /// No attachment, or one that is not the [`Meta`] JSON.
    #[error("DecodeError::Attachment: {0}")]
    Attachment(String),
    /// A version this crate does not read.
    #[error("DecodeError::Version: version {found}, this decoder reads {VERSION}")]
    Version {
        /// The version found.
        found: u32,
    },
    /// The pose's bytes are not the CDR of `nav_msgs/msg/Odometry`.
    #[error("DecodeError::Cdr: {0}")]
    Cdr(#[from] cdr::DecodeError),
    /// The bytes are not the JSON of the kind.
    #[error("DecodeError::Json: {0}")]
    Json(String),
    /// The odometry holds values no fused state has (NaN, a quaternion
    /// that is not a rotation, a stamp out of range).
    #[error("DecodeError::Convert: {0}")]
    Convert(#[from] ConvertError),
    /// The payload or the attachment is larger than any of this version
    /// ([`MAX_PAYLOAD_BYTES`], [`MAX_ATTACHMENT_BYTES`]); not read.
    #[error("DecodeError::TooLarge: the {what} has {len} bytes, at most {max} are read")]
    TooLarge {
        /// `payload` or `attachment`.
        what: &'static str,
        /// Its size, bytes.
        len: usize,
        /// The limit, bytes.
        max: usize,
    },
}

fn check_size(what: &'static str, bytes: &[u8], max: usize) -> Result<(), DecodeError> {
    if bytes.len() > max {
        Err(DecodeError::TooLarge {
            what,
            len: bytes.len(),
            max,
        })
    } else {
        Ok(())
    }
}

fn check_version(found: u32) -> Result<(), DecodeError> {
    if found == VERSION {
        Ok(())
    } else {
        Err(DecodeError::Version { found })
    }
}

fn to_json<T: Serialize>(v: &T) -> Result<Vec<u8>, EncodeError> {
    serde_json::to_vec(v).map_err(|e| EncodeError::Json(e.to_string()))
}

fn from_json<'a, T: Deserialize<'a>>(bytes: &'a [u8]) -> Result<T, DecodeError> {
    serde_json::from_slice(bytes).map_err(|e| DecodeError::Json(e.to_string()))
}

/// The attachment of every sample: `{"v":1,"seq":N,"flags":F}`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Meta {
    /// The payload version ([`VERSION`]).
    #[serde(rename = "v")]
    pub version: u32,
    /// The publisher's count of the samples of this key, from 0 at its
    /// start (a restarted bridge starts again): a gap is a lost sample.
    #[serde(default)]
    pub seq: u64,
    /// The insuwb flags of the sample (`FusedState::FLAG_*` for a pose,
    /// `UwbFix::FLAG_*` for a fix, `FilterDiag::FLAG_*` for a diagnostic;
    /// 0 for health).
    #[serde(default)]
    pub flags: u32,
}

impl Meta {
    /// Version [`VERSION`], sample `seq`, `flags`.
    #[must_use]
    pub const fn new(seq: u64, flags: u32) -> Self {
        Self {
            version: VERSION,
            seq,
            flags,
        }
    }

    /// The attachment's bytes (JSON).
    #[must_use]
    pub fn to_attachment(&self) -> Vec<u8> {
        format!(
            "{{\"v\":{},\"seq\":{},\"flags\":{}}}",
            self.version, self.seq, self.flags
        )
        .into_bytes()
    }

    /// The meta of an attachment.
    ///
    /// # Errors
    /// [`DecodeError::Attachment`] when there is none or it is not the
    /// JSON object, [`DecodeError::Version`] for another version,
    /// [`DecodeError::TooLarge`] over [`MAX_ATTACHMENT_BYTES`].
    pub fn from_attachment(bytes: Option<&[u8]>) -> Result<Self, DecodeError> {
        let bytes =
            bytes.ok_or_else(|| DecodeError::Attachment("the sample has none".to_owned()))?;
        check_size("attachment", bytes, MAX_ATTACHMENT_BYTES)?;
        let m: Self = serde_json::from_slice(bytes)
            .map_err(|e| DecodeError::Attachment(format!("not {{\"v\":1,...}}: {e}")))?;
        check_version(m.version)?;
        Ok(m)
    }
}

/// The nanoseconds of a stamp.
fn time_ns(t: Time) -> u64 {
    // A stamp of `ClockOffset::stamp` has sec >= 0 and nanosec < 1e9.
    u64::try_from(t.sec).unwrap_or(0) * 1_000_000_000 + u64::from(t.nanosec)
}

/// The stamp of a CLOCK_MONOTONIC time in the stamp clock, ns.
fn stamp_ns(clock: &ClockOffset, monotonic_ns: u64) -> Result<u64, ConvertError> {
    clock.stamp(monotonic_ns).map(time_ns)
}

/// The frames of the pose: `map` and `base_link`.
fn frames() -> Frames {
    Frames {
        frame_id: FRAME_ID.to_owned(),
        child_frame_id: CHILD_FRAME_ID.to_owned(),
        imu_frame_id: CHILD_FRAME_ID.to_owned(),
    }
}

/// The pose payload of fused state `s`, sample `seq` of its key: the CDR of
/// its `nav_msgs/msg/Odometry` (frames `map` and `base_link`, stamp in
/// `clock`, covariance as `insuwb_ros2::convert::fused_to_odometry` lays
/// it out), and its attachment with the state's flags.
///
/// # Errors
/// [`EncodeError`] for a state no odometry holds.
pub fn encode_pose(
    s: &FusedState,
    seq: u64,
    clock: &ClockOffset,
) -> Result<(Vec<u8>, Meta), EncodeError> {
    let o = convert::fused_to_odometry(s, &frames(), clock)?;
    let bytes = cdr::encode(&o, &Odometry::type_name())?;
    Ok((bytes, Meta::new(seq, s.header.flags)))
}

/// A received pose.
#[derive(Debug, Clone, PartialEq)]
pub struct Pose {
    /// The odometry.
    pub odometry: Odometry,
    /// Its attachment (the fused state's flags).
    pub meta: Meta,
}

impl Pose {
    /// The pose of a payload and its attachment.
    ///
    /// # Errors
    /// [`DecodeError`] for another version or bytes that are not the CDR
    /// of `nav_msgs/msg/Odometry`.
    pub fn decode(payload: &[u8], attachment: Option<&[u8]>) -> Result<Self, DecodeError> {
        let meta = Meta::from_attachment(attachment)?;
        let odometry = cdr::decode::<Odometry>(payload, &Odometry::type_name())?;
        Ok(Self { odometry, meta })
    }

    /// The station's sample of it: stamp (ns, the robot's stamp clock),
    /// position, heading (yaw of the attitude, counter-clockwise from
    /// east).
    #[must_use]
    pub fn sample(&self) -> PoseSample {
        let p = &self.odometry.pose.pose.position;
        let q = &self.odometry.pose.pose.orientation;
        PoseSample {
            stamp_ns: time_ns(self.odometry.header.stamp),
            pos_m: [p.x, p.y, p.z],
            yaw_rad: (2.0 * (q.w * q.z + q.x * q.y)).atan2(1.0 - 2.0 * (q.y * q.y + q.z * q.z)),
        }
    }

    /// The fused state it holds (`insuwb_ros2::convert::odometry_to_fused`,
    /// the stamp mapped back by `clock`), with the flags and sequence
    /// number of its attachment.
    ///
    /// # Errors
    /// [`DecodeError::Convert`] for values no fused state holds.
    pub fn fused_state(&self, clock: &ClockOffset) -> Result<FusedState, DecodeError> {
        let mut s = convert::odometry_to_fused(&self.odometry, clock)?;
        s.header.flags = self.meta.flags;
        s.header.seq = self.meta.seq;
        Ok(s)
    }
}

/// One stage in a [`HealthPayload`]: the station's [`StageHealth`]
/// (`stage`, `state`, `restarts`) and what the heartbeats tell besides.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StagePayload {
    /// Stage name (`imu`, `fusion`, ...).
    pub stage: String,
    /// Its state: `ok`, `degraded` (also for a coasting fusion stage),
    /// `disconnected`, `stopping` or `down` (no heartbeat, or a stale one).
    pub state: StageState,
    /// Its condition in detail: `ok`, `degraded`, `coasting`,
    /// `disconnected`, `stopping`, `stale`, `down` or `unknown`.
    pub condition: String,
    /// How many times it was restarted (its heartbeat's generation).
    pub restarts: u64,
    /// Its process id (0: no heartbeat yet).
    pub pid: u32,
    /// Age of its last heartbeat, s (`null`: none came).
    pub heartbeat_age_s: Option<f64>,
    /// Samples received per second (`null` until two heartbeats).
    pub received_rate_hz: Option<f64>,
    /// Samples published per second (`null` until two heartbeats).
    pub published_rate_hz: Option<f64>,
    /// The counters of its kind from its last heartbeat, by name (empty
    /// without a heartbeat or for a kind this version does not know).
    #[serde(default)]
    pub counters: BTreeMap<String, CounterValue>,
}

impl StagePayload {
    /// Stage `name` from what its heartbeats told (`None`: none came) at
    /// `now_ns` (CLOCK_MONOTONIC).
    #[must_use]
    pub fn of(
        name: &str,
        seen: Option<&insuwb_report::health::StageSeen>,
        coasting: bool,
        now_ns: u64,
        stale_after_ns: u64,
    ) -> Self {
        let c = StageCondition::of(seen, coasting, now_ns, stale_after_ns);
        // The payload's coarse state; the condition word is the one table's.
        let state = match c {
            StageCondition::Down | StageCondition::Stale => StageState::Down,
            StageCondition::Stopping => StageState::Stopping,
            StageCondition::Disconnected => StageState::Disconnected,
            StageCondition::Degraded | StageCondition::Coasting | StageCondition::Unknown(_) => {
                StageState::Degraded
            }
            StageCondition::Ok => StageState::Ok,
        };
        let condition = c.name();
        Self {
            stage: name.to_owned(),
            state,
            condition: condition.to_owned(),
            restarts: seen.map_or(0, |s| u64::from(s.last.header.generation)),
            pid: seen.map_or(0, |s| s.last.pid),
            heartbeat_age_s: seen.map(|s| s.age_ns(now_ns) as f64 * 1e-9),
            received_rate_hz: seen.and_then(|s| s.rates_hz).map(|r| r.0),
            published_rate_hz: seen.and_then(|s| s.rates_hz).map(|r| r.1),
            counters: seen
                .and_then(|s| s.last.counters().ok())
                .map(|c| c.values().map(|(k, v)| (k.to_owned(), v)).collect())
                .unwrap_or_default(),
        }
    }
}

/// The health payload: the robot's stages, once per health period.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HealthPayload {
    /// [`VERSION`].
    pub version: u32,
    /// The robot id.
    pub robot: String,
    /// When the report was made, ns (the robot's stamp clock).
    pub stamp_ns: u64,
    /// Every stage of the group, in its start order.
    pub stages: Vec<StagePayload>,
}

impl HealthPayload {
    /// The health of every stage of `group` at `now_ns` (CLOCK_MONOTONIC),
    /// each down when its last heartbeat is older than `stale_after_ns`.
    ///
    /// # Errors
    /// [`EncodeError::Convert`] when `now_ns` has no stamp in `clock`.
    pub fn of_group(
        robot: &str,
        group: &GroupSeen,
        now_ns: u64,
        stale_after_ns: u64,
        clock: &ClockOffset,
    ) -> Result<Self, EncodeError> {
        Ok(Self {
            version: VERSION,
            robot: robot.to_owned(),
            stamp_ns: stamp_ns(clock, now_ns)?,
            stages: group
                .stages()
                .map(|(name, seen, coasting)| {
                    StagePayload::of(name, seen, coasting, now_ns, stale_after_ns)
                })
                .collect(),
        })
    }

    /// Its JSON.
    ///
    /// # Errors
    /// [`EncodeError::Json`] (a non-finite rate).
    pub fn encode(&self) -> Result<Vec<u8>, EncodeError> {
        to_json(self)
    }

    /// The health of a payload and its attachment.
    ///
    /// # Errors
    /// [`DecodeError`] for another version or bytes that are not its JSON.
    pub fn decode(payload: &[u8], attachment: Option<&[u8]>) -> Result<Self, DecodeError> {
        Meta::from_attachment(attachment)?;
        let h: Self = from_json(payload)?;
        check_version(h.version)?;
        Ok(h)
    }

    /// The station's sample of it.
    #[must_use]
    pub fn sample(&self) -> HealthSample {
        HealthSample {
            stamp_ns: self.stamp_ns,
            stages: self
                .stages
                .iter()
                .map(|s| StageHealth {
                    stage: s.stage.clone(),
                    state: s.state,
                    restarts: s.restarts,
                })
                .collect(),
        }
    }
}

/// The fix payload: a UWB fix.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FixPayload {
    /// [`VERSION`].
    pub version: u32,
    /// The fix epoch, ns (the robot's stamp clock).
    pub stamp_ns: u64,
    /// Position, ENU (`map`), m.
    pub pos_m: [f64; 3],
    /// Position covariance, m^2, row-major 3 x 3.
    pub pos_cov_m2: [[f64; 3]; 3],
    /// Velocity, ENU, m/s (`null` when the fix has none).
    pub vel_mps: Option<[f64; 3]>,
    /// Geometric dilution of precision.
    pub gdop: f64,
    /// TDOA measurements used.
    pub n_meas: u32,
    /// Two-dimensional (height held fixed).
    pub two_d: bool,
}

impl FixPayload {
    /// The payload of fix `f`.
    ///
    /// # Errors
    /// [`EncodeError::Convert`] for a non-finite value or a stamp out of
    /// range.
    pub fn of(f: &UwbFix, clock: &ClockOffset) -> Result<Self, EncodeError> {
        convert::check_finite("pos_m", &f.pos_m)?;
        convert::check_finite("pos_cov_m2", f.pos_cov_m2.as_flattened())?;
        convert::check_finite("gdop", &[f.gdop])?;
        let vel = f.header.flags & UwbFix::FLAG_VEL_VALID != 0;
        if vel {
            convert::check_finite("vel_mps", &f.vel_mps)?;
        }
        Ok(Self {
            version: VERSION,
            stamp_ns: stamp_ns(clock, f.header.meas_time_ns)?,
            pos_m: f.pos_m,
            pos_cov_m2: f.pos_cov_m2,
            vel_mps: vel.then_some(f.vel_mps),
            gdop: f.gdop,
            n_meas: f.n_meas,
            two_d: f.header.flags & UwbFix::FLAG_2D != 0,
        })
    }

    /// Its JSON.
    ///
    /// # Errors
    /// [`EncodeError::Json`].
    pub fn encode(&self) -> Result<Vec<u8>, EncodeError> {
        to_json(self)
    }

    /// The fix of a payload and its attachment.
    ///
    /// # Errors
    /// [`DecodeError`] for another version or bytes that are not its JSON.
    pub fn decode(payload: &[u8], attachment: Option<&[u8]>) -> Result<Self, DecodeError> {
        Meta::from_attachment(attachment)?;
        let f: Self = from_json(payload)?;
        check_version(f.version)?;
        Ok(f)
    }
}

/// The diagnostics payload: one filter update.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DiagPayload {
    /// [`VERSION`].
    pub version: u32,
    /// The update's time, ns (the robot's stamp clock).
    pub stamp_ns: u64,
    /// The filter (`kf`, `shaf`, `stf`, `iakf`, `iakf_tdoa`; `unknown`).
    pub filter: String,
    /// Innovation per component (measurement minus prediction).
    pub innovation: Vec<f64>,
    /// Innovation variance per component.
    pub innovation_var: Vec<f64>,
    /// Outlier weight per component (1: accepted as is).
    pub outlier_weight: Vec<f64>,
    /// Measurement noise variance in use per component.
    pub r_diag: Vec<f64>,
    /// Normalised innovation squared.
    pub nis: f64,
    /// Fading factor (1: none).
    pub fading: f64,
    /// The divergence test fired.
    pub divergence: bool,
    /// A component was weighted as an outlier.
    pub outlier: bool,
    /// The filter was reset.
    pub reset: bool,
}

impl DiagPayload {
    /// The payload of diagnostic `d`.
    ///
    /// # Errors
    /// [`EncodeError::Convert`] for a non-finite value or a stamp out of
    /// range.
    pub fn of(d: &FilterDiag, clock: &ClockOffset) -> Result<Self, EncodeError> {
        let n = (d.dim as usize).min(d.innovation.len());
        let part = |field: &'static str, v: &[f64; 8]| -> Result<Vec<f64>, ConvertError> {
            convert::check_finite(field, &v[..n])?;
            Ok(v[..n].to_vec())
        };
        convert::check_finite("nis", &[d.nis, d.fading])?;
        Ok(Self {
            version: VERSION,
            stamp_ns: stamp_ns(clock, d.header.meas_time_ns)?,
            filter: FilterKind::from_code(d.filter_kind)
                .map_or("unknown", FilterKind::name)
                .to_owned(),
            innovation: part("innovation", &d.innovation)?,
            innovation_var: part("innovation_var", &d.innovation_var)?,
            outlier_weight: part("lambda", &d.lambda)?,
            r_diag: part("r_diag", &d.r_diag)?,
            nis: d.nis,
            fading: d.fading,
            divergence: d.header.flags & FilterDiag::FLAG_DIVERGENCE != 0,
            outlier: d.header.flags & FilterDiag::FLAG_OUTLIER != 0,
            reset: d.header.flags & FilterDiag::FLAG_RESET != 0,
        })
    }

    /// Its JSON.
    ///
    /// # Errors
    /// [`EncodeError::Json`].
    pub fn encode(&self) -> Result<Vec<u8>, EncodeError> {
        to_json(self)
    }

    /// The diagnostic of a payload and its attachment.
    ///
    /// # Errors
    /// [`DecodeError`] for another version or bytes that are not its JSON.
    pub fn decode(payload: &[u8], attachment: Option<&[u8]>) -> Result<Self, DecodeError> {
        Meta::from_attachment(attachment)?;
        let d: Self = from_json(payload)?;
        check_version(d.version)?;
        Ok(d)
    }
}

/// A decoded payload of any kind.
#[derive(Debug, Clone, PartialEq)]
pub enum Payload {
    /// `insuwb/<robot>/pose` (boxed: an odometry is five times the size
    /// of the other payloads).
    Pose(Box<Pose>),
    /// `insuwb/<robot>/health`.
    Health(HealthPayload),
    /// `insuwb/<robot>/fix`.
    Fix(FixPayload),
    /// `insuwb/<robot>/diag`.
    Diag(DiagPayload),
}

/// A received sample: its key (robot and kind) and payload.
#[derive(Debug, Clone, PartialEq)]
pub struct Received {
    /// `insuwb/<robot>/<kind>`.
    pub key: Key,
    /// The payload of its kind.
    pub payload: Payload,
}

/// Decodes a sample from its parts: key expression, Zenoh encoding (as
/// text), payload bytes and attachment bytes (what a transport other
/// than Zenoh's Rust API hands over too).
///
/// # Errors
/// [`DecodeError`] for a key outside the fleet's, an encoding other than
/// its kind's ([`encoding`]), another version, a payload over
/// [`MAX_PAYLOAD_BYTES`], or bytes that do not hold the kind's payload.
pub fn decode(
    key: &str,
    encoding_text: &str,
    payload: &[u8],
    attachment: Option<&[u8]>,
) -> Result<Received, DecodeError> {
    let key: Key = key.parse()?;
    let want = encoding(key.kind());
    if encoding_text != want {
        return Err(DecodeError::Encoding {
            key: key.to_string(),
            got: encoding_text.to_owned(),
            want,
        });
    }
    check_size("payload", payload, MAX_PAYLOAD_BYTES)?;
    let payload = match key.kind() {
        Kind::Pose => Payload::Pose(Box::new(Pose::decode(payload, attachment)?)),
        Kind::Health => Payload::Health(HealthPayload::decode(payload, attachment)?),
        Kind::Fix => Payload::Fix(FixPayload::decode(payload, attachment)?),
        Kind::Diag => Payload::Diag(DiagPayload::decode(payload, attachment)?),
    };
    Ok(Received { key, payload })
}

#[cfg(test)]
mod tests {
    use super::*;
    use insuwb_msg::{fixed_name, FusionCounters, Header, Health, StageCounters};

    fn fused() -> FusedState {
        let a: f64 = 0.6;
        let mut s = FusedState {
            header: Header::new(11, 5_000_000_123),
            pos_m: [1.25, -3.5, 0.75],
            vel_mps: [0.5, 0.25, 0.0],
            quat: [(a / 2.0).cos(), 0.0, 0.0, (a / 2.0).sin()],
            yaw_rad: a,
            ..FusedState::default()
        };
        s.header.flags = FusedState::FLAG_VALID | FusedState::FLAG_DEGRADED;
        for i in 0..6 {
            s.cov[i][i] = 0.01 * (i + 1) as f64;
        }
        s
    }

    #[test]
    fn a_pose_round_trips_through_cdr_and_its_attachment() {
        let clock = ClockOffset {
            offset_ns: 1_700_000_000_000_000_000,
        };
        let s = fused();
        let (bytes, meta) = encode_pose(&s, 42, &clock).unwrap();
        assert_eq!(bytes[..4], cdr::CDR_LE);
        let att = meta.to_attachment();
        assert_eq!(
            std::str::from_utf8(&att).unwrap(),
            format!("{{\"v\":1,\"seq\":42,\"flags\":{}}}", s.header.flags)
        );
        let got = decode("insuwb/r-1/pose", POSE_ENCODING, &bytes, Some(&att)).unwrap();
        assert_eq!((got.key.robot(), got.key.kind()), ("r-1", Kind::Pose));
        let Payload::Pose(p) = got.payload else {
            panic!("{got:?}")
        };
        assert_eq!(p.odometry.header.frame_id, "map");
        assert_eq!(p.odometry.child_frame_id, "base_link");
        let sample = p.sample();
        assert_eq!(sample.stamp_ns, 1_700_000_005_000_000_123);
        assert_eq!(sample.pos_m, s.pos_m);
        assert!((sample.yaw_rad - 0.6).abs() < 1e-12);
        // The position block of the covariance, as laid out for ROS.
        assert_eq!(p.odometry.pose.covariance.0[0], 0.01);
        assert_eq!(p.odometry.pose.covariance.0[7], 0.02);
        let back = p.fused_state(&clock).unwrap();
        assert_eq!(back.header.meas_time_ns, s.header.meas_time_ns);
        assert_eq!((back.header.seq, back.header.flags), (42, s.header.flags));
        assert_eq!(back.pos_m, s.pos_m);
        for i in 0..3 {
            assert!((back.vel_mps[i] - s.vel_mps[i]).abs() < 1e-12);
            assert!((back.cov[i + 3][i + 3] - s.cov[i + 3][i + 3]).abs() < 1e-12);
        }
    }

    #[test]
    fn a_health_report_round_trips_and_is_the_stations_sample() {
        let mut g = GroupSeen::new(&["imu".to_owned(), "fusion".to_owned(), "logger".to_owned()]);
        for (stage, generation, t) in [
            ("imu", 2, 1_000_000_000),
            ("imu", 2, 1_200_000_000),
            ("fusion", 0, 1_100_000_000),
        ] {
            let mut h = Health {
                header: Header::new(0, t),
                stage: fixed_name(stage),
                pid: 99,
                received: t / 10_000_000,
                published: t / 1_000_000,
                ..Health::default()
            };
            h.header.generation = generation;
            h.header.pub_time_ns = t;
            if stage == "fusion" {
                h.set_counters(StageCounters::Fusion(FusionCounters {
                    updates: 7,
                    outliers: 2,
                    ..FusionCounters::default()
                }));
            }
            g.note_heartbeat(h, t);
        }
        let mut coasting = FusedState::default();
        coasting.header.flags = FusedState::FLAG_DEGRADED;
        g.note_fused(&coasting);
        let h = HealthPayload::of_group("r1", &g, 1_300_000_000, 1_000_000_000, &ClockOffset::ZERO)
            .unwrap();
        let bytes = h.encode().unwrap();
        let json: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
        assert_eq!(json["version"], 1);
        assert_eq!(json["stages"][0]["state"], "ok");
        assert_eq!(json["stages"][0]["restarts"], 2);
        assert_eq!(json["stages"][1]["condition"], "coasting");
        assert_eq!(json["stages"][1]["counters"]["outliers"], 2);
        assert_eq!(json["stages"][1]["counters"]["updates"], 7);
        assert_eq!(json["stages"][0]["counters"], serde_json::json!({}));
        assert_eq!(json["stages"][2]["state"], "down");
        assert!(json["stages"][2]["heartbeat_age_s"].is_null());
        let rate = json["stages"][0]["published_rate_hz"].as_f64().unwrap();
        assert!((rate - 1000.0).abs() < 1e-6, "{rate}");
        let att = Meta::new(3, 0).to_attachment();
        let got = decode("insuwb/r1/health", HEALTH_ENCODING, &bytes, Some(&att)).unwrap();
        assert_eq!(got.payload, Payload::Health(h.clone()));
        let sample = h.sample();
        assert_eq!(sample.stamp_ns, 1_300_000_000);
        assert_eq!(
            sample
                .stages
                .iter()
                .map(|s| (s.stage.as_str(), s.state, s.restarts))
                .collect::<Vec<_>>(),
            [
                ("imu", StageState::Ok, 2),
                ("fusion", StageState::Degraded, 0),
                ("logger", StageState::Down, 0)
            ]
        );
        // The station's own type reads the JSON as it is.
        let direct: HealthSample = serde_json::from_slice(&bytes).unwrap();
        assert_eq!(direct, sample);
    }

    #[test]
    fn fixes_and_diagnostics_round_trip() {
        let mut f = UwbFix {
            header: Header::new(1, 2_000_000_000),
            pos_m: [1.0, 2.0, 0.5],
            vel_mps: [0.1, 0.2, 0.0],
            gdop: 1.5,
            n_meas: 7,
            ..UwbFix::default()
        };
        f.pos_cov_m2[0][0] = 0.04;
        f.header.flags = UwbFix::FLAG_VEL_VALID | UwbFix::FLAG_2D;
        let p = FixPayload::of(&f, &ClockOffset::ZERO).unwrap();
        assert_eq!(
            (p.vel_mps, p.two_d, p.stamp_ns),
            (Some(f.vel_mps), true, 2_000_000_000)
        );
        let att = Meta::new(0, f.header.flags).to_attachment();
        let got = decode(
            "insuwb/r1/fix",
            FIX_ENCODING,
            &p.encode().unwrap(),
            Some(&att),
        )
        .unwrap();
        assert_eq!(got.payload, Payload::Fix(p));
        f.header.flags = 0;
        f.vel_mps = [f64::NAN; 3];
        assert_eq!(
            FixPayload::of(&f, &ClockOffset::ZERO).unwrap().vel_mps,
            None
        );

        let mut d = FilterDiag {
            header: Header::new(2, 3_000_000_000),
            nis: 2.5,
            fading: 1.1,
            dim: 2,
            filter_kind: FilterKind::Iakf as u32,
            ..FilterDiag::default()
        };
        d.innovation[..2].copy_from_slice(&[0.1, -0.2]);
        d.lambda[..2].copy_from_slice(&[1.0, 0.5]);
        d.innovation[5] = f64::NAN; // beyond `dim`: not read
        d.header.flags = FilterDiag::FLAG_OUTLIER;
        let p = DiagPayload::of(&d, &ClockOffset::ZERO).unwrap();
        assert_eq!(p.filter, "iakf");
        assert_eq!(p.innovation, [0.1, -0.2]);
        assert_eq!(p.outlier_weight, [1.0, 0.5]);
        assert!(p.outlier && !p.divergence && !p.reset);
        let att = Meta::new(5, d.header.flags).to_attachment();
        let got = decode(
            "insuwb/r1/diag",
            DIAG_ENCODING,
            &p.encode().unwrap(),
            Some(&att),
        )
        .unwrap();
        assert_eq!(got.payload, Payload::Diag(p));
    }

    #[test]
    fn other_versions_encodings_and_bytes_are_refused() {
        let (bytes, meta) = encode_pose(&fused(), 0, &ClockOffset::ZERO).unwrap();
        let att = meta.to_attachment();
        let e = decode("insuwb/r1/pose", HEALTH_ENCODING, &bytes, Some(&att)).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("DecodeError::Encoding: insuwb/r1/pose: "),
            "{e}"
        );
        let e = decode("insuwb/r1/pose", POSE_ENCODING, &bytes, None).unwrap_err();
        assert!(matches!(e, DecodeError::Attachment(_)), "{e}");
        let v2 = br#"{"v":2,"seq":0,"flags":0}"#;
        let e = decode("insuwb/r1/pose", POSE_ENCODING, &bytes, Some(v2)).unwrap_err();
        assert_eq!(e, DecodeError::Version { found: 2 });
        // Unknown attachment fields are ignored; seq and flags default to 0.
        let m = Meta::from_attachment(Some(br#"{"v":1,"later":true}"#)).unwrap();
        assert_eq!(m, Meta::new(0, 0));
        let e = decode("insuwb/r1/pose", POSE_ENCODING, &bytes[..20], Some(&att)).unwrap_err();
        assert!(matches!(e, DecodeError::Cdr(_)), "{e}");
        let e = decode("insuwb/r1/health", HEALTH_ENCODING, b"{}", Some(&att)).unwrap_err();
        assert!(matches!(e, DecodeError::Json(_)), "{e}");
        let h = br#"{"version":2,"robot":"r1","stamp_ns":0,"stages":[]}"#;
        let e = decode("insuwb/r1/health", HEALTH_ENCODING, h, Some(&att)).unwrap_err();
        assert_eq!(e, DecodeError::Version { found: 2 });
        let e = decode("insuwb/r1/imu", POSE_ENCODING, &bytes, Some(&att)).unwrap_err();
        assert!(matches!(e, DecodeError::Key(_)), "{e}");
        // Too large, too deep.
        let big = vec![b' '; MAX_PAYLOAD_BYTES + 1];
        let e = decode("insuwb/r1/health", HEALTH_ENCODING, &big, Some(&att)).unwrap_err();
        assert_eq!(
            e,
            DecodeError::TooLarge {
                what: "payload",
                len: MAX_PAYLOAD_BYTES + 1,
                max: MAX_PAYLOAD_BYTES
            }
        );
        let e = Meta::from_attachment(Some(&[b' '; MAX_ATTACHMENT_BYTES + 1])).unwrap_err();
        assert!(
            matches!(
                e,
                DecodeError::TooLarge {
                    what: "attachment",
                    ..
                }
            ),
            "{e}"
        );
        let deep = format!("{}{}", "[".repeat(30_000), "]".repeat(30_000));
        let e = decode(
            "insuwb/r1/health",
            HEALTH_ENCODING,
            deep.as_bytes(),
            Some(&att),
        );
        assert!(matches!(e, Err(DecodeError::Json(_))), "{e:?}");
        let deep = format!("{}1{}", "{\"a\":".repeat(150), "}".repeat(150));
        let e = Meta::from_attachment(Some(deep.as_bytes())).unwrap_err();
        assert!(matches!(e, DecodeError::Attachment(_)), "{e}");
        let mut bad = fused();
        bad.pos_m[1] = f64::INFINITY;
        assert!(matches!(
            encode_pose(&bad, 0, &ClockOffset::ZERO),
            Err(EncodeError::Convert(_))
        ));
    }
}
