//! The ROS 2 messages the bridge publishes, as serde structs whose field
//! order is the `.msg` field order, so that a CDR serializer (RustDDS's,
//! an MCAP writer's) writes the bytes a ROS 2 node expects. Fixed-size
//! arrays serialize without a length (`float64[36]`: [`Cov6`]); `Vec`s as
//! sequences.
//!
//! Each type implements [`RosMessage`]: its package and name, its DDS type
//! name (`nav_msgs::msg::dds_::Odometry_`) and its definition
//! ([`MsgDef`]); [`RosMessage::schema`] gives the `ros2msg` schema text of
//! MCAP (the type's definition, then each type it uses once, after a line
//! of 80 `=` and `MSG: pkg/Type`).
//!
//! ```
//! use insuwb_ros2::msgs::{Odometry, RosMessage};
//! assert_eq!(Odometry::type_name(), "nav_msgs/msg/Odometry");
//! assert_eq!(Odometry::dds_type_name(), "nav_msgs::msg::dds_::Odometry_");
//! let schema = Odometry::schema();
//! assert!(schema.starts_with("std_msgs/Header header\n"));
//! assert!(schema.contains("\nMSG: geometry_msgs/PoseWithCovariance\n"));
//! ```

use serde::{Deserialize, Serialize};

/// A message definition: package, name, the `.msg` text, and the
/// definitions of the types its fields use.
#[derive(Debug)]
pub struct MsgDef {
    /// Package, e.g. `nav_msgs`.
    pub package: &'static str,
    /// Type name, e.g. `Odometry`.
    pub name: &'static str,
    /// The `.msg` text (fields and constants, no comments).
    pub text: &'static str,
    /// The message types its fields use directly.
    pub uses: &'static [&'static MsgDef],
}

impl MsgDef {
    /// `pkg/Type`, as a `MSG:` line of a schema names it.
    #[must_use]
    pub fn short_name(&self) -> String {
        format!("{}/{}", self.package, self.name)
    }

    /// The `ros2msg` schema text: this definition, then every type used,
    /// directly or not, once each in the order of first use, each after a
    /// separator line and `MSG: pkg/Type`.
    #[must_use]
    pub fn schema(&'static self) -> String {
        let mut order: Vec<&'static MsgDef> = Vec::new();
        // Depth-first over `uses`, bounded by the (finite, acyclic) set of
        // definitions in this module: each is pushed at most once.
        let mut stack: Vec<&'static MsgDef> = self.uses.iter().rev().copied().collect();
        while let Some(d) = stack.pop() {
            if order.iter().any(|o| std::ptr::eq(*o, d)) {
                continue;
            }
            order.push(d);
            stack.extend(d.uses.iter().rev().copied());
        }
        let mut out = String::from(self.text);
        for d in order {
            out.push_str(SEPARATOR);
            out.push_str("MSG: ");
            out.push_str(&d.short_name());
            out.push('\n');
            out.push_str(d.text);
        }
        out
    }
}

/// The line between definitions in a `ros2msg` schema.
pub const SEPARATOR: &str =
    "================================================================================\n";

/// A ROS 2 message type.
pub trait RosMessage: Serialize {
    /// Its definition.
    const DEF: &'static MsgDef;

    /// `pkg/msg/Type` (the ROS 2 type name; also MCAP's schema name).
    #[must_use]
    fn type_name() -> String {
        format!("{}/msg/{}", Self::DEF.package, Self::DEF.name)
    }

    /// `pkg::msg::dds_::Type_`, the type name on DDS.
    #[must_use]
    fn dds_type_name() -> String {
        format!("{}::msg::dds_::{}_", Self::DEF.package, Self::DEF.name)
    }

    /// The `ros2msg` schema text ([`MsgDef::schema`]).
    #[must_use]
    fn schema() -> String {
        Self::DEF.schema()
    }
}

macro_rules! ros_message {
    ($ty:ident, $def:ident) => {
        impl RosMessage for $ty {
            const DEF: &'static MsgDef = &$def;
        }
    };
}

/// `builtin_interfaces/Time`: seconds and nanoseconds (see
/// [`insuwb_report::clock::StampClock`] for the clock).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Time {
    /// Seconds.
    pub sec: i32,
    /// Nanoseconds, 0..1e9.
    pub nanosec: u32,
}

