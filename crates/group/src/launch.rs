//! The launch loop every process group runs through (`insuwb launch`,
//! `demo`, `chaos` and the latency bench's floor graph): start the
//! supervisor, then until a shutdown request, a failed stage or the end of
//! the run, wait, let the caller's [`Watch`] look at the group (drain what
//! it published, forward heartbeats, sample CPU), inject the
//! [`FaultInjector`]'s faults and poll the supervisor; then stop the stages
//! in [`shutdown_order`].
//!
//! ```
//! use std::time::Duration;
//! use insuwb_group::launch::{Fault, FaultInjector};
//! let f: Fault = "fusion@2.5:STOP".parse().unwrap();
//! assert_eq!((f.stage.as_str(), f.at, f.signal), ("fusion", Duration::from_millis(2500), 19));
//! assert!("fusion@-1".parse::<Fault>().is_err());
//! let inj = FaultInjector::new(vec![f], None, Vec::new(), None);
//! assert_eq!(inj.injected(), 0);
//! ```

use std::time::{Duration, Instant};

use insuwb_launch::{Event, LaunchError, Supervisor, SupervisorState};
use insuwb_msg::StageRole;
use insuwb_sim::rng::{Noise, RngExt};

/// Signal numbers the injector sends (Linux).
mod sig {
    pub const KILL: i32 = 9;
    pub const TERM: i32 = 15;
    pub const STOP: i32 = 19;
    pub const CONT: i32 = 18;
}

/// A fault to inject into a running group (tests, chaos): a signal to a
/// stage at a time after the start.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Fault {
    /// Stage to hit (a [`StageRole`] name).
    pub stage: String,
    /// When, after start.
    pub at: Duration,
    /// Signal number (SIGKILL = 9, SIGSTOP = 19).
    pub signal: i32,
}

/// Why a fault specification was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FaultParseError {
    /// Not `STAGE@SECONDS[:SIGNAL]`.
    #[error("FaultParseError::Shape: fault '{0}': expected STAGE@SECONDS[:SIGNAL]")]
    Shape(String),
    /// The time is not a number of seconds >= 0.
    #[error("FaultParseError::Time: fault '{0}': the time must be a number of seconds >= 0")]
    Time(String),
    /// The signal is neither a number nor KILL, TERM or STOP.
    #[error(
        "FaultParseError::Signal: fault '{0}': the signal must be a number or KILL, TERM, STOP"
    )]
    Signal(String),
    /// No stage has that name.
    #[error("FaultParseError::Stage: fault '{0}': unknown stage")]
    Stage(String),
}

impl std::str::FromStr for Fault {
    type Err = FaultParseError;
    /// `STAGE@SECONDS` (SIGKILL) or `STAGE@SECONDS:SIGNAL` (a number or KILL/TERM/STOP).
    fn from_str(s: &str) -> Result<Self, FaultParseError> {
        let (stage, rest) = s
            .split_once('@')
            .ok_or_else(|| FaultParseError::Shape(s.to_owned()))?;
        let (at, signal) = rest.split_once(':').unwrap_or((rest, "KILL"));
        let at: f64 = at
            .parse()
            .map_err(|_| FaultParseError::Time(s.to_owned()))?;
        if !(at.is_finite() && at >= 0.0) {
            return Err(FaultParseError::Time(s.to_owned()));
        }
        let signal = match signal {
            "KILL" => sig::KILL,
            "TERM" => sig::TERM,
            "STOP" => sig::STOP,
            n => n
                .parse()
                .map_err(|_| FaultParseError::Signal(s.to_owned()))?,
        };
        if stage.parse::<StageRole>().is_err() {
            return Err(FaultParseError::Stage(s.to_owned()));
        }
        Ok(Self {
            stage: stage.to_owned(),
            at: Duration::from_secs_f64(at),
            signal,
        })
    }
}

/// A fault as injected: when, into which stage, which signal.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Injected {
    /// When, after the start.
    pub at: Duration,
    /// The stage hit (a [`StageRole`] name).
    pub stage: String,
    /// The signal (SIGKILL = 9, SIGSTOP = 19).
    pub signal: i32,
}

