//! The supervisor: spawns the stages, reaps and restarts them, watches their
//! heartbeats and stops them in order.

use std::fmt;
use std::os::unix::process::{CommandExt, ExitStatusExt};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use crate::backoff::{Backoff, RestartBudget};
use crate::policy::{
    RestartPolicy, RestartPolicyError, StageSpec, StageSpecError, GENERATION_ENV, STAGE_ENV,
};
use crate::sys;

/// Most events kept by [`Supervisor::events`]; beyond it the oldest half is
/// dropped. A restart is 3-4 events, so this is the last 64-128 restarts
/// (a few minutes of a chaos run): enough to see what just happened, and
/// filled early, so that a launcher running for days holds it at a
/// constant size.
pub const MAX_EVENT_HISTORY: usize = 512;
/// How long [`Supervisor::shutdown`] (and drop) waits for a SIGKILLed stage
/// to be reaped before giving up on it (a process stuck in the kernel).
pub const KILL_REAP_TIMEOUT: Duration = Duration::from_secs(2);
/// Sleep between checks while [`Supervisor::shutdown`] waits for a stage.
const SHUTDOWN_POLL: Duration = Duration::from_millis(2);

/// How a stage process ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExitKind {
    /// It exited with this status code.
    Code(i32),
    /// It was terminated by this signal.
    Signal(i32),
}

impl ExitKind {
    /// The exit kind of a wait status (`Code(-1)` if the status is neither,
    /// which waitpid does not report for a terminated child).
    #[must_use]
    pub fn from_status(status: ExitStatus) -> Self {
        match (status.code(), status.signal()) {
            (Some(c), _) => Self::Code(c),
            (None, Some(s)) => Self::Signal(s),
            (None, None) => Self::Code(-1),
        }
    }
}

impl fmt::Display for ExitKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Code(c) => write!(f, "exit code {c}"),
            Self::Signal(s) => write!(f, "signal {s}"),
        }
    }
}

/// Something the supervisor did or saw. Each is logged with `tracing` and
/// kept in [`Supervisor::events`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Event {
    /// The first start of a stage ([`Supervisor::start`]).
    Started {
        /// Stage name.
        stage: String,
        /// Process id.
        pid: u32,
        /// Start generation (0).
        generation: u32,
    },
    /// A stage process ended and was reaped.
    Exited {
        /// Stage name.
        stage: String,
        /// Process id it had.
        pid: u32,
        /// How it ended.
        status: ExitKind,
    },
    /// A stage's heartbeat was silent too long: it is being SIGKILLed.
    HeartbeatLost {
        /// Stage name.
        stage: String,
        /// Time since its last heartbeat (or since its spawn), ms.
        silent_ms: u64,
    },
    /// A restart of a stage that ended is planned after `delay_ms`.
    RestartScheduled {
        /// Stage name.
        stage: String,
        /// Backoff delay, ms.
        delay_ms: u64,
    },
    /// A stage was started again.
    Restarted {
        /// Stage name.
        stage: String,
        /// New process id.
        pid: u32,
        /// Start generation (counts up from 0 over the stage's starts).
        generation: u32,
    },
    /// A (re)start failed to spawn the program (counted as a fault).
    SpawnFailed {
        /// Stage name.
        stage: String,
        /// The operating system's reason.
        error: String,
    },
    /// A stage ended more often than the restart budget allows: the
    /// supervisor is [`SupervisorState::Failed`] and restarts nothing more.
    BudgetExhausted {
        /// Stage name.
        stage: String,
    },
    /// An optional stage ([`RestartPolicy::optional`]) ended more often than
    /// the restart budget allows: it is left down for good while the
    /// supervisor keeps the other stages running.
    GaveUp {
        /// Stage name.
        stage: String,
    },
    /// A stage is stopped for good ([`Supervisor::shutdown`]).
    Stopped {
        /// Stage name.
        stage: String,
    },
}

