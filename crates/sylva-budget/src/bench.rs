//! `sylva bench budget`: the budget's two stages timed, medians of several runs: building the
//! stand (its meshes and kd-trees) and tracing each band's photons, with photons and rays per
//! second. A band's rays per second against the same stand's first band, measured in the same
//! run, is the figure that survives a noisy host.

use crate::photons::{trace_budget, BudgetConfig};
use crate::stand::Stand;
use crate::{BudgetError, CanopySpec};
use serde::Serialize;
use std::time::Instant;
use sylva_core::measure::median;

/// One band's photons, timed.
#[derive(Debug, Clone, Serialize)]
pub struct BandBench {
    pub band: String,
    /// Median seconds of the runs.
    pub seconds: f64,
    pub seconds_min: f64,
    pub seconds_max: f64,
    pub photons_per_second: f64,
    /// Rays (photon segments and BRF rays) per second.
    pub rays_per_second: f64,
    /// Rays per photon (the same every run: the seed fixes them).
    pub rays_per_photon: f64,
}

/// The benchmark's report.
#[derive(Debug, Clone, Serialize)]
pub struct BudgetBench {
    pub stand: String,
    pub runs: u32,
    pub photons: u64,
    pub threads: usize,
    pub triangles: usize,
    pub instances: usize,
    /// Median seconds building the stand's meshes and kd-trees.
    pub build_seconds: f64,
    pub bands: Vec<BandBench>,
    /// Median seconds of a whole budget (build and every band).
    pub total_seconds: f64,
}

/// Builds and traces `spec`'s budget `runs` times.
pub fn bench_budget(
    spec: &CanopySpec,
    cfg: &BudgetConfig,
    runs: u32,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<BudgetBench, BudgetError> {
    if !(1..=50).contains(&runs) {
        return Err(BudgetError::invalid("--runs", runs, "must be 1 to 50"));
    }
    cfg.validate()?;
    let mut build = Vec::new();
    let mut total = Vec::new();
    let mut bands: Vec<Vec<f64>> = vec![Vec::new(); spec.bands.len()];
    let mut rays = vec![0u64; spec.bands.len()];
    let (mut triangles, mut instances) = (0, 0);
    for _ in 0..runs {
        let t0 = Instant::now();
        let stand = Stand::build(spec)?;
        let accel = sylva_trace::SceneAccel::from_parts(&stand.models, &stand.instances, None)?;
        build.push(t0.elapsed().as_secs_f64());
        (triangles, instances) = (stand.triangles(), stand.instances.len());
        let result = trace_budget(&stand, &accel, &spec.bands, spec.plot.cyclic, cfg, progress)?;
        for (k, b) in result.iter().enumerate() {
            bands[k].push(b.seconds);
            rays[k] = b.rays;
        }
        total.push(t0.elapsed().as_secs_f64());
    }
    let photons = cfg.photons as f64;
    let bands = spec
        .bands
        .iter()
        .zip(&bands)
        .zip(&rays)
        .map(|((band, secs), &rays)| {
            let (lo, hi) = secs.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &s| {
                (lo.min(s), hi.max(s))
            });
            let seconds = median(secs.clone());
            BandBench {
                band: band.name.clone(),
                seconds,
                seconds_min: lo,
                seconds_max: hi,
                photons_per_second: photons / seconds,
                rays_per_second: rays as f64 / seconds,
                rays_per_photon: rays as f64 / photons,
            }
        })
        .collect();
    Ok(BudgetBench {
        stand: spec.name.clone(),
        runs,
        photons: cfg.photons,
        threads: rayon::current_num_threads(),
        triangles,
        instances,
        build_seconds: median(build),
        bands,
        total_seconds: median(total),
    })
}

impl std::fmt::Display for BudgetBench {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{}: {} leaf triangles, {} instances; {} photons a band, {} threads, medians of {} runs",
            self.stand, self.triangles, self.instances, self.photons, self.threads, self.runs
        )?;
        writeln!(f, "  stand and kd-trees  {:>8.3} s", self.build_seconds)?;
        for b in &self.bands {
            writeln!(
                f,
                "  band {:<12} {:>8.3} s ({:.3}-{:.3}), {:.2} M photons/s, {:.2} M rays/s, {:.2} rays a photon",
                b.band,
                b.seconds,
                b.seconds_min,
                b.seconds_max,
                b.photons_per_second * 1e-6,
                b.rays_per_second * 1e-6,
                b.rays_per_photon
            )?;
        }
        writeln!(f, "  whole budget        {:>8.3} s", self.total_seconds)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::photons::{SunAngles, CHUNK};

    #[test]
    fn the_bench_times_the_budget_it_runs() {
        let spec = CanopySpec::parse(
            "[plot]\nsize = [3.0, 3.0]\n[layer]\nlai = 1.0\nheight = 1.0\n[leaves]\nsize = 0.05\n",
        )
        .unwrap();
        let cfg = BudgetConfig {
            photons: 2 * CHUNK,
            seed: 3,
            sun: SunAngles {
                zenith_deg: 30.0,
                azimuth_deg: 0.0,
            },
            views: Vec::new(),
        };
        let b = bench_budget(&spec, &cfg, 3, &|_| {}).unwrap();
        assert_eq!(b.bands.len(), 2);
        // The rays are the budget's own: the seed fixes them.
        let stand = Stand::build(&spec).unwrap();
        let accel =
            sylva_trace::SceneAccel::from_parts(&stand.models, &stand.instances, None).unwrap();
        let r = trace_budget(&stand, &accel, &spec.bands, true, &cfg, &|_| {}).unwrap();
        for (bench, run) in b.bands.iter().zip(&r) {
            assert_eq!(bench.rays_per_photon, run.rays as f64 / cfg.photons as f64);
            assert!(bench.seconds_min <= bench.seconds && bench.seconds <= bench.seconds_max);
            assert!(bench.rays_per_photon >= 1.0);
        }
        assert!(b.total_seconds >= b.build_seconds);
        assert!(bench_budget(&spec, &cfg, 0, &|_| {}).is_err());
    }
}
