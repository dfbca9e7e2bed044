//! The stage heartbeat ([`Health`], topic [`crate::topics::HEALTH`]): the
//! counters every stage keeps, its state ([`HealthState`]) and the counters
//! of its kind ([`StageCounters`]).
//!
//! On the wire the state is a `u32` code ([`StateCode`]) and the stage's own
//! counters one fixed block ([`CounterBlock`]): a kind code and
//! [`COUNTER_WORDS`] 64-bit words whose meaning the kind gives. Writers and
//! readers go through the typed views; a code this version does not know
//! reads as an error ([`UnknownState`], [`UnknownCounterKind`]). A change of
//! a kind's counters, their order or their meaning bumps
//! [`crate::LAYOUT_VERSION`]; a counter appended in a word the kind left
//! unused (0) does not: a record written before it reads it as 0, and an
//! older reader ignores it.
//!
//! ```
//! use insuwb_msg::{FusionCounters, Health, HealthState, StageCounters};
//! let mut h = Health::default();
//! h.set_state(HealthState::Degraded);
//! h.set_counters(StageCounters::Fusion(FusionCounters { updates: 9, outliers: 2, ..FusionCounters::default() }));
//! assert_eq!(h.state(), Ok(HealthState::Degraded));
//! let named: Vec<String> = h.counters().unwrap().values().map(|(k, v)| format!("{k}={v}")).collect();
//! assert_eq!(named, ["updates=9", "outliers=2", "resets=0", "corrections=0"]);
//! ```

use core::fmt;

use iceoryx2_bb_derive_macros::ZeroCopySend;
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;
use serde::{Deserialize, Serialize};

use crate::Header;

/// Stage health and heartbeat (topic [`crate::topics::HEALTH`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
#[type_name("insuwb::Health")]
pub struct Health {
    /// Common header (`source_id` is the stage id).
    pub header: Header,
    /// Stage name, NUL-padded ASCII.
    pub stage: [u8; 16],
    /// Process id.
    pub pid: u32,
    /// Stage state ([`Health::state`], [`Health::set_state`]).
    pub state: StateCode,
    /// Samples received.
    pub received: u64,
    /// Samples published.
    pub published: u64,
    /// Samples dropped for a wrong layout version.
    pub dropped_version: u64,
    /// Samples dropped for a NaN, infinity or out-of-range value.
    pub dropped_invalid: u64,
    /// Samples dropped for a timestamp going backwards or repeated.
    pub dropped_time: u64,
    /// Sequence gaps seen on inputs (samples missing).
    pub seq_gaps: u64,
    /// The counters of the stage's kind ([`Health::counters`],
    /// [`Health::set_counters`]).
    pub counters: CounterBlock,
}

impl Health {
    /// The state the stage reports; an error for a code this version does
    /// not know.
    ///
    /// # Errors
    /// [`UnknownState`] with the code.
    pub fn state(&self) -> Result<HealthState, UnknownState> {
        self.state.get()
    }

    /// Sets the state.
    pub fn set_state(&mut self, state: HealthState) {
        self.state = state.into();
    }

    /// The counters of the stage's kind; an error for a kind code this
    /// version does not know.
    ///
    /// # Errors
    /// [`UnknownCounterKind`] with the code.
    pub fn counters(&self) -> Result<StageCounters, UnknownCounterKind> {
        self.counters.get()
    }

    /// Sets the counters of the stage's kind.
    pub fn set_counters(&mut self, counters: StageCounters) {
        self.counters = counters.into();
    }
}

/// What a stage says of itself in its heartbeat (wire code in
/// [`Health::state`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
#[repr(u32)]
pub enum HealthState {
    /// Running normally.
    #[default]
    Ok = 0,
    /// Running with degraded inputs.
    Degraded = 1,
    /// Input source disconnected.
    Disconnected = 2,
    /// Shutting down.
    Stopping = 3,
}

impl HealthState {
    /// Every state, in code order.
    pub const ALL: [Self; 4] = [Self::Ok, Self::Degraded, Self::Disconnected, Self::Stopping];

    /// Its wire code.
    #[must_use]
    pub const fn code(self) -> u32 {
        self as u32
    }
}

impl TryFrom<u32> for HealthState {
    type Error = UnknownState;