impl fmt::Display for Event {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Started {
                stage,
                pid,
                generation,
            } => {
                write!(
                    f,
                    "stage {stage} started (pid {pid}, generation {generation})"
                )
            }
            Self::Exited { stage, pid, status } => {
                write!(f, "stage {stage} (pid {pid}) ended: {status}")
            }
            Self::HeartbeatLost { stage, silent_ms } => {
                write!(f, "stage {stage} silent for {silent_ms} ms: killing it")
            }
            Self::RestartScheduled { stage, delay_ms } => {
                write!(f, "stage {stage} restarts in {delay_ms} ms")
            }
            Self::Restarted {
                stage,
                pid,
                generation,
            } => {
                write!(
                    f,
                    "stage {stage} restarted (pid {pid}, generation {generation})"
                )
            }
            Self::SpawnFailed { stage, error } => {
                write!(f, "stage {stage} failed to start: {error}")
            }
            Self::BudgetExhausted { stage } => {
                write!(
                    f,
                    "stage {stage} exhausted its restart budget: supervisor failed"
                )
            }
            Self::GaveUp { stage } => write!(
                f,
                "optional stage {stage} exhausted its restart budget: left down, the rest keeps running"
            ),
            Self::Stopped { stage } => write!(f, "stage {stage} stopped"),
        }
    }
}

/// Where the supervisor stands.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SupervisorState {
    /// Started and keeping the stages running.
    Running,
    /// A stage that is not optional ([`RestartPolicy::optional`]) exhausted
    /// its restart budget: nothing is restarted any more
    /// (exits are still reaped, frozen stages still killed); the caller
    /// should [`Supervisor::shutdown`].
    Failed {
        /// The stage that exhausted its budget.
        stage: String,
    },
    /// Not started yet, or shut down.
    Stopped,
}

