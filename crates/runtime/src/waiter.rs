//! The stage's wait loop: a WaitSet over the listeners of chosen subscribers
//! and interval timers, reporting which fired, or SIGINT/SIGTERM.
//!
//! The stage owns its loop (`ipc::Service` ports are not `Send`, so callbacks
//! borrowing them are awkward): attach, then call [`Waiter::wait`] in a loop
//! and test the returned [`Fired`] set against each [`Attachment`]. See the
//! crate documentation for a complete example.
//!
//! No allocation happens in this layer per wake-up ([`Fired`] is a bit set);
//! iceoryx2 0.10's WaitSet itself allocates a small vector per wake-up with
//! triggered listeners.

use core::cell::RefCell;
use core::fmt::Debug;
use core::time::Duration;

use iceoryx2::prelude::*;
use iceoryx2::waitset::{
    WaitSetAttachmentError, WaitSetCreateError, WaitSetRunError, WaitSetRunResult,
};
use insuwb_msg::HasHeader;

use crate::monotonic_ns;
use crate::port::Sub;

/// Attachments one [`Waiter`] holds at most.
pub const MAX_ATTACHMENTS: usize = 32;

/// Why creating, attaching to or waiting on a [`Waiter`] failed.
#[derive(Debug, thiserror::Error)]
pub enum WaitError {
    /// The WaitSet could not be created.
    #[error("cannot create WaitSet: {0}")]
    Create(#[source] WaitSetCreateError),
    /// iceoryx2 refused the attachment.
    #[error("cannot attach {what} to the WaitSet: {source}")]
    Attach {
        /// What was attached (topic or interval).
        what: String,
        /// iceoryx2's reason.
        source: WaitSetAttachmentError,
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
    /// Waiting failed (no attachments, or an OS error).
    #[error("WaitSet wait failed: {0}")]
    Run(#[source] WaitSetRunError),
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

/// One attachment of a [`Waiter`]: a subscriber's listener or an interval
/// timer. Dropping it detaches it.
pub struct Attachment<'w, 'a> {
    _guard: WaitSetGuard<'w, 'a, ipc::Service>,
    waiter: &'w Waiter,
    slot: u32,
    what: String,
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
                *s = None;
            }
        }
    }
}

type Slots = [Option<WaitSetAttachmentId<ipc::Service>>; MAX_ATTACHMENTS];

/// The wait loop of a stage (see the module documentation).
#[derive(Debug)]
pub struct Waiter {
    ws: WaitSet<ipc::Service>,
    /// Attachment id of each slot (the bit of [`Fired`]).
    slots: RefCell<Slots>,
    busy_poll: bool,
}

impl Waiter {
    /// A waiter; with `busy_poll` it spins (non-blocking polls) instead of
    /// sleeping in the kernel: lower latency, one core at 100 %.
    pub fn new(busy_poll: bool) -> Result<Self, WaitError> {
        let ws = WaitSetBuilder::new()
            .create::<ipc::Service>()
            .map_err(WaitError::Create)?;
        Ok(Self {
            ws,
            slots: RefCell::new([const { None }; MAX_ATTACHMENTS]),
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

    fn free_slot(&self, what: &str) -> Result<u32, WaitError> {
        let full = || WaitError::TooManyAttachments {
            what: what.to_owned(),
            max: MAX_ATTACHMENTS,
        };
        let slots = self.slots.try_borrow().map_err(|_| full())?;
        let i = slots.iter().position(Option::is_none).ok_or_else(full)?;
        u32::try_from(i).map_err(|_| full())
    }

    fn register<'w, 'a>(
        &'w self,
        guard: WaitSetGuard<'w, 'a, ipc::Service>,
        slot: u32,
        what: String,
    ) -> Attachment<'w, 'a> {
        let id = WaitSetAttachmentId::from_guard(&guard);
        if let Ok(mut slots) = self.slots.try_borrow_mut() {
            if let Some(s) = slots.get_mut(slot as usize) {
                *s = Some(id);
            }
        }
        Attachment {
            _guard: guard,
            waiter: self,
            slot,
            what,
        }
    }

    /// Wakes the waiter when `sub`'s topic is published.
    pub fn attach<'w, 'a, T>(&'w self, sub: &'a Sub<T>) -> Result<Attachment<'w, 'a>, WaitError>
    where
        T: ZeroCopySend + Copy + Debug + HasHeader + 'static,
    {
        let what = format!("subscriber {:?}", sub.topic());
        let slot = self.free_slot(&what)?;
        let guard = self
            .ws
            .attach_notification(&sub.listener)
            .map_err(|source| WaitError::Attach {
                what: what.clone(),
                source,
            })?;
        Ok(self.register(guard, slot, what))
    }

    /// Wakes the waiter every `period` (heartbeat, coasting tick).
    pub fn attach_interval(&self, period: Duration) -> Result<Attachment<'_, 'static>, WaitError> {
        if period.is_zero() {
            return Err(WaitError::ZeroInterval(period));
        }
        let what = format!("interval {period:?}");
        let slot = self.free_slot(&what)?;
        let guard = self
            .ws
            .attach_interval(period)
            .map_err(|source| WaitError::Attach {
                what: what.clone(),
                source,
            })?;
        Ok(self.register(guard, slot, what))
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

    fn wait_until(&self, deadline_ns: Option<u64>) -> Result<Wake, WaitError> {
        let mut mask = 0u32;
        loop {
            let slice = if self.busy_poll {
                Duration::ZERO
            } else {
                match deadline_ns {
                    None => Duration::MAX,
                    Some(d) => Duration::from_nanos(d.saturating_sub(monotonic_ns())),
                }
            };
            let r = {
                let slots = self.slots.try_borrow().map_err(|_| WaitError::Reentrant)?;
                self.ws
                    .wait_and_process_once_with_timeout(
                        |id| {
                            if let Some(i) = slots.iter().position(|s| s.as_ref() == Some(&id)) {
                                mask |= 1u32 << i;
                            }
                            CallbackProgression::Continue
                        },
                        slice,
                    )
                    .map_err(WaitError::Run)?
            };
            match r {
                WaitSetRunResult::TerminationRequest => return Ok(Wake::Shutdown),
                // EINTR from any signal iceoryx2 captures (SIGCONT, SIGUSR1, ...
                // as well as SIGINT/SIGTERM): the next call's termination check
                // tells SIGINT/SIGTERM from the others.
                WaitSetRunResult::Interrupt => continue,
                WaitSetRunResult::StopRequest | WaitSetRunResult::AllEventsHandled => {}
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