    fn try_from(code: u32) -> Result<Self, Self::Error> {
        Self::ALL
            .into_iter()
            .find(|s| s.code() == code)
            .ok_or(UnknownState(code))
    }
}

/// A state code that is not one of [`HealthState::ALL`]'s (a newer
/// writer, a damaged record).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("unknown stage state code {0}")]
pub struct UnknownState(pub u32);

/// The wire form of a [`HealthState`]: its `u32` code, any value (a reader
/// may meet codes it does not know).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize, ZeroCopySend,
)]
#[repr(C)]
#[serde(transparent)]
#[type_name("insuwb::StateCode")]
pub struct StateCode(u32);

impl StateCode {
    /// The code `code` as it is (known or not).
    #[must_use]
    pub const fn from_raw(code: u32) -> Self {
        Self(code)
    }

    /// The code.
    #[must_use]
    pub const fn raw(self) -> u32 {
        self.0
    }

    /// The state of the code.
    ///
    /// # Errors
    /// [`UnknownState`] for a code this version does not know.
    pub fn get(self) -> Result<HealthState, UnknownState> {
        HealthState::try_from(self.0)
    }
}

impl From<HealthState> for StateCode {
    fn from(s: HealthState) -> Self {
        Self(s.code())
    }
}

/// Words in a [`CounterBlock`]: the most counters a stage kind has.
pub const COUNTER_WORDS: usize = 6;

/// The word of an optional signed counter that has no value ([`i64::MIN`],
/// never a value: a writer stores `i64::MIN + 1` instead).
pub const NO_VALUE: i64 = i64::MIN;

/// The wire form of [`StageCounters`]: the kind's code, a reserved zero
/// word and [`COUNTER_WORDS`] counters in the kind's order (unused words
/// zero; signed counters as two's complement, [`NO_VALUE`] for none).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, ZeroCopySend)]
#[repr(C)]
#[type_name("insuwb::CounterBlock")]
pub struct CounterBlock {
    kind: u32,
    reserved: u32,
    words: [u64; COUNTER_WORDS],
}

impl CounterBlock {
    /// A block of kind code `kind` and counter words `words` as they are
    /// (known or not): what a decoder of the wire form builds.
    #[must_use]
    pub const fn from_raw(kind: u32, words: [u64; COUNTER_WORDS]) -> Self {
        Self {
            kind,
            reserved: 0,
            words,
        }
    }

    /// The kind code.
    #[must_use]
    pub const fn kind_code(&self) -> u32 {
        self.kind
    }

    /// The counters it holds.
    ///
    /// # Errors
    /// [`UnknownCounterKind`] for a kind code this version does not know.
    pub fn get(&self) -> Result<StageCounters, UnknownCounterKind> {
        StageCounters::from_words(self.kind, &self.words)
    }
}

impl From<StageCounters> for CounterBlock {
    fn from(c: StageCounters) -> Self {
        Self::from_raw(c.kind().code(), c.to_words())
    }
}

/// A counter kind code that is not one of [`CounterKind::ALL`]'s.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("unknown stage counter kind {0}")]
pub struct UnknownCounterKind(pub u32);

/// One counter's value as reports show it.
///
/// Its JSON is a number (`null` for [`CounterValue::Unknown`]); JSON does
/// not tell a count from a signed value that is not negative, which reads
/// back as a [`CounterValue::Count`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum CounterValue {
    /// An event count.
    Count(u64),
    /// A signed quantity (an offset, a drift).
    Signed(i64),
    /// A signed quantity not known yet.
    Unknown,
}

impl fmt::Display for CounterValue {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Count(v) => write!(f, "{v}"),
            Self::Signed(v) => write!(f, "{v}"),
            Self::Unknown => f.write_str("unknown"),
        }
    }
}

/// How a counter's type sits in a 64-bit word.
trait Word: Copy {
    fn to_word(self) -> u64;
    fn from_word(w: u64) -> Self;
    fn value(self) -> CounterValue;
}

impl Word for u64 {
    fn to_word(self) -> u64 {
        self
    }
    fn from_word(w: u64) -> Self {
        w
    }
    fn value(self) -> CounterValue {
        CounterValue::Count(self)
    }
}

impl Word for i64 {
    fn to_word(self) -> u64 {
        self.cast_unsigned()
    }
    fn from_word(w: u64) -> Self {
        w.cast_signed()
    }
    fn value(self) -> CounterValue {
        CounterValue::Signed(self)
    }
}

