//! The `insuwb_msgs` package: ROS 2 message definitions of the insuwb
//! samples that have no standard ROS type (`uwb_tdoa`, `uwb_range`,
//! `uwb_fix`, `nav`, `correction`, `diag`, `truth`, `body_vel`, `height`)
//! and of the whole fused state, as serde structs in `.msg` field order, so
//! that CDR encodes them as a ROS 2 node would and every channel of an
//! export has a `ros2msg` schema.
//!
//! Each message starts with a `std_msgs/Header` (stamp from the sample's
//! `meas_time_ns`, see [`crate`]) and an [`SampleHeader`] (the insuwb
//! header). The other fields keep the insuwb names: 3-vectors of positions
//! are `geometry_msgs/Point`, other 3-vectors `geometry_msgs/Vector3`,
//! quaternions `geometry_msgs/Quaternion` in ROS order `x, y, z, w` (the
//! values as logged, not normalised), 3 x 3 and 6 x 6 matrices row-major
//! `float64[9]` / `float64[36]`, fixed-size names strings. One exception:
//! `FilterDiag.lambda` is `outlier_weight` (`lambda` is a Python keyword,
//! which the Python ROS tools cannot take as a field name).
//!
//! ```
//! use insuwb_mcap::msgs::UwbFix;
//! use insuwb_ros2::msgs::RosMessage;
//! assert_eq!(UwbFix::type_name(), "insuwb_msgs/msg/UwbFix");
//! assert!(UwbFix::schema().contains("\nMSG: insuwb_msgs/SampleHeader\n"));
//! ```

use insuwb_msg as m;
use insuwb_ros2::msgs::{
    self as ros, Cov6, Header, MsgDef, Point, Quaternion, RosMessage, Time, Vector3,
};
use serde::Serialize;

/// The ROS package of the custom messages.
pub const PACKAGE: &str = "insuwb_msgs";

/// `insuwb_msgs/SampleHeader`: the insuwb sample header (`reserved` left out).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct SampleHeader {
    /// Layout version of the sample.
    pub layout_version: u16,
    /// Source (sensor) id.
    pub source_id: u16,
    /// The topic's flags.
    pub flags: u32,
    /// Publisher's generation (restarts of its process).
    pub generation: u32,
    /// Sequence number within the generation.
    pub seq: u64,
    /// When the data was measured, CLOCK_MONOTONIC ns.
    pub meas_time_ns: u64,
    /// When the sample was published, CLOCK_MONOTONIC ns (0: not published).
    pub pub_time_ns: u64,
}

impl From<&m::Header> for SampleHeader {
    fn from(h: &m::Header) -> Self {
        Self {
            layout_version: h.layout_version,
            source_id: h.source_id,
            flags: h.flags,
            generation: h.generation,
            seq: h.seq,
            meas_time_ns: h.meas_time_ns,
            pub_time_ns: h.pub_time_ns,
        }
    }
}

/// `insuwb_msgs/UwbTdoa`: one range difference (`uwb_tdoa`).
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct UwbTdoa {
    /// Stamp and frame of the anchor positions.
    pub header: Header,
    /// The insuwb header.
    pub sample: SampleHeader,
    /// First anchor id.
    pub anchor_a: u32,
    /// Second anchor id.
    pub anchor_b: u32,
    /// Range to `anchor_a` minus range to `anchor_b`, m.
    pub diff_m: f64,
    /// Position of anchor A, m.
    pub anchor_a_pos_m: Point,
    /// Position of anchor B, m.
    pub anchor_b_pos_m: Point,
}

/// `insuwb_msgs/UwbRange`: one two-way range (`uwb_range`).
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct UwbRange {
    /// Stamp and frame of the anchor position.
    pub header: Header,
    /// The insuwb header.
    pub sample: SampleHeader,
    /// Anchor id.
    pub anchor: u32,
    /// The device's quality, 0-100 (valid with the sample's quality flag).
    pub quality: u32,
    /// Range from the tag to the anchor, m.
    pub range_m: f64,
    /// Position of the anchor, m.
    pub anchor_pos_m: Point,
}

