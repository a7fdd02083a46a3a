//! Relighting (paper 004, SPEC §3) in the renderer: the sun moves, nothing is solved.
//!
//! * [`weights`]: [`RelitIllumination`] (the sun in the world, how its weights are formed, the
//!   ambient scale) and the one function from it and an instance's placement to the weights
//!   of the 19 base solutions ([`RelitIllumination::weights`]): the place to extend when the light
//!   gains terms (sky, ground, a direct/scattered split).
//! * [`basis_cache`]: per model, the base solutions as independent jobs on any
//!   [`sylva_lb::LbSolver`] ([`BasisPlan`]), compressed and cached ([`model_basis`]: the
//!   cache lookup, the solves and the store, which a distributed precompute calls apart).
//! * [`global`]: the coarse global grid over the forest (004 §3.2) and the per-instance
//!   scales it gives ([`GlobalLight`]).
//! * [`light`]: [`RelitLight`], the [`crate::IndirectLight`] that combines each instance's
//!   base solutions for the current sun.
//! * [`physical_basis`]: the physical light's bases: per model its 25 sun parts and 3
//!   diffuse parts ([`PhysicalBasis`]), compressed with the codecs above (the sun parts and
//!   the diffuse parts each with its own, [`PhysicalTarget`]) and cached per model.
//! * [`physical`]: the physical light relit: [`physical::PhysicalRelitLight`] weighs each
//!   model's parts per instance for the current sun (with the forest grid's relit weights).

pub mod basis_cache;
pub mod global;
pub mod light;
pub mod physical;
pub mod physical_basis;
pub mod sun_parts;
pub mod weights;

pub use basis_cache::{
    basis_density, basis_key, basis_path, compressed_key, lookup_basis, model_basis, region_of,
    store_basis, BasisCacheOptions, BasisLookup, BasisPlan, BasisReport, ModelBasis, RAW_EXTENSION,
};
pub use global::{
    luminance_medium, GlobalGridOptions, GlobalInstance, GlobalLight, GlobalReport, InstanceScale,
    GLOBAL_EXTENSION,
};
pub use light::{ProjectedLight, RelitLight, StoredBasis};
pub use physical::{BakeSummary, PhysicalBasis, PhysicalRelitLight, DEFAULT_BAKE_BUDGET};
pub use physical_basis::{
    BakedLight, CompressedPhysicalBasis, PhysicalTarget, PhysicalTerms, StoredPhysicalBasis,
};
pub use weights::{RelitIllumination, SunWeights};

/// The 24 sun positions of 004 Table 1's sequence: over 90° about the zenith, along the
/// great circle through the zenith at azimuth `azimuth_deg` (degrees from +x towards +z):
/// from elevation 45° on the far side (azimuth + 180°) through the zenith to elevation 45°
/// at the azimuth, evenly spaced (`n` positions, the first and last at 45°). Unit vectors
/// towards the sun.
pub fn sun_path(n: usize, azimuth_deg: f64) -> Vec<glam::Vec3> {
    let a = azimuth_deg.to_radians();
    (0..n)
        .map(|k| {
            // Angle from the zenith, -45° .. 45°.
            let t = if n > 1 {
                k as f64 / (n - 1) as f64
            } else {
                0.5
            };
            let z = (-45.0 + 90.0 * t).to_radians();
            glam::DVec3::new(z.sin() * a.cos(), z.cos(), z.sin() * a.sin()).as_vec3()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sun_path_spans_90_degrees_about_the_zenith() {
        let p = sun_path(24, 30.0);
        assert_eq!(p.len(), 24);
        let elev = |v: glam::Vec3| v.y.asin().to_degrees();
        assert!((elev(p[0]) - 45.0).abs() < 1e-4 && (elev(p[23]) - 45.0).abs() < 1e-4);
        // The last sun stands at the azimuth, the first opposite it.
        let az = |v: glam::Vec3| v.z.atan2(v.x).to_degrees();
        assert!((az(p[23]) - 30.0).abs() < 1e-3);
        assert!((az(p[0]) - (30.0 - 180.0)).abs() < 1e-3);
        // Consecutive suns are 90°/23 apart, and the path spans 90°.
        for w in p.windows(2) {
            let step = w[0].dot(w[1]).clamp(-1.0, 1.0).acos().to_degrees();
            assert!((step - 90.0 / 23.0).abs() < 1e-3, "{step}");
        }
        let span = p[0].dot(p[23]).acos().to_degrees();
        assert!((span - 90.0).abs() < 1e-3);
        assert!(p
            .iter()
            .all(|v| (v.length() - 1.0).abs() < 1e-6 && v.y > 0.7));
    }
}
