//! The stage's wait loop: an epoll set over the listeners of chosen
//! subscribers plus interval timers, reporting which fired, or SIGINT/SIGTERM.
//!
//! The stage owns its loop (`ipc::Service` ports are not `Send`, so callbacks
//! borrowing them are awkward): attach, then call [`Waiter::wait`] in a loop
//! and test the returned [`Fired`] set against each [`Attachment`]. See the
//! crate documentation for a complete example.
//!
//! This is iceoryx2's WaitSet reduced to what a stage needs, written so that
//! a wake-up allocates nothing (iceoryx2 0.10's WaitSet allocates two vectors
//! per wake-up): the listeners' file descriptors sit in an epoll set whose
//! events land in an array on the stack, interval deadlines are kept per
//! slot, and [`Fired`] is a bit set. Deadlines (timeouts and intervals) are
//! kept by a timerfd in the same epoll set, armed at the earliest deadline
//! as an absolute CLOCK_MONOTONIC time: a high-resolution timer without
//! timer slack, so a wait ends within microseconds of its deadline (epoll's
//! own timeout counts milliseconds, rounded up) in one wake-up. Termination:
//! the waiter installs [`crate::signal`]'s SIGINT/SIGTERM handler, whose
//! eventfd sits in the epoll set too, so [`Wake::Shutdown`] is returned at
//! once whichever thread of the process took the signal, and at every later
//! wait (the flag is never cleared), as when the request came in while the
//! stage was busy.

use core::cell::RefCell;
use core::fmt::Debug;
use core::marker::PhantomData;
use core::time::Duration;

use iceoryx2::prelude::*;
use insuwb_msg::HasHeader;

use crate::monotonic_ns;
use crate::port::Sub;

/// Attachments one [`Waiter`] holds at most.
pub const MAX_ATTACHMENTS: usize = 32;

/// Why creating, attaching to or waiting on a [`Waiter`] failed.
#[derive(Debug, thiserror::Error)]
pub enum WaitError {
    /// The epoll set could not be created.
    #[error("cannot create the epoll set: {0}")]
    Create(std::io::Error),
    /// The SIGINT/SIGTERM handler could not be installed.
    #[error(transparent)]
    Signal(#[from] crate::signal::SignalError),
    /// The listener could not be added to the epoll set.
    #[error("cannot attach {what}: {error}")]
    Attach {
        /// What was attached (topic or interval).
        what: String,
        /// The OS's reason.
        error: std::io::Error,
    },
    /// More than [`MAX_ATTACHMENTS`] attachments.
    #[error("cannot attach {what}: the waiter already holds {max} attachments")]
    TooManyAttachments {
        /// What was attached.
        what: String,
        /// The limit.
        max: usize,
    },
    /// An interval of zero.
    #[error("interval timer period must be > 0, got {0:?}")]
    ZeroInterval(Duration),
    /// `wait` was called from inside itself (impossible through this API).
    #[error("Waiter::wait re-entered")]
    Reentrant,
    /// Nothing attached: waiting would never end.
    #[error("Waiter::wait with nothing attached and no timeout")]
    NoAttachments,
    /// `epoll_wait` failed.
    #[error("epoll_wait failed: {0}")]
    Run(std::io::Error),
}

/// What a [`Waiter::wait`] returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wake {
    /// These attachments fired.
    Fired(Fired),
    /// The timeout passed with nothing fired.
    Timeout,
    /// SIGINT or SIGTERM: leave the loop and exit 0.
    Shutdown,
}

/// The set of attachments that fired in one wake-up (a bit set, no allocation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Fired {
    mask: u32,
    /// Address of the waiter that produced it (attachments of another waiter never match).
    origin: usize,
}

impl Fired {
    /// True when `a` fired.
    #[must_use]
    pub fn contains(&self, a: &Attachment<'_, '_>) -> bool {
        a.waiter.addr() == self.origin && self.mask & (1u32 << a.slot) != 0
    }

    /// Number of attachments that fired.
    #[must_use]
    pub fn len(&self) -> usize {
        self.mask.count_ones() as usize
    }

    /// True when nothing fired.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.mask == 0
    }
}

/// What a slot holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Slot {
    Free,
    /// A listener's file descriptor in the epoll set.
    Listener(i32),
    /// An interval timer: its period and next deadline (CLOCK_MONOTONIC ns).
    Interval {
        period_ns: u64,
        due_ns: u64,
    },
}

