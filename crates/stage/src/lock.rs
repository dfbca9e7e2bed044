//! One group per prefix, one process per stage role: exclusive advisory
//! locks (flock(2), through [`std::fs::File::try_lock`]) taken by
//! `insuwb launch` before it touches anything of the group, and by every
//! stage binary before it opens its services.
//!
//! Two launchers of the same group would run two sets of stages on the same
//! iceoryx2 services (the rates double, samples are dropped, each removes
//! the other's "dead" resources); a stage started by hand beside its group
//! would publish a second stream on its role's topics. Both collide through
//! two keys, so each lock is taken twice:
//!
//! - by the prefix, in the shared-memory folder (`/dev/shm/.<prefix>.group.lock`,
//!   `/dev/shm/.<prefix>.stage-<role>.lock`): iceoryx2 names its shared
//!   memory after the prefix alone, so two groups with the same prefix
//!   collide there even with different run directories. The names start
//!   with a dot, which no prefix may hold, so removing a prefix's files
//!   (`insuwb_runtime::cleanup::remove_prefix_files`) never removes a lock,
//!   and they live in the same namespace as the segments they protect;
//! - by the run directory (`<run_dir>/group.lock`, `<run_dir>/stage-<role>.lock`):
//!   two groups with different prefixes but one run directory would share
//!   the fusion checkpoint, the recording and the iceoryx2 root.
//!
//! The prefix lock is taken first: a refused launch has created nothing,
//! not even the run directory. A lock file holds the PID, group name,
//! prefix, run directory and role of its holder (written once the lock is
//! held, never truncated by anyone else), for the refusal's message. The
//! kernel drops a lock when the last descriptor of its open file closes, so
//! a crashed holder never blocks the next start, and a lock file left
//! behind is reused, not obeyed; a clean release removes the file. Files
//! are owner-only (0600), opened without following a symbolic link, and
//! the path is checked to still name the locked file, so a file removed or
//! replaced meanwhile is locked again.
//!
//! ```
//! use insuwb_group::robot::GroupConfig;
//! use insuwb_stage::lock::{GroupLock, LockError};
//!
//! let id = std::process::id();
//! let group = GroupConfig {
//!     name: "doc".into(),
//!     prefix: format!("insuwb_lockdoc{id}_"),
//!     run_dir: std::env::temp_dir().join(format!("insuwb-lockdoc-{id}")),
//! };
//! let held = GroupLock::acquire(&group)?;
//! // A second launcher of the group is refused, naming the first.
//! match GroupLock::acquire(&group) {
//!     Err(LockError::GroupRunning { holder, .. }) => assert_eq!(holder.pid, Some(id)),
//!     other => panic!("not refused: {other:?}"),
//! }
//! drop(held);
//! let again = GroupLock::acquire(&group)?;
//! drop(again);
//! std::fs::remove_dir_all(&group.run_dir)?;
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use std::fs::{File, OpenOptions, TryLockError};
use std::io::{Read, Write};
use std::os::unix::fs::{DirBuilderExt, MetadataExt, OpenOptionsExt};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use insuwb_runtime::cleanup::SHM_DIR;
use insuwb_runtime::MAX_PREFIX_LEN;

use insuwb_group::robot::GroupConfig;

/// How long a stage waits for its role's lock before refusing: its
/// predecessor, SIGKILLed by the launcher, is reaped before the restart, so
/// its lock is free already; the wait only covers a process that is still
/// on its way out.
pub const STAGE_LOCK_WAIT: Duration = Duration::from_secs(1);

/// Role written in the group lock's file.
const LAUNCHER_ROLE: &str = "launcher";
/// Pause between two attempts (lock busy, holder's record not written yet).
const RETRY_PAUSE: Duration = Duration::from_millis(20);
/// Attempts to find the holder's record written before naming it unknown.
const READ_ATTEMPTS: u32 = 10;
/// Attempts to lock a file that keeps being removed or replaced.
const REPLACED_ATTEMPTS: u32 = 50;

