//! What a group's processes hold, read from `/proc` and `/dev/shm`: each
//! process's resident memory and open file descriptors
//! ([`insuwb_bench::cpu::of_process`]), and the group's shared-memory
//! files. `insuwb soak` samples them periodically to show
//! that nothing grows over hours.

use std::path::Path;

pub use insuwb_bench::cpu::{of_process, ProcessResources};

/// Files of a group: those in /dev/shm whose name starts with `prefix`,
/// and every file under its iceoryx2 root `iox_root`.
pub fn group_files(prefix: &str, iox_root: &Path) -> usize {
    let shm = std::fs::read_dir("/dev/shm")
        .map(|d| {
            d.filter_map(Result::ok)
                .filter(|e| e.file_name().to_string_lossy().starts_with(prefix))
                .count()
        })
        .unwrap_or(0);
    fn count(p: &Path) -> usize {
        std::fs::read_dir(p).map_or(0, |d| {
            d.filter_map(Result::ok)
                .map(|e| {
                    if e.path().is_dir() {
                        count(&e.path())
                    } else {
                        1
                    }
                })
                .sum()
        })
    }
    shm + count(iox_root)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    #[test]
    fn this_process_has_memory_and_descriptors_and_a_dead_one_none() {
        let me = of_process(std::process::id()).unwrap();
        assert!(me.rss_kib > 100 && me.rss_anon_kib > 0, "{me:?}");
        assert!(me.rss_anon_kib <= me.rss_kib, "{me:?}");
        assert!(me.fds >= 3, "{me:?}");
        // A pid above the kernel's limit (4194304) is never a process.
        assert_eq!(of_process(5_000_000), None);
    }

    #[test]
    fn group_files_count_the_prefix_and_the_root() {
        let dir = std::env::temp_dir().join(format!("insuwb-res-{}", std::process::id()));
        let sub = dir.join("a/b");
        std::fs::create_dir_all(&sub).unwrap();
        std::fs::write(dir.join("x"), b"").unwrap();
        std::fs::write(sub.join("y"), b"").unwrap();
        let prefix = format!("insuwb_res_test_{}_", std::process::id());
        let shm = Path::new("/dev/shm").join(format!("{prefix}z"));
        let in_shm = std::fs::write(&shm, b"").is_ok();
        assert_eq!(group_files(&prefix, &dir), 2 + usize::from(in_shm));
        let _ = std::fs::remove_file(shm);
        std::fs::remove_dir_all(&dir).unwrap();
        assert_eq!(group_files(&prefix, &dir), 0);
    }
}