/// The most injected faults remembered ([`FaultInjector::log`]): a day at
/// the chaos rate (one every 3 s on average), 8 bytes each.
const INJECTED_KEPT: usize = 30_000;

/// A fault as kept in the log: milliseconds after the start (saturating),
/// the stage's index in [`StageRole::NAMES`], the signal. Fixed size and
/// no heap of its own, so that hours of faults cost the launcher 8 bytes
/// each.
#[derive(Debug, Clone, Copy)]
struct Kept {
    at_ms: u32,
    role: u8,
    signal: u8,
}

impl Kept {
    fn new(at: Duration, stage: &str, signal: i32) -> Option<Self> {
        let role = StageRole::NAMES.iter().position(|n| *n == stage)?;
        Some(Self {
            at_ms: u32::try_from(at.as_millis()).unwrap_or(u32::MAX),
            role: u8::try_from(role).ok()?,
            signal: u8::try_from(signal).ok()?,
        })
    }

    fn at(self) -> Duration {
        Duration::from_millis(u64::from(self.at_ms))
    }

    fn expand(self) -> Injected {
        Injected {
            at: self.at(),
            stage: StageRole::NAMES
                .get(usize::from(self.role))
                .copied()
                .unwrap_or("?")
                .to_owned(),
            signal: i32::from(self.signal),
        }
    }
}

/// Injects faults into a supervised group: the timed [`Fault`]s in time
/// order, and with a chaos seed every 1-5 s a random stage of `stages`
/// gets SIGKILL, or SIGSTOP for 2 s then SIGCONT (the draws from the
/// seed's own stream, so a seed replays the same schedule), except in the
/// last 3 s of a bounded run, so the group can show it recovered.
#[derive(Debug)]
pub struct FaultInjector {
    timed: std::iter::Peekable<std::vec::IntoIter<Fault>>,
    chaos: Option<insuwb_sim::rng::SimRng>,
    next_chaos: Option<Duration>,
    stages: Vec<String>,
    duration: Option<Duration>,
    pending_cont: Vec<(Duration, String)>,
    injected: u32,
    log: Vec<Kept>,
}

impl FaultInjector {
    /// An injector of `faults` and, with `chaos_seed`, chaos among
    /// `stages`, for a run of `duration` (None: unbounded).
    #[must_use]
    pub fn new(
        mut faults: Vec<Fault>,
        chaos_seed: Option<u64>,
        stages: Vec<String>,
        duration: Option<Duration>,
    ) -> Self {
        faults.sort_by_key(|f| f.at);
        let mut chaos = chaos_seed.map(|seed| insuwb_sim::rng::stream(seed, 0x000C_4A05));
        let next_chaos = chaos
            .as_mut()
            .map(|r| Duration::from_secs_f64(r.uniform_in(1.0, 5.0)));
        Self {
            timed: faults.into_iter().peekable(),
            chaos,
            next_chaos,
            stages,
            duration,
            pending_cont: Vec::new(),
            injected: 0,
            log: Vec::new(),
        }
    }

    fn note(&mut self, at: Duration, stage: &str, signal: i32) {
        self.injected += 1;
        if self.log.len() < INJECTED_KEPT {
            if let Some(k) = Kept::new(at, stage, signal) {
                self.log.push(k);
            }
        }
    }

