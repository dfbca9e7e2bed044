//! Latency benchmark of the process pipeline (`insuwb bench latency`).
//!
//! It owns:
//! - the **floor** ([`floor`], [`graph`]): the same process graph as the
//!   pipeline (IMU driver, UWB driver, INS, fusion, logger), built from bare
//!   iceoryx2 processes of `insuwb-runtime` that only forward samples: the
//!   same payload types and sizes, the same rates, the same waiter wake-ups
//!   and the same waiting rule at the fusion node (it emits when it has the
//!   UWB fix and the INS sample covering the fix epoch), with no maths and no
//!   logging. The floor and the pipeline differ only by what insuwb adds.
//! - the **analysis** ([`analysis`]): per-hop and end-to-end latency
//!   percentiles (HdrHistogram), the period jitter of the 10 Hz fused output
//!   and the missed cycles, computed from the headers of a recording (the
//!   group's log, or the floor logger's) and the logger's receive times
//!   ([`trace`]).
//! - the CPU time of each process ([`cpu`], from `/proc`).
//!
//! Every time is CLOCK_MONOTONIC nanoseconds ([`insuwb_runtime::monotonic_ns`]),
//! comparable across the processes of the machine.
#![warn(missing_docs)]

pub mod analysis;
pub mod cpu;
pub mod floor;
pub mod graph;
pub mod trace;