/// `insuwb_msgs/UwbFix`: a multilaterated fix (`uwb_fix`).
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct UwbFix {
    /// Stamp and frame.
    pub header: Header,
    /// The insuwb header.
    pub sample: SampleHeader,
    /// Position, m.
    pub pos_m: Point,
    /// Velocity, m/s.
    pub vel_mps: Vector3,
    /// Position covariance, m^2, row-major 3 x 3.
    pub pos_cov_m2: [f64; 9],
    /// Velocity covariance, (m/s)^2, row-major 3 x 3.
    pub vel_cov: [f64; 9],
    /// Geometric dilution of precision.
    pub gdop: f64,
    /// Range differences used.
    pub n_meas: u32,
    /// Solver iterations.
    pub iterations: u32,
}

/// `insuwb_msgs/NavState`: the INS state of one IMU sample (`nav`).
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct NavState {
    /// Stamp and frame.
    pub header: Header,
    /// The insuwb header.
    pub sample: SampleHeader,
    /// Last correction folded in.
    pub correction_id: u64,
    /// IMU sample this state integrates.
    pub imu_seq: u64,
    /// Generation of that IMU sample's publisher.
    pub imu_generation: u32,
    /// Position, m.
    pub pos_m: Point,
    /// Velocity, m/s.
    pub vel_mps: Vector3,
    /// Attitude, body to ENU.
    pub quat: Quaternion,
    /// Acceleration in the navigation frame, m/s^2.
    pub accel_nav_mps2: Vector3,
    /// Angular rate in the navigation frame, rad/s.
    pub omega_nav_rps: Vector3,
    /// Accelerometer bias, m/s^2.
    pub accel_bias_mps2: Vector3,
    /// Gyroscope bias, rad/s.
    pub gyro_bias_rps: Vector3,
}

/// `insuwb_msgs/InsCorrection`: the fusion's correction to the INS (`correction`).
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct InsCorrection {
    /// Stamp and frame.
    pub header: Header,
    /// The insuwb header.
    pub sample: SampleHeader,
    /// Id of this correction.
    pub correction_id: u64,
    /// IMU sample it applies after.
    pub apply_at_seq: u64,
    /// Generation of that IMU sample's publisher.
    pub imu_generation: u32,
    /// Position error, m.
    pub d_pos_m: Vector3,
    /// Velocity error, m/s.
    pub d_vel_mps: Vector3,
    /// Attitude error, rad.
    pub d_att_rad: Vector3,
    /// Accelerometer bias error, m/s^2.
    pub d_accel_bias_mps2: Vector3,
    /// Gyroscope bias error, rad/s.
    pub d_gyro_bias_rps: Vector3,
    /// Reset position (with the reset flag), m.
    pub reset_pos_m: Point,
    /// Reset velocity, m/s.
    pub reset_vel_mps: Vector3,
    /// Reset attitude.
    pub reset_quat: Quaternion,
}

/// `insuwb_msgs/FusedState`: the whole fused state (`fused`), flags and
/// input times included, beside its `nav_msgs/Odometry` and `/tf` forms.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct FusedState {
    /// Stamp and frame.
    pub header: Header,
    /// The insuwb header (flags: valid 1, degraded 2, stale 4, resumed 8, reset 16).
    pub sample: SampleHeader,
    /// Position, m (ENU).
    pub pos_m: Point,
    /// Velocity, m/s (ENU).
    pub vel_mps: Vector3,
    /// Attitude, body to ENU.
    pub quat: Quaternion,
    /// Heading, rad.
    pub yaw_rad: f64,
    /// Covariance of position and velocity (ENU), row-major 6 x 6.
    pub cov: Cov6,
    /// The sample's frame name.
    pub frame_id: String,
    /// Last UWB input used: sequence number.
    pub uwb_seq: u64,
    /// Its measurement time, CLOCK_MONOTONIC ns.
    pub uwb_meas_time_ns: u64,
    /// Its publication time, CLOCK_MONOTONIC ns.
    pub uwb_pub_time_ns: u64,
    /// Last INS input used: sequence number.
    pub ins_seq: u64,
    /// Its measurement time, CLOCK_MONOTONIC ns.
    pub ins_meas_time_ns: u64,
    /// Its publication time, CLOCK_MONOTONIC ns.
    pub ins_pub_time_ns: u64,
    /// Filter code (`insuwb_msg::FilterKind`).
    pub filter_kind: u32,
}