/// One attachment of a [`Waiter`]: a subscriber's listener or an interval
/// timer. Dropping it detaches it. `'a` is the subscriber's borrow: the
/// listener outlives its place in the epoll set.
pub struct Attachment<'w, 'a> {
    waiter: &'w Waiter,
    slot: u32,
    what: String,
    _attached: PhantomData<&'a ()>,
}

impl Debug for Attachment<'_, '_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Attachment")
            .field("what", &self.what)
            .field("slot", &self.slot)
            .finish_non_exhaustive()
    }
}

impl Drop for Attachment<'_, '_> {
    fn drop(&mut self) {
        if let Ok(mut slots) = self.waiter.slots.try_borrow_mut() {
            if let Some(s) = slots.get_mut(self.slot as usize) {
                if let Slot::Listener(fd) = *s {
                    // Failure leaves a closed descriptor's entry, which the
                    // kernel drops itself when the listener closes it.
                    let _ = epoll_ctl(self.waiter.epfd.0, libc::EPOLL_CTL_DEL, fd, 0);
                }
                *s = Slot::Free;
            }
        }
    }
}

/// An owned file descriptor (the epoll set, the timerfd).
#[derive(Debug)]
struct EpollFd(i32);

/// The epoll data of the deadline timer (never a slot number).
const TIMER_TOKEN: u64 = u64::MAX;
/// The epoll data of the termination eventfd ([`crate::signal::wake_fd`]).
const SIGNAL_TOKEN: u64 = u64::MAX - 1;

/// Arms `tfd` to expire at `at_ns` (CLOCK_MONOTONIC, absolute), or disarms it
/// with `None`. Either clears an expiry not yet read, so the timer is
/// readable only when the deadline it was last armed with has passed.
fn arm_timer(tfd: i32, at_ns: Option<u64>) -> std::io::Result<()> {
    let ns = at_ns.map_or(0, |t| t.max(1));
    let value = libc::timespec {
        tv_sec: libc::time_t::try_from(ns / 1_000_000_000).unwrap_or(libc::time_t::MAX),
        tv_nsec: libc::c_long::try_from(ns % 1_000_000_000).unwrap_or(0),
    };
    let spec = libc::itimerspec {
        it_interval: libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        },
        it_value: value,
    };
    // SAFETY: `spec` is a valid itimerspec for the call's duration; the old
    // value is not asked for (null); a bad descriptor is reported.
    #[allow(unsafe_code)]
    let rc = unsafe {
        libc::timerfd_settime(tfd, libc::TFD_TIMER_ABSTIME, &spec, core::ptr::null_mut())
    };
    if rc == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

impl Drop for EpollFd {
    fn drop(&mut self) {
        // SAFETY: the descriptor is owned by this value and closed once.
        #[allow(unsafe_code)]
        unsafe {
            libc::close(self.0);
        }
    }
}

