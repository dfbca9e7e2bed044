//! Pure conversions from insuwb samples to ROS 2 messages: no I/O, no
//! transport (the bridge and an MCAP writer call the same functions).
//!
//! - Stamps: insuwb headers hold CLOCK_MONOTONIC ns; ROS nodes stamp with
//!   the system clock (CLOCK_REALTIME, ROS time without simulation). A
//!   [`ClockOffset`] (`insuwb_report::clock`) maps one to the other by an
//!   offset measured at start and again at each diagnostics period
//!   (`StampClock::Realtime`, the default), or keeps the monotonic value
//!   (`StampClock::Monotonic`); [`RosStamp`] makes the ROS time of it.
//! - Frames: the pose is in `frame_id` (ENU, `map`), the twist in
//!   `child_frame_id` (the body, FLU `base_link`), as `nav_msgs/Odometry`
//!   says: the ENU velocity is rotated into the body frame, with its
//!   covariance.
//! - Quaternions: insuwb's `[w, x, y, z]` becomes ROS's `x, y, z, w`.
//! - Unknown entries: `FusedState` has no attitude or angular-rate
//!   covariance, so the rotation rows of the pose covariance and the
//!   angular rows of the twist covariance hold [`UNKNOWN_VARIANCE`] on the
//!   diagonal and 0 off it (a large variance, as robot_localization and
//!   RViz read it; `-1` is a `sensor_msgs/Imu` convention only). The IMU
//!   message carries no orientation: `orientation_covariance[0] = -1`
//!   (sensor_msgs/Imu, REP-145), rate and acceleration covariances all zero
//!   ("unknown").
//! - The other way: [`ros_to_imu_sample`] reads a `sensor_msgs/Imu` of an
//!   IMU already in ROS (the IMU driver's `ros2:/TOPIC` source), timed by
//!   its stamp mapped back to CLOCK_MONOTONIC ([`stamp_to_monotonic`]);
//!   [`TwistMessage::body_velocity`] reads the twist of a base's
//!   `nav_msgs/Odometry` or `geometry_msgs/TwistStamped` (the bridge's
//!   `[ros2] odometry_in`) as a body velocity, its sigmas from the twist's
//!   covariance ([`twist_sigma_mps`]), timed the same way.
//!
//! ```
//! use insuwb_msg::{FusedState, Header};
//! use insuwb_report::clock::ClockOffset;
//! use insuwb_ros2::convert::{fused_to_odometry, Frames, RosStamp};
//! let mut s = FusedState { header: Header::new(0, 5_000_000_001), quat: [1.0, 0.0, 0.0, 0.0], ..Default::default() };
//! s.pos_m = [1.0, 2.0, 3.0];
//! let odom = fused_to_odometry(&s, &Frames::default(), &ClockOffset::ZERO).unwrap();
//! assert_eq!((odom.header.stamp.sec, odom.header.stamp.nanosec), (5, 1));
//! assert_eq!(odom.pose.pose.position.z, 3.0);
//! assert_eq!(odom.pose.pose.orientation.w, 1.0);
//! ```

use insuwb_msg::{name_str, BodyVelocity, FusedState, ImuSample};

use crate::msgs::{
    Cov6, DiagnosticStatus, Header, Imu, KeyValue, Odometry, Point, Pose, PoseWithCovariance,
    Quaternion, Time, Transform, TransformStamped, Twist, TwistStamped, TwistWithCovariance,
    Vector3,
};
use insuwb_report::clock::ClockOffset;
use insuwb_report::health::{StageCondition, StageSeen};

/// Variance of the pose and twist entries `FusedState` does not estimate
/// (attitude, angular rate): large, so that any consumer ignores them.
pub const UNKNOWN_VARIANCE: f64 = 1e6;

/// A sample that cannot become a ROS message (nor, through the checks the
/// Foxglove live view shares, a Foxglove one).
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum ConvertError {
    /// A field holds NaN or an infinity.
    #[error("ConvertError::NotFinite: field {0} is not finite")]
    NotFinite(&'static str),
    /// The attitude quaternion is not a rotation (norm far from 1).
    #[error("ConvertError::BadQuaternion: norm {0}")]
    BadQuaternion(f64),
    /// The stamp does not fit the message's time: before 1970, or after 2038
    /// for `builtin_interfaces/Time` (after 2106 for a Foxglove time).
    #[error("ConvertError::StampOutOfRange: {0} ns")]
    StampOutOfRange(i128),
}

/// A CLOCK_MONOTONIC time as a ROS `builtin_interfaces/Time` on a
/// [`ClockOffset`]'s clock.
pub trait RosStamp {
    /// The stamp of a CLOCK_MONOTONIC time.
    ///
    /// # Errors
    /// [`ConvertError::StampOutOfRange`] when it does not fit.
    fn stamp(&self, monotonic_ns: u64) -> Result<Time, ConvertError>;
}

impl RosStamp for ClockOffset {
    fn stamp(&self, monotonic_ns: u64) -> Result<Time, ConvertError> {
        let t = self.stamp_ns(monotonic_ns);
        let sec = t.div_euclid(1_000_000_000);
        let nanosec = t.rem_euclid(1_000_000_000);
        match (i32::try_from(sec), u32::try_from(nanosec)) {
            (Ok(sec), Ok(nanosec)) if sec >= 0 => Ok(Time { sec, nanosec }),
            _ => Err(ConvertError::StampOutOfRange(t)),
        }
    }
}

/// The frame ids of the messages (from `[ros2]`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frames {
    /// Parent of the pose and `/tf` (`map`).
    pub frame_id: String,
    /// The body (`base_link`).
    pub child_frame_id: String,
    /// The IMU messages' frame.
    pub imu_frame_id: String,
}

impl Default for Frames {
    fn default() -> Self {
        Self {
            frame_id: "map".into(),
            child_frame_id: "base_link".into(),
            imu_frame_id: "base_link".into(),
        }
    }
}

/// Checks that every value of `field` is finite.
///
/// # Errors
/// [`ConvertError::NotFinite`] naming `field` for a NaN or an infinity.
pub fn check_finite(field: &'static str, v: &[f64]) -> Result<(), ConvertError> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(ConvertError::NotFinite(field))
    }
}

