//! The few libc calls std does not offer: signalling a process group,
//! peeking at a child's exit without reaping it, and the parent-death signal.
//! Each is one small function with its own `SAFETY` argument.

use std::io;
use std::os::unix::process::CommandExt;
use std::process::Command;

/// Sends `signal` to every process of the process group `pgid` (`kill(-pgid, signal)`).
///
/// Callers pass the pid of a child they have not reaped yet (each stage leads
/// its own group), so the number cannot have been reused by another process.
pub(crate) fn signal_group(pgid: u32, signal: i32) -> io::Result<()> {
    let pgid = libc::pid_t::try_from(pgid)
        .ok()
        .filter(|&p| p > 1)
        .ok_or_else(|| io::Error::from(io::ErrorKind::InvalidInput))?;
    kill(-pgid, signal)
}

#[allow(unsafe_code)]
fn kill(target: libc::pid_t, signal: i32) -> io::Result<()> {
    // SAFETY: kill(2) takes plain integers and touches no memory of ours; a
    // bad target or signal is reported through errno.
    let rc = unsafe { libc::kill(target, signal) };
    if rc == 0 {
        Ok(())
    } else {
        Err(io::Error::last_os_error())
    }
}

/// True when the child `pid` has terminated, WITHOUT reaping it
/// (`waitid(P_PID, pid, WEXITED | WNOHANG | WNOWAIT)`): the zombie keeps its
/// pid and process-group number reserved while the caller sweeps the group.
/// Stopped children are not "terminated".
#[allow(unsafe_code)]
pub(crate) fn has_terminated(pid: u32) -> io::Result<bool> {
    // SAFETY: siginfo_t is a plain C struct for which all-zero bytes is a
    // valid value (waitid with WNOHANG leaves si_pid 0 when nothing changed).
    let mut info: libc::siginfo_t = unsafe { std::mem::zeroed() };
    // SAFETY: `info` is a valid, writable siginfo_t that outlives the call;
    // the other arguments are plain integers.
    let rc = unsafe {
        libc::waitid(
            libc::P_PID,
            pid,
            &mut info,
            libc::WEXITED | libc::WNOHANG | libc::WNOWAIT,
        )
    };
    if rc != 0 {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: waitid filled `info` (or left it zeroed); si_pid reads the pid
    // field of the SIGCHLD layout, which is what waitid writes.
    Ok(unsafe { info.si_pid() } != 0)
}

/// Makes the child about to be spawned by `cmd` receive SIGKILL when the
/// thread that spawns it exits (`prctl(PR_SET_PDEATHSIG, SIGKILL)`), and exit
/// at once if the launcher already died between fork and exec.
#[allow(unsafe_code)]
pub(crate) fn kill_child_with_parent(cmd: &mut Command) {
    let parent = std::process::id();
    // SAFETY: the closure runs in the forked child before exec and only makes
    // async-signal-safe system calls (prctl, getppid); it allocates nothing
    // and takes no lock.
    unsafe {
        cmd.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                return Err(io::Error::last_os_error());
            }
            if u32::try_from(libc::getppid()).ok() != Some(parent) {
                // The launcher is gone already: fail the exec.
                return Err(io::Error::from_raw_os_error(libc::ESRCH));
            }
            Ok(())
        });
    }
}
