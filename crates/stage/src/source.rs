//! Recorded sources of the drivers: the simulator and the replay of a
//! recorded log. Every sample carries its time since the start of the
//! recording, and the driver paces it against a start epoch
//! ([`crate::driver::pacing`]). Real sensors (serial, network) are read by
//! the live loop of [`crate::device`] instead, which stamps each sample when
//! it is read.

use anyhow::{bail, Context, Result};
use insuwb_group::sources;
use insuwb_log::Record;
use insuwb_msg::{BodyVelocity, GroundTruth, Height, ImuSample, UwbRange, UwbTdoa};

/// One sample from a source.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Item {
    /// An IMU sample.
    Imu(ImuSample),
    /// A TDOA measurement.
    Tdoa(UwbTdoa),
    /// A two-way range.
    Range(UwbRange),
    /// Ground truth (simulation and replay only; fusion never reads it).
    Truth(GroundTruth),
    /// A body-frame velocity (odometry, flow), from the IMU driver.
    Velocity(BodyVelocity),
    /// A height (a range finder's), from the IMU driver.
    Height(Height),
}

impl Item {
    /// The sample's measurement time (relative to the recording's start for recorded sources).
    #[must_use]
    pub fn time_ns(&self) -> u64 {
        match self {
            Self::Imu(s) => s.header.meas_time_ns,
            Self::Tdoa(s) => s.header.meas_time_ns,
            Self::Range(s) => s.header.meas_time_ns,
            Self::Truth(s) => s.header.meas_time_ns,
            Self::Velocity(s) => s.header.meas_time_ns,
            Self::Height(s) => s.header.meas_time_ns,
        }
    }
}

/// Which samples a driver wants.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Want {
    /// IMU, body velocities, heights and ground truth (the IMU driver).
    Imu,
    /// TDOA differences and two-way ranges (the UWB driver).
    Uwb,
}

impl Want {
    /// The driver's stage role.
    #[must_use]
    pub const fn role(self) -> insuwb_msg::StageRole {
        match self {
            Self::Imu => insuwb_msg::StageRole::Imu,
            Self::Uwb => insuwb_msg::StageRole::Uwb,
        }
    }
}

/// A source of samples for a driver.
pub trait Source: std::fmt::Debug {
    /// The next sample, in time order; `None` at the end of a recording.
    fn next_item(&mut self) -> Option<Item>;
    /// Whether sample times are recorded times to be paced (true) or live stamps.
    fn is_recorded(&self) -> bool;
}

/// A recorded source held in memory (simulation output or a replayed log).
#[derive(Debug)]
pub struct Recorded {
    items: Vec<Item>,
    next: usize,
}

impl Recorded {
    /// The streams of `items` (IMU, TDOA, range, body velocity, height,
    /// truth) merged by time, each kept in its given order: a sample
    /// recorded with a time before its predecessor's stays behind it, so the
    /// driver drops and counts it as it would from a live sensor. At equal
    /// times IMU, TDOA and ranges go before body velocities, and those
    /// before heights (the order `insuwb eval` feeds them), and
    /// sensor samples before ground truth (truth is for evaluation: it must
    /// not delay a sensor sample).
    #[must_use]
    pub fn new(items: Vec<Item>) -> Self {
        let kind = |i: &Item| match i {
            Item::Imu(_) => 0usize,
            Item::Tdoa(_) => 1,
            Item::Range(_) => 2,
            Item::Velocity(_) => 3,
            Item::Height(_) => 4,
            Item::Truth(_) => 5,
        };
        let mut streams: [Vec<Item>; 6] = Default::default();
        for i in items {
            if let Some(s) = streams.get_mut(kind(&i)) {
                s.push(i);
            }
        }
        let total = streams.iter().map(Vec::len).sum();
        let mut merged = Vec::with_capacity(total);
        let mut heads = [0usize; 6];
        loop {
            let next = (0..6)
                .filter_map(|k| {
                    let item = streams.get(k)?.get(*heads.get(k)?)?;
                    Some((item.time_ns(), k))
                })
                .min();
            let Some((_, k)) = next else { break };
            if let (Some(s), Some(h)) = (streams.get(k), heads.get_mut(k)) {
                if let Some(item) = s.get(*h) {
                    merged.push(*item);
                }
                *h += 1;
            }
        }
        Self {
            items: merged,
            next: 0,
        }
    }

