//! The Monte Carlo reference of 003 §4.2: photons from the light through the scene, Lambertian
//! leaves that reflect and transmit alike, and the number of photons that meet each leaf mesh.
//!
//! Photons start uniformly over a [`Beam`] (unit irradiance across it, so each carries
//! `area / photons`) and are traced with the renderer's kd-trees and alpha rule (a photon
//! meeting a transparent texel goes on). At a leaf a photon is reflected with probability
//! `R`, transmitted with probability `T`, else absorbed; the new direction is cosine-weighted
//! about the face it leaves from (Lambert). Wood reflects with probability `wood_reflectance`
//! and never transmits (a stem tube is closed). Analog tallies (integer counts) make the
//! standard errors binomial and the result exact to reproduce: photons run in chunks of
//! [`CHUNK`], each seeded from the run's seed and its index
//! ([`sylva_core::SplitMix64::for_chunk`]), so the result depends on the seed only, never on
//! the thread count. Every photon meeting a leaf mesh is counted there (both faces): the
//! mesh's two-sided irradiance is `count · area_beam / (photons · area_mesh)`.

use super::beam::{frame, Beam};
use super::meshes::SceneMeshes;
use super::TreeError;
use glam::Vec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use sylva_core::SplitMix64;
use sylva_trace::{Ray, SceneAccel, TraceStats, TraversalConfig};

/// Photons per chunk (the unit of parallel work and of seeding).
pub const CHUNK: u64 = 4096;

/// What to simulate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhotonConfig {
    pub photons: u64,
    pub seed: u64,
    /// Probability that a leaf reflects a photon (Lambertian, back to the side it came from).
    pub leaf_reflectance: f64,
    /// Probability that a leaf transmits a photon (Lambertian, to the other side).
    pub leaf_transmittance: f64,
    /// Probability that wood reflects a photon.
    pub wood_reflectance: f64,
    /// A photon still bouncing after this many surfaces is counted as unfinished.
    pub max_bounces: u32,
}

impl PhotonConfig {
    /// Leaves with `R = T = albedo/2` and wood reflecting `albedo` (003 Table 3 sets one
    /// albedo for the whole tree).
    pub fn with_albedo(photons: u64, seed: u64, albedo: f64) -> PhotonConfig {
        PhotonConfig {
            photons,
            seed,
            leaf_reflectance: 0.5 * albedo,
            leaf_transmittance: 0.5 * albedo,
            wood_reflectance: albedo,
            max_bounces: 10_000,
        }
    }

    pub fn validate(&self) -> Result<(), TreeError> {
        if !sylva_core::limits::PHOTONS.contains(&self.photons) {
            return Err(TreeError::invalid(
                "photons",
                self.photons.to_string(),
                "photons must be 1 to 10^12 (10^12 take most of a day on two cores)",
            ));
        }
        for (name, v) in [
            ("leaf reflectance", self.leaf_reflectance),
            ("leaf transmittance", self.leaf_transmittance),
            ("wood reflectance", self.wood_reflectance),
        ] {
            if !(v.is_finite() && (0.0..=1.0).contains(&v)) {
                return Err(TreeError::invalid(name, v.to_string(), "must be in [0, 1]"));
            }
        }
        if self.leaf_reflectance + self.leaf_transmittance > 1.0 + 1e-12 {
            return Err(TreeError::invalid(
                "leaf reflectance + transmittance",
                (self.leaf_reflectance + self.leaf_transmittance).to_string(),
                "must not exceed 1 (a leaf cannot give out more light than it receives)",
            ));
        }
        if self.max_bounces == 0 {
            return Err(TreeError::invalid(
                "max bounces",
                "0".into(),
                "must be at least 1",
            ));
        }
        Ok(())
    }
}

/// Counts of a run.
#[derive(Debug, Clone, PartialEq)]
pub struct PhotonTally {
    pub photons: u64,
    /// Photons meeting each leaf mesh, split by the parity of their chunk (two independent
    /// halves of the run, for an estimate of the noise); the total is their sum.
    pub hits: [Vec<u32>; 2],
    /// Photons meeting each leaf mesh before any scattering (the direct light).
    pub first_hits: Vec<u32>,
    /// Left the scene.
    pub escaped: u64,
    /// Absorbed by leaves and by wood.
    pub absorbed_leaves: u64,
    pub absorbed_wood: u64,
    /// Still bouncing after `max_bounces`.
    pub unfinished: u64,
    /// Surface interactions on leaves and on wood.
    pub leaf_hits: u64,
    pub wood_hits: u64,
    /// Power per photon: the beam's area over the photon count.
    pub power_per_photon: f64,
}

impl PhotonTally {
    /// Photons meeting mesh `m` in the whole run.
    pub fn total_hits(&self, m: usize) -> u64 {
        self.hits[0][m] as u64 + self.hits[1][m] as u64
    }
}

