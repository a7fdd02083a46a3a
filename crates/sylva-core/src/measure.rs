//! Small statistics of timed runs, and the process's peak memory, for the benchmarks.

/// The median of `v` (the mean of the middle two of an even count); NaN for none.
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    match n {
        0 => f64::NAN,
        _ if n % 2 == 1 => v[n / 2],
        _ => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

/// The index of the median of `v` (the lower one of an even count); 0 for none.
pub fn median_index(v: &[f64]) -> usize {
    let mut idx: Vec<usize> = (0..v.len()).collect();
    idx.sort_by(|&a, &b| v[a].total_cmp(&v[b]));
    idx.get(v.len().saturating_sub(1) / 2).copied().unwrap_or(0)
}

/// Run times in seconds, three decimals, space-separated.
pub fn format_runs(runs: &[f64]) -> String {
    runs.iter()
        .map(|t| format!("{t:.3}"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// Peak resident memory of this process (VmHWM), where /proc exists.
pub fn peak_rss_bytes() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_of_odd_and_even() {
        assert_eq!(median(vec![3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(vec![4.0, 1.0, 3.0, 2.0]), 2.5);
        assert!(median(Vec::new()).is_nan());
    }

    #[test]
    fn median_index_points_at_the_lower_middle() {
        assert_eq!(median_index(&[5.0, 1.0, 3.0]), 2);
        assert_eq!(median_index(&[4.0, 1.0, 3.0, 2.0]), 3);
        assert_eq!(median_index(&[]), 0);
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn peak_rss_is_at_least_a_live_allocation() {
        let block = vec![1u8; 8 << 20];
        std::hint::black_box(&block);
        assert!(peak_rss_bytes().expect("VmHWM on Linux") >= 8 << 20);
    }
}
