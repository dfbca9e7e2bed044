//! The closed-loop INS/UWB fusion engine shared by eval, replay and the fusion stage.
#![warn(missing_docs)]
