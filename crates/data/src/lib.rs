//! Dataset readers: the Crazyflie micro-SD event log of the UTIL dataset and its anchor files.
//!
//! - [`cflog`]: the binary event log (versions 1 and 2), format detection;
//! - [`anchors`]: the `anN_p,x,y,z` anchor survey files;
//! - [`util`]: import of a UTIL flight as `insuwb-msg` samples (IMU, TDOA,
//!   ground truth, flow-deck records) with counts of what was skipped;
//! - [`flow`]: the flow deck's model, pixel flow and range to body velocity;
//! - [`segment`]: the flight segment and ground-truth interpolation.
//!
//! ```no_run
//! use insuwb_data::{load_util_flight, ImportOptions, ParseOptions};
//! let dir = std::path::Path::new("../shared/data/util");
//! let flight = load_util_flight(
//!     &dir.join("cfBolt-log00"),
//!     &dir.join("anchors-const3.txt"),
//!     &ParseOptions::default(),
//!     &ImportOptions::default(),
//! )?;
//! println!("{} IMU, {} TDOA, {} truth", flight.imu.len(), flight.tdoa.len(), flight.truth.len());
//! # Ok::<(), insuwb_data::LoadError>(())
//! ```
#![warn(missing_docs)]

pub mod anchors;
pub mod cflog;
pub mod flow;
pub mod segment;
#[cfg(test)]
mod testlog;
pub mod util;

pub use anchors::{AnchorError, Anchors};
pub use cflog::{is_cflog, CfLog, CfLogError, CutKind, CutReport, Integrity, ParseOptions};
pub use flow::{
    flow_velocities, range_heights, FlowDeck, FlowDeckError, FlowRecord, FlowStats, HeightStats,
    RangeRecord,
};
pub use segment::{flight_segment, interpolate_truth, interpolate_truth_within};
pub use util::{
    load_util_flight, ImportError, ImportOptions, ImportStats, LoadError, UtilFlight,
    STANDARD_GRAVITY_MPS2, UWB_ANTENNA_LEVER_ARM_M,
};
