//! The process's resident memory, from Linux `/proc/self/status` (0 where unavailable), and the
//! memory a run may still take: the machine's available memory, or less where the process's
//! control group sets a lower limit.

/// Peak resident set size (`VmHWM`).
pub fn peak_rss_bytes() -> u64 {
    proc_status_bytes("VmHWM:")
}

/// Resident set size now (`VmRSS`).
pub fn rss_bytes() -> u64 {
    proc_status_bytes("VmRSS:")
}

fn proc_status_bytes(key: &str) -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with(key))
                .and_then(|l| l.split_whitespace().nth(1))
                .and_then(|kb| kb.parse::<u64>().ok())
        })
        .map_or(0, |kb| kb * 1024)
}

/// The soft limit on this process's address space (`ulimit -v`, `RLIMIT_AS`); `None` where
/// there is none.
fn address_space_limit() -> Option<u64> {
    let limits = std::fs::read_to_string("/proc/self/limits").ok()?;
    // "Max address space    unlimited    unlimited    bytes"
    limits
        .lines()
        .find(|l| l.starts_with("Max address space"))?
        .trim_start_matches("Max address space")
        .split_whitespace()
        .next()?
        .parse::<u64>()
        .ok()
}

/// Whether this process's address space is limited (`ulimit -v`).
pub fn address_space_limited() -> bool {
    address_space_limit().is_some()
}

/// The address-space limit less the address space this process already maps (`VmSize`);
/// `None` where there is no limit.
fn address_space_left() -> Option<u64> {
    Some(address_space_limit()?.saturating_sub(proc_status_bytes("VmSize:")))
}

/// For a message about a failure to allocate or to start a thread: where the process's address
/// space is limited (`ulimit -v`, as batch systems set it for a job's memory), a note saying so,
/// since that limit, not the machine's memory, is then the likely cause; empty otherwise.
pub fn address_space_note() -> String {
    match address_space_limit() {
        Some(limit) => format!(
            " (this process's address space is limited to {} by `ulimit -v`, and it maps {} \
             already, mostly its libraries: raise the limit)",
            size(limit),
            size(proc_status_bytes("VmSize:"))
        ),
        None => String::new(),
    }
}

/// Memory this process can still take: `MemAvailable` of `/proc/meminfo`, or less where the
/// cgroup (v2) limit `memory.max` minus `memory.current`, or the address space left under
/// `ulimit -v`, is lower. `None` where none is known.
pub fn available_bytes() -> Option<u64> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok().and_then(|s| {
        s.lines()
            .find(|l| l.starts_with("MemAvailable:"))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|kb| kb.parse::<u64>().ok())
            .map(|kb| kb * 1024)
    });
    let read = |f: &str| {
        std::fs::read_to_string(format!("/sys/fs/cgroup/{f}"))
            .ok()
            .and_then(|s| s.trim().parse::<u64>().ok())
    };
    // "max" (no limit) does not parse: no cgroup bound.
    let cgroup =
        read("memory.max").map(|max| max.saturating_sub(read("memory.current").unwrap_or(0)));
    [meminfo, cgroup, address_space_left()]
        .into_iter()
        .flatten()
        .min()
}

/// `bytes` for a message: "1.6 GB" from a tenth of a gigabyte, else "37 MB" or "512 KB" (a
/// small need and a small limit both read "0.0 GB", which said nothing).
pub fn size(bytes: u64) -> String {
    let b = bytes as f64;
    if b >= 1e8 {
        format!("{:.1} GB", b / 1e9)
    } else if b >= 1e6 {
        format!("{:.0} MB", b / 1e6)
    } else {
        format!("{:.0} KB", (b / 1e3).ceil())
    }
}

/// Room for one more element of `v`, taken fallibly (doubling as `push` does): false where the
/// memory left does not hold it. An allocation that fails aborts the process; the lists a large
/// OBJ grows (its reader's, its mesh's) use this to fail in one line instead.
#[inline]
pub fn grow<T>(v: &mut Vec<T>) -> bool {
    v.len() < v.capacity() || v.try_reserve(v.capacity().max(64)).is_ok()
}

#[cfg(test)]
mod tests {
    #[test]
    fn available_memory_is_known_and_plausible() {
        // Linux always has MemAvailable; a machine that runs the tests has more than 64 MB free
        // and less than 64 TB.
        let a = super::available_bytes().expect("MemAvailable");
        assert!(a > 64 << 20 && a < 64 << 40, "{a}");
    }

    #[test]
    fn sizes_read_in_the_unit_that_shows_them() {
        assert_eq!(super::size(1_600_000_000), "1.6 GB");
        assert_eq!(super::size(100_000_000), "0.1 GB");
        assert_eq!(super::size(37_400_000), "37 MB");
        assert_eq!(super::size(512_000), "512 KB");
        assert_eq!(super::size(1), "1 KB");
    }
}