/// Why [`Supervisor::new`] or [`Supervisor::start`] failed.
#[derive(Debug, thiserror::Error)]
pub enum LaunchError {
    /// The restart policy is invalid.
    #[error(transparent)]
    Policy(#[from] RestartPolicyError),
    /// A stage specification is invalid.
    #[error(transparent)]
    Stage(#[from] StageSpecError),
    /// The stage list is empty.
    #[error("launch.stages must list at least one stage, got none")]
    NoStages,
    /// [`Supervisor::start`] was called a second time.
    #[error("the supervisor was already started (state {state:?})")]
    AlreadyStarted {
        /// The state it was in.
        state: SupervisorState,
    },
    /// A stage's program could not be spawned. The stages started before it
    /// keep running: call [`Supervisor::shutdown`].
    #[error("cannot start stage {stage} ({program:?}): {error}")]
    Spawn {
        /// Stage name.
        stage: String,
        /// The program (lossy).
        program: String,
        /// The operating system's error.
        error: std::io::Error,
    },
}

/// Why [`Supervisor::kill_stage`] failed.
#[derive(Debug, thiserror::Error)]
pub enum KillError {
    /// No stage has this name.
    #[error("no stage named {0:?}")]
    UnknownStage(String),
    /// The stage has no process now (waiting for a restart, or stopped).
    #[error("stage {0:?} has no running process")]
    NotRunning(String),
    /// kill(2) failed.
    #[error("cannot send signal {signal} to stage {stage} (pid {pid}): {error}")]
    Signal {
        /// Stage name.
        stage: String,
        /// Its process id.
        pid: u32,
        /// The signal.
        signal: i32,
        /// The operating system's error.
        error: std::io::Error,
    },
}

/// Hook called with a stage's name just before the stage is restarted.
pub type BeforeRestart = Box<dyn FnMut(&str) + Send>;

/// One supervised stage.
#[derive(Debug)]
struct Slot {
    spec: StageSpec,
    /// The live (or exited but not yet reaped) process.
    child: Option<Child>,
    /// When the current process was spawned.
    started_at: Instant,
    /// Last heartbeat of the current process, or its spawn time.
    last_beat: Instant,
    /// The watchdog fires at or after this instant.
    beat_deadline: Instant,
    /// SIGKILL was sent by the watchdog to the current process.
    killed: bool,
    /// Generation of the next start (= starts so far).
    starts: u32,
    /// Successful restarts.
    restarts: u32,
    /// When a restart is due.
    restart_due: Option<Instant>,
    /// Optional stage left down after exhausting its budget.
    gave_up: bool,
    backoff: Backoff,
    budget: RestartBudget,
}

impl Slot {
    fn pid(&self) -> Option<u32> {
        self.child.as_ref().map(Child::id)
    }
}

/// Keeps a group of stage processes running.
///
/// Process groups: each child is the leader of its own process group
/// (`setpgid(0, 0)`), with stdin `/dev/null` and the launcher's stdout and
/// stderr. Ctrl-C in a terminal therefore reaches only the launcher (the
/// foreground group), which stops the stages itself in the order it chooses
/// ([`Supervisor::shutdown`]): drivers first, logger last. Every signal the
/// supervisor sends goes to a stage's whole group, so helpers a stage forked
/// go with it; when a stage's main process ends, the rest of its group is
/// SIGKILLed before it is reaped. With
/// [`RestartPolicy::die_with_launcher`] the stages die if the launcher dies.
///
/// Time: [`poll`](Self::poll) and [`note_heartbeat`](Self::note_heartbeat)
/// decide with the `now` they are given (pass `Instant::now()`); only
/// [`shutdown`](Self::shutdown) waits, on the real clock.
///
/// Dropping a supervisor that still has processes SIGKILLs and reaps them;
/// call [`shutdown`](Self::shutdown) for an orderly stop.
pub struct Supervisor {
    policy: RestartPolicy,
    slots: Vec<Slot>,
    state: SupervisorState,
    started: bool,
    history: Vec<Event>,
    before_restart: Option<BeforeRestart>,
}

impl fmt::Debug for Supervisor {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Supervisor")
            .field("policy", &self.policy)
            .field("slots", &self.slots)
            .field("state", &self.state)
            .field("events", &self.history.len())
            .field("before_restart", &self.before_restart.is_some())
            .finish()
    }
}

impl Supervisor {
    /// A supervisor of `stages` (validated, names unique) under `policy`
    /// (validated); nothing is spawned yet.
    pub fn new(policy: RestartPolicy, stages: Vec<StageSpec>) -> Result<Self, LaunchError> {
        policy.validate()?;
        if stages.is_empty() {
            return Err(LaunchError::NoStages);
        }
        StageSpec::validate_all(&stages)?;
        let now = Instant::now();
        let slots = stages
            .into_iter()
            .map(|spec| Slot {
                spec,
                child: None,
                started_at: now,
                last_beat: now,
                beat_deadline: now,
                killed: false,
                starts: 0,
                restarts: 0,
                restart_due: None,
                gave_up: false,
                backoff: Backoff::new(
                    policy.backoff_initial_ms,
                    policy.backoff_max_ms,
                    policy.stable_after(),
                ),
                budget: RestartBudget::new(policy.budget_restarts, policy.budget_window()),
            })
            .collect();
        Ok(Self {
            policy,
            slots,
            state: SupervisorState::Stopped,
            started: false,
            history: Vec::with_capacity(MAX_EVENT_HISTORY),
            before_restart: None,
        })
    }

    /// Sets the hook called with a stage's name just before each restart (to
    /// remove the dead process's iceoryx2 resources, for example).
    pub fn set_before_restart(&mut self, hook: BeforeRestart) {
        self.before_restart = Some(hook);
    }