impl Word for Option<i64> {
    fn to_word(self) -> u64 {
        self.map_or(NO_VALUE, |v| v.max(NO_VALUE + 1)).to_word()
    }
    fn from_word(w: u64) -> Self {
        let v = i64::from_word(w);
        (v != NO_VALUE).then_some(v)
    }
    fn value(self) -> CounterValue {
        self.map_or(CounterValue::Unknown, CounterValue::Signed)
    }
}

/// The per-kind views, [`StageCounters`] and [`CounterKind`] from one list:
/// each kind's code, view and counters in block order.
macro_rules! stage_counters {
    ($(
        $(#[$doc:meta])*
        $variant:ident($view:ident) = $code:literal {
            $( $(#[$fdoc:meta])* $field:ident: $ty:ty, )+
        }
    )+) => {
        $(
            $(#[$doc])*
            #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
            pub struct $view {
                $( $(#[$fdoc])* pub $field: $ty, )+
            }

            impl $view {
                /// The counters' names, in block order.
                pub const NAMES: &'static [&'static str] = &[$(stringify!($field)),+];
            }

            const _: () = assert!($view::NAMES.len() <= COUNTER_WORDS);
        )+

        /// The counters of a stage's kind, each kind its own named
        /// counters (wire form [`CounterBlock`]).
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
        pub enum StageCounters {
            /// Only the counters every stage has.
            #[default]
            Common,
            $( $(#[$doc])* $variant($view), )+
        }

        /// The kind of a [`StageCounters`], with its wire code.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        #[repr(u32)]
        pub enum CounterKind {
            /// Only the counters every stage has.
            Common = 0,
            $( $(#[$doc])* $variant = $code, )+
        }

        impl CounterKind {
            /// Every kind, in code order.
            pub const ALL: &'static [Self] = &[Self::Common, $(Self::$variant),+];

            /// Its wire code.
            #[must_use]
            pub const fn code(self) -> u32 {
                self as u32
            }

            /// The names of its counters, in block order.
            #[must_use]
            pub const fn names(self) -> &'static [&'static str] {
                match self {
                    Self::Common => &[],
                    $( Self::$variant => $view::NAMES, )+
                }
            }
        }

        impl StageCounters {
            /// Its kind.
            #[must_use]
            pub const fn kind(&self) -> CounterKind {
                match self {
                    Self::Common => CounterKind::Common,
                    $( Self::$variant(_) => CounterKind::$variant, )+
                }
            }

            /// Each counter's name and value, in block order.
            pub fn values(self) -> impl Iterator<Item = (&'static str, CounterValue)> {
                let mut out = [None; COUNTER_WORDS];
                match self {
                    Self::Common => {}
                    $( Self::$variant(v) => {
                        let mut slots = out.iter_mut();
                        $(
                            if let Some(s) = slots.next() {
                                *s = Some((stringify!($field), Word::value(v.$field)));
                            }
                        )+
                    } )+
                }
                out.into_iter().flatten()
            }

            fn to_words(self) -> [u64; COUNTER_WORDS] {
                let mut out = [0; COUNTER_WORDS];
                match self {
                    Self::Common => {}
                    $( Self::$variant(v) => {
                        let mut slots = out.iter_mut();
                        $(
                            if let Some(s) = slots.next() {
                                *s = Word::to_word(v.$field);
                            }
                        )+
                    } )+
                }
                out
            }

            fn from_words(kind: u32, words: &[u64; COUNTER_WORDS]) -> Result<Self, UnknownCounterKind> {
                match kind {
                    0 => Ok(Self::Common),
                    $( $code => {
                        let mut w = words.iter().copied();
                        Ok(Self::$variant($view {
                            $( $field: Word::from_word(w.next().unwrap_or(0)), )+
                        }))
                    } )+
                    other => Err(UnknownCounterKind(other)),
                }
            }
        }
    };
}

stage_counters! {
    /// The fusion stage.
    Fusion(FusionCounters) = 1 {
        /// Filter updates.
        updates: u64,
        /// Measurement components weighted as outliers.
        outliers: u64,
        /// Filter resets after divergence.
        resets: u64,
        /// Corrections sent to the INS.
        corrections: u64,
    }
    /// The UWB driver on a recorded source: the fix builder's figures.
    UwbDriver(UwbDriverCounters) = 2 {
        /// Fixes published.
        fixes: u64,
        /// Epochs skipped for too few anchor pairs.
        skipped_too_few_pairs: u64,
        /// Epochs skipped for their geometry (too few distinct anchors or
        /// independent pairs, collinear or coincident anchors).
        skipped_geometry: u64,
        /// Epochs the solver failed on (no convergence, a solution run
        /// away from the anchors, another solver error).
        skipped_solver: u64,
    }
    /// The INS stage.
    Ins(InsCounters) = 3 {
        /// Corrections applied.
        corrections: u64,
        /// IMU samples integrated again after a correction.
        repropagated: u64,
        /// Corrections refused as older than the INS's history.
        corrections_too_old: u64,
        /// IMU driver restarts seen (a new generation).
        imu_restarts: u64,
    }
    /// The logger stage (and its benchmark twin).
    Logger(LoggerCounters) = 4 {
        /// Records handed to the writer.
        sent: u64,
        /// Records dropped (writer channel full).
        dropped: u64,
    }
    /// A driver on a serial or TCP device.
    Device(DeviceCounters) = 5 {
        /// Decoder resynchronisations plus checksum errors.
        decoder_errors: u64,
        /// Link reconnections (connections after the first).
        reconnects: u64,
        /// Device clock offset, host minus device, ns (`None`: unknown).
        clock_offset_ns: Option<i64>,
        /// Device clock drift, parts per billion (`None`: unknown).
        clock_drift_ppb: Option<i64>,
    }
    /// The IMU driver on a ROS 2 topic.
    Ros2Source(Ros2SourceCounters) = 6 {
        /// Samples timed by their receive time (stamp unset, ahead or too
        /// old).
        receive_timed: u64,
        /// Messages that did not decode as `sensor_msgs/Imu`.
        undecodable: u64,
        /// Clock offset, CLOCK_MONOTONIC minus the stamp clock, ns (0 for
        /// monotonic stamps).
        clock_offset_ns: i64,
        /// Messages in a frame other than the body frame.
        other_frame: u64,
    }
    /// The ROS 2 bridge.
    Ros2Bridge(Ros2BridgeCounters) = 7 {
        /// Odometry messages written.
        odometry: u64,
        /// IMU messages written.
        imu: u64,
        /// Transforms written.
        tf: u64,
        /// DDS writes refused (a full send window).
        write_failures: u64,
        /// Body velocities published on `body_vel` from the base's odometry
        /// (`[ros2] odometry_in`). Appended in a word that was unused, so a
        /// heartbeat written before it reads 0 here.
        velocities: u64,
        /// Odometry messages whose twist is in a frame other than the body
        /// frame (used all the same). Appended as `velocities`.
        velocities_other_frame: u64,
    }
    /// The Foxglove live view.
    Foxglove(FoxgloveCounters) = 8 {
        /// Poses logged.
        poses: u64,
        /// UWB fixes logged.
        fixes: u64,
        /// Filter diagnostics logged.
        diags: u64,
        /// Clients connected now.
        clients: u64,
    }
    /// The Zenoh bridge.
    Zenoh(ZenohCounters) = 9 {
        /// Poses put.
        poses: u64,
        /// Health reports put.
        health: u64,
        /// UWB fixes put.
        fixes: u64,
        /// Filter diagnostics put.
        diags: u64,
        /// Puts that failed.
        put_failures: u64,
    }
}

impl Serialize for StageCounters {
    /// A map of each counter's name to its value, in block order.
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_map(self.values())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::mem::{align_of, offset_of, size_of};

    /// The wire layout: a change here is a change of
    /// [`crate::LAYOUT_VERSION`] (and of docs/LOG_FORMAT.md).
    #[test]
    fn health_layout_is_pinned() {
        assert_eq!(crate::LAYOUT_VERSION, 2);
        assert_eq!(size_of::<StateCode>(), 4);
        assert_eq!(align_of::<StateCode>(), 4);

        assert_eq!(COUNTER_WORDS, 6);
        assert_eq!(size_of::<CounterBlock>(), 56);
        assert_eq!(align_of::<CounterBlock>(), 8);
        assert_eq!(offset_of!(CounterBlock, kind), 0);
        assert_eq!(offset_of!(CounterBlock, reserved), 4);
        assert_eq!(offset_of!(CounterBlock, words), 8);

        assert_eq!(size_of::<Health>(), 168);
        assert_eq!(align_of::<Health>(), 8);
        assert_eq!(offset_of!(Health, header), 0);
        assert_eq!(offset_of!(Health, stage), 40);
        assert_eq!(offset_of!(Health, pid), 56);
        assert_eq!(offset_of!(Health, state), 60);
        assert_eq!(offset_of!(Health, received), 64);
        assert_eq!(offset_of!(Health, published), 72);
        assert_eq!(offset_of!(Health, dropped_version), 80);
        assert_eq!(offset_of!(Health, dropped_invalid), 88);
        assert_eq!(offset_of!(Health, dropped_time), 96);
        assert_eq!(offset_of!(Health, seq_gaps), 104);
        assert_eq!(offset_of!(Health, counters), 112);
    }

    /// The codes and each kind's counters in block order: part of the
    /// layout too.
    #[test]
    fn codes_and_counter_orders_are_pinned() {
        assert_eq!(HealthState::ALL.map(HealthState::code), [0, 1, 2, 3]);
        let kinds: Vec<(u32, &[&str])> = CounterKind::ALL
            .iter()
            .map(|k| (k.code(), k.names()))
            .collect();
        let want: [(u32, &[&str]); 10] = [
            (0, &[]),
            (1, &["updates", "outliers", "resets", "corrections"]),
            (
                2,
                &[
                    "fixes",
                    "skipped_too_few_pairs",
                    "skipped_geometry",
                    "skipped_solver",
                ],
            ),
            (
                3,
                &[
                    "corrections",
                    "repropagated",
                    "corrections_too_old",
                    "imu_restarts",
                ],
            ),
            (4, &["sent", "dropped"]),
            (
                5,
                &[
                    "decoder_errors",
                    "reconnects",
                    "clock_offset_ns",
                    "clock_drift_ppb",
                ],
            ),
            (
                6,
                &[
                    "receive_timed",
                    "undecodable",
                    "clock_offset_ns",
                    "other_frame",
                ],
            ),
            (
                7,
                &[
                    "odometry",
                    "imu",
                    "tf",
                    "write_failures",
                    "velocities",
                    "velocities_other_frame",
                ],
            ),
            (8, &["poses", "fixes", "diags", "clients"]),
            (9, &["poses", "health", "fixes", "diags", "put_failures"]),
        ];
        assert_eq!(kinds, want);
        let c = StageCounters::Zenoh(ZenohCounters {
            poses: 1,
            health: 2,
            fixes: 3,
            diags: 4,
            put_failures: 5,
        });
        let b = CounterBlock::from(c);
        assert_eq!(b, CounterBlock::from_raw(9, [1, 2, 3, 4, 5, 0]));
    }

    #[test]
    fn states_convert_and_an_unknown_code_is_an_error() {
        for s in HealthState::ALL {
            assert_eq!(StateCode::from(s).get(), Ok(s));
            assert_eq!(HealthState::try_from(s.code()), Ok(s));
        }
        assert_eq!(StateCode::from_raw(4).get(), Err(UnknownState(4)));
        assert_eq!(UnknownState(4).to_string(), "unknown stage state code 4");
        let mut h = Health::default();
        assert_eq!(h.state(), Ok(HealthState::Ok));
        h.set_state(HealthState::Stopping);
        assert_eq!((h.state(), h.state.raw()), (Ok(HealthState::Stopping), 3));
    }

    #[test]
    fn every_kind_round_trips_through_its_block() {
        let all = [
            StageCounters::Common,
            StageCounters::Fusion(FusionCounters {
                updates: 1,
                outliers: 2,
                resets: 3,
                corrections: u64::MAX,
            }),
            StageCounters::UwbDriver(UwbDriverCounters {
                fixes: 4,
                skipped_too_few_pairs: 5,
                skipped_geometry: 6,
                skipped_solver: 7,
            }),
            StageCounters::Ins(InsCounters {
                corrections: 1,
                repropagated: 2,
                corrections_too_old: 3,
                imu_restarts: 4,
            }),
            StageCounters::Logger(LoggerCounters {
                sent: 10,
                dropped: 1,
            }),
            StageCounters::Device(DeviceCounters {
                decoder_errors: 1,
                reconnects: 2,
                clock_offset_ns: Some(-1_700),
                clock_drift_ppb: None,
            }),
            StageCounters::Ros2Source(Ros2SourceCounters {
                receive_timed: 1,
                undecodable: 2,
                clock_offset_ns: -5,
                other_frame: 3,
            }),
            StageCounters::Ros2Bridge(Ros2BridgeCounters {
                odometry: 1,
                imu: 2,
                tf: 3,
                write_failures: 4,
                velocities: 5,
                velocities_other_frame: 6,
            }),
            StageCounters::Foxglove(FoxgloveCounters {
                poses: 1,
                fixes: 2,
                diags: 3,
                clients: 4,
            }),
            StageCounters::Zenoh(ZenohCounters::default()),
        ];
        assert_eq!(all.len(), CounterKind::ALL.len());
        for c in all {
            let mut h = Health::default();
            h.set_counters(c);
            assert_eq!(h.counters(), Ok(c));
            assert_eq!(h.counters.kind_code(), c.kind().code());
            let names: Vec<&str> = c.values().map(|(k, _)| k).collect();
            assert_eq!(names, c.kind().names());
        }
    }

    /// The ROS 2 bridge's velocity counters were appended in words a
    /// bridge before them left 0: such a heartbeat (a log's Health record)
    /// reads the same, with no velocities.
    #[test]
    fn a_bridge_heartbeat_from_before_the_velocity_counters_reads() {
        let old = CounterBlock::from_raw(7, [1, 2, 3, 4, 0, 0]);
        assert_eq!(
            old.get(),
            Ok(StageCounters::Ros2Bridge(Ros2BridgeCounters {
                odometry: 1,
                imu: 2,
                tf: 3,
                write_failures: 4,
                velocities: 0,
                velocities_other_frame: 0,
            }))
        );
    }

    #[test]
    fn optional_signed_counters_keep_none_apart_from_zero() {
        let d = |offset| {
            StageCounters::Device(DeviceCounters {
                clock_offset_ns: offset,
                ..DeviceCounters::default()
            })
        };
        for offset in [None, Some(0), Some(-1), Some(i64::MAX)] {
            assert_eq!(CounterBlock::from(d(offset)).get(), Ok(d(offset)));
        }
        // The one value that is the "none" word is stored one above it.
        assert_eq!(
            CounterBlock::from(d(Some(i64::MIN))).get(),
            Ok(d(Some(i64::MIN + 1)))
        );
        let values: Vec<String> = d(None).values().map(|(_, v)| v.to_string()).collect();
        assert_eq!(values, ["0", "0", "unknown", "unknown"]);
    }

    #[test]
    fn an_unknown_kind_is_an_error_and_unused_words_are_ignored() {
        let b = CounterBlock::from_raw(77, [1; COUNTER_WORDS]);
        assert_eq!(b.get(), Err(UnknownCounterKind(77)));
        assert_eq!(
            UnknownCounterKind(77).to_string(),
            "unknown stage counter kind 77"
        );
        let b = CounterBlock::from_raw(4, [3, 1, 9, 9, 9, 9]);
        assert_eq!(
            b.get(),
            Ok(StageCounters::Logger(LoggerCounters {
                sent: 3,
                dropped: 1
            }))
        );
    }

    #[test]
    fn counters_serialize_as_named_values() {
        let c = StageCounters::Device(DeviceCounters {
            decoder_errors: 3,
            reconnects: 0,
            clock_offset_ns: Some(-1_700),
            clock_drift_ppb: None,
        });
        let mut h = Health::default();
        h.set_counters(c);
        let bytes = postcard::to_stdvec(&h).unwrap();
        let back: Health = postcard::from_bytes(&bytes).unwrap();
        assert_eq!(back, h);
        let json = serde_json::to_string(&c).unwrap();
        assert_eq!(
            json,
            r#"{"decoder_errors":3,"reconnects":0,"clock_offset_ns":-1700,"clock_drift_ppb":null}"#
        );
        assert_eq!(serde_json::to_string(&StageCounters::Common).unwrap(), "{}");
        let v: Vec<CounterValue> = serde_json::from_str("[3, -2, null]").unwrap();
        assert_eq!(
            v,
            [
                CounterValue::Count(3),
                CounterValue::Signed(-2),
                CounterValue::Unknown
            ]
        );
    }
}
