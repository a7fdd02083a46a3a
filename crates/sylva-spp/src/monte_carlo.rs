//! Monte Carlo reference: photons through the slab with Henyey-Greenstein scattering.
//!
//! Analog simulation (a photon is absorbed with probability `1 - albedo` at each collision), so
//! every tally is a count and its standard error is binomial. Photons are split into fixed
//! chunks, each with its own seed derived from the run's seed, and counts are integers: the
//! result depends on the seed only, never on the thread count.

use crate::error::SppError;
use crate::phase::hg_inverse_cdf;
use crate::slab::Slab;
use rayon::prelude::*;
use serde::Serialize;
use sylva_core::SplitMix64;

/// Photons per chunk (the unit of parallel work and of seeding).
const CHUNK: u64 = 16_384;
/// A photon still inside after this many collisions is counted as `unfinished` (only a
/// conservative half-space comes near it).
const MAX_COLLISIONS: u32 = 1_000_000;

/// What to simulate.
#[derive(Clone, Debug, PartialEq)]
pub struct McConfig {
    pub photons: u64,
    pub seed: u64,
    /// Edges of the `|mu|` bands in which leaving photons are binned, ascending in [0, 1].
    pub band_edges: Vec<f64>,
}

impl McConfig {
    /// `photons` photons, five equal `|mu|` bands.
    pub fn new(photons: u64, seed: u64) -> Self {
        Self {
            photons,
            seed,
            band_edges: vec![0.0, 0.2, 0.4, 0.6, 0.8, 1.0],
        }
    }
}

/// A fraction of the photons with its standard error.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct Estimate {
    pub mean: f64,
    pub std_error: f64,
}

impl Estimate {
    fn from_count(count: u64, total: u64) -> Self {
        let n = total as f64;
        let p = count as f64 / n;
        Self {
            mean: p,
            std_error: (p * (1.0 - p) / n).sqrt(),
        }
    }
}

/// Fractions of the incident photons (= of the incident flux) by fate.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct McResult {
    pub photons: u64,
    /// Left through `z = 0` after scattering.
    pub reflectance: Estimate,
    /// Left through `z = w` after at least one scattering.
    pub diffuse_transmittance: Estimate,
    /// Left through `z = w` unscattered (Beer-Lambert: `exp(-σt w / mu0)`).
    pub direct_transmittance: Estimate,
    pub absorbed: Estimate,
    /// Still inside after the collision cap.
    pub unfinished: u64,
    /// Reflectance split by `|mu|` band (edges in the config).
    pub reflect_bands: Vec<Estimate>,
    /// Diffuse transmittance split by `|mu|` band.
    pub transmit_bands: Vec<Estimate>,
}

#[derive(Clone, Debug, Default)]
struct Counts {
    reflected: u64,
    diffuse: u64,
    direct: u64,
    absorbed: u64,
    unfinished: u64,
    reflect_bands: Vec<u64>,
    transmit_bands: Vec<u64>,
}

impl Counts {
    fn zero(bands: usize) -> Self {
        Self {
            reflect_bands: vec![0; bands],
            transmit_bands: vec![0; bands],
            ..Default::default()
        }
    }

    fn add(mut self, other: Counts) -> Counts {
        self.reflected += other.reflected;
        self.diffuse += other.diffuse;
        self.direct += other.direct;
        self.absorbed += other.absorbed;
        self.unfinished += other.unfinished;
        for (a, b) in self.reflect_bands.iter_mut().zip(other.reflect_bands) {
            *a += b;
        }
        for (a, b) in self.transmit_bands.iter_mut().zip(other.transmit_bands) {
            *a += b;
        }
        self
    }
}