/// `std_msgs/Header`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Header {
    /// When the data was measured.
    pub stamp: Time,
    /// Frame of the data.
    pub frame_id: String,
}

/// `geometry_msgs/Vector3`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `geometry_msgs/Point`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Point {
    /// x, m.
    pub x: f64,
    /// y, m.
    pub y: f64,
    /// z, m.
    pub z: f64,
}

/// `geometry_msgs/Quaternion`, in ROS order `x, y, z, w` (insuwb's is
/// `[w, x, y, z]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w.
    pub w: f64,
}

impl Default for Quaternion {
    /// The identity, as the `.msg` defaults say.
    fn default() -> Self {
        Self {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }
    }
}

/// `geometry_msgs/Pose`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Pose {
    /// Position.
    pub position: Point,
    /// Orientation.
    pub orientation: Quaternion,
}

/// `float64[36]`: a row-major 6 x 6 covariance, serialized as 36 numbers
/// without a length (serde's derives stop at 32 elements).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cov6(pub [f64; 36]);

impl Default for Cov6 {
    fn default() -> Self {
        Self([0.0; 36])
    }
}

impl Cov6 {
    /// Entry `(row, col)`, both 0..6.
    #[must_use]
    pub fn at(&self, row: usize, col: usize) -> f64 {
        self.0[row * 6 + col]
    }
}

impl Serialize for Cov6 {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeTuple;
        let mut t = s.serialize_tuple(36)?;
        for v in &self.0 {
            t.serialize_element(v)?;
        }
        t.end()
    }
}

impl<'de> Deserialize<'de> for Cov6 {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> serde::de::Visitor<'de> for V {
            type Value = Cov6;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("36 numbers")
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut a: A) -> Result<Cov6, A::Error> {
                let mut out = [0.0; 36];
                for (i, o) in out.iter_mut().enumerate() {
                    *o = a
                        .next_element()?
                        .ok_or_else(|| serde::de::Error::invalid_length(i, &self))?;
                }
                Ok(Cov6(out))
            }
        }
        d.deserialize_tuple(36, V)
    }
}

/// `geometry_msgs/PoseWithCovariance`: covariance over
/// `(x, y, z, rotation about x, about y, about z)`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct PoseWithCovariance {
    /// Pose.
    pub pose: Pose,
    /// Row-major 6 x 6 covariance.
    pub covariance: Cov6,
}

/// `geometry_msgs/Twist`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Twist {
    /// Linear velocity, m/s.
    pub linear: Vector3,
    /// Angular velocity, rad/s.
    pub angular: Vector3,
}

/// `geometry_msgs/TwistStamped`: a twist with its stamp and frame (what
/// base drivers without a covariance publish).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TwistStamped {
    /// Stamp and frame of the twist.
    pub header: Header,
    /// Twist.
    pub twist: Twist,
}

/// `geometry_msgs/TwistWithCovariance`: covariance over
/// `(vx, vy, vz, wx, wy, wz)`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct TwistWithCovariance {
    /// Twist.
    pub twist: Twist,
    /// Row-major 6 x 6 covariance.
    pub covariance: Cov6,
}

/// `geometry_msgs/Transform`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Transform {
    /// Translation, m.
    pub translation: Vector3,
    /// Rotation.
    pub rotation: Quaternion,
}

/// `geometry_msgs/TransformStamped`: the pose of `child_frame_id` in
/// `header.frame_id`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TransformStamped {
    /// Stamp and parent frame.
    pub header: Header,
    /// Child frame.
    pub child_frame_id: String,
    /// The transform.
    pub transform: Transform,
}

/// `nav_msgs/Odometry`: pose in `header.frame_id`, twist in `child_frame_id`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Odometry {
    /// Stamp and pose frame.
    pub header: Header,
    /// Frame of the twist (the body).
    pub child_frame_id: String,
    /// Pose with covariance.
    pub pose: PoseWithCovariance,
    /// Twist with covariance.
    pub twist: TwistWithCovariance,
}