/// `insuwb_msgs/FilterDiag`: filter diagnostics of one update (`diag`).
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct FilterDiag {
    /// Stamp (no frame).
    pub header: Header,
    /// The insuwb header (flags: divergence 1, outlier 2, reset 4).
    pub sample: SampleHeader,
    /// Innovations (the first `dim` are used).
    pub innovation: [f64; 8],
    /// Innovation variances.
    pub innovation_var: [f64; 8],
    /// Outlier weights (insuwb's `lambda`).
    pub outlier_weight: [f64; 8],
    /// Diagonal of R in use.
    pub r_diag: [f64; 8],
    /// Normalised innovation squared.
    pub nis: f64,
    /// Fading factor.
    pub fading: f64,
    /// Measurement dimension.
    pub dim: u32,
    /// Filter code (`insuwb_msg::FilterKind`).
    pub filter_kind: u32,
}

/// `insuwb_msgs/GroundTruth`: the simulator's or the data set's truth (`truth`).
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct GroundTruth {
    /// Stamp and frame.
    pub header: Header,
    /// The insuwb header (flags: velocity valid 1).
    pub sample: SampleHeader,
    /// Position, m.
    pub pos_m: Point,
    /// Velocity, m/s.
    pub vel_mps: Vector3,
    /// Attitude, body to ENU.
    pub quat: Quaternion,
}

/// `insuwb_msgs/BodyVelocity`: a velocity measured in the body frame
/// (`body_vel`: wheel odometry, optical flow).
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct BodyVelocity {
    /// Stamp and the body frame (`base_link`).
    pub header: Header,
    /// The insuwb header.
    pub sample: SampleHeader,
    /// Velocity of the body in its own frame (FLU), m/s.
    pub vel_mps: Vector3,
    /// Standard deviation of each axis, m/s; 0: the axis is not measured.
    pub sigma_mps: Vector3,
    /// What measured it: 1 wheel odometry, 2 optical flow.
    pub source: u32,
    /// The range finder's distance along body z that scaled a flow
    /// velocity, mm; 0: none.
    pub range_mm: u32,
}

/// `insuwb_msgs/Height`: a range finder's distance to the floor along
/// body z (`height`).
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct Height {
    /// Stamp and the body frame (`base_link`).
    pub header: Header,
    /// The insuwb header.
    pub sample: SampleHeader,
    /// The distance measured along the body z axis down to the floor, m.
    pub range_m: f64,
    /// What measured it: 1 a range finder.
    pub source: u32,
}

