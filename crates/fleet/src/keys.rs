//! Key expressions of the fleet: a robot publishes each stream under
//! `insuwb/<robot>/<kind>` ([`Key`]; kinds `pose`, `health`, and
//! optionally `fix` and `diag`), and a station subscribes to
//! `insuwb/*/<kind>` ([`Kind::subscription`]).
//!
//! A robot id is 1 to 64 characters of `A-Z a-z 0-9 _ -`: one chunk of a
//! key expression with none of the characters Zenoh reserves (`/ * $ ? #`).

use std::fmt;
use std::str::FromStr;

/// The first chunk of every key.
pub const ROOT: &str = "insuwb";

/// The longest robot id.
pub const MAX_ROBOT_ID_LEN: usize = 64;

/// A stream of a robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Kind {
    /// The fused pose, at its full rate.
    Pose,
    /// The stages' health, 1 Hz.
    Health,
    /// The UWB fixes (optional: the bridge's `publish_fixes`).
    Fix,
    /// The filter's diagnostics after each update (optional: the bridge's
    /// `publish_diag`).
    Diag,
}

impl Kind {
    /// Every kind.
    pub const ALL: [Self; 4] = [Self::Pose, Self::Health, Self::Fix, Self::Diag];

    /// Its last chunk: `pose`, `health`, `fix` or `diag`.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Pose => "pose",
            Self::Health => "health",
            Self::Fix => "fix",
            Self::Diag => "diag",
        }
    }

    /// The key expression a station subscribes to for this kind from
    /// every robot: `insuwb/*/<kind>`.
    #[must_use]
    pub fn subscription(self) -> String {
        format!("{ROOT}/*/{}", self.name())
    }
}

/// Why a robot id or key was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum KeyError {
    /// The robot id is empty, too long or holds a character outside
    /// `A-Z a-z 0-9 _ -`.
    #[error("KeyError::RobotId: robot id {0:?} must be 1 to 64 characters of A-Z a-z 0-9 _ -")]
    RobotId(String),
    /// The key is not `insuwb/<robot>/<kind>`.
    #[error("KeyError::Shape: key {0:?} is not insuwb/<robot>/<kind> with kind pose, health, fix or diag")]
    Shape(String),
}

/// Checks a robot id.
///
/// # Errors
/// [`KeyError::RobotId`].
pub fn check_robot_id(id: &str) -> Result<(), KeyError> {
    let ok = !id.is_empty()
        && id.len() <= MAX_ROBOT_ID_LEN
        && id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-');
    if ok {
        Ok(())
    } else {
        Err(KeyError::RobotId(id.to_owned()))
    }
}

/// One robot's stream: `insuwb/<robot>/<kind>`.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Key {
    robot: String,
    kind: Kind,
}

impl Key {
    /// The key of `robot`'s `kind` stream.
    ///
    /// # Errors
    /// [`KeyError::RobotId`].
    pub fn new(robot: &str, kind: Kind) -> Result<Self, KeyError> {
        check_robot_id(robot)?;
        Ok(Self {
            robot: robot.to_owned(),
            kind,
        })
    }

    /// The robot id.
    #[must_use]
    pub fn robot(&self) -> &str {
        &self.robot
    }

    /// The stream.
    #[must_use]
    pub fn kind(&self) -> Kind {
        self.kind
    }
}

impl fmt::Display for Key {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{ROOT}/{}/{}", self.robot, self.kind.name())
    }
}

impl FromStr for Key {
    type Err = KeyError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let shape = || KeyError::Shape(s.to_owned());
        let mut parts = s.split('/');
        let (Some(ROOT), Some(robot), Some(kind), None) =
            (parts.next(), parts.next(), parts.next(), parts.next())
        else {
            return Err(shape());
        };
        let kind = Kind::ALL
            .into_iter()
            .find(|k| k.name() == kind)
            .ok_or_else(shape)?;
        Self::new(robot, kind)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_print_and_parse_back() {
        for kind in Kind::ALL {
            let k = Key::new("robot_7-a", kind).unwrap();
            assert_eq!(k.to_string().parse::<Key>().unwrap(), k);
        }
        assert_eq!(
            Key::new("r1", Kind::Pose).unwrap().to_string(),
            "insuwb/r1/pose"
        );
        assert_eq!(Kind::Health.subscription(), "insuwb/*/health");
    }

    #[test]
    fn bad_ids_and_shapes_are_refused() {
        for id in ["", "a/b", "r*", "r$", "r?", "r#", "é", &"x".repeat(65)] {
            assert_eq!(
                check_robot_id(id),
                Err(KeyError::RobotId(id.to_owned())),
                "{id:?}"
            );
        }
        assert!(check_robot_id(&"x".repeat(64)).is_ok());
        for k in [
            "insuwb/r1",
            "insuwb/r1/pose/x",
            "other/r1/pose",
            "insuwb/r1/imu",
            "insuwb//pose",
        ] {
            assert!(k.parse::<Key>().is_err(), "{k}");
        }
        let e = "insuwb/r1/imu".parse::<Key>().unwrap_err();
        assert!(e.to_string().contains("insuwb/r1/imu"), "{e}");
        assert_eq!("insuwb/r1/fix".parse::<Key>().unwrap().kind(), Kind::Fix);
        assert_eq!("insuwb/r1/diag".parse::<Key>().unwrap().kind(), Kind::Diag);
    }
}
