use thiserror::Error;

/// A request for more memory than the machine can give.
#[derive(Debug, Error)]
#[error("{what} needs {} but only {} is available", format_bytes(*.needed), format_bytes(*.available))]
pub struct MemoryError {
    pub what: String,
    pub needed: u64,
    pub available: u64,
}

/// Memory this process may still use: the system's available memory (`MemAvailable` on
/// Linux) as `sysinfo` reports it, or a conservative 4 GiB where it reports none.
pub fn available_memory_bytes() -> u64 {
    let mut system = sysinfo::System::new();
    system.refresh_memory_specifics(sysinfo::MemoryRefreshKind::nothing().with_ram());
    match system.available_memory() {
        0 => 4 << 30,
        bytes => bytes,
    }
}

/// Refuses an allocation of `needed` bytes that would not fit in available memory (keeping a
/// 10 % margin for everything else).
pub fn check_memory(what: &str, needed: u64) -> Result<(), MemoryError> {
    let available = available_memory_bytes();
    if needed > available / 10 * 9 {
        return Err(MemoryError {
            what: what.to_string(),
            needed,
            available,
        });
    }
    Ok(())
}

/// `1536` → `"1.5 KiB"`.
pub fn format_bytes(bytes: u64) -> String {
    const UNITS: [&str; 6] = ["B", "KiB", "MiB", "GiB", "TiB", "PiB"];
    let mut v = bytes as f64;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < UNITS.len() {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{bytes} B")
    } else {
        format!("{v:.1} {}", UNITS[u])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats() {
        assert_eq!(format_bytes(512), "512 B");
        assert_eq!(format_bytes(1536), "1.5 KiB");
        assert_eq!(format_bytes(3 << 30), "3.0 GiB");
    }

    #[test]
    fn absurd_request_is_refused_with_sizes() {
        let e = check_memory("a 100000³ grid", u64::MAX / 2).unwrap_err();
        let msg = e.to_string();
        assert!(msg.contains("a 100000³ grid needs"), "{msg}");
        assert!(check_memory("small", 1024).is_ok());
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn available_memory_is_meminfo_s_mem_available() {
        let meminfo = std::fs::read_to_string("/proc/meminfo").unwrap();
        let kib: u64 = meminfo
            .lines()
            .find_map(|l| l.strip_prefix("MemAvailable:"))
            .and_then(|v| v.split_whitespace().next()?.parse().ok())
            .unwrap();
        // Read at slightly different times: within 1 % of each other.
        let (expected, got) = (kib * 1024, available_memory_bytes());
        assert!(
            got.abs_diff(expected) <= expected / 100,
            "{got} vs {expected}"
        );
    }
}
