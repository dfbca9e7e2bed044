//! Evaluation: runs every solution on a dataset in process, computes the
//! metrics of the paper's Table 1 (and more) against ground truth, formats
//! tables and draws figures; a log that holds fused states and no sensor
//! records is evaluated as its recorded track ([`recorded`]).
#![warn(missing_docs)]

pub mod batch;
pub mod consistency;
pub mod metrics;
pub mod plot;
pub mod recorded;
pub mod run;
pub mod scenario;
pub mod tracks;
