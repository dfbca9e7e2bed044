//! Former home of the fusion configuration and the lockstep runner, now
//! [`crate::config`] and [`crate::runner`]. Only
//! `insuwb_stage::group` still names [`FusionConfig`] here; it goes once
//! that file follows.

#[doc(hidden)]
pub use crate::config::FusionConfig;