/// `sensor_msgs/Imu`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Imu {
    /// Stamp and sensor frame.
    pub header: Header,
    /// Orientation (unknown: `orientation_covariance[0] = -1`).
    pub orientation: Quaternion,
    /// Row-major 3 x 3.
    pub orientation_covariance: [f64; 9],
    /// Angular rate, rad/s.
    pub angular_velocity: Vector3,
    /// Row-major 3 x 3 (all zero: unknown).
    pub angular_velocity_covariance: [f64; 9],
    /// Specific force, m/s^2 (about +9.81 on z at rest).
    pub linear_acceleration: Vector3,
    /// Row-major 3 x 3 (all zero: unknown).
    pub linear_acceleration_covariance: [f64; 9],
}

/// `sensor_msgs/Range`: one reading of a ranger (ultrasound, infrared,
/// time of flight) along its axis. REP 117: `-inf` for an object closer
/// than `min_range`, `+inf` for nothing within `max_range`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Range {
    /// Stamp (when the ranger returned the reading) and sensor frame.
    pub header: Header,
    /// [`Range::ULTRASOUND`] or [`Range::INFRARED`].
    pub radiation_type: u8,
    /// Angular size of the arc the reading is valid over, rad.
    pub field_of_view: f32,
    /// Shortest range the sensor reports, m.
    pub min_range: f32,
    /// Longest range the sensor reports, m.
    pub max_range: f32,
    /// The range, m (or `±inf`, REP 117).
    pub range: f32,
}

impl Range {
    /// `radiation_type` of a sonar.
    pub const ULTRASOUND: u8 = 0;
    /// `radiation_type` of an infrared or laser ranger (time of flight).
    pub const INFRARED: u8 = 1;
}

/// `tf2_msgs/TFMessage`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TfMessage {
    /// Transforms.
    pub transforms: Vec<TransformStamped>,
}

/// `diagnostic_msgs/KeyValue`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct KeyValue {
    /// Key.
    pub key: String,
    /// Value.
    pub value: String,
}

/// `diagnostic_msgs/DiagnosticStatus`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    /// [`DiagnosticStatus::OK`], `WARN`, `ERROR` or `STALE`.
    pub level: u8,
    /// Name of the component.
    pub name: String,
    /// What is going on.
    pub message: String,
    /// Hardware identifier.
    pub hardware_id: String,
    /// Figures.
    pub values: Vec<KeyValue>,
}

impl DiagnosticStatus {
    /// Level OK.
    pub const OK: u8 = 0;
    /// Level WARN.
    pub const WARN: u8 = 1;
    /// Level ERROR.
    pub const ERROR: u8 = 2;
    /// Level STALE.
    pub const STALE: u8 = 3;
}

/// `diagnostic_msgs/DiagnosticArray`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct DiagnosticArray {
    /// Stamp.
    pub header: Header,
    /// One status per component.
    pub status: Vec<DiagnosticStatus>,
}

