//! The `[ros2]` table of the robot config: node, topics, frames, what to
//! publish, the clock of the stamps, the DDS domain.
//!
//! ```
//! use insuwb_ros2::config::Ros2Config;
//! let c: Ros2Config = toml::from_str("namespace = \"/robot1\"\npublish_tf = false").unwrap();
//! assert_eq!(c.odom_topic_name(), "/robot1/odom");
//! assert!(c.validate().is_ok());
//! let bad: Ros2Config = toml::from_str("frame_id = \"/map\"").unwrap();
//! assert_eq!(
//!     bad.validate().unwrap_err().to_string(),
//!     "key 'ros2.frame_id': a frame id must not start with '/' (tf2), got \"/map\""
//! );
//! ```

use serde::{Deserialize, Serialize};

use insuwb_report::clock::StampClock;

/// `[ros2]`: the ROS 2 bridge stage (`insuwb-stage-ros2`, run when `stages`
/// lists `ros2`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Ros2Config {
    /// DDS domain (`ROS_DOMAIN_ID`), 0..=232.
    pub domain_id: u16,
    /// Namespace of the node and of its relative topics, absolute.
    pub namespace: String,
    /// Node name.
    pub node_name: String,
    /// `nav_msgs/Odometry` topic, relative to the namespace or absolute.
    pub odom_topic: String,
    /// `sensor_msgs/Imu` topic, relative to the namespace or absolute.
    pub imu_topic: String,
    /// `diagnostic_msgs/DiagnosticArray` topic.
    pub diagnostics_topic: String,
    /// Parent frame of the pose and of `/tf` (REP-105 `map`).
    pub frame_id: String,
    /// The robot's body frame: child of `/tf`, frame of the twist.
    pub child_frame_id: String,
    /// Frame of the IMU messages; an identity transform from
    /// `child_frame_id` goes on `/tf_static` when it differs.
    pub imu_frame_id: String,
    /// Frame of the UWB antenna, on `/tf_static` under `child_frame_id`.
    pub antenna_frame_id: String,
    /// The antenna's position in the body frame, m; unset: the fusion
    /// settings' lever arm (`[fusion.loose] lever_arm_m`).
    pub antenna_lever_arm_m: Option<[f64; 3]>,
    /// Publish `frame_id -> child_frame_id` on `/tf` (off where another node
    /// owns that transform).
    pub publish_tf: bool,
    /// Publish the IMU samples.
    pub publish_imu: bool,
    /// Publish only fused states flagged valid (aligned, converged, fresh).
    pub only_valid: bool,
    /// Clock of the stamps: `realtime` (ROS system time) or `monotonic`.
    pub stamp_clock: StampClock,
    /// Period of `/diagnostics`, s.
    pub diagnostics_period_s: f64,
    /// A stage whose last heartbeat is older than this is reported ERROR, s.
    pub stale_after_s: f64,
    /// A ROS topic of the robot's base odometry, read and published as body
    /// velocities on iceoryx2 (`body_vel`, source odometry), relative to the
    /// namespace or absolute; empty: none.
    pub odometry_in: String,
    /// The message type of `odometry_in`.
    pub odometry_in_type: OdometryInType,
    /// The standard deviation of an axis of `odometry_in` whose variance is
    /// 0 (unset, as many base drivers publish it), m/s; every axis's for
    /// `geometry_msgs/TwistStamped`, which has no covariance.
    pub odometry_in_sigma_mps: f64,
    /// A ROS topic of a downward range finder (`sensor_msgs/Range`), read
    /// and published as heights on iceoryx2 (`height`, source range
    /// finder), relative to the namespace or absolute; empty: none.
    pub height_in: String,
}

/// The message type of `[ros2] odometry_in`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OdometryInType {
    /// `nav_msgs/Odometry`: the twist in `child_frame_id`, with its
    /// covariance.
    #[default]
    Odometry,
    /// `geometry_msgs/TwistStamped`: the twist in `header.frame_id`,
    /// without covariance.
    TwistStamped,
}

impl OdometryInType {
    /// Its spelling in `[ros2] odometry_in_type`.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Odometry => "odometry",
            Self::TwistStamped => "twist_stamped",
        }
    }
}

/// The default of `[ros2] odometry_in_sigma_mps`, m/s.
pub const DEFAULT_ODOMETRY_IN_SIGMA_MPS: f64 = 0.1;