    /// Spawns every stage, in order, with generation 0. Only once per supervisor.
    ///
    /// On a spawn error the stages already started keep running (the state
    /// is `Running`): call [`shutdown`](Self::shutdown).
    pub fn start(&mut self, now: Instant) -> Result<(), LaunchError> {
        if self.started {
            return Err(LaunchError::AlreadyStarted {
                state: self.state.clone(),
            });
        }
        self.started = true;
        self.state = SupervisorState::Running;
        let mut events = Vec::new();
        let mut result = Ok(());
        for slot in &mut self.slots {
            match spawn(&self.policy, slot, now) {
                Ok((pid, generation)) => events.push(Event::Started {
                    stage: slot.spec.name.clone(),
                    pid,
                    generation,
                }),
                Err(source) => {
                    result = Err(LaunchError::Spawn {
                        stage: slot.spec.name.clone(),
                        program: slot.spec.program.to_string_lossy().into_owned(),
                        error: source,
                    });
                    break;
                }
            }
        }
        self.record(&events);
        result
    }

    /// One non-blocking supervision step at `now`: reaps every ended stage
    /// and plans its restart (when its budget is spent: gives up an optional
    /// stage alone, or enters `Failed`),
    /// SIGKILLs stages whose heartbeat is too old, and performs the restarts
    /// that are due (calling the before-restart hook first). Returns the
    /// events of this step. Does nothing unless started and not shut down.
    ///
    /// Every exit of a stage, even with code 0, is a fault: stages run until
    /// they are stopped.
    pub fn poll(&mut self, now: Instant) -> Vec<Event> {
        let mut events = Vec::new();
        if !self.started || self.state == SupervisorState::Stopped {
            return events;
        }
        for slot in &mut self.slots {
            // Reap (first, so a stage that just died is not reported silent).
            if let Some((pid, status)) = reap_if_ended(slot) {
                events.push(Event::Exited {
                    stage: slot.spec.name.clone(),
                    pid,
                    status,
                });
                let ran_for = now.saturating_duration_since(slot.started_at);
                let optional = self.policy.is_optional(&slot.spec.name);
                fault(&mut self.state, slot, optional, ran_for, now, &mut events);
            }
            // Watchdog: a live process whose heartbeat is too old.
            if self.policy.heartbeat_timeout_ms > 0 && !slot.killed && now >= slot.beat_deadline {
                if let Some(pid) = slot.pid() {
                    let silent = now.saturating_duration_since(slot.last_beat);
                    events.push(Event::HeartbeatLost {
                        stage: slot.spec.name.clone(),
                        silent_ms: millis(silent),
                    });
                    // SIGKILL also ends a stopped process.
                    if let Err(e) = sys::signal_group(pid, libc::SIGKILL) {
                        tracing::warn!(stage = %slot.spec.name, pid, "SIGKILL failed: {e}");
                    }
                    slot.killed = true;
                }
            }
            // Restart when due.
            let due = slot.restart_due.is_some_and(|t| now >= t);
            if due && self.state == SupervisorState::Running {
                slot.restart_due = None;
                if let Some(hook) = self.before_restart.as_mut() {
                    hook(&slot.spec.name);
                }
                match spawn(&self.policy, slot, now) {
                    Ok((pid, generation)) => {
                        slot.restarts = slot.restarts.saturating_add(1);
                        events.push(Event::Restarted {
                            stage: slot.spec.name.clone(),
                            pid,
                            generation,
                        });
                    }
                    Err(e) => {
                        events.push(Event::SpawnFailed {
                            stage: slot.spec.name.clone(),
                            error: e.to_string(),
                        });
                        let optional = self.policy.is_optional(&slot.spec.name);
                        fault(
                            &mut self.state,
                            slot,
                            optional,
                            Duration::ZERO,
                            now,
                            &mut events,
                        );
                    }
                }
            }
        }
        self.record(&events);
        events
    }

    /// Notes a heartbeat of `stage` at `now` (forward every `Health` sample).
    /// Returns false (and does nothing) for an unknown stage or one without a
    /// process.
    pub fn note_heartbeat(&mut self, stage: &str, now: Instant) -> bool {
        self.beat(stage, None, now)
    }