/// Who holds a lock, as its lock file says (fields it does not say are
/// this process's own: the same key).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Holder {
    /// Its process id (`None` when the file does not say yet).
    pub pid: Option<u32>,
    /// Its group's name.
    pub group: String,
    /// Its group's service prefix.
    pub prefix: String,
    /// Its group's run directory.
    pub run_dir: PathBuf,
    /// Its role: `launcher`, or the stage's name.
    pub role: String,
}

impl Holder {
    /// The PID as text: the number, or `unknown`.
    #[must_use]
    pub fn pid_text(&self) -> String {
        self.pid
            .map_or_else(|| "unknown".to_owned(), |p| p.to_string())
    }

    /// The record this process writes into a lock it holds.
    fn record(&self) -> String {
        format!(
            "pid={}\ngroup={}\nprefix={}\nrun_dir={}\nrole={}\n",
            self.pid_text(),
            one_line(&self.group),
            one_line(&self.prefix),
            one_line(&self.run_dir.display().to_string()),
            one_line(&self.role),
        )
    }

    /// `mine` with the fields `text` (a lock file's record) states.
    fn parse(text: &str, mine: &Self) -> Self {
        let mut h = Self {
            pid: None,
            ..mine.clone()
        };
        for line in text.lines() {
            let Some((key, value)) = line.split_once('=') else {
                continue;
            };
            match key {
                "pid" => h.pid = value.parse().ok(),
                "group" => h.group = value.to_owned(),
                "prefix" => h.prefix = value.to_owned(),
                "run_dir" => h.run_dir = PathBuf::from(value),
                "role" => h.role = value.to_owned(),
                _ => {}
            }
        }
        h
    }
}

/// A value on one line of a lock file's record.
fn one_line(s: &str) -> String {
    s.replace(['\n', '\r'], " ")
}

/// Why a lock was not taken.
#[derive(Debug, thiserror::Error)]
pub enum LockError {
    /// Another launcher runs a group with this prefix or this run directory.
    #[error(
        "group '{group}' is already running (prefix {prefix}, run dir {run_dir}, launcher PID {pid}; lock {lock}): \
         a second launch would run a second set of stages on the same services; \
         stop it first (SIGINT or SIGTERM to PID {pid}), or give this config another group.prefix and group.run_dir",
        group = .holder.group,
        prefix = .holder.prefix,
        run_dir = .holder.run_dir.display(),
        pid = .holder.pid_text(),
        lock = .lock.display()
    )]
    GroupRunning {
        /// The running launcher.
        holder: Box<Holder>,
        /// The lock file it holds.
        lock: PathBuf,
    },
    /// A process of this role already runs with this prefix or this run directory.
    #[error(
        "stage '{role}' of group '{group}' is already running as PID {pid} (prefix {prefix}, run dir {run_dir}; lock {lock}): \
         a second '{role}' would publish on the same services; stop that process (or its group) first",
        role = .holder.role,
        group = .holder.group,
        prefix = .holder.prefix,
        run_dir = .holder.run_dir.display(),
        pid = .holder.pid_text(),
        lock = .lock.display()
    )]
    StageRunning {
        /// The running stage.
        holder: Box<Holder>,
        /// The lock file it holds.
        lock: PathBuf,
    },
    /// The prefix or role cannot name a lock file.
    #[error(
        "cannot name a lock file after {what} {value:?}: must be 1..={MAX_PREFIX_LEN} ASCII letters, digits, '_' or '-'"
    )]
    Name {
        /// `group.prefix` or `stage role`.
        what: &'static str,
        /// The rejected value.
        value: String,
    },
    /// A lock file (or the run directory) cannot be created, opened, locked or written.
    #[error("cannot lock {path}: {error}", path = .path.display())]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The operating system's error.
        error: std::io::Error,
    },
}

/// A lock file this process holds; released (and removed, when it is still
/// the file at its path) on drop.
#[derive(Debug)]
struct Held {
    path: PathBuf,
    file: File,
}