impl Default for Ros2Config {
    fn default() -> Self {
        Self {
            domain_id: 0,
            namespace: "/insuwb".into(),
            node_name: "insuwb".into(),
            odom_topic: "odom".into(),
            imu_topic: "imu".into(),
            diagnostics_topic: "/diagnostics".into(),
            frame_id: "map".into(),
            child_frame_id: "base_link".into(),
            imu_frame_id: "base_link".into(),
            antenna_frame_id: "uwb_antenna".into(),
            antenna_lever_arm_m: None,
            publish_tf: true,
            publish_imu: true,
            only_valid: true,
            stamp_clock: StampClock::Realtime,
            diagnostics_period_s: 1.0,
            stale_after_s: 1.0,
            odometry_in: String::new(),
            odometry_in_type: OdometryInType::Odometry,
            odometry_in_sigma_mps: DEFAULT_ODOMETRY_IN_SIGMA_MPS,
            height_in: String::new(),
        }
    }
}

/// A `[ros2]` key with a value the bridge cannot use.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("key 'ros2.{key}': {reason}")]
pub struct Ros2ConfigError {
    /// The key, without `ros2.`.
    pub key: &'static str,
    /// What is wrong, with the value.
    pub reason: String,
}

impl Ros2Config {
    /// Checks every key; the error names the first bad one.
    ///
    /// # Errors
    /// [`Ros2ConfigError`] naming the key.
    pub fn validate(&self) -> Result<(), Ros2ConfigError> {
        let bad = |key, reason: String| Err(Ros2ConfigError { key, reason });
        if self.domain_id > 232 {
            return bad(
                "domain_id",
                format!("must be 0..=232, got {}", self.domain_id),
            );
        }
        if !self.namespace.starts_with('/') {
            return bad(
                "namespace",
                format!(
                    "must be absolute (start with '/'), got {:?}",
                    self.namespace
                ),
            );
        }
        if self.namespace != "/" {
            check_name("namespace", &self.namespace)?;
        }
        check_token("node_name", &self.node_name)?;
        for (key, t) in [
            ("odom_topic", &self.odom_topic),
            ("imu_topic", &self.imu_topic),
            ("diagnostics_topic", &self.diagnostics_topic),
        ] {
            check_name(key, t)?;
        }
        for (key, f) in [
            ("frame_id", &self.frame_id),
            ("child_frame_id", &self.child_frame_id),
            ("imu_frame_id", &self.imu_frame_id),
            ("antenna_frame_id", &self.antenna_frame_id),
        ] {
            check_frame(key, f)?;
        }
        if self.frame_id == self.child_frame_id {
            return bad(
                "child_frame_id",
                format!("must differ from frame_id, both {:?}", self.frame_id),
            );
        }
        if self.antenna_frame_id == self.child_frame_id {
            return bad(
                "antenna_frame_id",
                format!(
                    "must differ from child_frame_id, both {:?}",
                    self.child_frame_id
                ),
            );
        }
        if let Some(l) = self.antenna_lever_arm_m {
            if l.iter().any(|v| !v.is_finite()) {
                return bad("antenna_lever_arm_m", format!("must be finite, got {l:?}"));
            }
        }
        for (key, v) in [
            ("diagnostics_period_s", self.diagnostics_period_s),
            ("stale_after_s", self.stale_after_s),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= 3600.0) {
                return bad(key, format!("must be in (0, 3600] s, got {v}"));
            }
        }
        for (key, topic) in [
            ("odometry_in", &self.odometry_in),
            ("height_in", &self.height_in),
        ] {
            if !topic.is_empty() {
                check_name(key, topic)?;
            }
        }
        let sigma = self.odometry_in_sigma_mps;
        if !(sigma.is_finite() && sigma > 0.0 && sigma <= MAX_ODOMETRY_IN_SIGMA_MPS) {
            return bad(
                "odometry_in_sigma_mps",
                format!("must be in (0, {MAX_ODOMETRY_IN_SIGMA_MPS}] m/s, got {sigma}"),
            );
        }
        Ok(())
    }

    /// The full name of `odometry_in`, `None` when it is empty.
    #[must_use]
    pub fn odometry_in_topic_name(&self) -> Option<String> {
        (!self.odometry_in.is_empty()).then(|| self.full_topic(&self.odometry_in))
    }

    /// The full name of `height_in`, `None` when it is empty.
    #[must_use]
    pub fn height_in_topic_name(&self) -> Option<String> {
        (!self.height_in.is_empty()).then(|| self.full_topic(&self.height_in))
    }

    /// The full name of a topic of the node: `topic` when absolute, else
    /// under the namespace.
    #[must_use]
    pub fn full_topic(&self, topic: &str) -> String {
        if topic.starts_with('/') {
            topic.to_owned()
        } else if self.namespace == "/" {
            format!("/{topic}")
        } else {
            format!("{}/{topic}", self.namespace)
        }
    }

    /// The odometry topic's full name (default `/insuwb/odom`).
    #[must_use]
    pub fn odom_topic_name(&self) -> String {
        self.full_topic(&self.odom_topic)
    }

    /// The IMU topic's full name (default `/insuwb/imu`).
    #[must_use]
    pub fn imu_topic_name(&self) -> String {
        self.full_topic(&self.imu_topic)
    }

    /// The diagnostics topic's full name (default `/diagnostics`).
    #[must_use]
    pub fn diagnostics_topic_name(&self) -> String {
        self.full_topic(&self.diagnostics_topic)
    }
}

