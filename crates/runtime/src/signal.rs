//! SIGINT/SIGTERM for a stage process: a termination flag that stays set,
//! and a descriptor that wakes every [`crate::Waiter`] of the process.
//!
//! iceoryx2 0.10 records signals in one slot that the next reader empties
//! (`SignalHandler::termination_requested` swaps it) and that any later
//! captured signal overwrites. The launcher stops a stage with SIGTERM and
//! then SIGCONT (for a stage that is stopped): when the two land on
//! different threads of a stage (the logger's writer thread, say), SIGCONT
//! can overwrite SIGTERM, and the stage never learns it should stop (seen:
//! the logger killed after the launcher's 2 s grace, its receive trace
//! lost). And a signal taken by another thread does not interrupt the
//! loop's `epoll_wait` at all.
//!
//! [`install`] puts a handler in front of iceoryx2's for SIGINT and SIGTERM:
//! it sets a flag no reader clears ([`termination_requested`]), makes an
//! eventfd readable for good (every waiter of the process has it in its epoll
//! set, so the loop wakes whichever thread took the signal), then calls
//! iceoryx2's handler, so iceoryx2's own checks (`Node::wait`) see the
//! signal as before. The handler only stores an atomic and writes eight
//! bytes: both async-signal-safe.

use core::sync::atomic::{AtomicBool, AtomicI32, AtomicUsize, Ordering};
use std::sync::Mutex;

use iceoryx2_bb_posix::signal::SignalHandler;

/// Why the handler could not be installed.
#[derive(Debug, thiserror::Error)]
pub enum SignalError {
    /// `eventfd` failed.
    #[error("cannot create the termination eventfd: {0}")]
    EventFd(std::io::Error),
    /// `sigaction` failed.
    #[error("cannot install the handler of signal {signal}: {error}")]
    Sigaction {
        /// The signal number.
        signal: i32,
        /// The error.
        #[source]
        error: std::io::Error,
    },
}

/// Set by the handler, never cleared.
static TERMINATION: AtomicBool = AtomicBool::new(false);
/// The eventfd the handler writes (-1 before [`install`]).
static WAKE_FD: AtomicI32 = AtomicI32::new(-1);
/// iceoryx2's handlers of SIGINT and SIGTERM (`sighandler_t`), called after ours.
static PREV_INT: AtomicUsize = AtomicUsize::new(0);
static PREV_TERM: AtomicUsize = AtomicUsize::new(0);
/// Serialises [`install`]; `true` once done.
static INSTALLED: Mutex<bool> = Mutex::new(false);

/// Makes the eventfd readable (async-signal-safe: one write(2)).
fn poke(fd: i32) {
    if fd >= 0 {
        let one: u64 = 1;
        // SAFETY: `one` lives for the call; a bad descriptor or a full
        // counter (EAGAIN, the descriptor readable anyway) is harmless.
        #[allow(unsafe_code)]
        unsafe {
            libc::write(fd, core::ptr::from_ref(&one).cast(), 8);
        }
    }
}

extern "C" fn on_termination(signal: libc::c_int) {
    TERMINATION.store(true, Ordering::SeqCst);
    poke(WAKE_FD.load(Ordering::SeqCst));
    let prev = match signal {
        libc::SIGINT => PREV_INT.load(Ordering::SeqCst),
        _ => PREV_TERM.load(Ordering::SeqCst),
    };
    if prev != libc::SIG_DFL && prev != libc::SIG_IGN && prev != libc::SIG_ERR {
        // SAFETY: `prev` is the plain (non-SA_SIGINFO) handler sigaction
        // reported for this signal before ours replaced it.
        #[allow(unsafe_code)]
        unsafe {
            let f = core::mem::transmute::<usize, extern "C" fn(libc::c_int)>(prev);
            f(signal);
        }
    }
}

/// Installs the handler (see the module documentation) once per process;
/// later calls do nothing. After it, SIGINT and SIGTERM no longer end the
/// process: the stage must check [`termination_requested`] (its
/// [`crate::Waiter`] does) and return. A signal that arrived before, and that
/// iceoryx2's handler recorded, counts.
pub fn install() -> Result<(), SignalError> {
    let mut done = INSTALLED
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    if *done {
        return Ok(());
    }
    // iceoryx2's handler first (its first check installs it), so that ours
    // can call it; a termination it recorded already is kept.
    if SignalHandler::termination_requested() {
        TERMINATION.store(true, Ordering::SeqCst);
    }
    // SAFETY: plain system call without pointers.
    #[allow(unsafe_code)]
    let fd = unsafe { libc::eventfd(0, libc::EFD_CLOEXEC | libc::EFD_NONBLOCK) };
    if fd < 0 {
        return Err(SignalError::EventFd(std::io::Error::last_os_error()));
    }
    WAKE_FD.store(fd, Ordering::SeqCst);
    if TERMINATION.load(Ordering::SeqCst) {
        poke(fd);
    }
    for (signal, prev) in [(libc::SIGINT, &PREV_INT), (libc::SIGTERM, &PREV_TERM)] {
        // SAFETY: zeroed sigaction structs are valid; the kernel fills `old`.
        #[allow(unsafe_code)]
        let rc = unsafe {
            let mut old: libc::sigaction = core::mem::zeroed();
            let rc = libc::sigaction(signal, core::ptr::null(), &mut old);
            if rc == 0 {
                let plain = old.sa_flags & libc::SA_SIGINFO == 0;
                prev.store(if plain { old.sa_sigaction } else { 0 }, Ordering::SeqCst);
                let mut new: libc::sigaction = core::mem::zeroed();
                new.sa_sigaction = on_termination as extern "C" fn(libc::c_int) as usize;
                new.sa_mask = old.sa_mask;
                new.sa_flags = old.sa_flags & !(libc::SA_SIGINFO | libc::SA_RESETHAND);
                libc::sigaction(signal, &new, core::ptr::null_mut())
            } else {
                rc
            }
        };
        if rc != 0 {
            return Err(SignalError::Sigaction {
                signal,
                error: std::io::Error::last_os_error(),
            });
        }
    }
    *done = true;
    Ok(())
}

