//! SIGTERM reaches a stage's wait loop whichever thread takes it, and a
//! SIGCONT right after it (as the launcher sends) does not erase it.
//!
//! One test function: the termination flag is process-wide and never
//! cleared, so the steps run in order in this process of their own.

// Signal masks and kill(2) have no safe wrapper here.
#![allow(unsafe_code)]

use std::time::Duration;

use iceoryx2_bb_posix::signal::SignalHandler;
use insuwb_runtime::{signal, Waiter, Wake};

fn block_in_this_thread(signals: &[i32]) {
    // SAFETY: a zeroed sigset is valid; the calls fill and apply it.
    unsafe {
        let mut set: libc::sigset_t = core::mem::zeroed();
        libc::sigemptyset(&mut set);
        for s in signals {
            libc::sigaddset(&mut set, *s);
        }
        assert_eq!(
            libc::pthread_sigmask(libc::SIG_BLOCK, &set, core::ptr::null_mut()),
            0
        );
    }
}

#[test]
fn sigterm_then_sigcont_on_another_thread_ends_the_wait_and_stays_seen() {
    let waiter = Waiter::new(false).unwrap();
    // Nothing else would end this wait for 30 s.
    let _interval = waiter.attach_interval(Duration::from_secs(30)).unwrap();
    assert!(!signal::termination_requested());

    // Another thread of the process takes both signals, as the logger's
    // writer thread can; the waiting thread blocks them.
    let sender = std::thread::spawn(|| {
        std::thread::sleep(Duration::from_millis(200));
        // To this thread, each handled before raise(3) returns: SIGTERM,
        // then SIGCONT, in that order. SAFETY: plain calls; the handler is
        // installed (Waiter::new).
        unsafe {
            assert_eq!(libc::raise(libc::SIGTERM), 0);
            assert_eq!(libc::raise(libc::SIGCONT), 0);
        }
    });
    block_in_this_thread(&[libc::SIGTERM, libc::SIGCONT]);
    let wake = waiter.wait().unwrap();
    assert!(
        matches!(wake, Wake::Shutdown),
        "the wait ended without the termination: {wake:?}"
    );
    sender.join().unwrap();

    // The flag stays set for every later check and every waiter.
    assert!(signal::termination_requested());
    assert!(matches!(waiter.wait().unwrap(), Wake::Shutdown));
    let other = Waiter::new(false).unwrap();
    let _i = other.attach_interval(Duration::from_secs(30)).unwrap();
    assert!(matches!(other.wait().unwrap(), Wake::Shutdown));
    assert!(signal::sleep(Duration::from_secs(30)));

    // Why the flag is ours: iceoryx2 keeps the last captured signal in one
    // slot, which the SIGCONT after the SIGTERM overwrote (our handler
    // passes both on to iceoryx2's).
    assert!(!SignalHandler::termination_requested());
}
