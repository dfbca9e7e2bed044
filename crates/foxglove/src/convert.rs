//! Pure conversions from insuwb samples to what the live view shows: no
//! I/O, no server.
//!
//! - Stamps: insuwb headers hold CLOCK_MONOTONIC ns. Every message's
//!   `timestamp` and its log time are the sample's measurement time in the
//!   `[foxglove] stamp_clock`: CLOCK_REALTIME by an offset measured at
//!   start and again at each health period (`realtime`, the default, what
//!   the Foxglove app shows as wall-clock time), or CLOCK_MONOTONIC as it
//!   is (`monotonic`). See [`ClockOffset`].
//! - Positions are ENU in `frame_id` (`map`); the fused pose is also the
//!   transform `frame_id -> child_frame_id` (`base_link`), which a 3D panel
//!   follows.
//! - Quaternions: insuwb's `[w, x, y, z]` becomes Foxglove's `x, y, z, w`,
//!   normalised.
//! - `diag`, the position error against ground truth, body velocities
//!   (odometry, optical flow), heights (a range finder), UWB two-way ranges
//!   and stage health are JSON messages with a JSON schema
//!   ([`DIAG_SCHEMA`], [`ERROR_SCHEMA`], [`BODY_VEL_SCHEMA`],
//!   [`HEIGHT_SCHEMA`], [`UWB_RANGE_SCHEMA`], [`HEALTH_SCHEMA`]): every
//!   number is a plottable field.
//!
//! ```
//! use insuwb_foxglove::convert::fused_pose;
//! use insuwb_report::clock::ClockOffset;
//! use insuwb_msg::{FusedState, Header};
//! let s = FusedState { header: Header::new(0, 5_000_000_001), pos_m: [1.0, 2.0, 3.0], quat: [1.0, 0.0, 0.0, 0.0], ..Default::default() };
//! let p = fused_pose(&s, "map", &ClockOffset::ZERO).unwrap();
//! let t = p.timestamp.unwrap();
//! assert_eq!((t.sec(), t.nsec()), (5, 1));
//! assert_eq!(p.pose.unwrap().position.unwrap().z, 3.0);
//! ```

use std::collections::VecDeque;

use foxglove::messages::{
    ArrowPrimitive, Color, CubePrimitive, FrameTransform, KeyValuePair, Pose, PoseInFrame,
    PosesInFrame, Quaternion, SceneEntity, SceneUpdate, SpherePrimitive, TextPrimitive, Timestamp,
    Vector3,
};
use insuwb_msg::check::{
    height_values, range_values, velocity_values, InvalidHeight, InvalidRange, InvalidVelocity,
};
use insuwb_msg::{
    name_str, BodyVelocity, FilterDiag, FilterKind, FusedState, GroundTruth, Health, Height,
    StageCounters, UwbFix, UwbRange,
};
use insuwb_report::clock::ClockOffset;
use insuwb_report::health::StageCondition;
use insuwb_report::health::StageSeen;
use insuwb_ros2::convert::{check_finite, unit_quaternion_xyzw, ConvertError as SampleError};
use serde::Serialize;