    /// Injects what is due at `elapsed` after the start.
    pub fn apply(&mut self, sup: &mut Supervisor, elapsed: Duration) {
        while let Some(f) = self.timed.next_if(|f| elapsed >= f.at) {
            tracing::warn!("injecting signal {} into stage {}", f.signal, f.stage);
            self.note(elapsed, &f.stage, f.signal);
            if let Err(e) = sup.kill_stage(&f.stage, f.signal) {
                tracing::warn!("fault injection: {e}");
            }
        }
        if let (Some(rng), Some(at)) = (self.chaos.as_mut(), self.next_chaos) {
            let quiet = self
                .duration
                .is_some_and(|d| elapsed + Duration::from_secs(3) > d);
            if elapsed >= at && !quiet && !self.stages.is_empty() {
                let stage = self.stages[rng.random_range(0..self.stages.len())].clone();
                let stop = rng.random::<bool>();
                let signal = if stop { sig::STOP } else { sig::KILL };
                tracing::warn!(
                    "chaos: {} {stage}",
                    if stop { "SIGSTOP (2 s)" } else { "SIGKILL" }
                );
                if let Err(e) = sup.kill_stage(&stage, signal) {
                    tracing::warn!("chaos: {e}");
                }
                self.next_chaos = Some(elapsed + Duration::from_secs_f64(rng.uniform_in(1.0, 5.0)));
                self.note(elapsed, &stage, signal);
                if stop {
                    self.pending_cont
                        .push((elapsed + Duration::from_secs(2), stage));
                }
            }
        }
        self.pending_cont.retain(|(at, stage)| {
            if elapsed >= *at {
                let _ = sup.kill_stage(stage, sig::CONT);
                false
            } else {
                true
            }
        });
    }

    /// Faults injected so far (timed and chaos).
    #[must_use]
    pub fn injected(&self) -> u32 {
        self.injected
    }

    /// The faults injected so far, in time order (the first
    /// [`INJECTED_KEPT`]), their times to the millisecond.
    #[must_use]
    pub fn log(&self) -> Vec<Injected> {
        self.log.iter().map(|k| k.expand()).collect()
    }

    /// The last fault injected at or before `at` (to the millisecond), if any.
    #[must_use]
    pub fn last_before(&self, at: Duration) -> Option<Injected> {
        self.log
            .iter()
            .rev()
            .find(|k| k.at() <= at)
            .map(|k| k.expand())
    }
}

/// What the launch loop asks of its caller.
pub trait Watch {
    /// The caller's error.
    type Error;
    /// Waits for the group's next samples or heartbeats, at most `max`;
    /// `Ok(true)`: a shutdown was requested (SIGINT/SIGTERM).
    ///
    /// # Errors
    /// The caller's, ending the loop (the stages are still stopped).
    fn wait(&mut self, max: Duration) -> Result<bool, Self::Error>;
    /// After each wait: look at the group (drain its topics, forward
    /// heartbeats with [`Supervisor::note_heartbeat_from`], sample CPU).
    ///
    /// # Errors
    /// The caller's, ending the loop.
    fn on_wake(
        &mut self,
        sup: &mut Supervisor,
        now: Instant,
        elapsed: Duration,
    ) -> Result<(), Self::Error>;
}

/// How the launch loop ended.
#[derive(Debug)]
pub enum LoopEnd {
    /// The run's duration passed.
    Duration,
    /// A shutdown was requested.
    Shutdown,
    /// This stage failed the group (it exhausted its restart budget, or
    /// exited under a policy with no budget).
    Failed(String),
    /// The supervisor could not start the stages.
    NotStarted(LaunchError),
}

/// Options of the launch loop.
#[derive(Debug, Clone)]
pub struct LoopOptions {
    /// Stop after this long (None: until a shutdown or a failure).
    pub duration: Option<Duration>,
    /// The longest single wait.
    pub max_wait: Duration,
    /// Stop order: stage names (see [`shutdown_order`]).
    pub shutdown_order: Vec<String>,
}