/// insuwb's `[w, x, y, z]`, normalised, as `[x, y, z, w]` (the order of
/// ROS and Foxglove quaternions).
///
/// # Errors
/// [`ConvertError::NotFinite`], or [`ConvertError::BadQuaternion`] when its
/// norm is not within 1e-3 of 1.
pub fn unit_quaternion_xyzw(q: &[f64; 4]) -> Result<[f64; 4], ConvertError> {
    check_finite("quat", q)?;
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    if (n - 1.0).abs() > 1e-3 {
        return Err(ConvertError::BadQuaternion(n));
    }
    Ok([q[1] / n, q[2] / n, q[3] / n, q[0] / n])
}

/// insuwb's `[w, x, y, z]`, normalised, in ROS order.
///
/// # Errors
/// As [`unit_quaternion_xyzw`].
pub fn quaternion(q: &[f64; 4]) -> Result<Quaternion, ConvertError> {
    let [x, y, z, w] = unit_quaternion_xyzw(q)?;
    Ok(Quaternion { x, y, z, w })
}

/// The rotation matrix (body to ENU) of a ROS quaternion.
fn rotation(q: &Quaternion) -> [[f64; 3]; 3] {
    let (w, x, y, z) = (q.w, q.x, q.y, q.z);
    [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - w * z),
            2.0 * (x * z + w * y),
        ],
        [
            2.0 * (x * y + w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - w * x),
        ],
        [
            2.0 * (x * z - w * y),
            2.0 * (y * z + w * x),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ]
}

/// `Rᵀ v`: an ENU vector in the body frame.
fn to_body(r: &[[f64; 3]; 3], v: &[f64; 3]) -> [f64; 3] {
    let mut out = [0.0; 3];
    for (j, o) in out.iter_mut().enumerate() {
        *o = (0..3).map(|i| r[i][j] * v[i]).sum();
    }
    out
}

/// `Rᵀ C R`: an ENU covariance in the body frame.
fn cov_to_body(r: &[[f64; 3]; 3], c: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut out = [[0.0; 3]; 3];
    for (a, row) in out.iter_mut().enumerate() {
        for (b, o) in row.iter_mut().enumerate() {
            let mut s = 0.0;
            for i in 0..3 {
                for j in 0..3 {
                    s += r[i][a] * c[i][j] * r[j][b];
                }
            }
            *o = s;
        }
    }
    out
}

/// A 6 x 6 covariance with `block` in the top-left 3 x 3 and
/// [`UNKNOWN_VARIANCE`] on the rest of the diagonal.
fn cov6(block: &[[f64; 3]; 3]) -> Cov6 {
    let mut c = [0.0; 36];
    for i in 0..3 {
        for j in 0..3 {
            c[i * 6 + j] = block[i][j];
        }
        c[(i + 3) * 6 + i + 3] = UNKNOWN_VARIANCE;
    }
    Cov6(c)
}

/// `nav_msgs/Odometry` of a fused state: position and attitude in
/// `frame_id` with the position block of the fused covariance (rotation
/// rows unknown), velocity rotated into `child_frame_id` with its
/// covariance (angular rows unknown, angular velocity 0).
///
/// # Errors
/// [`ConvertError`] for a non-finite field, a quaternion that is not a
/// rotation, or a stamp out of range.
pub fn fused_to_odometry(
    s: &FusedState,
    frames: &Frames,
    clock: &ClockOffset,
) -> Result<Odometry, ConvertError> {
    check_finite("pos_m", &s.pos_m)?;
    check_finite("vel_mps", &s.vel_mps)?;
    check_finite("cov", s.cov.as_flattened())?;
    let q = quaternion(&s.quat)?;
    let r = rotation(&q);
    let mut pos_cov = [[0.0; 3]; 3];
    let mut vel_cov = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            pos_cov[i][j] = s.cov[i][j];
            vel_cov[i][j] = s.cov[i + 3][j + 3];
        }
    }
    let v = to_body(&r, &s.vel_mps);
    Ok(Odometry {
        header: Header {
            stamp: clock.stamp(s.header.meas_time_ns)?,
            frame_id: frames.frame_id.clone(),
        },
        child_frame_id: frames.child_frame_id.clone(),
        pose: PoseWithCovariance {
            pose: Pose {
                position: Point {
                    x: s.pos_m[0],
                    y: s.pos_m[1],
                    z: s.pos_m[2],
                },
                orientation: q,
            },
            covariance: cov6(&pos_cov),
        },
        twist: TwistWithCovariance {
            twist: Twist {
                linear: Vector3 {
                    x: v[0],
                    y: v[1],
                    z: v[2],
                },
                angular: Vector3::default(),
            },
            covariance: cov6(&cov_to_body(&r, &vel_cov)),
        },
    })
}