/// `builtin_interfaces/Time`.
pub static TIME: MsgDef = MsgDef {
    package: "builtin_interfaces",
    name: "Time",
    text: "int32 sec\nuint32 nanosec\n",
    uses: &[],
};
/// `std_msgs/Header`.
pub static HEADER: MsgDef = MsgDef {
    package: "std_msgs",
    name: "Header",
    text: "builtin_interfaces/Time stamp\nstring frame_id\n",
    uses: &[&TIME],
};
/// `geometry_msgs/Vector3`.
pub static VECTOR3: MsgDef = MsgDef {
    package: "geometry_msgs",
    name: "Vector3",
    text: "float64 x\nfloat64 y\nfloat64 z\n",
    uses: &[],
};
/// `geometry_msgs/Point`.
pub static POINT: MsgDef = MsgDef {
    package: "geometry_msgs",
    name: "Point",
    text: "float64 x\nfloat64 y\nfloat64 z\n",
    uses: &[],
};
/// `geometry_msgs/Quaternion`.
pub static QUATERNION: MsgDef = MsgDef {
    package: "geometry_msgs",
    name: "Quaternion",
    text: "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    uses: &[],
};
/// `geometry_msgs/Pose`.
pub static POSE: MsgDef = MsgDef {
    package: "geometry_msgs",
    name: "Pose",
    text: "Point position\nQuaternion orientation\n",
    uses: &[&POINT, &QUATERNION],
};
/// `geometry_msgs/PoseWithCovariance`.
pub static POSE_WITH_COVARIANCE: MsgDef = MsgDef {
    package: "geometry_msgs",
    name: "PoseWithCovariance",
    text: "Pose pose\nfloat64[36] covariance\n",
    uses: &[&POSE],
};
/// `geometry_msgs/Twist`.
pub static TWIST: MsgDef = MsgDef {
    package: "geometry_msgs",
    name: "Twist",
    text: "Vector3 linear\nVector3 angular\n",
    uses: &[&VECTOR3],
};
/// `geometry_msgs/TwistStamped`.
pub static TWIST_STAMPED: MsgDef = MsgDef {
    package: "geometry_msgs",
    name: "TwistStamped",
    text: "std_msgs/Header header\nTwist twist\n",
    uses: &[&HEADER, &TWIST],
};
/// `geometry_msgs/TwistWithCovariance`.
pub static TWIST_WITH_COVARIANCE: MsgDef = MsgDef {
    package: "geometry_msgs",
    name: "TwistWithCovariance",
    text: "Twist twist\nfloat64[36] covariance\n",
    uses: &[&TWIST],
};
/// `geometry_msgs/Transform`.
pub static TRANSFORM: MsgDef = MsgDef {
    package: "geometry_msgs",
    name: "Transform",
    text: "Vector3 translation\nQuaternion rotation\n",
    uses: &[&VECTOR3, &QUATERNION],
};
/// `geometry_msgs/TransformStamped`.
pub static TRANSFORM_STAMPED: MsgDef = MsgDef {
    package: "geometry_msgs",
    name: "TransformStamped",
    text: "std_msgs/Header header\nstring child_frame_id\nTransform transform\n",
    uses: &[&HEADER, &TRANSFORM],
};
/// `nav_msgs/Odometry`.
pub static ODOMETRY: MsgDef = MsgDef {
    package: "nav_msgs",
    name: "Odometry",
    text: "std_msgs/Header header\nstring child_frame_id\n\
           geometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n",
    uses: &[&HEADER, &POSE_WITH_COVARIANCE, &TWIST_WITH_COVARIANCE],
};
/// `sensor_msgs/Imu`.
pub static IMU: MsgDef = MsgDef {
    package: "sensor_msgs",
    name: "Imu",
    text: "std_msgs/Header header\n\
           geometry_msgs/Quaternion orientation\nfloat64[9] orientation_covariance\n\
           geometry_msgs/Vector3 angular_velocity\nfloat64[9] angular_velocity_covariance\n\
           geometry_msgs/Vector3 linear_acceleration\nfloat64[9] linear_acceleration_covariance\n",
    uses: &[&HEADER, &QUATERNION, &VECTOR3],
};
/// `sensor_msgs/Range`.
pub static RANGE: MsgDef = MsgDef {
    package: "sensor_msgs",
    name: "Range",
    text: "uint8 ULTRASOUND=0\nuint8 INFRARED=1\n\
           std_msgs/Header header\nuint8 radiation_type\nfloat32 field_of_view\n\
           float32 min_range\nfloat32 max_range\nfloat32 range\n",
    uses: &[&HEADER],
};
/// `tf2_msgs/TFMessage`.
pub static TF_MESSAGE: MsgDef = MsgDef {
    package: "tf2_msgs",
    name: "TFMessage",
    text: "geometry_msgs/TransformStamped[] transforms\n",
    uses: &[&TRANSFORM_STAMPED],
};
/// `diagnostic_msgs/KeyValue`.
pub static KEY_VALUE: MsgDef = MsgDef {
    package: "diagnostic_msgs",
    name: "KeyValue",
    text: "string key\nstring value\n",
    uses: &[],
};
/// `diagnostic_msgs/DiagnosticStatus`.
pub static DIAGNOSTIC_STATUS: MsgDef = MsgDef {
    package: "diagnostic_msgs",
    name: "DiagnosticStatus",
    text: "byte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\n\
           byte level\nstring name\nstring message\nstring hardware_id\nKeyValue[] values\n",
    uses: &[&KEY_VALUE],
};
/// `diagnostic_msgs/DiagnosticArray`.
pub static DIAGNOSTIC_ARRAY: MsgDef = MsgDef {
    package: "diagnostic_msgs",
    name: "DiagnosticArray",
    text: "std_msgs/Header header\nDiagnosticStatus[] status\n",
    uses: &[&HEADER, &DIAGNOSTIC_STATUS],
};

