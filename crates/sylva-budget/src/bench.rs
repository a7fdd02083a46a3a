//! `sylva bench budget`: the budget's stages timed, medians of several runs: building the
//! stand (its meshes and kd-trees), tracing each band's photons (photons and rays per
//! second) and, with a lattice configuration, the lattice budget (its traced flights and
//! each band's steps). A band's rays per second against the same stand's first band, measured in the same
//! run, is the figure that survives a noisy host.

use crate::lattice::{lb_budget, LbConfig};
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
    /// The lattice budget's, when asked for.
    pub lattice: Option<LatticeBench>,
    /// Median seconds of a whole budget (build and every band, of each method run).
    pub total_seconds: f64,
}

/// The lattice budget, timed.
#[derive(Debug, Clone, Serialize)]
pub struct LatticeBench {
    pub cell_m: f64,
    pub grid: [usize; 3],
    /// Median seconds binning the leaves and tracing the first flights.
    pub flights_seconds: f64,
    /// Per band: median seconds and the steps (the same every run).
    pub bands: Vec<(String, f64, usize)>,
    /// Median seconds of the lattice budget (flights and every band).
    pub seconds: f64,
}

/// Builds and traces `spec`'s budget `runs` times: the photons' unless `photons` is false,
/// and the lattice's with `lattice`.
pub fn bench_budget(
    spec: &CanopySpec,
    cfg: &BudgetConfig,
    photons: bool,
    lattice: Option<&LbConfig>,
    runs: u32,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<BudgetBench, BudgetError> {
    if !(1..=50).contains(&runs) {
        return Err(BudgetError::invalid("--runs", runs, "must be 1 to 50"));
    }
    cfg.validate()?;
    if let Some(l) = lattice {
        l.validate()?;
    }
    let mut build = Vec::new();
    let mut total = Vec::new();
    let mut bands: Vec<Vec<f64>> = vec![Vec::new(); spec.bands.len()];
    let mut rays = vec![0u64; spec.bands.len()];
    let (mut triangles, mut instances) = (0, 0);
    let (mut lb_flights, mut lb_total) = (Vec::new(), Vec::new());
    let mut lb_bands: Vec<Vec<f64>> = vec![Vec::new(); spec.bands.len()];
    let mut lb_last = None;
    for _ in 0..runs {
        let t0 = Instant::now();
        let stand = Stand::build(spec)?;
        let accel = sylva_trace::SceneAccel::from_parts(&stand.models, &stand.instances, None)?;
        build.push(t0.elapsed().as_secs_f64());
        (triangles, instances) = (stand.triangles(), stand.instances.len());
        if photons {
            let result =
                trace_budget(&stand, &accel, &spec.bands, spec.plot.cyclic, cfg, progress)?;
            for (k, b) in result.iter().enumerate() {
                bands[k].push(b.seconds);
                rays[k] = b.rays;
            }
        }
        if let Some(l) = lattice {
            let t1 = Instant::now();
            let run = lb_budget(spec, &stand, &accel, cfg.sun, l, &|_, _, _| {})?;
            lb_total.push(t1.elapsed().as_secs_f64());
            lb_flights.push(run.build_seconds);
            for (k, b) in run.bands.iter().enumerate() {
                lb_bands[k].push(b.seconds);
            }
            lb_last = Some(run);
        }
        total.push(t0.elapsed().as_secs_f64());
    }
    let lattice = lb_last.map(|run| LatticeBench {
        cell_m: run.cell_m,
        grid: run.grid,
        flights_seconds: median(lb_flights),
        bands: run
            .bands
            .iter()
            .zip(&lb_bands)
            .map(|(b, secs)| (b.band.clone(), median(secs.clone()), b.steps))
            .collect(),
        seconds: median(lb_total),
    });
    let photons = cfg.photons as f64;
    let bands = spec
        .bands
        .iter()
        .zip(&bands)
        .zip(&rays)
        .filter(|((_, secs), _)| !secs.is_empty())
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
        lattice,
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
        if let Some(l) = &self.lattice {
            writeln!(
                f,
                "  lattice, cells of {:.3} m ({}×{}×{}): flights {:.3} s",
                l.cell_m, l.grid[0], l.grid[1], l.grid[2], l.flights_seconds
            )?;
            for (band, seconds, steps) in &l.bands {
                writeln!(
                    f,
                    "  lattice band {band:<8} {seconds:>8.3} s, {steps} steps"
                )?;
            }
            writeln!(f, "  lattice budget      {:>8.3} s", l.seconds)?;
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
            image: None,
        };
        let b = bench_budget(&spec, &cfg, true, None, 3, &|_| {}).unwrap();
        assert_eq!(b.bands.len(), 2);
        assert!(b.lattice.is_none());
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
        assert!(bench_budget(&spec, &cfg, true, None, 0, &|_| {}).is_err());
        // The lattice alone: its steps are the budget's own.
        let lb = LbConfig {
            cell: 0.5,
            ..LbConfig::default()
        };
        let b = bench_budget(&spec, &cfg, false, Some(&lb), 2, &|_| {}).unwrap();
        assert!(b.bands.is_empty());
        let l = b.lattice.unwrap();
        let run = lb_budget(&spec, &stand, &accel, cfg.sun, &lb, &|_, _, _| {}).unwrap();
        for ((band, seconds, steps), r) in l.bands.iter().zip(&run.bands) {
            assert_eq!((band, *steps), (&r.band, r.steps));
            assert!(*seconds > 0.0 && *seconds <= l.seconds);
        }
        // A layer 1 m thick, the stand's top a millimetre over it: 3 rows of 0.5 m.
        assert_eq!(l.grid, [6, 3, 6]);
    }
}
