//! Stage runtime: iceoryx2 node with a service prefix, typed publishers and subscribers with the QoS of insuwb-msg, WaitSet loop, signals, heartbeat, tracing.
#![warn(missing_docs)]
