//! What this process costs the machine, read from `/proc` through `procfs` (no unsafe
//! `getrusage` call).

/// Peak resident set of this process in bytes (`VmHWM`), 0 where `/proc` is unavailable.
pub fn peak_rss_bytes() -> u64 {
    procfs::process::Process::myself()
        .and_then(|p| p.status())
        .ok()
        .and_then(|s| s.vmhwm)
        .map_or(0, |kib| kib * 1024)
}

#[cfg(test)]
mod tests {
    #[test]
    fn this_process_has_a_peak() {
        if std::path::Path::new("/proc/self/status").exists() {
            assert!(super::peak_rss_bytes() > 0);
        }
    }
}