/// `insuwb_msgs/SampleHeader`.
pub static SAMPLE_HEADER: MsgDef = MsgDef {
    package: PACKAGE,
    name: "SampleHeader",
    text: "uint16 layout_version\nuint16 source_id\nuint32 flags\nuint32 generation\n\
           uint64 seq\nuint64 meas_time_ns\nuint64 pub_time_ns\n",
    uses: &[],
};
/// `insuwb_msgs/UwbTdoa`.
pub static UWB_TDOA: MsgDef = MsgDef {
    package: PACKAGE,
    name: "UwbTdoa",
    text:
        "std_msgs/Header header\nSampleHeader sample\nuint32 anchor_a\nuint32 anchor_b\n\
           float64 diff_m\ngeometry_msgs/Point anchor_a_pos_m\ngeometry_msgs/Point anchor_b_pos_m\n",
    uses: &[&ros::HEADER, &SAMPLE_HEADER, &ros::POINT],
};
/// `insuwb_msgs/UwbRange`.
pub static UWB_RANGE: MsgDef = MsgDef {
    package: PACKAGE,
    name: "UwbRange",
    text: "std_msgs/Header header\nSampleHeader sample\nuint32 anchor\nuint32 quality\n\
           float64 range_m\ngeometry_msgs/Point anchor_pos_m\n",
    uses: &[&ros::HEADER, &SAMPLE_HEADER, &ros::POINT],
};
/// `insuwb_msgs/UwbFix`.
pub static UWB_FIX: MsgDef = MsgDef {
    package: PACKAGE,
    name: "UwbFix",
    text: "std_msgs/Header header\nSampleHeader sample\ngeometry_msgs/Point pos_m\n\
           geometry_msgs/Vector3 vel_mps\nfloat64[9] pos_cov_m2\nfloat64[9] vel_cov\n\
           float64 gdop\nuint32 n_meas\nuint32 iterations\n",
    uses: &[&ros::HEADER, &SAMPLE_HEADER, &ros::POINT, &ros::VECTOR3],
};
/// `insuwb_msgs/NavState`.
pub static NAV_STATE: MsgDef = MsgDef {
    package: PACKAGE,
    name: "NavState",
    text: "std_msgs/Header header\nSampleHeader sample\nuint64 correction_id\nuint64 imu_seq\n\
           uint32 imu_generation\ngeometry_msgs/Point pos_m\ngeometry_msgs/Vector3 vel_mps\n\
           geometry_msgs/Quaternion quat\ngeometry_msgs/Vector3 accel_nav_mps2\n\
           geometry_msgs/Vector3 omega_nav_rps\ngeometry_msgs/Vector3 accel_bias_mps2\n\
           geometry_msgs/Vector3 gyro_bias_rps\n",
    uses: &[
        &ros::HEADER,
        &SAMPLE_HEADER,
        &ros::POINT,
        &ros::VECTOR3,
        &ros::QUATERNION,
    ],
};
/// `insuwb_msgs/InsCorrection`.
pub static INS_CORRECTION: MsgDef = MsgDef {
    package: PACKAGE,
    name: "InsCorrection",
    text: "std_msgs/Header header\nSampleHeader sample\nuint64 correction_id\n\
           uint64 apply_at_seq\nuint32 imu_generation\ngeometry_msgs/Vector3 d_pos_m\n\
           geometry_msgs/Vector3 d_vel_mps\ngeometry_msgs/Vector3 d_att_rad\n\
           geometry_msgs/Vector3 d_accel_bias_mps2\ngeometry_msgs/Vector3 d_gyro_bias_rps\n\
           geometry_msgs/Point reset_pos_m\ngeometry_msgs/Vector3 reset_vel_mps\n\
           geometry_msgs/Quaternion reset_quat\n",
    uses: &[
        &ros::HEADER,
        &SAMPLE_HEADER,
        &ros::VECTOR3,
        &ros::POINT,
        &ros::QUATERNION,
    ],
};
/// `insuwb_msgs/FusedState`.
pub static FUSED_STATE: MsgDef = MsgDef {
    package: PACKAGE,
    name: "FusedState",
    text: "std_msgs/Header header\nSampleHeader sample\ngeometry_msgs/Point pos_m\n\
           geometry_msgs/Vector3 vel_mps\ngeometry_msgs/Quaternion quat\nfloat64 yaw_rad\n\
           float64[36] cov\nstring frame_id\nuint64 uwb_seq\nuint64 uwb_meas_time_ns\n\
           uint64 uwb_pub_time_ns\nuint64 ins_seq\nuint64 ins_meas_time_ns\n\
           uint64 ins_pub_time_ns\nuint32 filter_kind\n",
    uses: &[
        &ros::HEADER,
        &SAMPLE_HEADER,
        &ros::POINT,
        &ros::VECTOR3,
        &ros::QUATERNION,
    ],
};
/// `insuwb_msgs/FilterDiag`.
pub static FILTER_DIAG: MsgDef = MsgDef {
    package: PACKAGE,
    name: "FilterDiag",
    text: "std_msgs/Header header\nSampleHeader sample\nfloat64[8] innovation\n\
           float64[8] innovation_var\nfloat64[8] outlier_weight\nfloat64[8] r_diag\n\
           float64 nis\nfloat64 fading\nuint32 dim\nuint32 filter_kind\n",
    uses: &[&ros::HEADER, &SAMPLE_HEADER],
};
/// `insuwb_msgs/GroundTruth`.
pub static GROUND_TRUTH: MsgDef = MsgDef {
    package: PACKAGE,
    name: "GroundTruth",
    text: "std_msgs/Header header\nSampleHeader sample\ngeometry_msgs/Point pos_m\n\
           geometry_msgs/Vector3 vel_mps\ngeometry_msgs/Quaternion quat\n",
    uses: &[
        &ros::HEADER,
        &SAMPLE_HEADER,
        &ros::POINT,
        &ros::VECTOR3,
        &ros::QUATERNION,
    ],
};