/// A sample that cannot become a Foxglove message.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum ConvertError {
    /// A field holds NaN or an infinity, the attitude quaternion is not a
    /// rotation, or the stamp does not fit a Foxglove time (before 1970 or
    /// after 2106): the checks of the ROS 2 conversions, shown as theirs
    /// (`ConvertError::NotFinite: ...`).
    #[error(transparent)]
    Sample(#[from] SampleError),
    /// `FilterDiag::dim` is larger than its arrays.
    #[error("ConvertError::BadDimension: {0} entries, at most 8")]
    BadDimension(u32),
    /// A body velocity that cannot be a measurement (`insuwb_msg::check`'s
    /// value check: not finite, no axis measured, a negative sigma, out of
    /// range, an unknown source).
    #[error("ConvertError::Velocity: {0}")]
    Velocity(#[from] InvalidVelocity),
    /// A UWB range that cannot be a measurement (`insuwb_msg::check`'s
    /// value check: a non-finite range or anchor position, a range out of
    /// range, a quality above 100).
    #[error("ConvertError::Range: {0}")]
    Range(#[from] InvalidRange),
    /// A height that cannot be a measurement (`insuwb_msg::check`'s value
    /// check: a non-finite range, a range out of range, an unknown source).
    #[error("ConvertError::Height: {0}")]
    Height(#[from] InvalidHeight),
}

/// One UWB anchor on the map.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Anchor {
    /// Its id (`UwbTdoa::anchor_a` / `anchor_b`, `UwbRange::anchor`).
    pub id: u32,
    /// Its surveyed position, ENU, m.
    pub pos_m: [f64; 3],
}

/// The stamp of a CLOCK_MONOTONIC time in the clock of `clock`, ns since
/// that clock's epoch.
///
/// # Errors
/// [`ConvertError::Sample`] ([`SampleError::StampOutOfRange`]) when it is
/// negative or past what a Foxglove time holds (u32 seconds).
pub fn stamp_ns(monotonic_ns: u64, clock: &ClockOffset) -> Result<u64, ConvertError> {
    let t = i128::from(monotonic_ns) + i128::from(clock.offset_ns);
    match u64::try_from(t) {
        Ok(v) if v / 1_000_000_000 <= u64::from(u32::MAX) => Ok(v),
        _ => Err(SampleError::StampOutOfRange(t).into()),
    }
}

/// A Foxglove time of a stamp from [`stamp_ns`].
#[must_use]
pub fn timestamp(stamp_ns: u64) -> Timestamp {
    let sec = u32::try_from(stamp_ns / 1_000_000_000).unwrap_or(u32::MAX);
    // Below 1e9: fits.
    let nsec = (stamp_ns % 1_000_000_000) as u32;
    Timestamp::new(sec, nsec)
}

fn vector(v: &[f64; 3]) -> Vector3 {
    Vector3 {
        x: v[0],
        y: v[1],
        z: v[2],
    }
}

const IDENTITY: Quaternion = Quaternion {
    x: 0.0,
    y: 0.0,
    z: 0.0,
    w: 1.0,
};

/// insuwb's `[w, x, y, z]`, normalised, in Foxglove's order.
///
/// # Errors
/// [`ConvertError::Sample`]: [`SampleError::NotFinite`], or
/// [`SampleError::BadQuaternion`] when its norm is not within 1e-3 of 1.
pub fn quaternion(q: &[f64; 4]) -> Result<Quaternion, ConvertError> {
    let [x, y, z, w] = unit_quaternion_xyzw(q)?;
    Ok(Quaternion { x, y, z, w })
}

/// A position and an attitude as a Foxglove pose.
///
/// # Errors
/// [`ConvertError`] for a non-finite position or a bad quaternion.
pub fn pose(pos_m: &[f64; 3], quat: &[f64; 4]) -> Result<Pose, ConvertError> {
    check_finite("pos_m", pos_m)?;
    Ok(Pose {
        position: Some(vector(pos_m)),
        orientation: Some(quaternion(quat)?),
    })
}

/// The fused pose at its measurement time.
///
/// # Errors
/// [`ConvertError`] for a non-finite field, a bad quaternion or a stamp
/// out of range.
pub fn fused_pose(
    s: &FusedState,
    frame_id: &str,
    clock: &ClockOffset,
) -> Result<PoseInFrame, ConvertError> {
    let t = stamp_ns(s.header.meas_time_ns, clock)?;
    Ok(PoseInFrame {
        timestamp: Some(timestamp(t)),
        frame_id: frame_id.to_owned(),
        pose: Some(pose(&s.pos_m, &s.quat)?),
    })
}

/// The transform `frame_id -> child_frame_id` of a fused pose (from
/// [`fused_pose`]).
#[must_use]
pub fn pose_transform(p: &PoseInFrame, child_frame_id: &str) -> FrameTransform {
    let pose = p.pose.unwrap_or_default();
    FrameTransform {
        timestamp: p.timestamp,
        parent_frame_id: p.frame_id.clone(),
        child_frame_id: child_frame_id.to_owned(),
        translation: pose.position,
        rotation: pose.orientation,
    }
}

/// A UWB fix as a pose (identity attitude: a fix has none) at its epoch.
///
/// # Errors
/// [`ConvertError`] for a non-finite position or a stamp out of range.
pub fn fix_pose(
    f: &UwbFix,
    frame_id: &str,
    clock: &ClockOffset,
) -> Result<PoseInFrame, ConvertError> {
    check_finite("pos_m", &f.pos_m)?;
    let t = stamp_ns(f.header.meas_time_ns, clock)?;
    Ok(PoseInFrame {
        timestamp: Some(timestamp(t)),
        frame_id: frame_id.to_owned(),
        pose: Some(Pose {
            position: Some(vector(&f.pos_m)),
            orientation: Some(IDENTITY),
        }),
    })
}

/// Ground truth as a pose at its time.
///
/// # Errors
/// [`ConvertError`] for a non-finite field, a bad quaternion or a stamp
/// out of range.
pub fn truth_pose(
    t: &GroundTruth,
    frame_id: &str,
    clock: &ClockOffset,
) -> Result<PoseInFrame, ConvertError> {
    let ts = stamp_ns(t.header.meas_time_ns, clock)?;
    Ok(PoseInFrame {
        timestamp: Some(timestamp(ts)),
        frame_id: frame_id.to_owned(),
        pose: Some(pose(&t.pos_m, &t.quat)?),
    })
}

/// The last poses of the robot, oldest first, at most `capacity`.
#[derive(Debug, Clone, PartialEq)]
pub struct Path {
    poses: VecDeque<Pose>,
    capacity: usize,
}

impl Path {
    /// An empty path of at most `capacity` poses (at least 1).
    #[must_use]
    pub fn new(capacity: usize) -> Self {
        let capacity = capacity.max(1);
        Self {
            poses: VecDeque::with_capacity(capacity.min(4096)),
            capacity,
        }
    }

    /// Appends a pose, forgetting the oldest beyond the capacity.
    pub fn push(&mut self, p: Pose) {
        if self.poses.len() == self.capacity {
            self.poses.pop_front();
        }
        self.poses.push_back(p);
    }

    /// Poses held.
    #[must_use]
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// No pose yet.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// The path as one message, oldest pose first.
    #[must_use]
    pub fn message(&self, frame_id: &str, stamp: Timestamp) -> PosesInFrame {
        PosesInFrame {
            timestamp: Some(stamp),
            frame_id: frame_id.to_owned(),
            poses: self.poses.iter().copied().collect(),
        }
    }
}

/// The id of an anchor's scene entity.
#[must_use]
pub fn anchor_entity_id(id: u32) -> String {
    format!("anchor/{id}")
}

const ANCHOR_COLOR: Color = Color {
    r: 1.0,
    g: 0.55,
    b: 0.0,
    a: 1.0,
};

/// One scene entity per anchor (id `anchor/<id>`, a sphere and its label,
/// metadata `id`), lasting until replaced. Anchors with a non-finite
/// position are left out.
#[must_use]
pub fn anchors_scene(anchors: &[Anchor], frame_id: &str, stamp: Timestamp) -> SceneUpdate {
    let entities = anchors
        .iter()
        .filter(|a| a.pos_m.iter().all(|v| v.is_finite()))
        .map(|a| {
            let at = Pose {
                position: Some(vector(&a.pos_m)),
                orientation: Some(IDENTITY),
            };
            let mut label = at;
            if let Some(p) = label.position.as_mut() {
                p.z += 0.4;
            }
            SceneEntity {
                timestamp: Some(stamp),
                frame_id: frame_id.to_owned(),
                id: anchor_entity_id(a.id),
                frame_locked: false,
                metadata: vec![KeyValuePair {
                    key: "id".into(),
                    value: a.id.to_string(),
                }],
                spheres: vec![SpherePrimitive {
                    pose: Some(at),
                    size: Some(Vector3 {
                        x: 0.3,
                        y: 0.3,
                        z: 0.3,
                    }),
                    color: Some(ANCHOR_COLOR),
                }],
                texts: vec![TextPrimitive {
                    pose: Some(label),
                    billboard: true,
                    font_size: 14.0,
                    scale_invariant: true,
                    color: Some(ANCHOR_COLOR),
                    text: format!("anchor {}", a.id),
                }],
                ..SceneEntity::default()
            }
        })
        .collect();
    SceneUpdate {
        deletions: Vec::new(),
        entities,
    }
}

/// The robot's model in its body frame (entity `robot`: a box and an arrow
/// along body x), locked to that frame so that it moves with the fused
/// pose's transform.
#[must_use]
pub fn robot_scene(child_frame_id: &str, stamp: Timestamp) -> SceneUpdate {
    let color = Color {
        r: 0.1,
        g: 0.6,
        b: 1.0,
        a: 0.9,
    };
    let origin = Pose {
        position: Some(Vector3::default()),
        orientation: Some(IDENTITY),
    };
    SceneUpdate {
        deletions: Vec::new(),
        entities: vec![SceneEntity {
            timestamp: Some(stamp),
            frame_id: child_frame_id.to_owned(),
            id: "robot".into(),
            frame_locked: true,
            cubes: vec![CubePrimitive {
                pose: Some(origin),
                size: Some(Vector3 {
                    x: 0.5,
                    y: 0.35,
                    z: 0.2,
                }),
                color: Some(color),
            }],
            arrows: vec![ArrowPrimitive {
                pose: Some(origin),
                shaft_length: 0.6,
                shaft_diameter: 0.05,
                head_length: 0.2,
                head_diameter: 0.12,
                color: Some(color),
            }],
            ..SceneEntity::default()
        }],
    }
}

/// A Foxglove time in a JSON message.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct JsonTime {
    /// Seconds.
    pub sec: u32,
    /// Nanoseconds.
    pub nsec: u32,
}

impl From<Timestamp> for JsonTime {
    fn from(t: Timestamp) -> Self {
        Self {
            sec: t.sec(),
            nsec: t.nsec(),
        }
    }
}

/// The filter's diagnostics of one update, as plottable values (topic
/// `diag`; schema [`DIAG_SCHEMA`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DiagJson {
    /// The update's time.
    pub timestamp: JsonTime,
    /// The filter (`kf`, `shaf`, `stf`, `iakf`, `iakf_tdoa`, or `unknown`).
    pub filter: &'static str,
    /// Entries of the arrays.
    pub dim: u32,
    /// Innovation (measurement minus prediction), one per entry.
    pub innovation: Vec<f64>,
    /// Square root of the innovation variance `S_ii`.
    pub innovation_sigma: Vec<f64>,
    /// Innovation over its sigma.
    pub normalized_innovation: Vec<f64>,
    /// Outlier weight per entry (1: accepted as is).
    pub outlier_weight: Vec<f64>,
    /// The smallest outlier weight of the update.
    pub min_outlier_weight: f64,
    /// Measurement noise diagonal in use.
    pub r_diag: Vec<f64>,
    /// Normalised innovation squared.
    pub nis: f64,
    /// Fading factor applied (1: none).
    pub fading: f64,
    /// An entry was weighted as an outlier.
    pub outlier: bool,
    /// The divergence test fired.
    pub divergence: bool,
    /// The filter was reset.
    pub reset: bool,
}