ros_message!(Time, TIME);
ros_message!(Header, HEADER);
ros_message!(Vector3, VECTOR3);
ros_message!(Point, POINT);
ros_message!(Quaternion, QUATERNION);
ros_message!(Pose, POSE);
ros_message!(PoseWithCovariance, POSE_WITH_COVARIANCE);
ros_message!(Twist, TWIST);
ros_message!(TwistStamped, TWIST_STAMPED);
ros_message!(TwistWithCovariance, TWIST_WITH_COVARIANCE);
ros_message!(Transform, TRANSFORM);
ros_message!(TransformStamped, TRANSFORM_STAMPED);
ros_message!(Odometry, ODOMETRY);
ros_message!(Imu, IMU);
ros_message!(Range, RANGE);
ros_message!(TfMessage, TF_MESSAGE);
ros_message!(KeyValue, KEY_VALUE);
ros_message!(DiagnosticStatus, DIAGNOSTIC_STATUS);
ros_message!(DiagnosticArray, DIAGNOSTIC_ARRAY);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schemas_list_each_used_type_once_in_first_use_order() {
        let s = Odometry::schema();
        let msgs: Vec<&str> = s.lines().filter_map(|l| l.strip_prefix("MSG: ")).collect();
        assert_eq!(
            msgs,
            [
                "std_msgs/Header",
                "builtin_interfaces/Time",
                "geometry_msgs/PoseWithCovariance",
                "geometry_msgs/Pose",
                "geometry_msgs/Point",
                "geometry_msgs/Quaternion",
                "geometry_msgs/TwistWithCovariance",
                "geometry_msgs/Twist",
                "geometry_msgs/Vector3",
            ]
        );
        assert_eq!(s.matches(SEPARATOR).count(), msgs.len());
        assert_eq!(SEPARATOR.len(), 81);
        let tf = TfMessage::schema();
        assert!(tf.starts_with("geometry_msgs/TransformStamped[] transforms\n"));
        assert_eq!(tf.matches("MSG: geometry_msgs/Quaternion\n").count(), 1);
        assert_eq!(Time::schema(), "int32 sec\nuint32 nanosec\n");
    }

    #[test]
    fn names_follow_the_ros2_and_dds_conventions() {
        assert_eq!(TfMessage::type_name(), "tf2_msgs/msg/TFMessage");
        assert_eq!(
            TfMessage::dds_type_name(),
            "tf2_msgs::msg::dds_::TFMessage_"
        );
        assert_eq!(Imu::dds_type_name(), "sensor_msgs::msg::dds_::Imu_");
        assert_eq!(Range::dds_type_name(), "sensor_msgs::msg::dds_::Range_");
        assert!(Range::schema().contains("\nfloat32 range\n================"));
        assert_eq!(
            TwistStamped::dds_type_name(),
            "geometry_msgs::msg::dds_::TwistStamped_"
        );
        let ts = TwistStamped::schema();
        assert!(ts.starts_with("std_msgs/Header header\nTwist twist\n"));
        assert_eq!(ts.matches("MSG: geometry_msgs/Vector3\n").count(), 1);
        assert_eq!(
            DiagnosticArray::type_name(),
            "diagnostic_msgs/msg/DiagnosticArray"
        );
    }

    #[test]
    fn covariance_serializes_as_36_numbers_without_a_length() {
        let mut c = Cov6::default();
        c.0[7] = 2.5;
        let t = toml::Value::try_from(PoseWithCovariance {
            covariance: c,
            ..PoseWithCovariance::default()
        })
        .unwrap();
        let arr = t["covariance"].as_array().unwrap();
        assert_eq!(arr.len(), 36);
        assert_eq!(arr[7].as_float(), Some(2.5));
        let back: PoseWithCovariance = t.try_into().unwrap();
        assert_eq!(back.covariance, c);
        assert_eq!(c.at(1, 1), 2.5);
    }
}