/// Simulates `config.photons` photons through `slab`.
pub fn simulate(slab: &Slab, config: &McConfig) -> Result<McResult, SppError> {
    slab.validate()?;
    if !sylva_core::limits::PHOTONS.contains(&config.photons) {
        return Err(SppError::InvalidParameter {
            name: "photons",
            value: config.photons as f64,
            reason: "photons must be 1 to 10^12 (10^12 take most of a day on two cores)",
        });
    }
    let edges = &config.band_edges;
    let edges_ok = edges.len() >= 2
        && edges.windows(2).all(|p| p[0] < p[1])
        && edges[0] >= 0.0
        && edges[edges.len() - 1] <= 1.0;
    if !edges_ok {
        return Err(SppError::InvalidParameter {
            name: "band_edges",
            value: f64::NAN,
            reason: "band edges must be at least two ascending values in [0, 1]",
        });
    }
    let bands = edges.len() - 1;
    let chunks = config.photons.div_ceil(CHUNK);
    let counts = (0..chunks)
        .into_par_iter()
        .map(|c| {
            let start = c * CHUNK;
            let n = CHUNK.min(config.photons - start);
            let mut rng = SplitMix64::for_chunk(config.seed, c);
            let mut counts = Counts::zero(bands);
            for _ in 0..n {
                trace(slab, edges, &mut rng, &mut counts);
            }
            counts
        })
        // Reduced as the chunks finish (integer sums: the order cannot change them), so
        // memory does not grow with the photon count.
        .reduce(|| Counts::zero(bands), Counts::add);
    let total = config.photons;
    Ok(McResult {
        photons: total,
        reflectance: Estimate::from_count(counts.reflected, total),
        diffuse_transmittance: Estimate::from_count(counts.diffuse, total),
        direct_transmittance: Estimate::from_count(counts.direct, total),
        absorbed: Estimate::from_count(counts.absorbed, total),
        unfinished: counts.unfinished,
        reflect_bands: counts
            .reflect_bands
            .iter()
            .map(|&c| Estimate::from_count(c, total))
            .collect(),
        transmit_bands: counts
            .transmit_bands
            .iter()
            .map(|&c| Estimate::from_count(c, total))
            .collect(),
    })
}

fn band_of(edges: &[f64], mu_abs: f64) -> Option<usize> {
    edges
        .windows(2)
        .position(|p| mu_abs >= p[0] && mu_abs <= p[1])
}

/// Follows one photon from the lit face to its fate.
fn trace(slab: &Slab, edges: &[f64], rng: &mut SplitMix64, counts: &mut Counts) {
    let w = slab.thickness;
    let mut z = 0.0;
    // Direction (x, y, z-component = mu); the beam travels in the x-z plane.
    let mut dir = [(1.0 - slab.mu0 * slab.mu0).max(0.0).sqrt(), 0.0, slab.mu0];
    let mut scattered = false;
    for _ in 0..MAX_COLLISIONS {
        let step = -rng.next_f64_open0().ln() / slab.sigma_t;
        let z_next = z + dir[2] * step;
        if z_next < 0.0 {
            counts.reflected += 1;
            if let Some(b) = band_of(edges, dir[2].abs()) {
                counts.reflect_bands[b] += 1;
            }
            return;
        }
        if z_next > w {
            if scattered {
                counts.diffuse += 1;
                if let Some(b) = band_of(edges, dir[2].abs()) {
                    counts.transmit_bands[b] += 1;
                }
            } else {
                counts.direct += 1;
            }
            return;
        }
        z = z_next;
        if rng.next_f64() >= slab.albedo {
            counts.absorbed += 1;
            return;
        }
        scattered = true;
        let cos_t = hg_inverse_cdf(slab.g, rng.next_f64());
        let psi = 2.0 * std::f64::consts::PI * rng.next_f64();
        dir = rotate(dir, cos_t, psi);
    }
    counts.unfinished += 1;
}

