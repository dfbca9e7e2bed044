//! Real sensor devices. Frame codecs of the published protocols the drivers
//! speak ([`witmotion`], [`mavlink`] for IMUs; [`nlink`], [`eliko`],
//! [`dwm1001`] for UWB positioning systems and their two-way ranges), each
//! a streaming decoder that resynchronises after garbage plus an encoder
//! used by the emulators; the device-clock to host CLOCK_MONOTONIC mapping
//! ([`clock`]); byte links to the devices that survive unplugging
//! ([`link`]); and device emulators over pseudo-terminals and loopback TCP
//! for users and tests ([`emulator`], playing the timed frames [`play`]
//! encodes from IMU samples, UWB fixes and UWB ranges).
//!
//! Nothing here knows about iceoryx2: the driver stage turns readings into
//! samples.
#![warn(missing_docs)]

pub mod clock;
pub mod dwm1001;
pub mod eliko;
pub mod emulator;
pub mod frame;
pub mod link;
pub mod mavlink;
pub mod nlink;
pub mod play;
pub mod witmotion;

pub use clock::{ClockConfig, ClockFilter};
pub use frame::{wire_time_ns, AnyDecoder, DecoderStats, DeviceTime, Protocol, Reading};