impl Drop for Held {
    fn drop(&mut self) {
        // Removed while still locked: a process that opened it meanwhile
        // sees it gone once it gets the lock, and locks a new file.
        if names_file(&self.path, &self.file) {
            let _ = std::fs::remove_file(&self.path);
        }
        let _ = self.file.unlock();
    }
}

/// The group lock a launcher holds while its group runs (see the module
/// documentation); released when dropped or when the process ends.
#[derive(Debug)]
pub struct GroupLock {
    // Dropped in order: run directory first, then prefix (the reverse of
    // taking them).
    _locks: [Held; 2],
}

impl GroupLock {
    /// Takes the group's locks (prefix first, then run directory, which is
    /// created 0700 when missing), without waiting: refuses with
    /// [`LockError::GroupRunning`] while another launcher holds either.
    pub fn acquire(group: &GroupConfig) -> Result<Self, LockError> {
        let mine = Holder {
            pid: Some(std::process::id()),
            group: group.name.clone(),
            prefix: group.prefix.clone(),
            run_dir: group.run_dir.clone(),
            role: LAUNCHER_ROLE.to_owned(),
        };
        let busy = |holder, lock| LockError::GroupRunning { holder, lock };
        let [by_prefix, by_dir] = group_lock_paths(group)?;
        let prefix_lock = take(&by_prefix, &mine, Duration::ZERO, busy)?;
        create_run_dir(&group.run_dir)?;
        let dir_lock = take(&by_dir, &mine, Duration::ZERO, busy)?;
        Ok(Self {
            _locks: [dir_lock, prefix_lock],
        })
    }
}

/// The lock a stage process holds for its role while it runs (see the
/// module documentation); released when dropped or when the process ends.
#[derive(Debug)]
pub struct StageLock {
    _locks: [Held; 2],
}

impl StageLock {
    /// Takes the locks of stage `role` of the group (prefix first, then run
    /// directory, which is created 0700 when missing), waiting up to
    /// `wait` for each: refuses with [`LockError::StageRunning`] while
    /// another process holds either.
    pub fn acquire(group: &GroupConfig, role: &str, wait: Duration) -> Result<Self, LockError> {
        let mine = Holder {
            pid: Some(std::process::id()),
            group: group.name.clone(),
            prefix: group.prefix.clone(),
            run_dir: group.run_dir.clone(),
            role: role.to_owned(),
        };
        let busy = |holder, lock| LockError::StageRunning { holder, lock };
        let [by_prefix, by_dir] = stage_lock_paths(group, role)?;
        let prefix_lock = take(&by_prefix, &mine, wait, busy)?;
        create_run_dir(&group.run_dir)?;
        let dir_lock = take(&by_dir, &mine, wait, busy)?;
        Ok(Self {
            _locks: [dir_lock, prefix_lock],
        })
    }
}

/// The group lock files: by prefix (in the shared-memory folder) and in the
/// run directory.
pub fn group_lock_paths(group: &GroupConfig) -> Result<[PathBuf; 2], LockError> {
    check_name("group.prefix", &group.prefix)?;
    Ok([
        Path::new(SHM_DIR).join(format!(".{}.group.lock", group.prefix)),
        group.run_dir.join("group.lock"),
    ])
}

/// The lock files of stage `role`: by prefix (in the shared-memory folder)
/// and in the run directory.
pub fn stage_lock_paths(group: &GroupConfig, role: &str) -> Result<[PathBuf; 2], LockError> {
    check_name("group.prefix", &group.prefix)?;
    check_name("stage role", role)?;
    Ok([
        Path::new(SHM_DIR).join(format!(".{}.stage-{role}.lock", group.prefix)),
        group.run_dir.join(format!("stage-{role}.lock")),
    ])
}

