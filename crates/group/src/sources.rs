//! A driver's source (`[sources] imu` and `uwb` of the robot config, a
//! stage's `--source`): parsed once from its text form (`sim`, `device`,
//! `replay:FILE`, `ros2:/TOPIC`) into [`Source`], which every stage and the
//! launcher take; [`Source`]'s `Display` writes the text back.

use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// Where a driver gets its samples.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum Source {
    /// `sim`: the simulator, running the config's scenario.
    #[default]
    Sim,
    /// `device`: a real sensor (`[devices.imu]` / `[devices.uwb]`).
    Device,
    /// `replay:FILE`: an insuwb log. The robot config makes a relative
    /// path absolute under its folder (a stage's `--source` leaves it
    /// relative to the current directory).
    Replay(PathBuf),
    /// `ros2:/TOPIC` (IMU only): `sensor_msgs/Imu` over DDS, the topic a
    /// valid ROS topic name.
    Ros2 {
        /// The topic, as written after `ros2:` (relative names are taken
        /// under the `[ros2]` namespace).
        topic: String,
    },
}

/// The text forms, for messages.
const FORMS: &str = "sim, device, replay:FILE or ros2:/TOPIC";

/// Why a text is not a [`Source`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SourceParseError {
    /// None of the forms.
    #[error("unknown source '{0}' (sim, device, replay:FILE or ros2:/TOPIC)")]
    Unknown(String),
    /// `replay:` without a file.
    #[error("'replay:' needs a file (replay:FILE)")]
    NoFile,
    /// `ros2:` with a topic name ROS refuses.
    #[error("ros2:TOPIC: {0}")]
    Topic(insuwb_ros2::config::TopicNameError),
}

impl Source {
    /// Recorded samples (`sim` or `replay:FILE`), paced against the
    /// group's start epoch, with ground truth where the recording has it;
    /// `device` and `ros2:` are live.
    #[must_use]
    pub fn is_recorded(&self) -> bool {
        matches!(self, Self::Sim | Self::Replay(_))
    }

    /// The replayed log, for `replay:FILE`.
    #[must_use]
    pub fn replay_file(&self) -> Option<&Path> {
        match self {
            Self::Replay(p) => Some(p),
            _ => None,
        }
    }
}

impl FromStr for Source {
    type Err = SourceParseError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.split_once(':') {
            None if s == "sim" => Ok(Self::Sim),
            None if s == "device" => Ok(Self::Device),
            Some(("replay", "")) => Err(SourceParseError::NoFile),
            Some(("replay", file)) => Ok(Self::Replay(PathBuf::from(file))),
            Some(("ros2", topic)) => insuwb_ros2::config::check_topic_name(topic)
                .map(|()| Self::Ros2 {
                    topic: topic.to_owned(),
                })
                .map_err(SourceParseError::Topic),
            _ => Err(SourceParseError::Unknown(s.to_owned())),
        }
    }
}

impl fmt::Display for Source {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Sim => f.write_str("sim"),
            Self::Device => f.write_str("device"),
            Self::Replay(p) => write!(f, "replay:{}", p.display()),
            Self::Ros2 { topic } => write!(f, "ros2:{topic}"),
        }
    }
}

impl Serialize for Source {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        if let Self::Replay(p) = self {
            if p.to_str().is_none() {
                return Err(serde::ser::Error::custom(format!(
                    "replay file {} is not UTF-8",
                    p.display()
                )));
            }
        }
        s.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for Source {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Text;
        impl serde::de::Visitor<'_> for Text {
            type Value = Source;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                write!(f, "a source: {FORMS}")
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<Source, E> {
                v.parse().map_err(E::custom)
            }
        }
        d.deserialize_str(Text)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    #[test]
    fn the_text_form_round_trips() {
        for (text, source) in [
            ("sim", Source::Sim),
            ("device", Source::Device),
            (
                "replay:/data/run 1.iulog",
                Source::Replay("/data/run 1.iulog".into()),
            ),
            (
                "replay:rel/a:b.iulog",
                Source::Replay("rel/a:b.iulog".into()),
            ),
            (
                "ros2:/imu/data",
                Source::Ros2 {
                    topic: "/imu/data".into(),
                },
            ),
            (
                "ros2:imu",
                Source::Ros2 {
                    topic: "imu".into(),
                },
            ),
        ] {
            assert_eq!(text.parse::<Source>().unwrap(), source, "{text}");
            assert_eq!(source.to_string(), text);
            let toml = toml::to_string(&Wrap { s: source.clone() }).unwrap();
            assert_eq!(toml::from_str::<Wrap>(&toml).unwrap().s, source, "{toml}");
        }
    }

    #[derive(Debug, Serialize, Deserialize)]
    struct Wrap {
        s: Source,
    }

    #[test]
    fn bad_text_says_what_is_accepted() {
        for (text, want) in [
            (
                "ros:/imu",
                "unknown source 'ros:/imu' (sim, device, replay:FILE or ros2:/TOPIC)",
            ),
            ("Sim", "unknown source 'Sim'"),
            ("serial:/dev/ttyUSB0", "unknown source"),
            ("", "unknown source ''"),
            ("replay:", "needs a file"),
            ("ros2:", "ros2:TOPIC"),
            ("ros2:/imu//data", "ros2:TOPIC"),
            ("ros2:/9imu", "ros2:TOPIC"),
        ] {
            let e = text.parse::<Source>().unwrap_err().to_string();
            assert!(e.contains(want), "{text}: {e}");
        }
        let e = toml::from_str::<Wrap>("s = 3").unwrap_err().to_string();
        assert!(e.contains("replay:FILE"), "{e}");
    }

    #[test]
    fn recorded_sources_are_sim_and_replay() {
        assert!(Source::Sim.is_recorded());
        assert!(Source::Replay("x".into()).is_recorded());
        assert!(!Source::Device.is_recorded());
        assert!(!Source::Ros2 { topic: "/i".into() }.is_recorded());
        assert_eq!(
            Source::Replay("x".into()).replay_file(),
            Some(Path::new("x"))
        );
        assert_eq!(Source::Sim.replay_file(), None);
    }
}