    /// Like [`note_heartbeat`](Self::note_heartbeat), but ignores a heartbeat
    /// whose `pid` (the `Health::pid` field) is not the stage's current
    /// process: a late sample of a killed generation does not feed the
    /// watchdog of its successor.
    pub fn note_heartbeat_from(&mut self, stage: &str, pid: u32, now: Instant) -> bool {
        self.beat(stage, Some(pid), now)
    }

    fn beat(&mut self, stage: &str, pid: Option<u32>, now: Instant) -> bool {
        let timeout = Duration::from_millis(self.policy.heartbeat_timeout_ms);
        let Some(slot) = self.slots.iter_mut().find(|s| s.spec.name == stage) else {
            return false;
        };
        let Some(current) = slot.pid() else {
            return false;
        };
        if pid.is_some_and(|p| p != current) || slot.killed {
            return false;
        }
        slot.last_beat = now;
        slot.beat_deadline = now + timeout;
        true
    }

    /// Sends `signal` (e.g. `libc::SIGKILL`, `SIGSTOP`, `SIGCONT`) to the
    /// process group of `stage`: for tests and the chaos command. The
    /// consequences (exit, silence) are seen by later [`poll`](Self::poll)s.
    pub fn kill_stage(&mut self, stage: &str, signal: i32) -> Result<(), KillError> {
        let slot = self
            .slots
            .iter()
            .find(|s| s.spec.name == stage)
            .ok_or_else(|| KillError::UnknownStage(stage.to_owned()))?;
        let pid = slot
            .pid()
            .ok_or_else(|| KillError::NotRunning(stage.to_owned()))?;
        tracing::info!(stage, pid, signal, "sending signal to stage");
        sys::signal_group(pid, signal).map_err(|source| KillError::Signal {
            stage: stage.to_owned(),
            pid,
            signal,
            error: source,
        })
    }

    /// Stops every stage for good: for each stage of `order` (names; unknown
    /// ones are ignored), then each remaining stage in configuration order:
    /// SIGTERM (and SIGCONT, in case it is stopped) to its group, wait up to
    /// `grace_ms` for it to exit, else SIGKILL; each is reaped (no zombie
    /// left) and gets `Exited` (if it had a process) and `Stopped`. Pending
    /// restarts are cancelled; the state becomes `Stopped`. Blocks up to
    /// about `grace_ms` per stage that ignores SIGTERM.
    pub fn shutdown(&mut self, order: &[&str]) -> Vec<Event> {
        self.state = SupervisorState::Stopped;
        self.started = true;
        let mut sequence: Vec<usize> = Vec::with_capacity(self.slots.len());
        for name in order {
            match self.slots.iter().position(|s| s.spec.name == *name) {
                Some(i) if !sequence.contains(&i) => sequence.push(i),
                Some(_) => {}
                None => tracing::warn!(stage = name, "shutdown order names an unknown stage"),
            }
        }
        for i in 0..self.slots.len() {
            if !sequence.contains(&i) {
                sequence.push(i);
            }
        }
        let grace = Duration::from_millis(self.policy.grace_ms);
        let mut events = Vec::new();
        for i in sequence {
            let Some(slot) = self.slots.get_mut(i) else {
                continue;
            };
            slot.restart_due = None;
            if let Some(pid) = slot.pid() {
                tracing::info!(stage = %slot.spec.name, pid, "stopping stage (SIGTERM)");
                let _ = sys::signal_group(pid, libc::SIGTERM);
                let _ = sys::signal_group(pid, libc::SIGCONT);
                let mut ended = wait_reaped(slot, grace);
                if ended.is_none() {
                    tracing::warn!(
                        stage = %slot.spec.name,
                        pid,
                        grace_ms = self.policy.grace_ms,
                        "stage ignored SIGTERM: SIGKILL"
                    );
                    let _ = sys::signal_group(pid, libc::SIGKILL);
                    ended = wait_reaped(slot, KILL_REAP_TIMEOUT);
                }
                match ended {
                    Some((pid, status)) => events.push(Event::Exited {
                        stage: slot.spec.name.clone(),
                        pid,
                        status,
                    }),
                    None => tracing::error!(
                        stage = %slot.spec.name,
                        pid,
                        "stage did not die after SIGKILL; left unreaped"
                    ),
                }
            }
            events.push(Event::Stopped {
                stage: slot.spec.name.clone(),
            });
        }
        self.record(&events);
        events
    }