/// A direction cosine-distributed about unit `n`.
fn lambert(n: Vec3, rng: &mut SplitMix64) -> Vec3 {
    let (a, b) = frame(n);
    let u1 = rng.next_f64();
    let phi = 2.0 * std::f64::consts::PI * rng.next_f64();
    let r = u1.sqrt();
    let (x, y, z) = (r * phi.cos(), r * phi.sin(), (1.0 - u1).max(0.0).sqrt());
    (a * x as f32 + b * y as f32 + n * z as f32).normalize()
}

/// Scalar counts of one chunk.
#[derive(Default)]
struct ChunkCounts {
    escaped: u64,
    absorbed_leaves: u64,
    absorbed_wood: u64,
    unfinished: u64,
    leaf_hits: u64,
    wood_hits: u64,
}

/// Traces `cfg.photons` photons from `beam` through `accel` (its leaf meshes in `meshes`);
/// `progress(n)` hears every finished chunk of `n` photons.
pub fn trace_photons(
    accel: &SceneAccel,
    meshes: &SceneMeshes,
    beam: &Beam,
    cfg: &PhotonConfig,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<PhotonTally, TreeError> {
    cfg.validate()?;
    let total = meshes.total();
    sylva_core::check_memory("the photon tallies of every leaf mesh", total as u64 * 12)?;
    let hits: [Vec<AtomicU32>; 2] = [0, 1].map(|_| (0..total).map(|_| AtomicU32::new(0)).collect());
    let first: Vec<AtomicU32> = (0..total).map(|_| AtomicU32::new(0)).collect();
    let scalars: [AtomicU64; 6] = Default::default();
    let chunks = cfg.photons.div_ceil(CHUNK);
    let (r, t) = (cfg.leaf_reflectance, cfg.leaf_transmittance);
    (0..chunks).into_par_iter().for_each(|c| {
        let n = CHUNK.min(cfg.photons - c * CHUNK);
        let mut rng = SplitMix64::for_chunk(cfg.seed, c);
        let tally = &hits[(c % 2) as usize];
        let mut k = ChunkCounts::default();
        let mut stats = TraceStats::default();
        'photon: for _ in 0..n {
            let u = (2.0 * rng.next_f64() - 1.0) as f32 * beam.half_u;
            let v = (2.0 * rng.next_f64() - 1.0) as f32 * beam.half_v;
            let mut ray = beam.ray(u, v);
            for bounce in 0..cfg.max_bounces {
                let Some(hit) = accel.closest_hit(&ray, TraversalConfig::default(), &mut stats)
                else {
                    k.escaped += 1;
                    continue 'photon;
                };
                let p = ray.at(hit.t);
                let ng = accel.geometric_normal(&hit);
                // The face the photon arrives on.
                let facing = if ng.dot(ray.dir) < 0.0 { ng } else { -ng };
                let group = meshes.group(hit.instance, hit.triangle);
                let x = rng.next_f64();
                let leave = if let Some(m) = meshes.leaf_id(hit.instance, group) {
                    k.leaf_hits += 1;
                    tally[m as usize].fetch_add(1, Ordering::Relaxed);
                    if bounce == 0 {
                        first[m as usize].fetch_add(1, Ordering::Relaxed);
                    }
                    if x < r {
                        facing
                    } else if x < r + t {
                        -facing
                    } else {
                        k.absorbed_leaves += 1;
                        continue 'photon;
                    }
                } else {
                    k.wood_hits += 1;
                    if x < cfg.wood_reflectance {
                        facing
                    } else {
                        k.absorbed_wood += 1;
                        continue 'photon;
                    }
                };
                let eps = 1e-4 * p.abs().max_element().max(1.0);
                ray = Ray::new(p + leave * eps, lambert(leave, &mut rng));
            }
            k.unfinished += 1;
        }
        for (s, v) in scalars.iter().zip([
            k.escaped,
            k.absorbed_leaves,
            k.absorbed_wood,
            k.unfinished,
            k.leaf_hits,
            k.wood_hits,
        ]) {
            s.fetch_add(v, Ordering::Relaxed);
        }
        progress(n);
    });
    let [escaped, absorbed_leaves, absorbed_wood, unfinished, leaf_hits, wood_hits] =
        scalars.map(AtomicU64::into_inner);
    Ok(PhotonTally {
        photons: cfg.photons,
        hits: hits.map(|h| h.into_iter().map(AtomicU32::into_inner).collect()),
        first_hits: first.into_iter().map(AtomicU32::into_inner).collect(),
        escaped,
        absorbed_leaves,
        absorbed_wood,
        unfinished,
        leaf_hits,
        wood_hits,
        power_per_photon: beam.area() / cfg.photons as f64,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trees::synthetic::{plates, single_instance};
    use sylva_geom::Model;

    fn scene(model: Model) -> (Vec<Model>, SceneAccel, SceneMeshes) {
        let models = vec![model];
        let accel = SceneAccel::from_parts(&models, &single_instance(), None).unwrap();
        let meshes = SceneMeshes::new(&models, &accel);
        (models, accel, meshes)
    }

    /// Two-sided irradiance of mesh `m`.
    fn irradiance(t: &PhotonTally, meshes: &SceneMeshes, m: usize) -> f64 {
        t.total_hits(m) as f64 * t.power_per_photon / meshes.models[0].area[m] as f64
    }

    #[test]
    fn two_plates_interreflect_as_in_closed_form() {
        // Wide plates 0.1 apart under a vertical beam: the top one gets the beam and what the
        // bottom one reflects, x = T + R y, y = R x per unit flux, so the bottom plate gets
        // x = T/(1 − R²) and the top one 1 + R T/(1 − R²). Light escaping sideways through
        // the gap is a fraction of order gap/side = 0.5 %.
        let (_, accel, meshes) = scene(plates(20.0, &[1.0, 0.9]));
        assert_eq!(meshes.total(), 2);
        let beam = Beam::covering(&accel, Vec3::NEG_Y).unwrap();
        let cfg = PhotonConfig::with_albedo(200_000, 5, 0.95);
        let t = trace_photons(&accel, &meshes, &beam, &cfg, &|_| {}).unwrap();
        let (r, tr) = (0.475, 0.475);
        let x = tr / (1.0 - r * r);
        let top = irradiance(&t, &meshes, 0);
        let bottom = irradiance(&t, &meshes, 1);
        assert!(
            (top - (1.0 + r * x)).abs() < 0.015 * (1.0 + r * x),
            "top {top}"
        );
        assert!((bottom - x).abs() < 0.015 * x, "bottom {bottom}");
        // The beam alone: every photon over the top plate meets it first, so its first-hit
        // irradiance is 1 up to the binomial error.
        let direct = t.first_hits[0] as f64 * t.power_per_photon / meshes.models[0].area[0] as f64;
        assert!((direct - 1.0).abs() < 0.01, "direct {direct}");
        assert_eq!(
            t.first_hits[1], 0,
            "the bottom plate is in the top one's shadow"
        );
        // Every photon ends somewhere.
        assert_eq!(
            t.escaped + t.absorbed_leaves + t.absorbed_wood + t.unfinished,
            t.photons
        );
        assert_eq!(t.leaf_hits, t.total_hits(0) + t.total_hits(1));
    }

    #[test]
    fn conservative_leaves_absorb_nothing_and_absorption_matches_the_albedo() {
        let (_, accel, meshes) = scene(plates(4.0, &[1.0, 0.5, 0.0]));
        let beam = Beam::covering(&accel, Vec3::new(0.3, -1.0, 0.1)).unwrap();
        let lossless = PhotonConfig::with_albedo(20_000, 2, 1.0);
        let t = trace_photons(&accel, &meshes, &beam, &lossless, &|_| {}).unwrap();
        assert_eq!(t.absorbed_leaves, 0);
        assert_eq!(t.escaped + t.unfinished, t.photons);
        assert_eq!(t.unfinished, 0);
        // With albedo a, each leaf interaction absorbs with probability 1 − a.
        let lossy = PhotonConfig::with_albedo(50_000, 2, 0.6);
        let t = trace_photons(&accel, &meshes, &beam, &lossy, &|_| {}).unwrap();
        let p = 0.4;
        let n = t.leaf_hits as f64;
        let sigma = (n * p * (1.0 - p)).sqrt();
        assert!(
            (t.absorbed_leaves as f64 - p * n).abs() < 4.0 * sigma,
            "{} of {n}",
            t.absorbed_leaves
        );
    }

    #[test]
    fn results_depend_on_the_seed_only() {
        let (_, accel, meshes) = scene(plates(3.0, &[2.0, 1.3, 1.0, 0.2]));
        let beam = Beam::covering(&accel, Vec3::new(-0.2, -1.0, 0.4)).unwrap();
        let cfg = PhotonConfig::with_albedo(3 * CHUNK + 17, 9, 0.9);
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| trace_photons(&accel, &meshes, &beam, &cfg, &|_| {}).unwrap())
        };
        let (a, b) = (run(1), run(3));
        assert_eq!(a, b);
        let other = PhotonConfig { seed: 10, ..cfg };
        let c = trace_photons(&accel, &meshes, &beam, &other, &|_| {}).unwrap();
        assert_ne!(a.hits, c.hits);
    }

    #[test]
    fn bad_configurations_are_errors() {
        let (_, accel, meshes) = scene(plates(1.0, &[0.0]));
        let beam = Beam::covering(&accel, Vec3::NEG_Y).unwrap();
        let good = PhotonConfig::with_albedo(10, 1, 0.5);
        for bad in [
            PhotonConfig { photons: 0, ..good },
            PhotonConfig {
                leaf_reflectance: 0.7,
                leaf_transmittance: 0.6,
                ..good
            },
            PhotonConfig {
                wood_reflectance: f64::NAN,
                ..good
            },
            PhotonConfig {
                max_bounces: 0,
                ..good
            },
        ] {
            assert!(trace_photons(&accel, &meshes, &beam, &bad, &|_| {}).is_err());
        }
    }
}
