//! The machine's memory copy bandwidth, the yardstick for a memory-bound solver.

use std::time::Instant;

use rayon::prelude::*;

/// Median copy bandwidth in GB/s (10⁹ bytes per second), counting bytes read plus bytes
/// written, over `repeats` copies of a `bytes`-sized buffer split across the rayon pool.
/// Counting both directions matches how the solver's effective bandwidth is counted.
pub fn copy_bandwidth_gbs(bytes: usize, repeats: usize) -> f64 {
    let n = bytes / 4;
    // Huge pages as for the solver's states, so both are measured the same way.
    let mut src = crate::alloc::AlignedBuf::zeroed(n);
    src.par_iter_mut()
        .enumerate()
        .for_each(|(i, v)| *v = i as f32);
    let mut dst = crate::alloc::AlignedBuf::zeroed(n);
    let chunk = n.div_ceil(rayon::current_num_threads() * 4).max(1024);
    // First touch outside the timing so page faults are not measured.
    dst.par_chunks_mut(chunk)
        .zip(src.par_chunks(chunk))
        .for_each(|(d, s)| d.copy_from_slice(s));
    let mut times: Vec<f64> = (0..repeats.max(1))
        .map(|_| {
            let t = Instant::now();
            dst.par_chunks_mut(chunk)
                .zip(src.par_chunks(chunk))
                .for_each(|(d, s)| d.copy_from_slice(s));
            std::hint::black_box(&dst);
            t.elapsed().as_secs_f64()
        })
        .collect();
    times.sort_by(f64::total_cmp);
    let median = times[times.len() / 2];
    2.0 * (n * 4) as f64 / median / 1e9
}
