//! Optional real-time settings of a stage process: CPU affinity and the
//! SCHED_FIFO scheduling class. Off by default: on a shared 2-core PC
//! pinning and real-time priorities can starve the rest of the system; on a
//! robot PC with cores to spare they keep a stage's wake-up latency down.
//! SCHED_FIFO needs CAP_SYS_NICE (or an RLIMIT_RTPRIO above the priority,
//! e.g. `LimitRTPRIO=` in the systemd unit); a refusal is an error naming
//! the setting, so a robot never runs silently without what it asked for.

/// What a stage asks of the scheduler.
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RealtimeConfig {
    /// CPUs the stage may run on (empty: any).
    pub cpus: Vec<usize>,
    /// SCHED_FIFO priority, 1 (lowest) to 99 (None: the normal scheduler).
    pub fifo_priority: Option<i32>,
}

/// Why a real-time setting could not be applied.
#[derive(Debug, thiserror::Error)]
pub enum RealtimeError {
    /// A CPU index beyond what the affinity mask holds.
    #[error("cpu {cpu} is out of range (0..{max})")]
    CpuOutOfRange {
        /// The CPU asked for.
        cpu: usize,
        /// The mask size.
        max: usize,
    },
    /// `sched_setaffinity` refused.
    #[error("cannot pin to cpus {cpus:?}: {error}")]
    Affinity {
        /// The CPUs asked for.
        cpus: Vec<usize>,
        /// The OS's reason.
        error: std::io::Error,
    },
    /// A priority outside 1..=99.
    #[error("SCHED_FIFO priority must be in 1..=99, got {0}")]
    Priority(i32),
    /// `sched_setscheduler` refused (no CAP_SYS_NICE or RLIMIT_RTPRIO).
    #[error("cannot switch to SCHED_FIFO priority {priority}: {error} (needs CAP_SYS_NICE or LimitRTPRIO)")]
    Fifo {
        /// The priority asked for.
        priority: i32,
        /// The OS's reason.
        error: std::io::Error,
    },
}

impl RealtimeConfig {
    /// Checks the values without applying them.
    ///
    /// # Errors
    /// A CPU index beyond the affinity mask, or a priority outside 1..=99.
    pub fn validate(&self) -> Result<(), RealtimeError> {
        let max = 8 * core::mem::size_of::<libc::cpu_set_t>();
        if let Some(&cpu) = self.cpus.iter().find(|&&c| c >= max) {
            return Err(RealtimeError::CpuOutOfRange { cpu, max });
        }
        if let Some(p) = self.fifo_priority {
            if !(1..=99).contains(&p) {
                return Err(RealtimeError::Priority(p));
            }
        }
        Ok(())
    }

    /// Applies the settings to the calling process (its main thread and the
    /// threads it starts afterwards).
    ///
    /// # Errors
    /// [`RealtimeConfig::validate`]'s, or the kernel's refusal.
    pub fn apply(&self) -> Result<(), RealtimeError> {
        self.validate()?;
        if !self.cpus.is_empty() {
            // SAFETY: `set` is a plain bit mask owned by this frame; CPU_SET
            // is given indices checked against its size by `validate`, and
            // sched_setaffinity reads `size_of` bytes of it.
            #[allow(unsafe_code)]
            let rc = unsafe {
                let mut set: libc::cpu_set_t = core::mem::zeroed();
                for &c in &self.cpus {
                    libc::CPU_SET(c, &mut set);
                }
                libc::sched_setaffinity(0, core::mem::size_of::<libc::cpu_set_t>(), &set)
            };
            if rc != 0 {
                return Err(RealtimeError::Affinity {
                    cpus: self.cpus.clone(),
                    error: std::io::Error::last_os_error(),
                });
            }
        }
        if let Some(priority) = self.fifo_priority {
            let param = libc::sched_param {
                sched_priority: priority,
            };
            // SAFETY: `param` is a valid sched_param for the call's duration.
            #[allow(unsafe_code)]
            let rc = unsafe { libc::sched_setscheduler(0, libc::SCHED_FIFO, &param) };
            if rc != 0 {
                return Err(RealtimeError::Fifo {
                    priority,
                    error: std::io::Error::last_os_error(),
                });
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn bad_values_are_refused_before_any_system_call() {
        let c = RealtimeConfig {
            cpus: vec![100_000],
            fifo_priority: None,
        };
        assert!(matches!(
            c.apply(),
            Err(RealtimeError::CpuOutOfRange { cpu: 100_000, .. })
        ));
        let c = RealtimeConfig {
            cpus: vec![],
            fifo_priority: Some(0),
        };
        assert!(matches!(c.apply(), Err(RealtimeError::Priority(0))));
        assert!(RealtimeConfig::default().apply().is_ok());
    }

    #[test]
    fn pinning_to_cpu_0_takes_effect() {
        // In a thread of its own: the affinity is per thread on Linux.
        std::thread::spawn(|| {
            RealtimeConfig {
                cpus: vec![0],
                fifo_priority: None,
            }
            .apply()
            .unwrap();
            let status = std::fs::read_to_string("/proc/thread-self/status").unwrap();
            let line = status
                .lines()
                .find(|l| l.starts_with("Cpus_allowed_list:"))
                .unwrap();
            assert_eq!(line.split_whitespace().nth(1), Some("0"), "{line}");
        })
        .join()
        .unwrap();
    }
}
