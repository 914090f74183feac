//! What the machine offers this process (memory, threads), read from `/proc` through `procfs`;
//! its peak resident set is `lightfold_telemetry::process`'s.

/// Memory this process may use, bytes: the machine's total (`MemTotal`), or its control group's
/// limit (`memory.max`, cgroup v2: a container's or a Slurm job's) where that is lower; 0 when
/// unknown.
pub fn memory_bytes() -> u64 {
    use procfs::Current;
    let total = procfs::Meminfo::current().map_or(0, |m| m.mem_total);
    let limit = std::fs::read_to_string("/sys/fs/cgroup/memory.max")
        .ok()
        .and_then(|s| s.trim().parse::<u64>().ok());
    match limit {
        Some(l) if total == 0 || l < total => l,
        _ => total,
    }
}

/// Threads available to this process (what lavapipe will use unless `LP_NUM_THREADS` says less).
pub fn threads() -> u32 {
    let available = std::thread::available_parallelism().map_or(1, |n| n.get() as u32);
    std::env::var("LP_NUM_THREADS")
        .ok()
        .and_then(|v| v.trim().parse::<u32>().ok())
        .filter(|n| *n > 0)
        .unwrap_or(available)
}

/// This machine, as every process on it sees it: the kernel's boot id (shared by every process,
/// network namespace and container on one kernel, new at every boot), or the host name where it
/// cannot be read. Nodes rendering on the CPU report it (`Capabilities::cpu_host`).
pub fn machine() -> String {
    std::fs::read_to_string("/proc/sys/kernel/random/boot_id")
        .ok()
        .map(|h| h.trim().to_string())
        .filter(|h| !h.is_empty())
        .map_or_else(hostname, |id| format!("boot:{id}"))
}

/// This machine's host name (the kernel's), or "localhost" where it cannot be read.
pub fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .map(|h| h.trim().to_string())
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "localhost".to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn this_machine_has_memory() {
        if std::path::Path::new("/proc/meminfo").exists() {
            assert!(memory_bytes() > 0);
        }
    }
}