/// The JSON schema of [`DiagJson`].
pub const DIAG_SCHEMA: &str = r#"{
  "title": "insuwb.FilterDiag",
  "description": "The fusion filter's diagnostics of one update",
  "type": "object",
  "properties": {
    "timestamp": {"type": "object", "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0}}},
    "filter": {"type": "string", "description": "kf, shaf, stf, iakf or iakf_tdoa"},
    "dim": {"type": "integer", "description": "entries of the arrays"},
    "innovation": {"type": "array", "items": {"type": "number"}, "description": "measurement minus prediction"},
    "innovation_sigma": {"type": "array", "items": {"type": "number"}, "description": "sqrt of the innovation variance"},
    "normalized_innovation": {"type": "array", "items": {"type": "number"}, "description": "innovation / innovation_sigma"},
    "outlier_weight": {"type": "array", "items": {"type": "number"}, "description": "1: accepted as is"},
    "min_outlier_weight": {"type": "number"},
    "r_diag": {"type": "array", "items": {"type": "number"}, "description": "measurement noise diagonal in use"},
    "nis": {"type": "number", "description": "normalised innovation squared"},
    "fading": {"type": "number", "description": "fading factor (1: none)"},
    "outlier": {"type": "boolean"},
    "divergence": {"type": "boolean"},
    "reset": {"type": "boolean"}
  }
}"#;

/// A diagnostics sample as [`DiagJson`].
///
/// # Errors
/// [`ConvertError`] for a dimension past the arrays, a non-finite value or
/// a stamp out of range.
pub fn diag_json(d: &FilterDiag, clock: &ClockOffset) -> Result<DiagJson, ConvertError> {
    let n = usize::try_from(d.dim)
        .ok()
        .filter(|n| *n <= d.innovation.len())
        .ok_or(ConvertError::BadDimension(d.dim))?;
    let (inn, var, lambda, r) = (
        &d.innovation[..n],
        &d.innovation_var[..n],
        &d.lambda[..n],
        &d.r_diag[..n],
    );
    check_finite("innovation", inn)?;
    check_finite("innovation_var", var)?;
    check_finite("lambda", lambda)?;
    check_finite("r_diag", r)?;
    check_finite("nis", &[d.nis])?;
    check_finite("fading", &[d.fading])?;
    let sigma: Vec<f64> = var.iter().map(|v| v.max(0.0).sqrt()).collect();
    let normalized = inn
        .iter()
        .zip(&sigma)
        .map(|(i, s)| if *s > 0.0 { i / s } else { 0.0 })
        .collect();
    let t = stamp_ns(d.header.meas_time_ns, clock)?;
    Ok(DiagJson {
        timestamp: timestamp(t).into(),
        filter: FilterKind::from_code(d.filter_kind).map_or("unknown", FilterKind::name),
        dim: d.dim,
        innovation: inn.to_vec(),
        innovation_sigma: sigma,
        normalized_innovation: normalized,
        outlier_weight: lambda.to_vec(),
        min_outlier_weight: lambda.iter().copied().fold(1.0, f64::min),
        r_diag: r.to_vec(),
        nis: d.nis,
        fading: d.fading,
        outlier: d.header.flags & FilterDiag::FLAG_OUTLIER != 0,
        divergence: d.header.flags & FilterDiag::FLAG_DIVERGENCE != 0,
        reset: d.header.flags & FilterDiag::FLAG_RESET != 0,
    })
}

/// A body-frame velocity (wheel odometry, optical flow) as plottable
/// values (topic `body_vel`; schema [`BODY_VEL_SCHEMA`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BodyVelocityJson {
    /// The measurement's time.
    pub timestamp: JsonTime,
    /// The body frame the velocity is in (`child_frame_id`).
    pub frame_id: String,
    /// What measured it: `odometry` or `flow`.
    pub source: &'static str,
    /// Velocity along body x (forward), y (left) and z (up), m/s; `null`
    /// for an axis the source does not measure.
    pub vel_mps: [Option<f64>; 3],
    /// Standard deviation of each axis, m/s (0: not measured).
    pub sigma_mps: [f64; 3],
    /// The range finder's distance along body z that scaled a flow
    /// velocity, m; `null` without one.
    pub range_m: Option<f64>,
}

/// The JSON schema of [`BodyVelocityJson`].
pub const BODY_VEL_SCHEMA: &str = r#"{
  "title": "insuwb.BodyVelocity",
  "description": "A velocity measured in the body frame (x forward, y left, z up): wheel odometry or optical flow",
  "type": "object",
  "properties": {
    "timestamp": {"type": "object", "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0}}},
    "frame_id": {"type": "string", "description": "the body frame"},
    "source": {"type": "string", "enum": ["odometry", "flow"]},
    "vel_mps": {"type": "array", "items": {"type": ["number", "null"]}, "description": "x, y, z in m/s; null: not measured"},
    "sigma_mps": {"type": "array", "items": {"type": "number"}, "description": "standard deviation of x, y, z in m/s; 0: not measured"},
    "range_m": {"type": ["number", "null"], "description": "the range finder's distance along body z that scaled a flow velocity, m; null: none"}
  }
}"#;

