//! The memory budget of a process when `--max-memory` is not given (a
//! leaf: the command line, its guards and the watch daemon all ask it).

/// Most the default memory budget ever is (2 GiB): far beyond any real
/// garment's files, small enough that a few processes at once (a daemon's
/// workers) cannot exhaust the machine.
pub const DEFAULT_MAX_MEMORY_CAP: u64 = crate::io::DEFAULT_MAX_MEMORY;

/// The memory budget when `--max-memory` is not given: an eighth of the
/// physical memory (`MemTotal` of /proc/meminfo), at most
/// [`DEFAULT_MAX_MEMORY_CAP`]; the cap itself when the memory is unknown.
pub fn default_max_memory() -> u64 {
    let total = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|t| mem_total(&t));
    default_for(total)
}

/// `MemTotal` of /proc/meminfo text, in bytes.
fn mem_total(meminfo: &str) -> Option<u64> {
    meminfo
        .lines()
        .find_map(|l| l.strip_prefix("MemTotal:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<u64>().ok())
        .map(|kib| kib.saturating_mul(1024))
}

fn default_for(mem_total: Option<u64>) -> u64 {
    mem_total
        .map(|b| b / 8)
        .filter(|&b| b > 0)
        .map_or(DEFAULT_MAX_MEMORY_CAP, |b| b.min(DEFAULT_MAX_MEMORY_CAP))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_budget_is_an_eighth_of_the_memory_and_at_most_2_gib() {
        assert_eq!(
            mem_total("MemTotal:       16384 kB\nMemFree: 1 kB\n"),
            Some(16 << 20)
        );
        assert_eq!(default_for(Some(4 << 30)), 512 << 20);
        assert_eq!(default_for(Some(256 << 30)), 2 << 30);
        assert_eq!(default_for(None), 2 << 30);
        assert_eq!(default_for(Some(0)), 2 << 30);
        assert!(default_max_memory() <= 2 << 30);
    }
}