    /// Skips every sample before `t_ns` (a restarted driver resumes where the recording is now).
    pub fn skip_before(&mut self, t_ns: u64) -> usize {
        let start = self.next;
        while self
            .items
            .get(self.next)
            .is_some_and(|i| i.time_ns() < t_ns)
        {
            self.next += 1;
        }
        self.next - start
    }

    /// Whether it holds body velocities (odometry, flow).
    #[must_use]
    pub fn has_velocity(&self) -> bool {
        self.items.iter().any(|i| matches!(i, Item::Velocity(_)))
    }

    /// Whether it holds heights (a range finder).
    #[must_use]
    pub fn has_height(&self) -> bool {
        self.items.iter().any(|i| matches!(i, Item::Height(_)))
    }

    /// How many TDOA differences and how many two-way ranges it holds.
    #[must_use]
    pub fn uwb_counts(&self) -> (usize, usize) {
        self.items.iter().fold((0, 0), |(t, r), i| match i {
            Item::Tdoa(_) => (t + 1, r),
            Item::Range(_) => (t, r + 1),
            _ => (t, r),
        })
    }

    /// Time of the last sample.
    #[must_use]
    pub fn end_ns(&self) -> u64 {
        self.items.last().map_or(0, Item::time_ns)
    }

    /// Peeks the next sample's time.
    #[must_use]
    pub fn peek_time(&self) -> Option<u64> {
        self.items.get(self.next).map(Item::time_ns)
    }
}

impl Source for Recorded {
    fn next_item(&mut self) -> Option<Item> {
        let i = self.items.get(self.next).copied();
        self.next += 1;
        i
    }
    fn is_recorded(&self) -> bool {
        true
    }
}

/// Opens the recorded source `source` (`sim` or `replay:FILE`) for `want`.
///
/// # Errors
/// A live source (`device`, `ros2:`); the scenario or the log cannot be read.
pub fn open(source: &sources::Source, scenario: &str, seed: u64, want: Want) -> Result<Recorded> {
    let mut items = Vec::new();
    if *source == sources::Source::Sim {
        let sc = insuwb_fusion::scenario::ScenarioFile::load(scenario)?;
        let out = insuwb_sim::simulate(&sc.sim, seed).context("simulating the scenario")?;
        match want {
            Want::Imu => {
                items.extend(out.truth.iter().map(|s| Item::Truth(*s)));
                items.extend(out.imu.iter().map(|s| Item::Imu(*s)));
                items.extend(out.velocity.iter().map(|s| Item::Velocity(*s)));
                items.extend(out.height.iter().map(|s| Item::Height(*s)));
            }
            Want::Uwb => {
                items.extend(out.tdoa.iter().map(|s| Item::Tdoa(*s)));
                items.extend(out.range.iter().map(|s| Item::Range(*s)));
            }
        }
    } else if let Some(file) = source.replay_file() {
        let (records, tail, _) = insuwb_log::read_all(file)
            .with_context(|| format!("{}: cannot read the log", file.display()))?;
        if let Some(t) = tail {
            tracing::warn!("{}: {t}", file.display());
        }
        for r in records {
            match (want, r) {
                (Want::Imu, Record::Imu(s)) => items.push(Item::Imu(s)),
                (Want::Imu, Record::Truth(s)) => items.push(Item::Truth(s)),
                (Want::Imu, Record::BodyVel(s)) => items.push(Item::Velocity(s)),
                (Want::Imu, Record::Height(s)) => items.push(Item::Height(s)),
                (Want::Uwb, Record::Tdoa(s)) => items.push(Item::Tdoa(s)),
                (Want::Uwb, Record::Range(s)) => items.push(Item::Range(s)),
                _ => {}
            }
        }
    } else {
        bail!("source '{source}' is live, not recorded (sim or replay:FILE)");
    }
    Ok(Recorded::new(items))
}