/// The fused state a `nav_msgs/Odometry` of [`fused_to_odometry`] holds
/// (the other way, for a reader of the odometry such as the fleet
/// station): measurement time from the stamp mapped back by `clock`
/// ([`stamp_to_monotonic`]), position and attitude as they are (`[w, x,
/// y, z]`), the heading of the attitude, the velocity and its covariance
/// rotated back into ENU, the position block of the pose covariance and
/// the velocity block of the twist's; what the message does not carry
/// (position-velocity cross-covariance, header counters and flags, the
/// inputs' times) is zero, `frame_id` is the message's.
///
/// # Errors
/// [`ConvertError`] for a non-finite field, a quaternion that is not a
/// rotation, or a stamp before the clock's start.
pub fn odometry_to_fused(o: &Odometry, clock: &ClockOffset) -> Result<FusedState, ConvertError> {
    let p = &o.pose.pose.position;
    let pos_m = [p.x, p.y, p.z];
    check_finite("pose.position", &pos_m)?;
    let v = &o.twist.twist.linear;
    check_finite("twist.linear", &[v.x, v.y, v.z])?;
    check_finite("pose.covariance", &o.pose.covariance.0)?;
    check_finite("twist.covariance", &o.twist.covariance.0)?;
    let q = &o.pose.pose.orientation;
    let [x, y, z, w] = unit_quaternion_xyzw(&[q.w, q.x, q.y, q.z])?;
    let q = Quaternion { x, y, z, w };
    let meas_time_ns = stamp_to_monotonic(&o.header.stamp, clock).ok_or_else(|| {
        ConvertError::StampOutOfRange(
            i128::from(o.header.stamp.sec) * 1_000_000_000 + i128::from(o.header.stamp.nanosec),
        )
    })?;
    let r = rotation(&q);
    // R v and R C R^T: the transpose of `to_body` and `cov_to_body`.
    let rt = [0, 1, 2].map(|i| [0, 1, 2].map(|j| r[j][i]));
    let mut vel_cov_body = [[0.0; 3]; 3];
    let mut cov = [[0.0; 6]; 6];
    for i in 0..3 {
        for j in 0..3 {
            cov[i][j] = o.pose.covariance.0[i * 6 + j];
            vel_cov_body[i][j] = o.twist.covariance.0[i * 6 + j];
        }
    }
    let vel_cov = cov_to_body(&rt, &vel_cov_body);
    for i in 0..3 {
        for j in 0..3 {
            cov[i + 3][j + 3] = vel_cov[i][j];
        }
    }
    Ok(FusedState {
        header: insuwb_msg::Header::new(0, meas_time_ns),
        pos_m,
        vel_mps: to_body(&rt, &[v.x, v.y, v.z]),
        quat: [w, x, y, z],
        yaw_rad: (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z)),
        cov,
        frame_id: insuwb_msg::fixed_name(&o.header.frame_id),
        ..FusedState::default()
    })
}

/// `frame_id -> child_frame_id` on `/tf` from a fused state.
///
/// # Errors
/// As [`fused_to_odometry`].
pub fn fused_to_transform(
    s: &FusedState,
    frames: &Frames,
    clock: &ClockOffset,
) -> Result<TransformStamped, ConvertError> {
    check_finite("pos_m", &s.pos_m)?;
    Ok(TransformStamped {
        header: Header {
            stamp: clock.stamp(s.header.meas_time_ns)?,
            frame_id: frames.frame_id.clone(),
        },
        child_frame_id: frames.child_frame_id.clone(),
        transform: Transform {
            translation: Vector3 {
                x: s.pos_m[0],
                y: s.pos_m[1],
                z: s.pos_m[2],
            },
            rotation: quaternion(&s.quat)?,
        },
    })
}

/// A fixed transform `parent -> child` (translation only) for `/tf_static`.
///
/// # Errors
/// [`ConvertError::NotFinite`] for a non-finite offset.
pub fn static_transform(
    parent: &str,
    child: &str,
    offset_m: [f64; 3],
    stamp: Time,
) -> Result<TransformStamped, ConvertError> {
    check_finite("offset_m", &offset_m)?;
    Ok(TransformStamped {
        header: Header {
            stamp,
            frame_id: parent.to_owned(),
        },
        child_frame_id: child.to_owned(),
        transform: Transform {
            translation: Vector3 {
                x: offset_m[0],
                y: offset_m[1],
                z: offset_m[2],
            },
            rotation: Quaternion::default(),
        },
    })
}

/// `sensor_msgs/Imu` of an IMU sample (body frame, specific force): no
/// orientation (`orientation_covariance[0] = -1`), covariances unknown.
///
/// # Errors
/// [`ConvertError`] for a non-finite value or a stamp out of range.
pub fn imu_to_ros(
    s: &ImuSample,
    frames: &Frames,
    clock: &ClockOffset,
) -> Result<Imu, ConvertError> {
    check_finite("accel_mps2", &s.accel_mps2)?;
    check_finite("gyro_rps", &s.gyro_rps)?;
    let mut orientation_covariance = [0.0; 9];
    orientation_covariance[0] = -1.0;
    Ok(Imu {
        header: Header {
            stamp: clock.stamp(s.header.meas_time_ns)?,
            frame_id: frames.imu_frame_id.clone(),
        },
        orientation: Quaternion::default(),
        orientation_covariance,
        angular_velocity: Vector3 {
            x: s.gyro_rps[0],
            y: s.gyro_rps[1],
            z: s.gyro_rps[2],
        },
        angular_velocity_covariance: [0.0; 9],
        linear_acceleration: Vector3 {
            x: s.accel_mps2[0],
            y: s.accel_mps2[1],
            z: s.accel_mps2[2],
        },
        linear_acceleration_covariance: [0.0; 9],
    })
}

/// The `diagnostic_msgs/DiagnosticStatus` of stage `stage` (named
/// `insuwb/<stage>`): ERROR when no heartbeat ever came, when the last is
/// older than `stale_after_ns`, or says stopping or disconnected; WARN when
/// it says degraded or `coasting` (the fusion stage's last output was
/// flagged degraded or stale); OK otherwise. The key-values are the
/// heartbeat's counters, its rates, its age and the stage's restarts.
#[must_use]
pub fn stage_status(
    stage: &str,
    hardware_id: &str,
    seen: Option<&StageSeen>,
    coasting: bool,
    now_ns: u64,
    stale_after_ns: u64,
) -> DiagnosticStatus {
    let age_ns = seen.map_or(0, |s| s.age_ns(now_ns));
    let condition = StageCondition::of(seen, coasting, now_ns, stale_after_ns);
    // The word and the level are the one table's (`StageCondition::name`,
    // `severity`); the message adds what explains it.
    let level = condition.severity().level();
    let word = condition.name();
    let message = match condition {
        StageCondition::Down => format!("{word}: no heartbeat received"),
        StageCondition::Stale => {
            format!("{word}: last heartbeat {:.1} s ago", age_ns as f64 * 1e-9)
        }
        StageCondition::Disconnected => format!("{word}: input lost"),
        StageCondition::Coasting => format!("{word}: no UWB update, INS only"),
        StageCondition::Unknown(code) => format!("{word}: state code {code}"),
        StageCondition::Stopping | StageCondition::Degraded | StageCondition::Ok => word.to_owned(),
    };
    DiagnosticStatus {
        level,
        name: format!("insuwb/{stage}"),
        message,
        hardware_id: hardware_id.to_owned(),
        values: seen.map_or_else(Vec::new, |s| heartbeat_values(s, age_ns)),
    }
}