/// `value` is 1..=[`MAX_PREFIX_LEN`] bytes of `[A-Za-z0-9_-]`.
fn check_name(what: &'static str, value: &str) -> Result<(), LockError> {
    let plain = !value.is_empty()
        && value.len() <= MAX_PREFIX_LEN
        && value
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-');
    if plain {
        Ok(())
    } else {
        Err(LockError::Name {
            what,
            value: value.to_owned(),
        })
    }
}

/// Creates the run directory (0700, parents too) when it is missing.
fn create_run_dir(dir: &Path) -> Result<(), LockError> {
    std::fs::DirBuilder::new()
        .recursive(true)
        .mode(0o700)
        .create(dir)
        .map_err(|source| LockError::Io {
            path: dir.to_owned(),
            error: source,
        })
}

/// Whether `path` (not followed) names the open `file`.
fn names_file(path: &Path, file: &File) -> bool {
    match (std::fs::symlink_metadata(path), file.metadata()) {
        (Ok(p), Ok(f)) => p.file_type().is_file() && p.dev() == f.dev() && p.ino() == f.ino(),
        _ => false,
    }
}

/// Locks the file at `path` (created 0600 when missing) and writes `mine`'s
/// record into it, retrying for `wait` while another process holds it;
/// `busy` makes the refusal from the holder's record.
fn take(
    path: &Path,
    mine: &Holder,
    wait: Duration,
    busy: impl Fn(Box<Holder>, PathBuf) -> LockError,
) -> Result<Held, LockError> {
    let io = |source| LockError::Io {
        path: path.to_owned(),
        error: source,
    };
    let deadline = Instant::now() + wait;
    let mut replaced = 0;
    loop {
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .mode(0o600)
            .custom_flags(libc::O_NOFOLLOW)
            .open(path)
            .map_err(io)?;
        match file.try_lock() {
            Ok(()) => {
                if !names_file(path, &file) {
                    // Removed or replaced between open and lock: lock the
                    // file that is there now.
                    replaced += 1;
                    if replaced >= REPLACED_ATTEMPTS {
                        return Err(io(std::io::Error::other(
                            "the lock file keeps being removed or replaced",
                        )));
                    }
                    continue;
                }
                let mut held = Held {
                    path: path.to_owned(),
                    file,
                };
                held.file.set_len(0).map_err(io)?;
                held.file.write_all(mine.record().as_bytes()).map_err(io)?;
                return Ok(held);
            }
            Err(TryLockError::WouldBlock) if Instant::now() < deadline => {
                std::thread::sleep(RETRY_PAUSE);
            }
            Err(TryLockError::WouldBlock) => {
                return Err(busy(Box::new(read_holder(&file, mine)), path.to_owned()));
            }
            Err(TryLockError::Error(e)) => return Err(io(e)),
        }
    }
}