/// Runs a group under `sup`: starts it at `t0`, loops as the module
/// documentation says, stops the stages in order, and says how it ended.
/// Fault injection, where wanted, runs in `faults`.
///
/// # Errors
/// The [`Watch`]'s, after the stages were stopped.
pub fn supervise<W: Watch>(
    sup: &mut Supervisor,
    t0: Instant,
    opts: &LoopOptions,
    watch: &mut W,
    mut faults: Option<&mut FaultInjector>,
) -> Result<LoopEnd, W::Error> {
    let order: Vec<&str> = opts.shutdown_order.iter().map(String::as_str).collect();
    if let Err(e) = sup.start(t0) {
        sup.shutdown(&order);
        return Ok(LoopEnd::NotStarted(e));
    }
    let end = loop {
        let shutdown = match watch.wait(opts.max_wait) {
            Ok(s) => s,
            Err(e) => {
                sup.shutdown(&order);
                return Err(e);
            }
        };
        let now = Instant::now();
        let elapsed = now.duration_since(t0);
        if let Err(e) = watch.on_wake(sup, now, elapsed) {
            sup.shutdown(&order);
            return Err(e);
        }
        if let Some(f) = faults.as_deref_mut() {
            f.apply(sup, elapsed);
        }
        let mut failed = None;
        for e in sup.poll(now) {
            if let Event::BudgetExhausted { stage } = e {
                failed = Some(stage);
            }
        }
        if let SupervisorState::Failed { stage } = sup.state() {
            failed = Some(stage);
        }
        if let Some(stage) = failed {
            break LoopEnd::Failed(stage);
        }
        if shutdown {
            break LoopEnd::Shutdown;
        }
        if opts.duration.is_some_and(|d| elapsed >= d) {
            break LoopEnd::Duration;
        }
    };
    sup.shutdown(&order);
    Ok(end)
}

/// The stop order of a group running `stages`: the sources first, so that
/// nothing new enters, the bridges after fusion, the logger last, so that
/// it records the end ([`StageRole::NAMES`] order).
#[must_use]
pub fn shutdown_order(stages: &[StageRole]) -> Vec<String> {
    StageRole::NAMES
        .into_iter()
        .filter(|n| stages.iter().any(|s| s.name() == *n))
        .map(str::to_owned)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn faults_parse_and_bad_ones_are_named() {
        let f: Fault = "imu@1".parse().unwrap();
        assert_eq!((f.signal, f.at), (9, Duration::from_secs(1)));
        assert_eq!("ins@0.5:15".parse::<Fault>().unwrap().signal, 15);
        for (s, want) in [
            ("imu", "Shape"),
            ("imu@x", "Time"),
            ("imu@nan", "Time"),
            ("imu@1:HUP", "Signal"),
            ("nope@1", "Stage"),
        ] {
            let e = s.parse::<Fault>().unwrap_err().to_string();
            assert!(e.contains(want) && e.contains(s), "{s}: {e}");
        }
    }

    /// The compact log gives back each fault as injected (times to the
    /// millisecond) and attributes a time to the fault before it.
    #[test]
    fn the_fault_log_keeps_each_fault_and_finds_the_one_before() {
        let faults = vec![
            "imu@1".parse().unwrap(),
            "ins@2.5:19".parse().unwrap(),
            "fusion@4:15".parse().unwrap(),
        ];
        let mut inj = FaultInjector::new(faults, None, Vec::new(), None);
        // Never started: each signal is refused (and warned about) but the
        // fault is still counted and kept.
        let spec = insuwb_launch::StageSpec {
            name: "imu".to_owned(),
            program: "true".into(),
            args: Vec::new(),
            env: Vec::new(),
        };
        let mut sup = Supervisor::new(insuwb_launch::RestartPolicy::default(), vec![spec]).unwrap();
        for ms in [500, 1000, 2600, 3000, 4200] {
            inj.apply(&mut sup, Duration::from_millis(ms));
        }
        assert_eq!(inj.injected(), 3);
        let log = inj.log();
        let got: Vec<(u128, &str, i32)> = log
            .iter()
            .map(|f| (f.at.as_millis(), f.stage.as_str(), f.signal))
            .collect();
        assert_eq!(
            got,
            [(1000, "imu", 9), (2600, "ins", 19), (4200, "fusion", 15)]
        );
        assert_eq!(inj.last_before(Duration::from_millis(999)), None);
        let f = inj.last_before(Duration::from_millis(3000)).unwrap();
        assert_eq!((f.stage.as_str(), f.signal), ("ins", 19));
    }

    #[test]
    fn the_shutdown_order_is_the_roles_order_over_the_stages_run() {
        let order = shutdown_order(&[StageRole::Logger, StageRole::Fusion, StageRole::Imu]);
        assert_eq!(order, ["imu", "fusion", "logger"]);
    }
}