fn epoll_ctl(epfd: i32, op: i32, fd: i32, slot: u64) -> std::io::Result<()> {
    let mut ev = libc::epoll_event {
        events: libc::EPOLLIN as u32,
        u64: slot,
    };
    // SAFETY: `ev` is a valid epoll_event for the call's duration; bad
    // descriptors are reported through the return value.
    #[allow(unsafe_code)]
    let rc = unsafe { libc::epoll_ctl(epfd, op, fd, &mut ev) };
    if rc == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

/// The wait loop of a stage (see the module documentation).
#[derive(Debug)]
pub struct Waiter {
    epfd: EpollFd,
    /// The deadline timer (CLOCK_MONOTONIC), in the epoll set as [`TIMER_TOKEN`].
    timer: EpollFd,
    /// The deadline the timer is armed with (`None`: disarmed).
    armed: core::cell::Cell<Option<u64>>,
    slots: RefCell<[Slot; MAX_ATTACHMENTS]>,
    busy_poll: bool,
}

impl Waiter {
    /// A waiter; with `busy_poll` it spins (non-blocking polls) instead of
    /// sleeping in the kernel: lower latency, one core at 100 %.
    pub fn new(busy_poll: bool) -> Result<Self, WaitError> {
        // SAFETY: plain system call without pointers.
        #[allow(unsafe_code)]
        let fd = unsafe { libc::epoll_create1(libc::EPOLL_CLOEXEC) };
        if fd < 0 {
            return Err(WaitError::Create(std::io::Error::last_os_error()));
        }
        let epfd = EpollFd(fd);
        // SAFETY: plain system call without pointers.
        #[allow(unsafe_code)]
        let tfd = unsafe {
            libc::timerfd_create(
                libc::CLOCK_MONOTONIC,
                libc::TFD_CLOEXEC | libc::TFD_NONBLOCK,
            )
        };
        if tfd < 0 {
            return Err(WaitError::Create(std::io::Error::last_os_error()));
        }
        let timer = EpollFd(tfd);
        epoll_ctl(epfd.0, libc::EPOLL_CTL_ADD, timer.0, TIMER_TOKEN).map_err(|source| {
            WaitError::Attach {
                what: "the deadline timer".to_owned(),
                error: source,
            }
        })?;
        crate::signal::install()?;
        if let Some(fd) = crate::signal::wake_fd() {
            epoll_ctl(epfd.0, libc::EPOLL_CTL_ADD, fd, SIGNAL_TOKEN).map_err(|source| {
                WaitError::Attach {
                    what: "the termination eventfd".to_owned(),
                    error: source,
                }
            })?;
        }
        Ok(Self {
            epfd,
            timer,
            armed: core::cell::Cell::new(None),
            slots: RefCell::new([Slot::Free; MAX_ATTACHMENTS]),
            busy_poll,
        })
    }

    /// True when this waiter busy-polls.
    #[must_use]
    pub fn is_busy_poll(&self) -> bool {
        self.busy_poll
    }

    fn addr(&self) -> usize {
        core::ptr::from_ref(self) as usize
    }

    fn claim<'a>(&self, what: String, slot: Slot) -> Result<Attachment<'_, 'a>, WaitError> {
        let full = |what: String| WaitError::TooManyAttachments {
            what,
            max: MAX_ATTACHMENTS,
        };
        let Ok(mut slots) = self.slots.try_borrow_mut() else {
            return Err(full(what));
        };
        let Some(i) = slots.iter().position(|s| *s == Slot::Free) else {
            return Err(full(what));
        };
        let Ok(index) = u32::try_from(i) else {
            return Err(full(what));
        };
        if let Slot::Listener(fd) = slot {
            if let Err(source) = epoll_ctl(self.epfd.0, libc::EPOLL_CTL_ADD, fd, u64::from(index)) {
                return Err(WaitError::Attach {
                    what,
                    error: source,
                });
            }
        }
        if let Some(s) = slots.get_mut(i) {
            *s = slot;
        }
        Ok(Attachment {
            waiter: self,
            slot: index,
            what,
            _attached: PhantomData,
        })
    }

    /// Wakes the waiter when `sub`'s topic is published.
    pub fn attach<'w, 'a, T>(&'w self, sub: &'a Sub<T>) -> Result<Attachment<'w, 'a>, WaitError>
    where
        T: ZeroCopySend + Copy + Debug + HasHeader + 'static,
    {
        // SAFETY: `native_handle` only reads the descriptor number; the
        // listener it belongs to outlives the attachment (`'a`).
        #[allow(unsafe_code)]
        let fd = unsafe { sub.listener.file_descriptor().native_handle() };
        self.claim(format!("subscriber {:?}", sub.topic()), Slot::Listener(fd))
    }

    /// Wakes the waiter every `period` (heartbeat, coasting tick), the first
    /// time between one and two periods from now, at the instants of
    /// [`crate::epoch::housekeeping_due`]: half way between the sample
    /// instants of a group, never just before one.
    pub fn attach_interval(&self, period: Duration) -> Result<Attachment<'_, 'static>, WaitError> {
        if period.is_zero() {
            return Err(WaitError::ZeroInterval(period));
        }
        let period_ns = u64::try_from(period.as_nanos()).unwrap_or(u64::MAX);
        self.claim(
            format!("interval {period:?}"),
            Slot::Interval {
                period_ns,
                due_ns: crate::epoch::housekeeping_due(monotonic_ns(), period_ns),
            },
        )
    }

    /// Blocks until an attachment fires or SIGINT/SIGTERM arrives.
    pub fn wait(&self) -> Result<Wake, WaitError> {
        self.wait_until(None)
    }

    /// As [`Waiter::wait`], giving up after `timeout` ([`Wake::Timeout`]).
    pub fn wait_timeout(&self, timeout: Duration) -> Result<Wake, WaitError> {
        let ns = u64::try_from(timeout.as_nanos()).unwrap_or(u64::MAX);
        self.wait_until(Some(monotonic_ns().saturating_add(ns)))
    }

    /// As [`Waiter::wait`], giving up at `deadline_ns` (CLOCK_MONOTONIC, see
    /// [`monotonic_ns`]) with [`Wake::Timeout`]: never before it, and late
    /// only by the wake-up itself (tens of microseconds), not by epoll's
    /// millisecond rounding. A driver paces its samples with it.
    pub fn wait_deadline(&self, deadline_ns: u64) -> Result<Wake, WaitError> {
        self.wait_until(Some(deadline_ns))
    }

    /// Arms the deadline timer at `until` unless it already is.
    fn arm(&self, until: Option<u64>) -> Result<(), WaitError> {
        if self.armed.get() != until {
            arm_timer(self.timer.0, until).map_err(WaitError::Run)?;
            self.armed.set(until);
        }
        Ok(())
    }

    /// Marks the intervals due at `now` and moves their deadlines on; the
    /// earliest deadline left.
    fn due_intervals(&self, now: u64, mask: &mut u32) -> Result<Option<u64>, WaitError> {
        let mut slots = self
            .slots
            .try_borrow_mut()
            .map_err(|_| WaitError::Reentrant)?;
        let mut next: Option<u64> = None;
        for (i, s) in slots.iter_mut().enumerate() {
            if let Slot::Interval { period_ns, due_ns } = s {
                if *due_ns <= now {
                    *mask |= 1u32 << i;
                    // Keep the phase; after a long stall start afresh
                    // rather than fire a burst.
                    *due_ns = due_ns.saturating_add(*period_ns);
                    if *due_ns <= now {
                        *due_ns = now.saturating_add(*period_ns);
                    }
                }
                next = Some(next.map_or(*due_ns, |n| n.min(*due_ns)));
            }
        }
        Ok(next)
    }

    fn wait_until(&self, deadline_ns: Option<u64>) -> Result<Wake, WaitError> {
        let mut events = [libc::epoll_event { events: 0, u64: 0 }; MAX_ATTACHMENTS];
        loop {
            if crate::signal::termination_requested() {
                return Ok(Wake::Shutdown);
            }
            let now = monotonic_ns();
            let mut mask = 0u32;
            let next_interval = self.due_intervals(now, &mut mask)?;
            let until = match (deadline_ns, next_interval) {
                (Some(d), Some(i)) => Some(d.min(i)),
                (d, i) => d.or(i),
            };
            let timeout_ms: i32 = if self.busy_poll || mask != 0 || until.is_some_and(|u| u <= now)
            {
                0
            } else {
                if until.is_none() {
                    let any = self
                        .slots
                        .try_borrow()
                        .map_err(|_| WaitError::Reentrant)?
                        .iter()
                        .any(|s| *s != Slot::Free);
                    if !any {
                        return Err(WaitError::NoAttachments);
                    }
                }
                // The timer ends the wait at `until`: epoll itself waits
                // without a timeout.
                self.arm(until)?;
                -1
            };
            // SAFETY: `events` is a valid array of MAX_ATTACHMENTS entries
            // that the kernel fills; the epoll descriptor is owned.
            #[allow(unsafe_code)]
            let n = unsafe {
                libc::epoll_wait(
                    self.epfd.0,
                    events.as_mut_ptr(),
                    MAX_ATTACHMENTS as i32,
                    timeout_ms,
                )
            };
            if n < 0 {
                let e = std::io::Error::last_os_error();
                if e.kind() == std::io::ErrorKind::Interrupted {
                    // A signal: SIGINT/SIGTERM are caught at the top of the loop.
                    continue;
                }
                return Err(WaitError::Run(e));
            }
            let mut timer_fired = false;
            for ev in events.iter().take(usize::try_from(n).unwrap_or(0)) {
                let slot = ev.u64;
                if slot < MAX_ATTACHMENTS as u64 {
                    mask |= 1u32 << slot;
                } else if slot == TIMER_TOKEN {
                    timer_fired = true;
                } else if slot == SIGNAL_TOKEN {
                    return Ok(Wake::Shutdown);
                }
            }
            if timer_fired {
                // Expired: readable until re-armed; the next wait arms it anew.
                self.arm(None)?;
            }
            if n > 0 {
                // Intervals that came due while waiting fire with the rest.
                self.due_intervals(monotonic_ns(), &mut mask)?;
            }
            if mask != 0 {
                return Ok(Wake::Fired(Fired {
                    mask,
                    origin: self.addr(),
                }));
            }
            if let Some(d) = deadline_ns {
                if monotonic_ns() >= d {
                    return Ok(Wake::Timeout);
                }
            }
            if self.busy_poll {
                core::hint::spin_loop();
            }
        }
    }
}
