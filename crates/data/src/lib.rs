//! Dataset readers: the Crazyflie micro-SD event log of the UTIL dataset and its anchor files.
#![warn(missing_docs)]
