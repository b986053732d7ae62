//! The real-time settings of `[realtime]`: CPU affinity and `SCHED_FIFO` for the control
//! loop's thread, locked memory for the process. Applied once at start, before the first
//! cycle; a setting the host refuses stops the start with the permission it lacks named, and
//! the unit file's line that grants it.
//!
//! They apply to the calling thread (the gateway's single-threaded runtime: the control
//! loop) and, for `mlockall`, to the whole process. The telemetry writer thread, started
//! before them, keeps the normal policy: its file writes must never compete with the loop.

use rustix::process::{getrlimit, Resource};

pub use crate::config::RealtimeSettings;
use thread_priority::{
    set_thread_priority_and_policy, thread_native_id, RealtimeThreadSchedulePolicy, ThreadPriority,
    ThreadPriorityValue, ThreadSchedulePolicy,
};

/// A setting the host refused.
#[derive(Debug, thiserror::Error)]
pub enum RealtimeError {
    #[error("realtime.cpus = {cpus:?}: cannot run on them ({source}): CPUs online here are {online}")]
    Affinity { cpus: Vec<usize>, online: String, source: std::io::Error },
    #[error(
        "realtime.fifo_priority = {priority}: SCHED_FIFO refused ({source}): the gateway needs CAP_SYS_NICE or an \
         RLIMIT_RTPRIO of at least {priority} (it has {limit}); in the unit: LimitRTPRIO={priority}"
    )]
    Priority { priority: u8, limit: String, source: std::io::Error },
    #[error(
        "realtime.lock_memory: mlockall refused ({source}): the gateway needs CAP_IPC_LOCK or an unlimited \
         RLIMIT_MEMLOCK (it has {limit}); in the unit: LimitMEMLOCK=infinity"
    )]
    LockMemory { limit: String, source: std::io::Error },
}

fn limit(resource: Resource, unit: &str) -> String {
    match getrlimit(resource).current {
        None => "unlimited".into(),
        Some(v) if unit == "bytes" => format!("{} KiB", v / 1024),
        Some(v) => v.to_string(),
    }
}

fn online_cpus() -> String {
    std::fs::read_to_string("/sys/devices/system/cpu/online").map_or_else(|_| "unknown".into(), |s| s.trim().into())
}

/// Apply the settings to the calling thread (and the process, for the memory lock).
pub fn apply(settings: &RealtimeSettings) -> Result<(), RealtimeError> {
    if !settings.cpus.is_empty() {
        let mut set = rustix::thread::CpuSet::new();
        for &cpu in &settings.cpus {
            set.set(cpu);
        }
        rustix::thread::sched_setaffinity(None, &set).map_err(|e| RealtimeError::Affinity {
            cpus: settings.cpus.clone(),
            online: online_cpus(),
            source: e.into(),
        })?;
    }
    if settings.lock_memory {
        use rustix::mm::{mlockall, MlockAllFlags};
        mlockall(MlockAllFlags::CURRENT | MlockAllFlags::FUTURE)
            .map_err(|e| RealtimeError::LockMemory { limit: limit(Resource::Memlock, "bytes"), source: e.into() })?;
    }
    if let Some(priority) = settings.fifo_priority {
        let refused =
            |source: std::io::Error| RealtimeError::Priority { priority, limit: limit(Resource::Rtprio, ""), source };
        let value = ThreadPriorityValue::try_from(priority)
            .map_err(|e| refused(std::io::Error::new(std::io::ErrorKind::InvalidInput, e)))?;
        set_thread_priority_and_policy(
            thread_native_id(),
            ThreadPriority::Crossplatform(value),
            ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo),
        )
        .map_err(|e| {
            refused(match e {
                thread_priority::Error::OS(code) => std::io::Error::from_raw_os_error(code),
                other => std::io::Error::other(other.to_string()),
            })
        })?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_describe_themselves() {
        assert_eq!(RealtimeSettings::default().to_string(), "none");
        let s = RealtimeSettings { cpus: vec![1], fifo_priority: Some(50), lock_memory: true };
        assert_eq!(s.to_string(), "CPUs [1], SCHED_FIFO 50, memory locked");
        assert!(apply(&RealtimeSettings::default()).is_ok(), "nothing asked, nothing refused");
    }

    #[test]
    fn a_cpu_that_is_not_there_is_named() {
        let s = RealtimeSettings { cpus: vec![1000], ..RealtimeSettings::default() };
        let e = apply(&s).unwrap_err().to_string();
        assert!(e.starts_with("realtime.cpus = [1000]: cannot run on them"), "{e}");
        assert!(e.contains("CPUs online here are 0-"), "{e}");
    }
}
