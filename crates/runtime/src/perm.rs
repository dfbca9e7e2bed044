//! Owner-only files: the process umask of a stage and the one iceoryx2
//! shared-memory file that iceoryx2 0.10 makes world-writable.
//!
//! Measured on a group run with iceoryx2 0.10.0 (umask 022): every data,
//! dynamic and event segment in `/dev/shm` is 0600, the node and service
//! records under the root folder 0600 or 0400 and their folders 0750, but
//! the global management segment (`<prefix>…_node.0_10_0.global_mgmt`, the
//! node counter) is 0666 whatever the umask (iceoryx2 opens it to every
//! user on purpose), and the folders and files the stages create themselves
//! (run directory, iceoryx2 root, fusion checkpoint) follow the umask: 0755
//! and 0644. iceoryx2 has no run-time permission setting (only the
//! `dev_permissions` build feature, which opens everything), so a stage
//! sets its umask to 0o077 ([`restrict_umask`]) and narrows that segment to
//! 0600 after creating its node ([`restrict_global_segment`]); the iceoryx2
//! root it creates is then 0700, so the 0750 folders inside it are out of
//! reach of others.

use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};

/// Where Linux keeps POSIX shared memory.
const SHM_DIR: &str = "/dev/shm";
/// Mode of the files the group keeps owner-only.
pub const OWNER_ONLY_FILE: u32 = 0o600;

/// Why [`restrict_global_segment`] failed.
#[derive(Debug, thiserror::Error)]
pub enum RestrictError {
    /// The shared-memory folder cannot be listed.
    #[error("cannot list {SHM_DIR}: {0}")]
    List(std::io::Error),
    /// A file's mode cannot be changed.
    #[error("cannot make {path:?} owner-only: {error}")]
    Chmod {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        error: std::io::Error,
    },
}

/// Sets the process umask to 0o077, so every file and folder this process
/// (and the children it starts afterwards) creates has no group or other
/// bits; returns the previous umask. Call it before creating files: it
/// applies to everything the process creates later (the command line's own
/// output files included).
#[allow(unsafe_code)]
pub fn restrict_umask() -> libc::mode_t {
    // SAFETY: umask(2) only swaps the calling process's file mode creation
    // mask; it has no memory effects, cannot fail and takes a plain integer.
    let previous: libc::mode_t = unsafe { libc::umask(0o077) };
    previous
}

/// Narrows to 0600 every file in `/dev/shm` whose name starts with `prefix`
/// and ends with `suffix` (the global management segment: `suffix` is
/// `iceoryx2::config::Config::global.node.global_mgmt_suffix`) and that has
/// group or other bits. Returns how many it changed. The owner keeps read
/// and write, which is all iceoryx2 needs to open it again.
pub fn restrict_global_segment(prefix: &str, suffix: &str) -> Result<usize, RestrictError> {
    restrict_files_in(Path::new(SHM_DIR), prefix, suffix)
}

/// [`restrict_global_segment`] over the folder `dir`.
fn restrict_files_in(dir: &Path, prefix: &str, suffix: &str) -> Result<usize, RestrictError> {
    let entries = std::fs::read_dir(dir).map_err(RestrictError::List)?;
    let mut changed = 0;
    for entry in entries.filter_map(Result::ok) {
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if !(name.starts_with(prefix) && name.ends_with(suffix)) {
            continue;
        }
        let path = entry.path();
        // The file may be removed by another stage meanwhile: skip it then.
        let Ok(meta) = std::fs::symlink_metadata(&path) else {
            continue;
        };
        if !meta.is_file() || meta.permissions().mode() & 0o077 == 0 {
            continue;
        }
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(OWNER_ONLY_FILE)).map_err(
            |source| RestrictError::Chmod {
                path,
                error: source,
            },
        )?;
        changed += 1;
    }
    Ok(changed)
}

/// Creates `dir` and its missing parents readable by the owner only
/// (0700), as a run directory or an iceoryx2 root should be.
pub fn create_private_dir(dir: &Path) -> std::io::Result<()> {
    use std::os::unix::fs::DirBuilderExt;
    std::fs::DirBuilder::new()
        .recursive(true)
        .mode(0o700)
        .create(dir)
}

/// Whether `path` exists with group or other permission bits.
#[must_use]
pub fn is_shared(path: &Path) -> bool {
    std::fs::metadata(path).is_ok_and(|m| m.permissions().mode() & 0o077 != 0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn private_dirs_are_owner_only_down_to_the_leaf() {
        use std::os::unix::fs::PermissionsExt;
        let base = std::env::temp_dir().join(format!("insuwb-privdir-{}", std::process::id()));
        let leaf = base.join("a").join("b");
        create_private_dir(&leaf).unwrap();
        for d in [&base, &base.join("a"), &leaf] {
            let mode = std::fs::metadata(d).unwrap().permissions().mode() & 0o777;
            assert_eq!(mode, 0o700, "{}", d.display());
        }
        assert!(!is_shared(&leaf));
        create_private_dir(&leaf).unwrap(); // existing: fine
        std::fs::remove_dir_all(&base).unwrap();
    }

    fn mode(p: &Path) -> u32 {
        std::fs::metadata(p).unwrap().permissions().mode() & 0o777
    }

    #[test]
    fn only_matching_files_with_wide_modes_are_narrowed() {
        let dir = std::env::temp_dir().join(format!("insuwb-perm-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let files = [
            ("pfx_abc_node.0_10_0.global_mgmt", 0o666, 0o600),
            ("pfx_def_node.0_10_0.global_mgmt", 0o600, 0o600),
            ("other_node.0_10_0.global_mgmt", 0o666, 0o666),
            ("pfx_abc.data", 0o644, 0o644),
        ];
        for (name, m, _) in files {
            let p = dir.join(name);
            std::fs::write(&p, b"x").unwrap();
            std::fs::set_permissions(&p, std::fs::Permissions::from_mode(m)).unwrap();
        }
        assert_eq!(restrict_files_in(&dir, "pfx_", ".global_mgmt").unwrap(), 1);
        for (name, _, want) in files {
            assert_eq!(mode(&dir.join(name)), want, "{name}");
        }
        assert!(!is_shared(&dir.join("pfx_abc_node.0_10_0.global_mgmt")));
        assert!(is_shared(&dir.join("pfx_abc.data")));
        assert!(!is_shared(&dir.join("missing")));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_restricted_umask_leaves_no_group_or_other_bits() {
        restrict_umask();
        let dir = std::env::temp_dir().join(format!("insuwb-umask-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("d")).unwrap();
        std::fs::write(dir.join("f"), b"x").unwrap();
        assert_eq!(mode(&dir.join("d")), 0o700);
        assert_eq!(mode(&dir.join("f")), 0o600);
        assert_eq!(restrict_umask(), 0o077);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