/// `insuwb_msgs/BodyVelocity`.
pub static BODY_VELOCITY: MsgDef = MsgDef {
    package: PACKAGE,
    name: "BodyVelocity",
    text: "std_msgs/Header header\nSampleHeader sample\ngeometry_msgs/Vector3 vel_mps\n\
           geometry_msgs/Vector3 sigma_mps\nuint32 source\nuint32 range_mm\n",
    uses: &[&ros::HEADER, &SAMPLE_HEADER, &ros::VECTOR3],
};

/// `insuwb_msgs/Height`.
pub static HEIGHT: MsgDef = MsgDef {
    package: PACKAGE,
    name: "Height",
    text: "std_msgs/Header header\nSampleHeader sample\nfloat64 range_m\nuint32 source\n",
    uses: &[&ros::HEADER, &SAMPLE_HEADER],
};

macro_rules! ros_message {
    ($($ty:ident => $def:ident),* $(,)?) => {$(
        impl RosMessage for $ty {
            const DEF: &'static MsgDef = &$def;
        }
    )*};
}
ros_message!(
    SampleHeader => SAMPLE_HEADER,
    UwbTdoa => UWB_TDOA,
    UwbRange => UWB_RANGE,
    UwbFix => UWB_FIX,
    NavState => NAV_STATE,
    InsCorrection => INS_CORRECTION,
    FusedState => FUSED_STATE,
    FilterDiag => FILTER_DIAG,
    GroundTruth => GROUND_TRUTH,
    BodyVelocity => BODY_VELOCITY,
    Height => HEIGHT,
);

fn point(v: &[f64; 3]) -> Point {
    Point {
        x: v[0],
        y: v[1],
        z: v[2],
    }
}

fn vector3(v: &[f64; 3]) -> Vector3 {
    Vector3 {
        x: v[0],
        y: v[1],
        z: v[2],
    }
}

/// insuwb's `[w, x, y, z]` in ROS order, as logged (not normalised).
fn quat(q: &[f64; 4]) -> Quaternion {
    Quaternion {
        x: q[1],
        y: q[2],
        z: q[3],
        w: q[0],
    }
}

fn mat3(a: &[[f64; 3]; 3]) -> [f64; 9] {
    let mut out = [0.0; 9];
    for (o, v) in out.iter_mut().zip(a.iter().flatten()) {
        *o = *v;
    }
    out
}

fn mat6(a: &[[f64; 6]; 6]) -> Cov6 {
    let mut out = [0.0; 36];
    for (o, v) in out.iter_mut().zip(a.iter().flatten()) {
        *o = *v;
    }
    Cov6(out)
}

fn header(stamp: Time, frame_id: &str) -> Header {
    Header {
        stamp,
        frame_id: frame_id.to_owned(),
    }
}

impl UwbTdoa {
    /// The message of a sample, with its stamp and frame.
    #[must_use]
    pub fn from_sample(s: &m::UwbTdoa, stamp: Time, frame_id: &str) -> Self {
        Self {
            header: header(stamp, frame_id),
            sample: (&s.header).into(),
            anchor_a: s.anchor_a,
            anchor_b: s.anchor_b,
            diff_m: s.diff_m,
            anchor_a_pos_m: point(&s.anchor_a_pos_m),
            anchor_b_pos_m: point(&s.anchor_b_pos_m),
        }
    }
}

