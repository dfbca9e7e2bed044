//! What a process group runs, shared by the stages, the launcher, `eval`
//! and the emulators: the scenario file ([`scenario`]), i.e. what the `sim`
//! sources simulate and the `[fusion]` settings that go with it.
#![warn(missing_docs)]

pub mod scenario;

pub use scenario::{ScenarioError, ScenarioFile};