/// The largest `[ros2] odometry_in_sigma_mps`, m/s: a larger one says
/// nothing a velocity aiding could use.
pub const MAX_ODOMETRY_IN_SIGMA_MPS: f64 = 100.0;

/// A ROS name token: `[A-Za-z_][A-Za-z0-9_]*`, no `__`, no trailing `_`
/// rule (ROS allows it).
fn check_token(key: &'static str, t: &str) -> Result<(), Ros2ConfigError> {
    let ok = t
        .chars()
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && t.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
        && !t.contains("__");
    if ok {
        Ok(())
    } else {
        Err(Ros2ConfigError {
            key,
            reason: format!(
                "a ROS name token is letters, digits and '_' (not first a digit, no '__'), got {t:?}"
            ),
        })
    }
}

/// A ROS topic or namespace name: tokens separated by single `/`, an
/// optional leading `/`, no trailing `/`.
fn check_name(key: &'static str, name: &str) -> Result<(), Ros2ConfigError> {
    let body = name.strip_prefix('/').unwrap_or(name);
    if body.is_empty() || body.ends_with('/') {
        return Err(Ros2ConfigError {
            key,
            reason: format!("must be a ROS name such as \"odom\" or \"/robot/odom\", got {name:?}"),
        });
    }
    body.split('/').try_for_each(|tok| {
        check_token(key, tok).map_err(|_| Ros2ConfigError {
            key,
            reason: format!(
                "must be a ROS name (tokens of letters, digits and '_', separated by '/'), got {name:?}"
            ),
        })
    })
}

/// A topic name outside `[ros2]` (the IMU source's, `sources.imu =
/// "ros2:/TOPIC"`) that the ROS naming rules refuse; the text says why,
/// with the name.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct TopicNameError(pub String);

/// Checks a ROS topic name as [`Ros2Config::validate`] checks its own:
/// tokens of letters, digits and `_` (not first a digit, no `__`)
/// separated by single `/`, an optional leading `/` (relative names are
/// taken under the `[ros2]` namespace, [`Ros2Config::full_topic`]), no
/// trailing `/`.
///
/// # Errors
/// [`TopicNameError`] with the reason and the name.
pub fn check_topic_name(name: &str) -> Result<(), TopicNameError> {
    check_name("topic", name).map_err(|e| TopicNameError(e.reason))
}