impl UwbRange {
    /// The message of a sample, with its stamp and frame.
    #[must_use]
    pub fn from_sample(s: &m::UwbRange, stamp: Time, frame_id: &str) -> Self {
        Self {
            header: header(stamp, frame_id),
            sample: (&s.header).into(),
            anchor: s.anchor,
            quality: s.quality,
            range_m: s.range_m,
            anchor_pos_m: point(&s.anchor_pos_m),
        }
    }
}

impl UwbFix {
    /// The message of a sample, with its stamp and frame.
    #[must_use]
    pub fn from_sample(s: &m::UwbFix, stamp: Time, frame_id: &str) -> Self {
        Self {
            header: header(stamp, frame_id),
            sample: (&s.header).into(),
            pos_m: point(&s.pos_m),
            vel_mps: vector3(&s.vel_mps),
            pos_cov_m2: mat3(&s.pos_cov_m2),
            vel_cov: mat3(&s.vel_cov),
            gdop: s.gdop,
            n_meas: s.n_meas,
            iterations: s.iterations,
        }
    }
}

impl NavState {
    /// The message of a sample, with its stamp and frame.
    #[must_use]
    pub fn from_sample(s: &m::NavState, stamp: Time, frame_id: &str) -> Self {
        Self {
            header: header(stamp, frame_id),
            sample: (&s.header).into(),
            correction_id: s.correction_id,
            imu_seq: s.imu_seq,
            imu_generation: s.imu_generation,
            pos_m: point(&s.pos_m),
            vel_mps: vector3(&s.vel_mps),
            quat: quat(&s.quat),
            accel_nav_mps2: vector3(&s.accel_nav_mps2),
            omega_nav_rps: vector3(&s.omega_nav_rps),
            accel_bias_mps2: vector3(&s.accel_bias_mps2),
            gyro_bias_rps: vector3(&s.gyro_bias_rps),
        }
    }
}

impl InsCorrection {
    /// The message of a sample, with its stamp and frame.
    #[must_use]
    pub fn from_sample(s: &m::InsCorrection, stamp: Time, frame_id: &str) -> Self {
        Self {
            header: header(stamp, frame_id),
            sample: (&s.header).into(),
            correction_id: s.correction_id,
            apply_at_seq: s.apply_at_seq,
            imu_generation: s.imu_generation,
            d_pos_m: vector3(&s.d_pos_m),
            d_vel_mps: vector3(&s.d_vel_mps),
            d_att_rad: vector3(&s.d_att_rad),
            d_accel_bias_mps2: vector3(&s.d_accel_bias_mps2),
            d_gyro_bias_rps: vector3(&s.d_gyro_bias_rps),
            reset_pos_m: point(&s.reset_pos_m),
            reset_vel_mps: vector3(&s.reset_vel_mps),
            reset_quat: quat(&s.reset_quat),
        }
    }
}

impl FusedState {
    /// The message of a sample, with its stamp and frame.
    #[must_use]
    pub fn from_sample(s: &m::FusedState, stamp: Time, frame_id: &str) -> Self {
        Self {
            header: header(stamp, frame_id),
            sample: (&s.header).into(),
            pos_m: point(&s.pos_m),
            vel_mps: vector3(&s.vel_mps),
            quat: quat(&s.quat),
            yaw_rad: s.yaw_rad,
            cov: mat6(&s.cov),
            frame_id: m::name_str(&s.frame_id),
            uwb_seq: s.uwb_seq,
            uwb_meas_time_ns: s.uwb_meas_time_ns,
            uwb_pub_time_ns: s.uwb_pub_time_ns,
            ins_seq: s.ins_seq,
            ins_meas_time_ns: s.ins_meas_time_ns,
            ins_pub_time_ns: s.ins_pub_time_ns,
            filter_kind: s.filter_kind,
        }
    }
}