/// The name of a body velocity's source (`BodyVelocity::SOURCE_*`).
#[must_use]
pub fn velocity_source_name(source: u32) -> &'static str {
    match source {
        BodyVelocity::SOURCE_ODOMETRY => "odometry",
        BodyVelocity::SOURCE_FLOW => "flow",
        _ => "unknown",
    }
}

/// A body velocity as [`BodyVelocityJson`] in `body_frame_id`, after the
/// value check the gates use ([`velocity_values`]).
///
/// # Errors
/// [`ConvertError::Velocity`] for values that cannot be a measurement,
/// [`ConvertError::Sample`] for a stamp out of range.
pub fn body_velocity_json(
    v: &BodyVelocity,
    body_frame_id: &str,
    clock: &ClockOffset,
) -> Result<BodyVelocityJson, ConvertError> {
    velocity_values(v)?;
    let t = stamp_ns(v.header.meas_time_ns, clock)?;
    let axis = |i: usize| (v.sigma_mps[i] > 0.0).then_some(v.vel_mps[i]);
    Ok(BodyVelocityJson {
        timestamp: timestamp(t).into(),
        frame_id: body_frame_id.to_owned(),
        source: velocity_source_name(v.source),
        vel_mps: [axis(0), axis(1), axis(2)],
        sigma_mps: v.sigma_mps,
        range_m: v.range_m(),
    })
}

/// A range finder's distance to the floor along body z (topic `height`;
/// schema [`HEIGHT_SCHEMA`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HeightJson {
    /// The measurement's time.
    pub timestamp: JsonTime,
    /// The body frame the range is along (`child_frame_id`).
    pub frame_id: String,
    /// What measured it: `range_finder`.
    pub source: &'static str,
    /// The distance measured along body z down to the floor, m.
    pub range_m: f64,
}

/// The JSON schema of [`HeightJson`].
pub const HEIGHT_SCHEMA: &str = r#"{
  "title": "insuwb.Height",
  "description": "A range finder's distance to the floor along the body z axis",
  "type": "object",
  "properties": {
    "timestamp": {"type": "object", "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0}}},
    "frame_id": {"type": "string", "description": "the body frame"},
    "source": {"type": "string", "enum": ["range_finder"]},
    "range_m": {"type": "number", "description": "the distance along body z down to the floor, m"}
  }
}"#;

/// The name of a height's source (`Height::SOURCE_*`).
#[must_use]
pub fn height_source_name(source: u32) -> &'static str {
    match source {
        Height::SOURCE_RANGE_FINDER => "range_finder",
        _ => "unknown",
    }
}

/// A height as [`HeightJson`] in `body_frame_id`, after the value check
/// the gates use ([`height_values`]).
///
/// # Errors
/// [`ConvertError::Height`] for values that cannot be a measurement,
/// [`ConvertError::Sample`] for a stamp out of range.
pub fn height_json(
    h: &Height,
    body_frame_id: &str,
    clock: &ClockOffset,
) -> Result<HeightJson, ConvertError> {
    height_values(h)?;
    let t = stamp_ns(h.header.meas_time_ns, clock)?;
    Ok(HeightJson {
        timestamp: timestamp(t).into(),
        frame_id: body_frame_id.to_owned(),
        source: height_source_name(h.source),
        range_m: h.range_m,
    })
}

/// One UWB two-way range (topic `uwb_range`; schema [`UWB_RANGE_SCHEMA`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct UwbRangeJson {
    /// The measurement's time.
    pub timestamp: JsonTime,
    /// The anchor's id.
    pub anchor: u32,
    /// Distance from the tag to the anchor, m.
    pub range_m: f64,
    /// The device's quality figure, 0-100; `null` when it gives none.
    pub quality: Option<u32>,
    /// The tag's common range offset (antenna delay) has been removed.
    pub offset_removed: bool,
    /// The anchor's surveyed position, ENU in `frame_id`, m.
    pub anchor_pos_m: [f64; 3],
}

/// The JSON schema of [`UwbRangeJson`].
pub const UWB_RANGE_SCHEMA: &str = r#"{
  "title": "insuwb.UwbRange",
  "description": "One UWB two-way range from the tag to an anchor",
  "type": "object",
  "properties": {
    "timestamp": {"type": "object", "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0}}},
    "anchor": {"type": "integer", "description": "the anchor's id"},
    "range_m": {"type": "number", "description": "distance from the tag to the anchor, m"},
    "quality": {"type": ["integer", "null"], "description": "the device's quality, 0-100; null: none given"},
    "offset_removed": {"type": "boolean", "description": "the tag's range offset (antenna delay) removed"},
    "anchor_pos_m": {"type": "array", "items": {"type": "number"}, "description": "the anchor's position, ENU, m"}
  }
}"#;

/// A UWB range as [`UwbRangeJson`], after the value check the gates use
/// ([`range_values`]).
///
/// # Errors
/// [`ConvertError::Range`] for values that cannot be a measurement,
/// [`ConvertError::Sample`] for a stamp out of range.
pub fn uwb_range_json(r: &UwbRange, clock: &ClockOffset) -> Result<UwbRangeJson, ConvertError> {
    range_values(r)?;
    let t = stamp_ns(r.header.meas_time_ns, clock)?;
    let flags = r.header.flags;
    Ok(UwbRangeJson {
        timestamp: timestamp(t).into(),
        anchor: r.anchor,
        range_m: r.range_m,
        quality: (flags & UwbRange::FLAG_QUALITY != 0).then_some(r.quality),
        offset_removed: flags & UwbRange::FLAG_OFFSET_REMOVED != 0,
        anchor_pos_m: r.anchor_pos_m,
    })
}

/// The fused position minus ground truth at the fused state's time (topic
/// `error`; schema [`ERROR_SCHEMA`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ErrorJson {
    /// The fused state's time.
    pub timestamp: JsonTime,
    /// East error, m.
    pub east_m: f64,
    /// North error, m.
    pub north_m: f64,
    /// Up error, m.
    pub up_m: f64,
    /// Horizontal error, m.
    pub horizontal_m: f64,
    /// 3-D error, m.
    pub norm_m: f64,
}

/// The JSON schema of [`ErrorJson`].
pub const ERROR_SCHEMA: &str = r#"{
  "title": "insuwb.PositionError",
  "description": "Fused position minus ground truth, ENU",
  "type": "object",
  "properties": {
    "timestamp": {"type": "object", "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0}}},
    "east_m": {"type": "number"},
    "north_m": {"type": "number"},
    "up_m": {"type": "number"},
    "horizontal_m": {"type": "number"},
    "norm_m": {"type": "number"}
  }
}"#;

