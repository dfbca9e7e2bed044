//! The [`Record`] enum: one variant per topic, the payload of every log frame.

use insuwb_msg::{
    topics, BodyVelocity, FilterDiag, FusedState, GroundTruth, Header, Health, Height, ImuSample,
    InsCorrection, NavState, UwbFix, UwbRange, UwbTdoa,
};
use serde::{Deserialize, Serialize};

/// One logged sample, tagged with its topic.
///
/// The postcard encoding starts with the variant index (a varint); the
/// indices are part of the format and frozen: `Imu` = 0, `Tdoa` = 1,
/// `Fix` = 2, `Nav` = 3, `Correction` = 4, `Fused` = 5, `Diag` = 6,
/// `Truth` = 7, `Health` = 8, `BodyVel` = 9, `Range` = 10, `Height` = 11. New variants are only ever
/// appended, so a log written before a variant existed reads unchanged.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Record {
    /// Raw IMU sample ([`topics::IMU`]).
    Imu(ImuSample),
    /// UWB TDOA measurement ([`topics::UWB_TDOA`]).
    Tdoa(UwbTdoa),
    /// UWB fix ([`topics::UWB_FIX`]).
    Fix(UwbFix),
    /// INS navigation state ([`topics::NAV`]).
    Nav(NavState),
    /// INS correction ([`topics::CORRECTION`]).
    Correction(InsCorrection),
    /// Fused state ([`topics::FUSED`]).
    Fused(FusedState),
    /// Filter diagnostics ([`topics::DIAG`]).
    Diag(FilterDiag),
    /// Ground truth ([`topics::TRUTH`]).
    Truth(GroundTruth),
    /// Stage health ([`topics::HEALTH`]).
    Health(Health),
    /// Body-frame velocity: odometry or optical flow ([`topics::BODY_VEL`]).
    BodyVel(BodyVelocity),
    /// UWB two-way range ([`topics::UWB_RANGE`]).
    Range(UwbRange),
    /// Height: a range finder's distance to the floor ([`topics::HEIGHT`]).
    Height(Height),
}

impl Record {
    /// Every topic a record can carry, in variant-index order.
    pub const TOPICS: [&'static str; 12] = [
        topics::IMU,
        topics::UWB_TDOA,
        topics::UWB_FIX,
        topics::NAV,
        topics::CORRECTION,
        topics::FUSED,
        topics::DIAG,
        topics::TRUTH,
        topics::HEALTH,
        topics::BODY_VEL,
        topics::UWB_RANGE,
        topics::HEIGHT,
    ];

    /// The topic name of this record (from [`insuwb_msg::topics`]).
    #[must_use]
    pub fn topic(&self) -> &'static str {
        match self {
            Self::Imu(_) => topics::IMU,
            Self::Tdoa(_) => topics::UWB_TDOA,
            Self::Fix(_) => topics::UWB_FIX,
            Self::Nav(_) => topics::NAV,
            Self::Correction(_) => topics::CORRECTION,
            Self::Fused(_) => topics::FUSED,
            Self::Diag(_) => topics::DIAG,
            Self::Truth(_) => topics::TRUTH,
            Self::Health(_) => topics::HEALTH,
            Self::BodyVel(_) => topics::BODY_VEL,
            Self::Range(_) => topics::UWB_RANGE,
            Self::Height(_) => topics::HEIGHT,
        }
    }

    /// The sample's common header.
    #[must_use]
    pub fn header(&self) -> &Header {
        match self {
            Self::Imu(s) => &s.header,
            Self::Tdoa(s) => &s.header,
            Self::Fix(s) => &s.header,
            Self::Nav(s) => &s.header,
            Self::Correction(s) => &s.header,
            Self::Fused(s) => &s.header,
            Self::Diag(s) => &s.header,
            Self::Truth(s) => &s.header,
            Self::Health(s) => &s.header,
            Self::BodyVel(s) => &s.header,
            Self::Range(s) => &s.header,
            Self::Height(s) => &s.header,
        }
    }

    /// The sample's common header, mutable.
    pub fn header_mut(&mut self) -> &mut Header {
        match self {
            Self::Imu(s) => &mut s.header,
            Self::Tdoa(s) => &mut s.header,
            Self::Fix(s) => &mut s.header,
            Self::Nav(s) => &mut s.header,
            Self::Correction(s) => &mut s.header,
            Self::Fused(s) => &mut s.header,
            Self::Diag(s) => &mut s.header,
            Self::Truth(s) => &mut s.header,
            Self::Health(s) => &mut s.header,
            Self::BodyVel(s) => &mut s.header,
            Self::Range(s) => &mut s.header,
            Self::Height(s) => &mut s.header,
        }
    }
}

macro_rules! impl_from_sample {
    ($($t:ty => $v:ident),*) => {$(
        impl From<$t> for Record {
            fn from(s: $t) -> Self { Self::$v(s) }
        }
    )*};
}
impl_from_sample!(
    ImuSample => Imu,
    UwbTdoa => Tdoa,
    UwbFix => Fix,
    NavState => Nav,
    InsCorrection => Correction,
    FusedState => Fused,
    FilterDiag => Diag,
    GroundTruth => Truth,
    Health => Health,
    BodyVelocity => BodyVel,
    UwbRange => Range,
    Height => Height
);