impl FilterDiag {
    /// The message of a sample, with its stamp (no frame).
    #[must_use]
    pub fn from_sample(s: &m::FilterDiag, stamp: Time) -> Self {
        Self {
            header: header(stamp, ""),
            sample: (&s.header).into(),
            innovation: s.innovation,
            innovation_var: s.innovation_var,
            outlier_weight: s.lambda,
            r_diag: s.r_diag,
            nis: s.nis,
            fading: s.fading,
            dim: s.dim,
            filter_kind: s.filter_kind,
        }
    }
}

impl GroundTruth {
    /// The message of a sample, with its stamp and frame.
    #[must_use]
    pub fn from_sample(s: &m::GroundTruth, stamp: Time, frame_id: &str) -> Self {
        Self {
            header: header(stamp, frame_id),
            sample: (&s.header).into(),
            pos_m: point(&s.pos_m),
            vel_mps: vector3(&s.vel_mps),
            quat: quat(&s.quat),
        }
    }
}

impl BodyVelocity {
    /// The message of a sample, with its stamp and the body frame.
    #[must_use]
    pub fn from_sample(s: &m::BodyVelocity, stamp: Time, body_frame_id: &str) -> Self {
        Self {
            header: header(stamp, body_frame_id),
            sample: (&s.header).into(),
            vel_mps: vector3(&s.vel_mps),
            sigma_mps: vector3(&s.sigma_mps),
            source: s.source,
            range_mm: s.range_mm,
        }
    }
}

impl Height {
    /// The message of a sample, with its stamp and the body frame.
    #[must_use]
    pub fn from_sample(s: &m::Height, stamp: Time, body_frame_id: &str) -> Self {
        Self {
            header: header(stamp, body_frame_id),
            sample: (&s.header).into(),
            range_m: s.range_m,
            source: s.source,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_definition_is_in_the_package_and_names_its_dependencies() {
        for (name, schema) in [
            (UwbTdoa::type_name(), UwbTdoa::schema()),
            (UwbRange::type_name(), UwbRange::schema()),
            (UwbFix::type_name(), UwbFix::schema()),
            (NavState::type_name(), NavState::schema()),
            (InsCorrection::type_name(), InsCorrection::schema()),
            (FusedState::type_name(), FusedState::schema()),
            (FilterDiag::type_name(), FilterDiag::schema()),
            (GroundTruth::type_name(), GroundTruth::schema()),
            (BodyVelocity::type_name(), BodyVelocity::schema()),
            (Height::type_name(), Height::schema()),
        ] {
            assert!(name.starts_with("insuwb_msgs/msg/"), "{name}");
            assert!(schema.starts_with("std_msgs/Header header\nSampleHeader sample\n"));
            for dep in [
                "std_msgs/Header",
                "builtin_interfaces/Time",
                "insuwb_msgs/SampleHeader",
            ] {
                assert_eq!(
                    schema.matches(&format!("\nMSG: {dep}\n")).count(),
                    1,
                    "{name}: {dep}"
                );
            }
            // Every field type of the definition is defined in the schema.
            for line in schema.lines().take_while(|l| !l.starts_with('=')) {
                let ty = line.split(' ').next().unwrap_or("");
                let ty = ty.split('[').next().unwrap_or("");
                if ty.contains('/') {
                    assert!(schema.contains(&format!("MSG: {ty}\n")), "{name}: {ty}");
                } else if ty.chars().next().is_some_and(char::is_uppercase) {
                    assert!(
                        schema.contains(&format!("MSG: insuwb_msgs/{ty}\n")),
                        "{name}: {ty}"
                    );
                }
            }
        }
    }

    #[test]
    fn quaternions_are_reordered_not_normalised() {
        let s = m::GroundTruth {
            quat: [2.0, 0.1, 0.2, 0.3],
            ..Default::default()
        };
        let t = GroundTruth::from_sample(&s, Time::default(), "map");
        assert_eq!(
            (t.quat.x, t.quat.y, t.quat.z, t.quat.w),
            (0.1, 0.2, 0.3, 2.0)
        );
    }
}