/// The error of `pos_m` against `truth_m` at `stamp`.
#[must_use]
pub fn position_error(pos_m: &[f64; 3], truth_m: &[f64; 3], stamp: Timestamp) -> ErrorJson {
    let d = [
        pos_m[0] - truth_m[0],
        pos_m[1] - truth_m[1],
        pos_m[2] - truth_m[2],
    ];
    ErrorJson {
        timestamp: stamp.into(),
        east_m: d[0],
        north_m: d[1],
        up_m: d[2],
        horizontal_m: d[0].hypot(d[1]),
        norm_m: (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt(),
    }
}

/// Ground truth positions by time, to compare fused states with: the
/// newest `capacity` samples, in time order.
#[derive(Debug, Clone, PartialEq)]
pub struct TruthTrack {
    samples: VecDeque<(u64, [f64; 3])>,
    capacity: usize,
}

impl TruthTrack {
    /// An empty track of at most `capacity` samples (at least 2).
    #[must_use]
    pub fn new(capacity: usize) -> Self {
        let capacity = capacity.max(2);
        Self {
            samples: VecDeque::with_capacity(capacity.min(8192)),
            capacity,
        }
    }

    /// Adds a sample; one not after the newest, or not finite, is ignored
    /// (returns false).
    pub fn push(&mut self, t_ns: u64, pos_m: [f64; 3]) -> bool {
        if pos_m.iter().any(|v| !v.is_finite())
            || self.samples.back().is_some_and(|(last, _)| t_ns <= *last)
        {
            return false;
        }
        if self.samples.len() == self.capacity {
            self.samples.pop_front();
        }
        self.samples.push_back((t_ns, pos_m));
        true
    }

    /// The newest sample's time.
    #[must_use]
    pub fn newest_ns(&self) -> Option<u64> {
        self.samples.back().map(|(t, _)| *t)
    }

    /// The position at `t_ns`, linear between the samples around it;
    /// `None` outside the samples held.
    #[must_use]
    pub fn at(&self, t_ns: u64) -> Option<[f64; 3]> {
        let i = self.samples.partition_point(|(t, _)| *t < t_ns);
        let (t1, p1) = *self.samples.get(i)?;
        if t1 == t_ns {
            return Some(p1);
        }
        let (t0, p0) = *self.samples.get(i.checked_sub(1)?)?;
        let a = (t_ns - t0) as f64 / (t1 - t0) as f64;
        Some([
            p0[0] + a * (p1[0] - p0[0]),
            p0[1] + a * (p1[1] - p0[1]),
            p0[2] + a * (p1[2] - p0[2]),
        ])
    }
}

/// One stage in the health message.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StageHealth {
    /// The stage's name.
    pub name: String,
    /// `ok`, `degraded`, `coasting`, `disconnected`, `stopping`, `stale`
    /// or `down` (no heartbeat yet).
    pub status: &'static str,
    /// 0 ok, 1 warning (degraded, coasting), 2 error (stale, down,
    /// stopping, disconnected): plottable.
    pub level: u8,
    /// Process id of the last heartbeat (0: none).
    pub pid: u32,
    /// Restarts of the stage (its publisher generation).
    pub restarts: u32,
    /// Age of the last heartbeat, s (-1: none).
    pub heartbeat_age_s: f64,
    /// Samples received.
    pub received: u64,
    /// Samples published.
    pub published: u64,
    /// Samples received per second between the last two heartbeats.
    pub received_rate_hz: Option<f64>,
    /// Samples published per second between the last two heartbeats.
    pub published_rate_hz: Option<f64>,
    /// Dropped for another layout version.
    pub dropped_version: u64,
    /// Dropped for a non-finite or out-of-range value.
    pub dropped_invalid: u64,
    /// Dropped for a time going backwards or repeated.
    pub dropped_time: u64,
    /// Samples missing on the inputs.
    pub seq_gaps: u64,
    /// The counters of the stage's kind, by name (a JSON object; `null`
    /// for a signed value not known yet; empty without a heartbeat or for
    /// a kind this version does not know).
    pub counters: StageCounters,
}

/// The health of every stage of the group (topic `health`; schema
/// [`HEALTH_SCHEMA`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HealthJson {
    /// When it was made.
    pub timestamp: JsonTime,
    /// One entry per stage, in the group's start order.
    pub stages: Vec<StageHealth>,
}