/// The key-values of a stage's last heartbeat aged `age_ns`: its counters
/// (those of its kind by their names), its rates, its age and the stage's
/// restarts.
fn heartbeat_values(s: &StageSeen, age_ns: u64) -> Vec<KeyValue> {
    let h = &s.last;
    let kv = |k: &str, v: String| KeyValue {
        key: k.to_owned(),
        value: v,
    };
    let mut values = vec![
        kv("stage", name_str(&h.stage)),
        kv("pid", h.pid.to_string()),
        kv("restarts", h.header.generation.to_string()),
        kv("heartbeat_age_s", format!("{:.3}", age_ns as f64 * 1e-9)),
        kv("received", h.received.to_string()),
        kv("published", h.published.to_string()),
    ];
    if let Some((rx, tx)) = s.rates_hz {
        values.push(kv("received_rate_hz", format!("{rx:.2}")));
        values.push(kv("published_rate_hz", format!("{tx:.2}")));
    }
    values.extend([
        kv("dropped_version", h.dropped_version.to_string()),
        kv("dropped_invalid", h.dropped_invalid.to_string()),
        kv("dropped_time", h.dropped_time.to_string()),
        kv("seq_gaps", h.seq_gaps.to_string()),
    ]);
    match h.counters() {
        Ok(c) => values.extend(c.values().map(|(k, v)| kv(k, v.to_string()))),
        Err(e) => values.push(kv("counters", e.to_string())),
    }
    values
}

/// The oldest an incoming message's stamp (IMU, body velocity) may be against its receive
/// time and still be its measurement time, ns: an older stamp is of another
/// clock (simulation time, a publisher whose clock is far off), and the
/// receive time is taken instead.
pub const MAX_STAMP_AGE_NS: u64 = 1_000_000_000;

/// Which time a sample received from ROS (an IMU sample, a body velocity)
/// got as its measurement time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RosTimeSource {
    /// `header.stamp`, mapped to CLOCK_MONOTONIC.
    Stamp,
    /// The receive time: the stamp was unset (0), invalid, after the
    /// receive time or older than [`MAX_STAMP_AGE_NS`].
    Receive,
}

/// Warns that a message read from ROS (`what`: odometry, a range) was
/// refused, `total` the refusals so far: the first and then one in a
/// thousand.
pub(crate) fn warn_refused(what: &str, total: u64, e: &dyn std::fmt::Display) {
    if total % 1000 == 1 {
        tracing::warn!("ros2: {what} refused ({total} so far): {e}");
    }
}

/// The CLOCK_MONOTONIC time of a stamp in the stamp clock (the inverse of
/// [`ClockOffset::stamp`]); `None` for an invalid stamp (`nanosec` of 1e9
/// or more) or one before the monotonic clock's start.
#[must_use]
pub fn stamp_to_monotonic(t: &Time, clock: &ClockOffset) -> Option<u64> {
    if t.nanosec >= 1_000_000_000 {
        return None;
    }
    let ns =
        i128::from(t.sec) * 1_000_000_000 + i128::from(t.nanosec) - i128::from(clock.offset_ns);
    u64::try_from(ns).ok()
}

/// The measurement time (CLOCK_MONOTONIC) of a message stamped `stamp` and
/// received at `rx_ns`: the stamp mapped by `clock`
/// ([`stamp_to_monotonic`]) when it is set, not after `rx_ns` and at most
/// [`MAX_STAMP_AGE_NS`] before it (the time the sensor measured, without
/// the transport's delay); otherwise `rx_ns`.
#[must_use]
pub fn measurement_time(stamp: &Time, clock: &ClockOffset, rx_ns: u64) -> (u64, RosTimeSource) {
    let stamped = (*stamp != Time::default())
        .then(|| stamp_to_monotonic(stamp, clock))
        .flatten()
        .filter(|t| *t <= rx_ns && rx_ns - *t <= MAX_STAMP_AGE_NS);
    match stamped {
        Some(t) => (t, RosTimeSource::Stamp),
        None => (rx_ns, RosTimeSource::Receive),
    }
}

/// The insuwb IMU sample of a `sensor_msgs/Imu` message received at
/// `rx_ns` (CLOCK_MONOTONIC): `linear_acceleration` (specific force, m/s^2)
/// and `angular_velocity` (rad/s) as they are, so the message's frame must
/// be the body frame; orientation and covariances are not read.
///
/// Measurement time: [`measurement_time`] of `header.stamp`. The values
/// are not checked here: the IMU driver drops and counts NaN, infinite and
/// out-of-range ones. The header's sequence number is 0 (the publisher
/// numbers it).
#[must_use]
pub fn ros_to_imu_sample(m: &Imu, clock: &ClockOffset, rx_ns: u64) -> (ImuSample, RosTimeSource) {
    let (t, source) = measurement_time(&m.header.stamp, clock, rx_ns);
    let v = |v: &Vector3| [v.x, v.y, v.z];
    let s = ImuSample {
        header: insuwb_msg::Header::new(0, t),
        accel_mps2: v(&m.linear_acceleration),
        gyro_rps: v(&m.angular_velocity),
    };
    (s, source)
}

/// The standard deviation, m/s, of one axis of an incoming twist whose
/// variance (the covariance's diagonal entry) is `variance`:
///
/// - `sqrt(variance)` when it is finite and above 0;
/// - 0 (the axis is not measured) at or above [`UNKNOWN_VARIANCE`], 1e6,
///   the ROS convention for an unknown entry (infinity included);
/// - `default_sigma_mps` for 0 (unset: many base drivers publish a zero
///   covariance);
/// - for a negative variance a negative sigma, for NaN a NaN one: values
///   no measurement has, which the one check of body velocities
///   ([`insuwb_msg::check::VelocityGate`]) refuses and counts (`sigma`,
///   `non_finite`).
#[must_use]
pub fn twist_sigma_mps(variance: f64, default_sigma_mps: f64) -> f64 {
    if variance.is_nan() {
        f64::NAN
    } else if variance < 0.0 {
        -(-variance).sqrt()
    } else if variance == 0.0 {
        default_sigma_mps
    } else if variance >= UNKNOWN_VARIANCE {
        0.0
    } else {
        variance.sqrt()
    }
}