    /// Each stage's name and current process id (`None` while down).
    #[must_use]
    pub fn pids(&self) -> Vec<(String, Option<u32>)> {
        self.slots
            .iter()
            .map(|s| (s.spec.name.clone(), s.pid()))
            .collect()
    }

    /// Successful restarts of `stage` (0 for an unknown name).
    #[must_use]
    pub fn restarts(&self, stage: &str) -> u32 {
        self.slots
            .iter()
            .find(|s| s.spec.name == stage)
            .map_or(0, |s| s.restarts)
    }

    /// The optional stages given up so far ([`Event::GaveUp`]), in
    /// configuration order.
    #[must_use]
    pub fn given_up(&self) -> Vec<String> {
        self.slots
            .iter()
            .filter(|s| s.gave_up)
            .map(|s| s.spec.name.clone())
            .collect()
    }

    /// Successful restarts of all stages.
    #[must_use]
    pub fn total_restarts(&self) -> u32 {
        self.slots
            .iter()
            .fold(0u32, |acc, s| acc.saturating_add(s.restarts))
    }

    /// The current state.
    #[must_use]
    pub fn state(&self) -> SupervisorState {
        self.state.clone()
    }

    /// The policy in force.
    #[must_use]
    pub fn policy(&self) -> &RestartPolicy {
        &self.policy
    }

    /// Events so far, oldest first (the last [`MAX_EVENT_HISTORY`] at most).
    #[must_use]
    pub fn events(&self) -> &[Event] {
        &self.history
    }

