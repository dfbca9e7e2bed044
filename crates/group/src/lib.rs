//! What a process group runs, shared by the stages, the launcher, `eval`
//! and the emulators: the robot group configuration ([`robot`]:
//! `config/robot.toml`, the one file every stage and the launcher read;
//! [`sources`]: a driver's source, parsed once from its text),
//! what emulated devices play ([`recording`]: a scenario or a log as the IMU
//! samples and UWB fixes real devices would have measured), and the launch
//! loop every group runs through ([`launch`]: supervision, watching, fault
//! injection and the stop order).
#![warn(missing_docs)]

pub mod launch;
pub mod recording;
pub mod robot;
pub mod sources;