/// A body velocity read from a ROS message, unchecked.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VelocityIn {
    /// The measurement: `twist.linear` in the twist's frame, a sigma per
    /// axis ([`twist_sigma_mps`]), source [`BodyVelocity::SOURCE_ODOMETRY`],
    /// `header.seq` 0 (the publisher numbers it). Not checked here: the
    /// bridge passes it through [`insuwb_msg::check::VelocityGate`].
    pub sample: BodyVelocity,
    /// Which time it got ([`measurement_time`]).
    pub time: RosTimeSource,
}

/// A ROS message that carries a twist of the robot's base
/// (`[ros2] odometry_in`): `nav_msgs/Odometry` or
/// `geometry_msgs/TwistStamped`.
pub trait TwistMessage {
    /// The frame of its twist (Odometry's `child_frame_id`, TwistStamped's
    /// `header.frame_id`): the body frame is expected.
    fn twist_frame(&self) -> &str;

    /// Its body velocity received at `rx_ns` (CLOCK_MONOTONIC), timed by
    /// [`measurement_time`] of its stamp; `default_sigma_mps` is the sigma
    /// of an axis whose variance is 0 or not sent.
    fn body_velocity(&self, default_sigma_mps: f64, clock: &ClockOffset, rx_ns: u64) -> VelocityIn;
}

fn velocity_in(
    stamp: &Time,
    linear: &Vector3,
    sigma_mps: [f64; 3],
    clock: &ClockOffset,
    rx_ns: u64,
) -> VelocityIn {
    let (t, time) = measurement_time(stamp, clock, rx_ns);
    VelocityIn {
        sample: BodyVelocity {
            header: insuwb_msg::Header::new(0, t),
            vel_mps: [linear.x, linear.y, linear.z],
            sigma_mps,
            source: BodyVelocity::SOURCE_ODOMETRY,
            range_mm: 0,
        },
        time,
    }
}

impl TwistMessage for Odometry {
    fn twist_frame(&self) -> &str {
        &self.child_frame_id
    }

    /// `twist.twist.linear`; each axis's sigma from the diagonal of
    /// `twist.covariance` (entries 0, 7, 14) by [`twist_sigma_mps`]. The
    /// pose and the angular velocity are not read.
    fn body_velocity(&self, default_sigma_mps: f64, clock: &ClockOffset, rx_ns: u64) -> VelocityIn {
        let c = &self.twist.covariance.0;
        let sigma = [0, 7, 14].map(|i| twist_sigma_mps(c[i], default_sigma_mps));
        velocity_in(
            &self.header.stamp,
            &self.twist.twist.linear,
            sigma,
            clock,
            rx_ns,
        )
    }
}

impl TwistMessage for TwistStamped {
    fn twist_frame(&self) -> &str {
        &self.header.frame_id
    }