/// True once SIGINT or SIGTERM arrived after [`install`] (or was recorded
/// by iceoryx2 before it). Never reset: every reader, in every thread, sees it.
#[must_use]
pub fn termination_requested() -> bool {
    TERMINATION.load(Ordering::SeqCst)
}

/// The eventfd that becomes readable (for good) on termination, once
/// [`install`] ran.
#[must_use]
pub fn wake_fd() -> Option<i32> {
    let fd = WAKE_FD.load(Ordering::SeqCst);
    (fd >= 0).then_some(fd)
}

/// Waits up to `timeout` for termination: `true` as soon as it arrives,
/// `false` when the time ran out. Wakes early only once [`install`] ran
/// (before, it sleeps the whole `timeout` and then looks at the flag).
#[must_use]
pub fn sleep(timeout: core::time::Duration) -> bool {
    let end =
        crate::monotonic_ns().saturating_add(u64::try_from(timeout.as_nanos()).unwrap_or(u64::MAX));
    loop {
        if termination_requested() {
            return true;
        }
        let now = crate::monotonic_ns();
        if now >= end {
            return false;
        }
        let left = end - now;
        let ts = libc::timespec {
            tv_sec: libc::time_t::try_from(left / 1_000_000_000).unwrap_or(libc::time_t::MAX),
            tv_nsec: libc::c_long::try_from(left % 1_000_000_000).unwrap_or(0),
        };
        // A negative descriptor (not installed) is ignored by ppoll.
        let mut pfd = libc::pollfd {
            fd: WAKE_FD.load(Ordering::SeqCst),
            events: libc::POLLIN,
            revents: 0,
        };
        // SAFETY: `pfd` and `ts` are valid for the call; no signal mask.
        // EINTR and early returns loop back to the checks above.
        #[allow(unsafe_code)]
        unsafe {
            libc::ppoll(&mut pfd, 1, &ts, core::ptr::null());
        }
    }
}

/// Runs `f` with every asynchronous signal blocked in this thread, so that
/// the threads it starts (a library's own: RustDDS's event loop and
/// discovery, an async runtime's workers) inherit the mask: the signals iceoryx2 and insuwb handle (SIGTERM, SIGINT, and the
/// SIGCONT the launcher sends after SIGTERM, among others) then land on the
/// stage's own thread and never interrupt RustDDS's poll, whose event loop
/// ends on EINTR (and the participant with it), or any such thread. Faults (SIGSEGV, SIGBUS,
/// SIGFPE, SIGILL, SIGTRAP, SIGSYS, SIGABRT) stay unblocked. A signal that
/// arrives meanwhile stays pending until the mask is restored.
pub fn with_signals_blocked<T>(f: impl FnOnce() -> T) -> T {
    // SAFETY: a zeroed `sigset_t` is valid storage for `sigfillset`; every
    // pointer is to a local that outlives the call.
    #[allow(unsafe_code)]
    let old = unsafe {
        let mut set: libc::sigset_t = core::mem::zeroed();
        libc::sigfillset(&mut set);
        for sig in [
            libc::SIGSEGV,
            libc::SIGBUS,
            libc::SIGFPE,
            libc::SIGILL,
            libc::SIGTRAP,
            libc::SIGSYS,
            libc::SIGABRT,
        ] {
            libc::sigdelset(&mut set, sig);
        }
        let mut old: libc::sigset_t = core::mem::zeroed();
        (libc::pthread_sigmask(libc::SIG_BLOCK, &set, &mut old) == 0).then_some(old)
    };
    if old.is_none() {
        tracing::warn!(
            "could not block signals for the threads about to start: a signal may land on one of them"
        );
    }
    let out = f();
    if let Some(old) = old {
        // SAFETY: restores the mask read above; the pointers are to locals.
        #[allow(unsafe_code)]
        unsafe {
            libc::pthread_sigmask(libc::SIG_SETMASK, &old, core::ptr::null_mut());
        }
    }
    out
}