/// The JSON schema of [`HealthJson`].
pub const HEALTH_SCHEMA: &str = r#"{
  "title": "insuwb.GroupHealth",
  "description": "One entry per stage of the group, from its heartbeats",
  "type": "object",
  "properties": {
    "timestamp": {"type": "object", "properties": {"sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0}}},
    "stages": {
      "type": "array",
      "items": {
        "type": "object",
        "properties": {
          "name": {"type": "string"},
          "status": {"type": "string", "enum": ["ok", "degraded", "coasting", "disconnected", "stopping", "stale", "down"]},
          "level": {"type": "integer", "description": "0 ok, 1 warning, 2 error"},
          "pid": {"type": "integer"},
          "restarts": {"type": "integer"},
          "heartbeat_age_s": {"type": "number", "description": "-1: no heartbeat yet"},
          "received": {"type": "integer"},
          "published": {"type": "integer"},
          "received_rate_hz": {"type": ["number", "null"]},
          "published_rate_hz": {"type": ["number", "null"]},
          "dropped_version": {"type": "integer"},
          "dropped_invalid": {"type": "integer"},
          "dropped_time": {"type": "integer"},
          "seq_gaps": {"type": "integer"},
          "counters": {"type": "object", "description": "the stage kind's own counters by name (e.g. outliers, fixes)", "additionalProperties": {"type": ["integer", "null"]}}
        }
      }
    }
  }
}"#;

/// The health entry of stage `name` from what its heartbeats told (`None`:
/// none came): `stale` when the last is older than `stale_after_ns`, else
/// its state, `coasting` for the fusion stage whose last output was
/// flagged degraded or stale.
#[must_use]
pub fn stage_health(
    name: &str,
    seen: Option<&StageSeen>,
    coasting: bool,
    now_ns: u64,
    stale_after_ns: u64,
) -> StageHealth {
    let condition = StageCondition::of(seen, coasting, now_ns, stale_after_ns);
    let (status, level) = (condition.name(), condition.severity().level());
    let Some(s) = seen else {
        return StageHealth {
            name: name.to_owned(),
            status,
            level,
            pid: 0,
            restarts: 0,
            heartbeat_age_s: -1.0,
            received: 0,
            published: 0,
            received_rate_hz: None,
            published_rate_hz: None,
            dropped_version: 0,
            dropped_invalid: 0,
            dropped_time: 0,
            seq_gaps: 0,
            counters: StageCounters::Common,
        };
    };
    let h = &s.last;
    StageHealth {
        name: name.to_owned(),
        status,
        level,
        pid: h.pid,
        restarts: h.header.generation,
        heartbeat_age_s: s.age_ns(now_ns) as f64 * 1e-9,
        received: h.received,
        published: h.published,
        received_rate_hz: s.rates_hz.map(|r| r.0),
        published_rate_hz: s.rates_hz.map(|r| r.1),
        dropped_version: h.dropped_version,
        dropped_invalid: h.dropped_invalid,
        dropped_time: h.dropped_time,
        seq_gaps: h.seq_gaps,
        counters: h.counters().unwrap_or_default(),
    }
}

/// The stage a heartbeat is from.
#[must_use]
pub fn heartbeat_stage(h: &Health) -> String {
    name_str(&h.stage)
}

#[cfg(test)]
mod tests {
    use super::*;
    use insuwb_msg::{fixed_name, FusionCounters, Header, HealthState};

    fn yaw(a: f64) -> [f64; 4] {
        [(a / 2.0).cos(), 0.0, 0.0, (a / 2.0).sin()]
    }

    #[test]
    fn fused_pose_is_its_position_and_attitude_at_its_time() {
        let s = FusedState {
            header: Header::new(3, 12_345_678_901),
            pos_m: [1.5, -2.0, 0.25],
            quat: yaw(std::f64::consts::FRAC_PI_2).map(|v| v * 1.0005),
            ..FusedState::default()
        };
        let clock = ClockOffset {
            offset_ns: 1_700_000_000_000_000_000,
        };
        let p = fused_pose(&s, "map", &clock).unwrap();
        assert_eq!(p.frame_id, "map");
        let t = p.timestamp.unwrap();
        assert_eq!(t.total_nanos(), 1_700_000_012_345_678_901);
        let pose = p.pose.unwrap();
        let pos = pose.position.unwrap();
        assert_eq!((pos.x, pos.y, pos.z), (1.5, -2.0, 0.25));
        let q = pose.orientation.unwrap();
        let h = std::f64::consts::FRAC_PI_4;
        assert!((q.w - h.cos()).abs() < 1e-12 && (q.z - h.sin()).abs() < 1e-12);
        assert_eq!((q.x, q.y), (0.0, 0.0));
        let tf = pose_transform(&p, "base_link");
        assert_eq!(
            (tf.parent_frame_id.as_str(), tf.child_frame_id.as_str()),
            ("map", "base_link")
        );
        assert_eq!(tf.translation.unwrap().y, -2.0);
        assert_eq!(tf.rotation, Some(q));
        assert_eq!(tf.timestamp, Some(t));
    }

    #[test]
    fn bad_samples_are_refused() {
        let mut s = FusedState {
            header: Header::new(0, 1),
            quat: [1.0, 0.0, 0.0, 0.0],
            ..FusedState::default()
        };
        s.pos_m[2] = f64::NAN;
        assert_eq!(
            fused_pose(&s, "map", &ClockOffset::ZERO),
            Err(ConvertError::Sample(SampleError::NotFinite("pos_m")))
        );
        s.pos_m[2] = 0.0;
        s.quat = [0.5, 0.0, 0.0, 0.0];
        assert_eq!(
            fused_pose(&s, "map", &ClockOffset::ZERO),
            Err(ConvertError::Sample(SampleError::BadQuaternion(0.5)))
        );
        s.quat = [1.0, 0.0, 0.0, 0.0];
        let before = ClockOffset { offset_ns: -10 };
        assert!(matches!(
            fused_pose(&s, "map", &before),
            Err(ConvertError::Sample(SampleError::StampOutOfRange(-9)))
        ));
        assert!(stamp_ns(
            u64::from(u32::MAX) * 1_000_000_000 + 999_999_999,
            &ClockOffset::ZERO
        )
        .is_ok());
        assert!(stamp_ns(
            u64::from(u32::MAX) * 1_000_000_000 + 1_000_000_000,
            &ClockOffset::ZERO
        )
        .is_err());
        let mut f = UwbFix {
            header: Header::new(0, 2_000_000_000),
            pos_m: [1.0, 2.0, 0.5],
            ..UwbFix::default()
        };
        let p = fix_pose(&f, "map", &ClockOffset::ZERO).unwrap();
        assert_eq!(p.timestamp.unwrap().sec(), 2);
        assert_eq!(p.pose.unwrap().orientation, Some(IDENTITY));
        f.pos_m[0] = f64::INFINITY;
        assert!(fix_pose(&f, "map", &ClockOffset::ZERO).is_err());
        let t = GroundTruth {
            header: Header::new(0, 5),
            pos_m: [1.0, 1.0, 1.0],
            quat: [0.0, 0.0, 0.0, 1.0],
            ..GroundTruth::default()
        };
        assert_eq!(
            truth_pose(&t, "map", &ClockOffset::ZERO)
                .unwrap()
                .pose
                .unwrap()
                .orientation
                .unwrap()
                .z,
            1.0
        );
    }

    #[test]
    fn the_path_keeps_the_last_poses_oldest_first() {
        let mut path = Path::new(3);
        assert!(path.is_empty());
        for i in 0..5 {
            path.push(pose(&[f64::from(i), 0.0, 0.0], &[1.0, 0.0, 0.0, 0.0]).unwrap());
        }
        assert_eq!(path.len(), 3);
        let m = path.message("map", Timestamp::new(1, 2));
        let xs: Vec<f64> = m
            .poses
            .iter()
            .map(|p| p.position.as_ref().unwrap().x)
            .collect();
        assert_eq!(xs, [2.0, 3.0, 4.0]);
        assert_eq!(m.frame_id, "map");
        assert_eq!(Path::new(0).capacity, 1);
    }

    #[test]
    fn each_anchor_is_one_entity() {
        let anchors = [
            Anchor {
                id: 7,
                pos_m: [1.0, 2.0, 3.0],
            },
            Anchor {
                id: 9,
                pos_m: [-4.0, 0.0, 2.5],
            },
            Anchor {
                id: 11,
                pos_m: [f64::NAN, 0.0, 0.0],
            },
        ];
        let u = anchors_scene(&anchors, "map", Timestamp::new(3, 0));
        assert!(u.deletions.is_empty());
        let ids: Vec<&str> = u.entities.iter().map(|e| e.id.as_str()).collect();
        assert_eq!(ids, ["anchor/7", "anchor/9"]);
        let e = &u.entities[1];
        assert_eq!(e.frame_id, "map");
        assert_eq!(e.metadata[0].value, "9");
        let p = e.spheres[0]
            .pose
            .as_ref()
            .unwrap()
            .position
            .as_ref()
            .unwrap();
        assert_eq!((p.x, p.y, p.z), (-4.0, 0.0, 2.5));
        assert_eq!(e.texts[0].text, "anchor 9");
        assert_eq!(e.lifetime, None, "lasts until replaced");
        let r = robot_scene("base_link", Timestamp::new(3, 0));
        assert_eq!(r.entities[0].frame_id, "base_link");
        assert!(r.entities[0].frame_locked);
    }

    #[test]
    fn diag_becomes_plottable_values() {
        let mut d = FilterDiag {
            header: Header::new(1, 1_500_000_000),
            dim: 2,
            nis: 3.5,
            fading: 1.2,
            filter_kind: FilterKind::Iakf as u32,
            ..FilterDiag::default()
        };
        d.header.flags = FilterDiag::FLAG_OUTLIER;
        d.innovation[..2].copy_from_slice(&[0.3, -0.8]);
        d.innovation_var[..2].copy_from_slice(&[0.09, 0.16]);
        d.lambda[..2].copy_from_slice(&[1.0, 0.25]);
        d.r_diag[..2].copy_from_slice(&[0.01, 0.04]);
        d.innovation[5] = f64::NAN; // past dim: not read
        let j = diag_json(&d, &ClockOffset::ZERO).unwrap();
        assert_eq!(j.filter, "iakf");
        assert_eq!(j.innovation, [0.3, -0.8]);
        assert!((j.innovation_sigma[0] - 0.3).abs() < 1e-12);
        assert!((j.normalized_innovation[1] + 2.0).abs() < 1e-12);
        assert_eq!(j.outlier_weight, [1.0, 0.25]);
        assert_eq!(j.min_outlier_weight, 0.25);
        assert!(j.outlier && !j.divergence && !j.reset);
        assert_eq!((j.timestamp.sec, j.timestamp.nsec), (1, 500_000_000));
        d.dim = 9;
        assert_eq!(
            diag_json(&d, &ClockOffset::ZERO),
            Err(ConvertError::BadDimension(9))
        );
        d.dim = 6;
        assert_eq!(
            diag_json(&d, &ClockOffset::ZERO),
            Err(ConvertError::Sample(SampleError::NotFinite("innovation")))
        );
    }

    /// Every field of a JSON message is a property of its schema.
    fn assert_schema_covers(schema: &str, value: &serde_json::Value) {
        let s: serde_json::Value = serde_json::from_str(schema).unwrap();
        let props = s["properties"].as_object().unwrap();
        for (k, v) in value.as_object().unwrap() {
            assert!(props.contains_key(k), "{k} missing in {}", s["title"]);
            if let (Some(items), Some(first)) = (
                props[k]["items"].get("properties"),
                v.as_array().and_then(|a| a.first()),
            ) {
                for k2 in first.as_object().unwrap().keys() {
                    assert!(items.get(k2).is_some(), "{k}.{k2} missing");
                }
            }
        }
        assert_eq!(
            props.len(),
            value.as_object().unwrap().len(),
            "{}",
            s["title"]
        );
    }

    #[test]
    fn json_messages_match_their_schemas() {
        let d = FilterDiag {
            header: Header::new(1, 1),
            dim: 1,
            ..FilterDiag::default()
        };
        let v = serde_json::to_value(diag_json(&d, &ClockOffset::ZERO).unwrap()).unwrap();
        assert_schema_covers(DIAG_SCHEMA, &v);
        let e = position_error(&[3.0, 4.0, 1.0], &[0.0, 0.0, 0.0], Timestamp::new(1, 0));
        assert_eq!((e.horizontal_m, e.up_m), (5.0, 1.0));
        assert!((e.norm_m - 26f64.sqrt()).abs() < 1e-12);
        assert_schema_covers(ERROR_SCHEMA, &serde_json::to_value(e).unwrap());
        let h = HealthJson {
            timestamp: Timestamp::new(1, 0).into(),
            stages: vec![stage_health("imu", None, false, 0, 1)],
        };
        assert_schema_covers(HEALTH_SCHEMA, &serde_json::to_value(h).unwrap());
    }

    #[test]
    fn a_body_velocity_shows_its_measured_axes() {
        let mut v = BodyVelocity {
            header: Header::new(4, 2_250_000_000),
            vel_mps: [0.75, -0.125, 9.0],
            sigma_mps: [0.05, 0.1, 0.0],
            source: BodyVelocity::SOURCE_FLOW,
            range_mm: 1234,
        };
        let j = body_velocity_json(&v, "base_link", &ClockOffset::ZERO).unwrap();
        assert_eq!(j.range_m, Some(1.234));
        assert_eq!((j.timestamp.sec, j.timestamp.nsec), (2, 250_000_000));
        assert_eq!(j.frame_id, "base_link");
        assert_eq!(j.source, "flow");
        assert_eq!(j.vel_mps, [Some(0.75), Some(-0.125), None]);
        assert_eq!(j.sigma_mps, [0.05, 0.1, 0.0]);
        let json = serde_json::to_value(&j).unwrap();
        assert!(json["vel_mps"][2].is_null(), "{json}");
        assert_schema_covers(BODY_VEL_SCHEMA, &json);
        v.source = BodyVelocity::SOURCE_ODOMETRY;
        v.sigma_mps = [0.02, 0.0, 0.0];
        v.range_mm = 0;
        let j = body_velocity_json(&v, "base_link", &ClockOffset::ZERO).unwrap();
        assert_eq!(
            (j.source, j.vel_mps, j.range_m),
            ("odometry", [Some(0.75), None, None], None)
        );
        // The gates' value check: refused with its reason.
        v.vel_mps[0] = f64::NAN;
        assert!(matches!(
            body_velocity_json(&v, "base_link", &ClockOffset::ZERO),
            Err(ConvertError::Velocity(InvalidVelocity::NonFinite { .. }))
        ));
        v.vel_mps[0] = 0.5;
        v.sigma_mps = [0.0; 3];
        assert!(matches!(
            body_velocity_json(&v, "base_link", &ClockOffset::ZERO),
            Err(ConvertError::Velocity(InvalidVelocity::Sigma { .. }))
        ));
        v.sigma_mps = [0.1, 0.0, 0.0];
        v.source = 7;
        let e = body_velocity_json(&v, "base_link", &ClockOffset::ZERO).unwrap_err();
        assert_eq!(
            e.to_string(),
            "ConvertError::Velocity: body velocity source 7 is unknown"
        );
        assert_eq!(velocity_source_name(7), "unknown");
    }

    #[test]
    fn a_height_shows_its_range_in_the_body_frame() {
        let mut h = Height {
            header: Header::new(6, 2_750_000_000),
            range_m: 1.375,
            source: Height::SOURCE_RANGE_FINDER,
        };
        let j = height_json(&h, "base_link", &ClockOffset::ZERO).unwrap();
        assert_eq!((j.timestamp.sec, j.timestamp.nsec), (2, 750_000_000));
        assert_eq!(j.frame_id, "base_link");
        assert_eq!((j.source, j.range_m), ("range_finder", 1.375));
        let json = serde_json::to_value(&j).unwrap();
        assert_eq!(json["range_m"], 1.375);
        assert_schema_covers(HEIGHT_SCHEMA, &json);
        // The gates' value check: refused with its reason.
        h.range_m = f64::NAN;
        assert!(matches!(
            height_json(&h, "base_link", &ClockOffset::ZERO),
            Err(ConvertError::Height(InvalidHeight::NonFinite(_)))
        ));
        h.range_m = 0.0;
        assert!(matches!(
            height_json(&h, "base_link", &ClockOffset::ZERO),
            Err(ConvertError::Height(InvalidHeight::OutOfRange { .. }))
        ));
        h.range_m = 1.375;
        h.source = 7;
        let e = height_json(&h, "base_link", &ClockOffset::ZERO).unwrap_err();
        assert_eq!(
            e.to_string(),
            "ConvertError::Height: height source 7 is unknown"
        );
        assert_eq!(height_source_name(7), "unknown");
    }

    #[test]
    fn a_uwb_range_shows_its_anchor_range_and_flags() {
        let mut r = UwbRange {
            header: Header::new(9, 3_125_000_000),
            anchor: 4,
            quality: 87,
            range_m: 5.25,
            anchor_pos_m: [1.0, -2.0, 2.5],
        };
        r.header.flags = UwbRange::FLAG_QUALITY | UwbRange::FLAG_OFFSET_REMOVED;
        let clock = ClockOffset { offset_ns: 1_000 };
        let j = uwb_range_json(&r, &clock).unwrap();
        assert_eq!((j.timestamp.sec, j.timestamp.nsec), (3, 125_001_000));
        assert_eq!((j.anchor, j.range_m, j.quality), (4, 5.25, Some(87)));
        assert!(j.offset_removed);
        assert_eq!(j.anchor_pos_m, [1.0, -2.0, 2.5]);
        let json = serde_json::to_value(j).unwrap();
        assert_eq!(json["quality"], 87);
        assert_eq!(json["anchor_pos_m"][2], 2.5);
        assert_schema_covers(UWB_RANGE_SCHEMA, &json);
        // Without the flag the quality field means nothing: null.
        r.header.flags = UwbRange::FLAG_EPOCH_END;
        r.quality = 0;
        let j = uwb_range_json(&r, &clock).unwrap();
        assert_eq!((j.quality, j.offset_removed), (None, false));
        let json = serde_json::to_value(j).unwrap();
        assert!(json["quality"].is_null(), "{json}");
        assert_schema_covers(UWB_RANGE_SCHEMA, &json);
        // The gates' value check: refused with its reason.
        r.range_m = f64::NAN;
        assert!(matches!(
            uwb_range_json(&r, &clock),
            Err(ConvertError::Range(InvalidRange::NonFinite {
                field: "range_m",
                ..
            }))
        ));
        r.range_m = 5.25;
        r.anchor_pos_m[1] = f64::INFINITY;
        let e = uwb_range_json(&r, &clock).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("ConvertError::Range: range anchor_pos_m is not finite"),
            "{e}"
        );
        r.anchor_pos_m[1] = -2.0;
        r.range_m = -0.5;
        assert!(matches!(
            uwb_range_json(&r, &clock),
            Err(ConvertError::Range(InvalidRange::OutOfRange {
                anchor: 4,
                ..
            }))
        ));
        r.range_m = 5.25;
        let before = ClockOffset {
            offset_ns: -4_000_000_000,
        };
        assert!(matches!(
            uwb_range_json(&r, &before),
            Err(ConvertError::Sample(SampleError::StampOutOfRange(_)))
        ));
    }

    #[test]
    fn truth_is_interpolated_between_samples() {
        let mut t = TruthTrack::new(3);
        assert_eq!(t.at(5), None);
        assert!(t.push(10, [0.0, 0.0, 0.0]));
        assert!(t.push(20, [1.0, 2.0, -1.0]));
        assert!(!t.push(20, [9.0; 3]), "not after the newest");
        assert!(!t.push(30, [f64::NAN, 0.0, 0.0]));
        assert_eq!(t.at(10), Some([0.0; 3]));
        assert_eq!(t.at(15), Some([0.5, 1.0, -0.5]));
        assert_eq!(t.at(20), Some([1.0, 2.0, -1.0]));
        assert_eq!(t.at(9), None);
        assert_eq!(t.at(21), None);
        assert!(t.push(30, [2.0; 3]));
        assert!(t.push(40, [3.0; 3]));
        assert_eq!(t.at(15), None, "forgotten beyond the capacity");
        assert_eq!(t.newest_ns(), Some(40));
    }

    #[test]
    fn stage_health_reads_the_heartbeats() {
        let h = Health {
            header: Header {
                generation: 2,
                meas_time_ns: 1_000_000_000,
                ..Header::new(0, 1_000_000_000)
            },
            stage: fixed_name("fusion"),
            pid: 42,
            received: 10,
            published: 5,
            ..Health::default()
        };
        assert_eq!(heartbeat_stage(&h), "fusion");
        let mut seen = StageSeen::new(h, 1_000_000_000);
        let mut h2 = h;
        h2.header.meas_time_ns = 2_000_000_000;
        h2.received = 110;
        h2.published = 15;
        seen.note(h2, 2_000_000_000);
        let ok = stage_health("fusion", Some(&seen), false, 2_100_000_000, 1_000_000_000);
        assert_eq!((ok.status, ok.level, ok.restarts, ok.pid), ("ok", 0, 2, 42));
        assert_eq!(ok.received_rate_hz, Some(100.0));
        assert_eq!(ok.published_rate_hz, Some(10.0));
        assert!((ok.heartbeat_age_s - 0.1).abs() < 1e-9);
        let coasting = stage_health("fusion", Some(&seen), true, 2_100_000_000, 1_000_000_000);
        assert_eq!((coasting.status, coasting.level), ("coasting", 1));
        let stale = stage_health("fusion", Some(&seen), false, 3_500_000_000, 1_000_000_000);
        assert_eq!((stale.status, stale.level), ("stale", 2));
        let down = stage_health("ros2", None, false, 0, 1);
        assert_eq!(
            (down.status, down.level, down.heartbeat_age_s),
            ("down", 2, -1.0)
        );
        h2.set_state(HealthState::Degraded);
        h2.set_counters(StageCounters::Fusion(FusionCounters {
            outliers: 4,
            ..FusionCounters::default()
        }));
        seen.note(h2, 2_000_000_000);
        let degraded = stage_health("fusion", Some(&seen), false, 2_000_000_000, 1);
        assert_eq!(degraded.status, "degraded");
        let json = serde_json::to_value(&degraded).unwrap();
        assert_eq!(json["counters"]["outliers"], 4);
        assert_eq!(json["counters"]["updates"], 0);
    }
}