    /// `twist.linear`, every axis with sigma `default_sigma_mps` (the
    /// message has no covariance).
    fn body_velocity(&self, default_sigma_mps: f64, clock: &ClockOffset, rx_ns: u64) -> VelocityIn {
        velocity_in(
            &self.header.stamp,
            &self.twist.linear,
            [default_sigma_mps; 3],
            clock,
            rx_ns,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use insuwb_msg::{
        fixed_name, FusionCounters, Header as MsgHeader, Health, HealthState, StageCounters,
    };

    /// Yaw of `a` rad about z as insuwb's `[w, x, y, z]`.
    fn yaw(a: f64) -> [f64; 4] {
        [(a / 2.0).cos(), 0.0, 0.0, (a / 2.0).sin()]
    }

    fn fused() -> FusedState {
        let mut s = FusedState {
            header: MsgHeader::new(4, 12_345_678_901),
            pos_m: [1.5, -2.0, 0.25],
            vel_mps: [0.0, 2.0, 0.1],
            quat: yaw(std::f64::consts::FRAC_PI_2),
            ..FusedState::default()
        };
        for i in 0..6 {
            for j in 0..6 {
                s.cov[i][j] = (10 * i + j) as f64 * 1e-3;
            }
        }
        s
    }

    #[test]
    fn quaternion_order_is_x_y_z_w() {
        let q = quaternion(&[0.5, 0.5, -0.5, 0.5]).unwrap();
        assert_eq!((q.x, q.y, q.z, q.w), (0.5, -0.5, 0.5, 0.5));
        assert!(matches!(
            quaternion(&[0.0; 4]),
            Err(ConvertError::BadQuaternion(_))
        ));
        assert!(matches!(
            quaternion(&[f64::NAN, 0.0, 0.0, 1.0]),
            Err(ConvertError::NotFinite("quat"))
        ));
    }

    #[test]
    fn pose_covariance_is_the_position_block_with_rotation_unknown() {
        let s = fused();
        let o = fused_to_odometry(&s, &Frames::default(), &ClockOffset::ZERO).unwrap();
        let c = &o.pose.covariance;
        for i in 0..6 {
            for j in 0..6 {
                let want = match (i < 3, j < 3) {
                    (true, true) => s.cov[i][j],
                    _ if i == j => UNKNOWN_VARIANCE,
                    _ => 0.0,
                };
                assert_eq!(c.at(i, j), want, "({i}, {j})");
            }
        }
        // Row-major: entry (0, 1) is index 1, (1, 0) index 6.
        assert_eq!(c.0[1], s.cov[0][1]);
        assert_eq!(c.0[6], s.cov[1][0]);
    }

    #[test]
    fn twist_is_in_the_body_frame() {
        // Facing north (yaw 90 deg), moving north at 2 m/s: forward 2 m/s.
        let mut s = fused();
        s.cov = [[0.0; 6]; 6];
        s.cov[3][3] = 0.04; // east
        s.cov[4][4] = 0.09; // north
        s.cov[5][5] = 0.01;
        let o = fused_to_odometry(&s, &Frames::default(), &ClockOffset::ZERO).unwrap();
        let v = o.twist.twist.linear;
        assert!((v.x - 2.0).abs() < 1e-12 && v.y.abs() < 1e-12 && (v.z - 0.1).abs() < 1e-12);
        let c = &o.twist.covariance;
        // Body x is north, body y is west.
        assert!((c.at(0, 0) - 0.09).abs() < 1e-12);
        assert!((c.at(1, 1) - 0.04).abs() < 1e-12);
        assert!((c.at(2, 2) - 0.01).abs() < 1e-12);
        assert_eq!(c.at(3, 3), UNKNOWN_VARIANCE);
        assert_eq!(c.at(5, 5), UNKNOWN_VARIANCE);
        assert_eq!(o.twist.twist.angular, Vector3::default());
    }

    #[test]
    fn odometry_reads_back_into_the_fused_state() {
        let mut s = fused();
        // A heading off the axes, so that the rotation back is exercised.
        s.quat = yaw(0.7);
        s.yaw_rad = 0.7;
        s.frame_id = fixed_name("map");
        for i in 0..3 {
            for j in 0..3 {
                // Symmetric blocks, as a covariance is.
                s.cov[i][j] = if i == j { 0.5 } else { 0.01 * (i + j) as f64 };
                s.cov[i + 3][j + 3] = if i == j { 0.2 + 0.1 * i as f64 } else { 0.02 };
            }
        }
        let clock = ClockOffset {
            offset_ns: 1_700_000_000_000_000_000,
        };
        let o = fused_to_odometry(&s, &Frames::default(), &clock).unwrap();
        let back = odometry_to_fused(&o, &clock).unwrap();
        assert_eq!(back.header.meas_time_ns, s.header.meas_time_ns);
        assert_eq!(back.pos_m, s.pos_m);
        assert_eq!(back.frame_id, s.frame_id);
        assert!((back.yaw_rad - 0.7).abs() < 1e-12, "{}", back.yaw_rad);
        for i in 0..4 {
            assert!((back.quat[i] - s.quat[i]).abs() < 1e-12);
        }
        for i in 0..3 {
            assert!((back.vel_mps[i] - s.vel_mps[i]).abs() < 1e-12);
        }
        for i in 0..6 {
            for j in 0..6 {
                let want = if (i < 3) == (j < 3) { s.cov[i][j] } else { 0.0 };
                assert!((back.cov[i][j] - want).abs() < 1e-12, "({i}, {j})");
            }
        }
        let mut bad = o.clone();
        bad.pose.pose.position.x = f64::NAN;
        assert!(matches!(
            odometry_to_fused(&bad, &clock),
            Err(ConvertError::NotFinite("pose.position"))
        ));
        // A stamp before the monotonic clock's start.
        assert!(matches!(
            odometry_to_fused(
                &o,
                &ClockOffset {
                    offset_ns: i64::MAX
                }
            ),
            Err(ConvertError::StampOutOfRange(_))
        ));
    }

    #[test]
    fn frames_and_stamps_come_from_config_and_header() {
        let s = fused();
        let frames = Frames {
            frame_id: "odom".into(),
            child_frame_id: "base_footprint".into(),
            imu_frame_id: "imu_link".into(),
        };
        let clock = ClockOffset {
            offset_ns: 1_700_000_000_000_000_000,
        };
        let o = fused_to_odometry(&s, &frames, &clock).unwrap();
        assert_eq!(o.header.frame_id, "odom");
        assert_eq!(o.child_frame_id, "base_footprint");
        assert_eq!(o.header.stamp.sec, 1_700_000_012);
        assert_eq!(o.header.stamp.nanosec, 345_678_901);
        let t = fused_to_transform(&s, &frames, &clock).unwrap();
        assert_eq!(
            (t.header.frame_id.as_str(), t.child_frame_id.as_str()),
            ("odom", "base_footprint")
        );
        assert_eq!(t.transform.translation.x, 1.5);
        assert_eq!(t.transform.rotation, o.pose.pose.orientation);
        assert_eq!(t.header.stamp, o.header.stamp);
        let imu = ImuSample {
            header: MsgHeader::new(1, 2_000_000_000),
            accel_mps2: [0.1, 0.2, 9.81],
            gyro_rps: [0.01, 0.02, 0.03],
        };
        let m = imu_to_ros(&imu, &frames, &ClockOffset::ZERO).unwrap();
        assert_eq!(m.header.frame_id, "imu_link");
        assert_eq!((m.header.stamp.sec, m.header.stamp.nanosec), (2, 0));
        assert_eq!(m.orientation_covariance[0], -1.0);
        assert_eq!(m.linear_acceleration.z, 9.81);
        assert_eq!(m.angular_velocity.y, 0.02);
    }

    #[test]
    fn bad_inputs_are_errors_not_panics() {
        let mut s = fused();
        s.pos_m[1] = f64::INFINITY;
        assert_eq!(
            fused_to_odometry(&s, &Frames::default(), &ClockOffset::ZERO),
            Err(ConvertError::NotFinite("pos_m"))
        );
        let s = fused();
        let far = ClockOffset {
            offset_ns: i64::MAX,
        };
        assert!(matches!(
            fused_to_odometry(&s, &Frames::default(), &far),
            Err(ConvertError::StampOutOfRange(_))
        ));
        let before = ClockOffset {
            offset_ns: -20_000_000_000,
        };
        assert!(before.stamp(1).is_err());
    }

    #[test]
    fn health_levels_follow_state_age_and_coasting() {
        let mut h = Health {
            header: MsgHeader::new(0, 1_000_000_000),
            stage: fixed_name("fusion"),
            pid: 42,
            state: HealthState::Ok.into(),
            received: 100,
            published: 10,
            ..Health::default()
        };
        h.header.generation = 2;
        let mut seen = StageSeen::new(h, 1_000_000_000);
        h.header.meas_time_ns = 1_200_000_000;
        h.received = 120;
        h.published = 12;
        h.set_counters(StageCounters::Fusion(FusionCounters {
            outliers: 3,
            ..FusionCounters::default()
        }));
        seen.note(h, 1_200_000_000);
        let st = |seen: Option<&StageSeen>, coasting, now| {
            stage_status("fusion", "robot", seen, coasting, now, 1_000_000_000)
        };
        let ok = st(Some(&seen), false, 1_300_000_000);
        assert_eq!(ok.level, DiagnosticStatus::OK);
        assert_eq!(ok.name, "insuwb/fusion");
        assert_eq!(ok.hardware_id, "robot");
        let get = |s: &DiagnosticStatus, k: &str| {
            s.values
                .iter()
                .find(|v| v.key == k)
                .map(|v| v.value.clone())
        };
        assert_eq!(get(&ok, "restarts").as_deref(), Some("2"));
        assert_eq!(get(&ok, "received_rate_hz").as_deref(), Some("100.00"));
        assert_eq!(get(&ok, "published_rate_hz").as_deref(), Some("10.00"));
        // The stage's own counters by their names.
        assert_eq!(get(&ok, "outliers").as_deref(), Some("3"));
        assert_eq!(get(&ok, "updates").as_deref(), Some("0"));
        assert!(ok.values.iter().all(|v| !v.key.starts_with("extra")));
        assert_eq!(
            st(Some(&seen), true, 1_300_000_000).level,
            DiagnosticStatus::WARN
        );
        assert_eq!(
            st(Some(&seen), false, 2_300_000_000).level,
            DiagnosticStatus::ERROR
        );
        assert_eq!(st(None, false, 0).level, DiagnosticStatus::ERROR);
        for (state, level) in [
            (HealthState::Degraded, DiagnosticStatus::WARN),
            (HealthState::Disconnected, DiagnosticStatus::ERROR),
            (HealthState::Stopping, DiagnosticStatus::ERROR),
        ] {
            let mut s = seen;
            s.last.set_state(state);
            assert_eq!(st(Some(&s), false, 1_300_000_000).level, level);
        }
        // A new process: no rate until its second heartbeat.
        h.pid = 43;
        seen.note(h, 1_400_000_000);
        assert_eq!(seen.rates_hz, None);
    }

    fn ros_imu(sec: i32, nanosec: u32) -> Imu {
        Imu {
            header: Header {
                stamp: Time { sec, nanosec },
                frame_id: "base_link".into(),
            },
            angular_velocity: Vector3 {
                x: 0.01,
                y: -0.02,
                z: 0.5,
            },
            linear_acceleration: Vector3 {
                x: 0.1,
                y: -0.2,
                z: 9.81,
            },
            ..Imu::default()
        }
    }

    #[test]
    fn ros_imu_becomes_a_sample_at_its_stamp() {
        // Stamp clock 1.7e18 ns ahead of CLOCK_MONOTONIC (the real-time clock).
        let clock = ClockOffset {
            offset_ns: 1_700_000_000_000_000_000,
        };
        let rx = 5_000_000_000;
        let stamp = clock.stamp(rx - 3_000_000).unwrap();
        assert_eq!(stamp_to_monotonic(&stamp, &clock), Some(rx - 3_000_000));
        let m = ros_imu(stamp.sec, stamp.nanosec);
        let (s, src) = ros_to_imu_sample(&m, &clock, rx);
        assert_eq!(src, RosTimeSource::Stamp);
        assert_eq!(s.header.meas_time_ns, rx - 3_000_000);
        assert_eq!(s.accel_mps2, [0.1, -0.2, 9.81]);
        assert_eq!(s.gyro_rps, [0.01, -0.02, 0.5]);
        // The way out and back in: the same sample.
        let back = imu_to_ros(&s, &Frames::default(), &clock).unwrap();
        assert_eq!(ros_to_imu_sample(&back, &clock, rx).0, s);
        // Monotonic stamps map as they are.
        let (s, src) = ros_to_imu_sample(&ros_imu(4, 990_000_000), &ClockOffset::ZERO, rx);
        assert_eq!(
            (s.header.meas_time_ns, src),
            (4_990_000_000, RosTimeSource::Stamp)
        );
        // Non-finite values pass through (the driver counts them).
        let mut nan = m.clone();
        nan.linear_acceleration.x = f64::NAN;
        assert!(ros_to_imu_sample(&nan, &clock, rx).0.accel_mps2[0].is_nan());
    }

    #[test]
    fn unusable_stamps_fall_back_to_the_receive_time() {
        let rx = 5_000_000_000;
        let z = ClockOffset::ZERO;
        let at = |sec, nanosec| ros_to_imu_sample(&ros_imu(sec, nanosec), &z, rx);
        // Unset, in the future, too old, invalid nanoseconds.
        for (sec, nanosec) in [(0, 0), (5, 1), (3, 999_999_999), (4, 1_000_000_000)] {
            let (s, src) = at(sec, nanosec);
            assert_eq!(
                (s.header.meas_time_ns, src),
                (rx, RosTimeSource::Receive),
                "{sec} s {nanosec} ns"
            );
        }
        // Exactly now and exactly the oldest allowed: the stamp.
        assert_eq!(at(5, 0).1, RosTimeSource::Stamp);
        assert_eq!(at(4, 0).1, RosTimeSource::Stamp);
        // Before the monotonic clock's start: no monotonic time.
        let late = ClockOffset {
            offset_ns: 10_000_000_000,
        };
        assert_eq!(
            stamp_to_monotonic(&Time { sec: 9, nanosec: 0 }, &late),
            None
        );
        assert_eq!(
            stamp_to_monotonic(
                &Time {
                    sec: -1,
                    nanosec: 0
                },
                &ClockOffset::ZERO
            ),
            None
        );
    }

    fn ros_odometry(sec: i32, nanosec: u32, variances: [f64; 3]) -> Odometry {
        let mut m = Odometry {
            header: Header {
                stamp: Time { sec, nanosec },
                frame_id: "odom".into(),
            },
            child_frame_id: "base_link".into(),
            ..Odometry::default()
        };
        m.twist.twist.linear = Vector3 {
            x: 0.8,
            y: -0.05,
            z: 0.01,
        };
        // Angular rate and pose: not read.
        m.twist.twist.angular.z = 0.3;
        m.pose.pose.position.x = 12.0;
        for (i, v) in variances.into_iter().enumerate() {
            m.twist.covariance.0[i * 7] = v;
        }
        // Off-diagonal and angular entries: not read.
        m.twist.covariance.0[1] = -5.0;
        m.twist.covariance.0[35] = f64::NAN;
        m
    }

    #[test]
    fn twist_sigmas_follow_the_covariance_rules() {
        let d = 0.1;
        assert_eq!(twist_sigma_mps(0.04, d), 0.2);
        assert_eq!(twist_sigma_mps(0.0, d), d);
        assert_eq!(twist_sigma_mps(-0.0, d), d);
        // 1e6 and above: the ROS "unknown", not measured.
        assert_eq!(twist_sigma_mps(UNKNOWN_VARIANCE, d), 0.0);
        assert_eq!(twist_sigma_mps(1e9, d), 0.0);
        assert_eq!(twist_sigma_mps(f64::INFINITY, d), 0.0);
        assert_eq!(twist_sigma_mps(999_999.0, d), 999_999f64.sqrt());
        // Invalid: values the velocity gate refuses.
        assert!(twist_sigma_mps(-0.01, d) < 0.0);
        assert!(twist_sigma_mps(f64::NEG_INFINITY, d) < 0.0);
        assert!(twist_sigma_mps(f64::NAN, d).is_nan());
    }

    #[test]
    fn odometry_becomes_a_body_velocity_at_its_stamp() {
        let clock = ClockOffset {
            offset_ns: 1_700_000_000_000_000_000,
        };
        let rx = 5_000_000_000;
        let stamp = clock.stamp(rx - 4_000_000).unwrap();
        let m = ros_odometry(stamp.sec, stamp.nanosec, [0.0004, 0.0, UNKNOWN_VARIANCE]);
        assert_eq!(m.twist_frame(), "base_link");
        let v = m.body_velocity(0.1, &clock, rx);
        assert_eq!(v.time, RosTimeSource::Stamp);
        assert_eq!(v.sample.header.meas_time_ns, rx - 4_000_000);
        assert_eq!(v.sample.header.seq, 0);
        assert_eq!(v.sample.vel_mps, [0.8, -0.05, 0.01]);
        assert_eq!(v.sample.sigma_mps, [0.02, 0.1, 0.0]);
        assert_eq!(v.sample.source, BodyVelocity::SOURCE_ODOMETRY);
        insuwb_msg::check::velocity_values(&v.sample).unwrap();
        // Unset, ahead, too old: the receive time.
        for (sec, nanosec) in [(0, 0), (stamp.sec + 2, 0), (stamp.sec - 2, 0)] {
            let v = ros_odometry(sec, nanosec, [0.01; 3]).body_velocity(0.1, &clock, rx);
            assert_eq!(
                (v.sample.header.meas_time_ns, v.time),
                (rx, RosTimeSource::Receive)
            );
        }
        // Monotonic stamps map as they are.
        let v = ros_odometry(4, 500_000_000, [0.01; 3]).body_velocity(0.1, &ClockOffset::ZERO, rx);
        assert_eq!(v.sample.header.meas_time_ns, 4_500_000_000);
    }

    #[test]
    fn invalid_twists_are_refused_by_the_velocity_gate() {
        use insuwb_msg::check::{InvalidVelocity, VelocityGate, VelocityRefusal};
        let z = ClockOffset::ZERO;
        let rx = 5_000_000_000;
        let mut gate = VelocityGate::new();
        let mut check = |m: &Odometry| gate.check(&m.body_velocity(0.1, &z, rx).sample);
        // A NaN velocity, a negative and a NaN variance, every axis unknown.
        let mut nan = ros_odometry(4, 0, [0.01; 3]);
        nan.twist.twist.linear.y = f64::NAN;
        assert!(matches!(
            check(&nan),
            Err(VelocityRefusal::Invalid(InvalidVelocity::NonFinite {
                field: "vel_mps",
                ..
            }))
        ));
        assert!(matches!(
            check(&ros_odometry(4, 0, [0.01, -0.01, 0.01])),
            Err(VelocityRefusal::Invalid(InvalidVelocity::Sigma { .. }))
        ));
        assert!(matches!(
            check(&ros_odometry(4, 0, [f64::NAN, 0.01, 0.01])),
            Err(VelocityRefusal::Invalid(InvalidVelocity::NonFinite {
                field: "sigma_mps",
                ..
            }))
        ));
        assert!(matches!(
            check(&ros_odometry(4, 0, [UNKNOWN_VARIANCE; 3])),
            Err(VelocityRefusal::Invalid(InvalidVelocity::Sigma { .. }))
        ));
        // Valid, then a stamp before it and the same again.
        check(&ros_odometry(4, 100, [0.01; 3])).unwrap();
        assert!(matches!(
            check(&ros_odometry(4, 0, [0.01; 3])),
            Err(VelocityRefusal::TimeBackwards { .. })
        ));
        assert!(matches!(
            check(&ros_odometry(4, 100, [0.01; 3])),
            Err(VelocityRefusal::TimeRepeated { .. })
        ));
        let r = gate.refusals();
        assert_eq!((r.invalid(), r.time()), (4, 2));
    }

    #[test]
    fn twist_stamped_has_the_default_sigma_on_every_axis() {
        let m = TwistStamped {
            header: Header {
                stamp: Time {
                    sec: 4,
                    nanosec: 250,
                },
                frame_id: "base_footprint".into(),
            },
            twist: Twist {
                linear: Vector3 {
                    x: 1.5,
                    y: 0.0,
                    z: 0.0,
                },
                angular: Vector3::default(),
            },
        };
        assert_eq!(m.twist_frame(), "base_footprint");
        let v = m.body_velocity(0.07, &ClockOffset::ZERO, 5_000_000_000);
        assert_eq!(v.sample.header.meas_time_ns, 4_000_000_250);
        assert_eq!(v.sample.vel_mps, [1.5, 0.0, 0.0]);
        assert_eq!(v.sample.sigma_mps, [0.07; 3]);
        assert_eq!(v.sample.source, BodyVelocity::SOURCE_ODOMETRY);
    }
}