/// A tf2 frame id: non-empty, no leading `/`, letters, digits, `_`, `/`.
fn check_frame(key: &'static str, f: &str) -> Result<(), Ros2ConfigError> {
    if f.starts_with('/') {
        return Err(Ros2ConfigError {
            key,
            reason: format!("a frame id must not start with '/' (tf2), got {f:?}"),
        });
    }
    if f.is_empty()
        || !f
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '/')
    {
        return Err(Ros2ConfigError {
            key,
            reason: format!("a frame id is letters, digits, '_' and '/', got {f:?}"),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_name_the_ros_topics() {
        let c = Ros2Config::default();
        c.validate().unwrap();
        assert_eq!(c.odom_topic_name(), "/insuwb/odom");
        assert_eq!(c.imu_topic_name(), "/insuwb/imu");
        assert_eq!(c.diagnostics_topic_name(), "/diagnostics");
        let root = Ros2Config {
            namespace: "/".into(),
            ..c
        };
        root.validate().unwrap();
        assert_eq!(root.odom_topic_name(), "/odom");
    }

    #[test]
    fn each_bad_value_names_its_key() {
        let cases: [(&str, Ros2Config); 13] = [
            (
                "domain_id",
                Ros2Config {
                    domain_id: 233,
                    ..Ros2Config::default()
                },
            ),
            (
                "namespace",
                Ros2Config {
                    namespace: "insuwb".into(),
                    ..Ros2Config::default()
                },
            ),
            (
                "namespace",
                Ros2Config {
                    namespace: "/a//b".into(),
                    ..Ros2Config::default()
                },
            ),
            (
                "node_name",
                Ros2Config {
                    node_name: "9x".into(),
                    ..Ros2Config::default()
                },
            ),
            (
                "odom_topic",
                Ros2Config {
                    odom_topic: "odom/".into(),
                    ..Ros2Config::default()
                },
            ),
            (
                "child_frame_id",
                Ros2Config {
                    child_frame_id: "map".into(),
                    ..Ros2Config::default()
                },
            ),
            (
                "imu_frame_id",
                Ros2Config {
                    imu_frame_id: String::new(),
                    ..Ros2Config::default()
                },
            ),
            (
                "antenna_lever_arm_m",
                Ros2Config {
                    antenna_lever_arm_m: Some([0.0, f64::NAN, 0.0]),
                    ..Ros2Config::default()
                },
            ),
            (
                "stale_after_s",
                Ros2Config {
                    stale_after_s: 0.0,
                    ..Ros2Config::default()
                },
            ),
            (
                "odometry_in",
                Ros2Config {
                    odometry_in: "/wheel//odom".into(),
                    ..Ros2Config::default()
                },
            ),
            (
                "height_in",
                Ros2Config {
                    height_in: "range down".into(),
                    ..Ros2Config::default()
                },
            ),
            (
                "odometry_in_sigma_mps",
                Ros2Config {
                    odometry_in_sigma_mps: 0.0,
                    ..Ros2Config::default()
                },
            ),
            (
                "odometry_in_sigma_mps",
                Ros2Config {
                    odometry_in_sigma_mps: f64::NAN,
                    ..Ros2Config::default()
                },
            ),
        ];
        for (key, c) in cases {
            let e = c.validate().unwrap_err();
            assert_eq!(e.key, key, "{e}");
            assert!(
                e.to_string().starts_with(&format!("key 'ros2.{key}': ")),
                "{e}"
            );
        }
    }

    #[test]
    fn unknown_keys_are_refused() {
        assert!(toml::from_str::<Ros2Config>("odom = \"x\"").is_err());
        let c: Ros2Config = toml::from_str("stamp_clock = \"monotonic\"").unwrap();
        assert_eq!(c.stamp_clock, StampClock::Monotonic);
    }

    #[test]
    fn odometry_in_is_off_unless_set() {
        let c = Ros2Config::default();
        assert_eq!(c.odometry_in_topic_name(), None);
        assert_eq!(c.odometry_in_type, OdometryInType::Odometry);
        assert_eq!(c.odometry_in_sigma_mps, DEFAULT_ODOMETRY_IN_SIGMA_MPS);
        let c: Ros2Config = toml::from_str(
            "odometry_in = \"wheel/odom\"\nodometry_in_type = \"twist_stamped\"\nodometry_in_sigma_mps = 0.05",
        )
        .unwrap();
        c.validate().unwrap();
        assert_eq!(
            c.odometry_in_topic_name().as_deref(),
            Some("/insuwb/wheel/odom")
        );
        assert_eq!(c.odometry_in_type, OdometryInType::TwistStamped);
        assert_eq!(c.odometry_in_type.name(), "twist_stamped");
        assert!(toml::from_str::<Ros2Config>("odometry_in_type = \"twist\"").is_err());
    }

    #[test]
    fn height_in_is_off_unless_set() {
        assert_eq!(Ros2Config::default().height_in_topic_name(), None);
        let c: Ros2Config = toml::from_str("height_in = \"/flow/range\"").unwrap();
        c.validate().unwrap();
        assert_eq!(c.height_in_topic_name().as_deref(), Some("/flow/range"));
    }

    #[test]
    fn topic_names_follow_the_ros_rules() {
        for ok in ["/imu/data", "imu", "/robot_1/imu_raw", "_x"] {
            check_topic_name(ok).unwrap();
        }
        for bad in [
            "",
            "/",
            "/imu/",
            "/a//b",
            "/9imu",
            "/imu data",
            "/a__b",
            "ros2:/x",
        ] {
            let e = check_topic_name(bad).unwrap_err();
            assert!(e.to_string().contains(&format!("{bad:?}")), "{e}");
        }
    }
}