/// The direction at angle `acos(cos_t)` from `d`, azimuth `psi` about it.
fn rotate(d: [f64; 3], cos_t: f64, psi: f64) -> [f64; 3] {
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    let (sp, cp) = psi.sin_cos();
    let [ux, uy, uz] = d;
    if uz.abs() > 0.999_999 {
        return [sin_t * cp, sin_t * sp, uz.signum() * cos_t];
    }
    let t = (1.0 - uz * uz).sqrt();
    let out = [
        sin_t * (ux * uz * cp - uy * sp) / t + ux * cos_t,
        sin_t * (uy * uz * cp + ux * sp) / t + uy * cos_t,
        -sin_t * cp * t + uz * cos_t,
    ];
    // Renormalise so rounding never accumulates over long walks.
    let n = (out[0] * out[0] + out[1] * out[1] + out[2] * out[2]).sqrt();
    [out[0] / n, out[1] / n, out[2] / n]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::full::FullModel;

    /// |model - mc| within 4.5 standard errors (several tallies are compared at once) plus the
    /// model's own discretisation error (below 1e-4, see full::tests).
    fn agrees(model: f64, mc: Estimate, what: &str) {
        let tol = 4.5 * mc.std_error + 1e-4;
        assert!(
            (model - mc.mean).abs() <= tol,
            "{what}: model {model:.5} vs MC {:.5} ± {:.5}",
            mc.mean,
            mc.std_error
        );
    }

    #[test]
    fn full_model_agrees_with_monte_carlo() {
        for &(albedo, g, w, deg) in &[
            (0.9, 0.5, 2.0, 30.0),
            (0.99, -0.5, 1.0, 60.0),
            (0.7, 0.0, 3.0, 0.0),
        ] {
            let slab = Slab::with_incidence_deg(1.0, albedo, g, w, deg).unwrap();
            let mc = simulate(&slab, &McConfig::new(300_000, 11)).unwrap();
            let model = FullModel::new(slab).unwrap();
            agrees(model.reflectance(), mc.reflectance, "reflectance");
            agrees(
                model.diffuse_transmittance(),
                mc.diffuse_transmittance,
                "diffuse transmittance",
            );
            agrees(
                slab.direct(w),
                mc.direct_transmittance,
                "direct transmittance",
            );
            let edges = McConfig::new(1, 0).band_edges;
            for b in 0..edges.len() - 1 {
                let up = model
                    .exit_flux_in_band(true, edges[b], edges[b + 1])
                    .unwrap();
                let down = model
                    .exit_flux_in_band(false, edges[b], edges[b + 1])
                    .unwrap();
                agrees(up, mc.reflect_bands[b], "reflected band");
                agrees(down, mc.transmit_bands[b], "transmitted band");
            }
        }
    }

    #[test]
    fn albedo_zero_monte_carlo_is_beer_lambert() {
        let slab = Slab::with_incidence_deg(1.0, 0.0, 0.5, 1.5, 20.0).unwrap();
        let mc = simulate(&slab, &McConfig::new(100_000, 3)).unwrap();
        assert_eq!(mc.reflectance.mean, 0.0);
        assert_eq!(mc.diffuse_transmittance.mean, 0.0);
        agrees(slab.direct(1.5), mc.direct_transmittance, "Beer-Lambert");
    }

    #[test]
    fn result_depends_on_the_seed_only_not_on_threads() {
        let slab = Slab::with_incidence_deg(1.0, 0.9, 0.3, 2.0, 10.0).unwrap();
        let config = McConfig::new(40_000, 99);
        let run = |threads| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| simulate(&slab, &config).unwrap())
        };
        let one = run(1);
        assert_eq!(one, run(3));
        assert_ne!(one, simulate(&slab, &McConfig::new(40_000, 100)).unwrap());
    }

    #[test]
    fn rotation_keeps_the_scattering_angle() {
        let mut rng = SplitMix64::new(5);
        for _ in 0..1000 {
            let mu = 2.0 * rng.next_f64() - 1.0;
            let s = (1.0 - mu * mu).sqrt();
            let phi = 6.0 * rng.next_f64();
            let d = [s * phi.cos(), s * phi.sin(), mu];
            let c = 2.0 * rng.next_f64() - 1.0;
            let o = rotate(d, c, 6.0 * rng.next_f64());
            let dot = d[0] * o[0] + d[1] * o[1] + d[2] * o[2];
            assert!((dot - c).abs() < 1e-9, "{dot} vs {c}");
        }
    }

    #[test]
    fn bad_config_is_an_error() {
        let slab = Slab::with_incidence_deg(1.0, 0.9, 0.3, 2.0, 10.0).unwrap();
        assert!(simulate(&slab, &McConfig::new(0, 1)).is_err());
        let mut c = McConfig::new(10, 1);
        c.band_edges = vec![0.5, 0.2];
        assert!(simulate(&slab, &c).is_err());
    }
}