    /// Logs `events` and appends them to the bounded history.
    fn record(&mut self, events: &[Event]) {
        for ev in events {
            match ev {
                Event::Started { .. }
                | Event::Restarted { .. }
                | Event::RestartScheduled { .. }
                | Event::Stopped { .. } => tracing::info!("{ev}"),
                Event::Exited { .. } if self.state == SupervisorState::Stopped => {
                    tracing::info!("{ev}");
                }
                Event::Exited { .. } | Event::HeartbeatLost { .. } | Event::SpawnFailed { .. } => {
                    tracing::warn!("{ev}");
                }
                Event::BudgetExhausted { .. } | Event::GaveUp { .. } => tracing::error!("{ev}"),
            }
            if self.history.len() >= MAX_EVENT_HISTORY {
                self.history.drain(..MAX_EVENT_HISTORY / 2);
            }
            self.history.push(ev.clone());
        }
    }
}

impl Drop for Supervisor {
    fn drop(&mut self) {
        let live: Vec<usize> = (0..self.slots.len())
            .filter(|&i| self.slots.get(i).is_some_and(|s| s.child.is_some()))
            .collect();
        for &i in &live {
            if let Some(pid) = self.slots.get(i).and_then(Slot::pid) {
                tracing::warn!(pid, "supervisor dropped with a live stage: SIGKILL");
                let _ = sys::signal_group(pid, libc::SIGKILL);
            }
        }
        for i in live {
            if let Some(slot) = self.slots.get_mut(i) {
                let _ = wait_reaped(slot, KILL_REAP_TIMEOUT);
            }
        }
    }
}

/// Spawns `slot`'s program at `now` as generation `slot.starts`; resets its
/// heartbeat clock (with the startup allowance). Returns pid and generation.
fn spawn(policy: &RestartPolicy, slot: &mut Slot, now: Instant) -> std::io::Result<(u32, u32)> {
    let generation = slot.starts;
    let mut cmd = Command::new(&slot.spec.program);
    cmd.args(&slot.spec.args)
        .envs(slot.spec.env.iter().map(|(k, v)| (k, v)))
        .env(GENERATION_ENV, generation.to_string())
        .env(STAGE_ENV, &slot.spec.name)
        .stdin(Stdio::null())
        .process_group(0);
    if policy.die_with_launcher {
        sys::kill_child_with_parent(&mut cmd);
    }
    let child = cmd.spawn()?;
    let pid = child.id();
    slot.child = Some(child);
    slot.starts = slot.starts.saturating_add(1);
    slot.started_at = now;
    slot.last_beat = now;
    slot.beat_deadline = now
        + Duration::from_millis(policy.startup_grace_ms)
        + Duration::from_millis(policy.heartbeat_timeout_ms);
    slot.killed = false;
    Ok((pid, generation))
}

/// A stage went down (exit, or failed spawn) at `now` after running
/// `ran_for`: plan its restart; when its budget is spent, give it up alone
/// (an `optional` stage) or fail the supervisor.
fn fault(
    state: &mut SupervisorState,
    slot: &mut Slot,
    optional: bool,
    ran_for: Duration,
    now: Instant,
    events: &mut Vec<Event>,
) {
    if *state != SupervisorState::Running {
        return;
    }
    if !slot.budget.try_take(now) {
        if optional {
            slot.gave_up = true;
            events.push(Event::GaveUp {
                stage: slot.spec.name.clone(),
            });
            return;
        }
        events.push(Event::BudgetExhausted {
            stage: slot.spec.name.clone(),
        });
        *state = SupervisorState::Failed {
            stage: slot.spec.name.clone(),
        };
        return;
    }
    let delay_ms = slot.backoff.on_exit(ran_for);
    slot.restart_due = Some(now + Duration::from_millis(delay_ms));
    events.push(Event::RestartScheduled {
        stage: slot.spec.name.clone(),
        delay_ms,
    });
}

/// If `slot`'s process has ended: SIGKILL what is left of its process group
/// (while the zombie still reserves the group number), reap it, and return
/// its pid and exit kind. Never blocks.
fn reap_if_ended(slot: &mut Slot) -> Option<(u32, ExitKind)> {
    let child = slot.child.as_mut()?;
    let pid = child.id();
    match sys::has_terminated(pid) {
        Ok(false) => return None,
        Ok(true) => {
            // Helpers the stage forked die with it; ESRCH (none left) is fine.
            let _ = sys::signal_group(pid, libc::SIGKILL);
        }
        Err(e) => tracing::debug!(pid, "waitid failed ({e}); falling back to try_wait"),
    }
    match child.try_wait() {
        Ok(Some(status)) => {
            slot.child = None;
            Some((pid, ExitKind::from_status(status)))
        }
        Ok(None) => None,
        Err(e) => {
            // Not our child any more (reaped elsewhere): forget it.
            tracing::warn!(stage = %slot.spec.name, pid, "cannot wait for stage: {e}");
            slot.child = None;
            Some((pid, ExitKind::Code(-1)))
        }
    }
}

/// Polls [`reap_if_ended`] until it reaps or `timeout` passes (real clock).
fn wait_reaped(slot: &mut Slot, timeout: Duration) -> Option<(u32, ExitKind)> {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(r) = reap_if_ended(slot) {
            return Some(r);
        }
        if slot.child.is_none() || Instant::now() >= deadline {
            return None;
        }
        std::thread::sleep(SHUTDOWN_POLL);
    }
}

/// Whole milliseconds of `d`, saturating.
fn millis(d: Duration) -> u64 {
    u64::try_from(d.as_millis()).unwrap_or(u64::MAX)
}