/// The holder's record in the locked `file` (it writes it just after taking
/// the lock: a few short retries while it is not there yet).
fn read_holder(file: &File, mine: &Holder) -> Holder {
    let mut holder = Holder::parse("", mine);
    for attempt in 0..READ_ATTEMPTS {
        let mut text = String::new();
        // Reads from the start: a positioned read leaves nothing to seek.
        let mut f = file;
        if std::io::Seek::rewind(&mut f).is_ok() && f.read_to_string(&mut text).is_ok() {
            holder = Holder::parse(&text, mine);
            if holder.pid.is_some() {
                break;
            }
        }
        if attempt + 1 < READ_ATTEMPTS {
            std::thread::sleep(RETRY_PAUSE);
        }
    }
    holder
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

    use super::*;

    fn group(tag: &str) -> GroupConfig {
        let id = std::process::id();
        GroupConfig {
            name: format!("g{tag}"),
            prefix: format!("insuwb_locktest{id}{tag}_"),
            run_dir: std::env::temp_dir().join(format!("insuwb-locktest-{id}-{tag}")),
        }
    }

    #[test]
    fn a_second_group_with_the_same_prefix_or_run_dir_is_refused() {
        let g = group("a");
        let held = GroupLock::acquire(&g).unwrap();
        // Same prefix, another run directory.
        let mut other = group("b");
        other.prefix = g.prefix.clone();
        let e = GroupLock::acquire(&other).unwrap_err();
        let LockError::GroupRunning { holder, lock } = &e else {
            panic!("{e}");
        };
        assert_eq!(holder.pid, Some(std::process::id()));
        assert_eq!(holder.run_dir, g.run_dir);
        assert!(lock.starts_with(SHM_DIR), "{}", lock.display());
        // The refusal created nothing: not the other run directory.
        assert!(!other.run_dir.exists());
        let text = e.to_string();
        assert!(text.contains("group 'ga' is already running"), "{text}");
        // Same run directory, another prefix.
        let mut other = group("c");
        other.run_dir = g.run_dir.clone();
        let e = GroupLock::acquire(&other).unwrap_err();
        let LockError::GroupRunning { lock, .. } = &e else {
            panic!("{e}");
        };
        assert_eq!(lock, &g.run_dir.join("group.lock"));
        drop(held);
        // Released and removed: both files are gone, and it can be taken again.
        for p in group_lock_paths(&g).unwrap() {
            assert!(!p.exists(), "{}", p.display());
        }
        drop(GroupLock::acquire(&g).unwrap());
        std::fs::remove_dir_all(&g.run_dir).unwrap();
    }

    #[test]
    fn a_left_over_lock_file_does_not_block() {
        let g = group("d");
        std::fs::create_dir_all(&g.run_dir).unwrap();
        let paths = group_lock_paths(&g).unwrap();
        for p in &paths {
            std::fs::write(p, "pid=1\ngroup=stale\n").unwrap();
        }
        let held = GroupLock::acquire(&g).unwrap();
        let text = std::fs::read_to_string(&paths[1]).unwrap();
        assert!(
            text.starts_with(&format!("pid={}\n", std::process::id())),
            "{text}"
        );
        drop(held);
        std::fs::remove_dir_all(&g.run_dir).unwrap();
    }

    #[test]
    fn a_second_stage_of_a_role_is_refused_after_the_wait() {
        let g = group("e");
        let held = StageLock::acquire(&g, "ins", Duration::ZERO).unwrap();
        // Another role is free.
        let fusion = StageLock::acquire(&g, "fusion", Duration::ZERO).unwrap();
        let t = Instant::now();
        let e = StageLock::acquire(&g, "ins", Duration::from_millis(100)).unwrap_err();
        assert!(t.elapsed() >= Duration::from_millis(100));
        let text = e.to_string();
        assert!(
            text.contains(&format!(
                "stage 'ins' of group 'ge' is already running as PID {}",
                std::process::id()
            )),
            "{text}"
        );
        drop((held, fusion));
        drop(StageLock::acquire(&g, "ins", Duration::ZERO).unwrap());
        std::fs::remove_dir_all(&g.run_dir).unwrap();
    }

    #[test]
    fn names_that_make_no_file_name_are_refused() {
        let mut g = group("f");
        g.prefix = "../x".into();
        assert!(matches!(
            GroupLock::acquire(&g),
            Err(LockError::Name { .. })
        ));
        let g = group("f");
        assert!(matches!(
            StageLock::acquire(&g, "a/b", Duration::ZERO),
            Err(LockError::Name { .. })
        ));
        assert!(!g.run_dir.exists());
    }

    #[test]
    fn a_record_round_trips() {
        let h = Holder {
            pid: Some(42),
            group: "robot".into(),
            prefix: "p_".into(),
            run_dir: PathBuf::from("/tmp/r"),
            role: "ins".into(),
        };
        let other = Holder {
            pid: None,
            group: String::new(),
            prefix: String::new(),
            run_dir: PathBuf::new(),
            role: String::new(),
        };
        assert_eq!(Holder::parse(&h.record(), &other), h);
        assert_eq!(Holder::parse("", &h).pid, None);
    }
}
