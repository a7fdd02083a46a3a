//! The final gather on plants (docs/light.md, "The final gather"): where its rays go.
//!
//! A model's LB grid is solved on the model alone and shared by all its instances; at a
//! leaf it holds the cell's mean light, not the light at that leaf in that instance's
//! neighbourhood (the gaps its own neighbours leave, the sunlit leaf next to it). So the
//! renderer gathers the light arriving at a plant point one bounce deep: per camera sample a
//! few rays, cosine-distributed about the shading normal (the reflecting side, `R`) and, for
//! leaves that transmit, about its opposite (`T`); each brings back the sky where it escapes,
//! or what the surface it meets sends back, that surface's direct sunlight (its own shadow
//! ray) plus its LB light. The LB light thus lights the second bounce on; the first is
//! traced through the real geometry of the forest.
//!
//! The directions are a per-pixel Cranley–Patterson rotation of Roberts' R2 sequence in
//! 32-bit fixed point, with a polynomial sine and cosine, so the CPU and `shade.wgsl` draw
//! the same directions from the seed, the pixel and the sample alone (any thread count, any
//! batching).

use glam::Vec3;

/// Gather rays per camera sample on a plant, by default, up to 16 samples per pixel
/// ([`rays_per_sample`]).
pub const DEFAULT_GATHER_RAYS: u32 = 8;
/// The gather rays a pixel's samples share by default ([`rays_per_sample`]).
pub const GATHER_RAYS_PER_PIXEL: u32 = 128;
/// The fewest gather rays per camera sample by default: one ray would take one side of a
/// leaf per sample ([`split`]), which measured worse than two.
pub const MIN_DEFAULT_GATHER_RAYS: u32 = 2;

/// The most gather rays per camera sample.
pub const MAX_GATHER_RAYS: u32 = 256;

/// The default gather rays per camera sample at `rays_per_pixel` samples per pixel: the
/// pixel's [`GATHER_RAYS_PER_PIXEL`] shared by its samples, [`DEFAULT_GATHER_RAYS`] at most
/// and [`MIN_DEFAULT_GATHER_RAYS`] at least (8 up to 16 samples, 4 at 32, 2 from 64 on).
/// At equal gather rays per pixel, more camera samples with fewer rays each lower the
/// error for little more time: on the catalpa, 16 × 8 12.1 %, 32 × 4 10.4 %, 64 × 2 9.4 %
/// of plant error in 3.2, 3.1-3.8 and 4.1 s (docs/PERFORMANCE.md, "Camera samples and
/// gather rays").
pub fn rays_per_sample(rays_per_pixel: u32) -> u32 {
    (GATHER_RAYS_PER_PIXEL / rays_per_pixel.max(1))
        .clamp(MIN_DEFAULT_GATHER_RAYS, DEFAULT_GATHER_RAYS)
}

/// R2's two irrational steps (1/φ₂ and 1/φ₂², φ₂ the plastic number) in 32-bit fixed point.
const R2: [u32; 2] = [3_242_174_889, 2_447_445_413];

/// How sample `sample` of pixel `pixel` splits its `rays` between the front (reflecting)
/// and back (transmitting) hemispheres: half each, rounded to the front, for a surface that
/// transmits; all in front otherwise. A single ray on a surface that transmits takes one
/// side, the pixel's samples alternating from an offset hashed from the seed and the pixel,
/// and counts for both ([`side_weight`]): a side with no ray would drop its light.
pub fn split(rays: u32, transmits: bool, seed: u64, pixel: u32, sample: u32) -> (u32, u32) {
    if !transmits {
        (rays, 0)
    } else if rays == 1 {
        let back = hash32(side_key(seed, pixel, 0) ^ 0x1656_67b1)
            .wrapping_add(sample)
            .is_multiple_of(2);
        if back {
            (0, 1)
        } else {
            (1, 0)
        }
    } else {
        (rays - rays / 2, rays / 2)
    }
}

/// What one side's mean gathered light counts for ([`split`]): 2 where a single ray on a
/// surface that transmits stood for both sides, 1 otherwise.
pub fn side_weight(rays: u32, transmits: bool) -> f32 {
    if transmits && rays == 1 {
        2.0
    } else {
        1.0
    }
}

/// A 32-bit integer hash (Wellons' lowbias32): every output bit depends on every input bit.
pub fn hash32(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^= x >> 16;
    x
}

/// The image pixel's index as the gather rays key it: `y · width + x` in wrapping 32-bit
/// arithmetic (as `shade.wgsl` computes it).
pub fn pixel_key(x: u32, y: u32, width: u32) -> u32 {
    y.wrapping_mul(width).wrapping_add(x)
}

/// The hash of the seed, the pixel and the side that rotates a pixel's gather rays on that
/// side ([`sample_point`], [`traces_sun`]).
fn side_key(seed: u64, pixel: u32, side: u32) -> u32 {
    hash32(
        hash32(pixel ^ hash32(seed as u32 ^ hash32((seed >> 32) as u32)))
            ^ side.wrapping_mul(0x9e37_79b9),
    )
}

/// Point `index` of hemisphere `side` (0 front, 1 back) of pixel `pixel` on the unit square:
/// R2 rotated by a hash of the seed, the pixel and the side. The pixel's `n` samples with
/// `k` rays each on a side use indices `s · k + j`, so they stratify together.
pub fn sample_point(seed: u64, pixel: u32, side: u32, index: u32) -> [f32; 2] {
    let key = side_key(seed, pixel, side);
    let shift = [hash32(key), hash32(key ^ 0x85eb_ca6b)];
    let to_unit = |v: u32| (v >> 8) as f32 * (1.0 / 16_777_216.0);
    [
        to_unit(shift[0].wrapping_add(index.wrapping_mul(R2[0]))),
        to_unit(shift[1].wrapping_add(index.wrapping_mul(R2[1]))),
    ]
}

/// One in this many gather rays traces the sun's shadow ray from what it hits; that one's
/// direct sunlight counts this many times (Russian roulette, unbiased). The hits' direct sun
/// is a small share of the gather's noise and its shadow rays were 40 % of the gather's rays:
/// on the catalpa one in 4 took the frame to 0.80 and the plant error from 11.7 % to 12.1 %
/// (docs/PERFORMANCE.md, "Fewer shadow rays from the gather's hits").
pub const SUN_SHADOW_EVERY: u32 = 4;

/// Whether gather ray `index` of side `side` of pixel `pixel` (numbered as in
/// [`sample_point`]) traces its hit's shadow ray: every [`SUN_SHADOW_EVERY`]th of the
/// pixel's rays on that side, from an offset hashed from the seed, the pixel and the side, so
/// the sun's samples stratify over the pixel as its directions do.
pub fn traces_sun(seed: u64, pixel: u32, side: u32, index: u32) -> bool {
    hash32(side_key(seed, pixel, side) ^ 0x27d4_eb2f)
        .wrapping_add(index)
        .is_multiple_of(SUN_SHADOW_EVERY)
}

/// Two unit vectors completing unit `n` to an orthonormal basis (Duff et al. 2017).
pub fn basis(n: Vec3) -> (Vec3, Vec3) {
    let sign = if n.z >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// `(cos 2πt, sin 2πt)` for `t` in [0, 1), to about 1e-7, from a quadrant and Taylor
/// polynomials in plain f32 arithmetic: `shade.wgsl` computes the same bits (the platforms'
/// own sine and cosine need not agree in their last bits).
pub fn cos_sin_turn(t: f32) -> (f32, f32) {
    let q = (4.0 * t).floor();
    let a = (4.0 * t - q) * 1.570_796_4;
    let a2 = a * a;
    let s = a
        * (1.0
            + a2 * (-0.166_666_67
                + a2 * (0.008_333_334
                    + a2 * (-0.000_198_412_7 + a2 * (2.755_731_9e-6 + a2 * -2.505_210_8e-8)))));
    let c = 1.0
        + a2 * (-0.5
            + a2 * (0.041_666_668
                + a2 * (-0.001_388_888_9
                    + a2 * (2.480_158_8e-5 + a2 * (-2.755_732e-7 + a2 * 2.087_675_8e-9)))));
    match q as i32 {
        0 => (c, s),
        1 => (-s, c),
        2 => (-c, -s),
        _ => (s, -c),
    }
}

/// The direction of square point `u` cosine-distributed about unit `n` (Malley's method:
/// the unit disc lifted to the hemisphere).
pub fn cosine_direction(n: Vec3, u: [f32; 2]) -> Vec3 {
    let r = u[0].sqrt();
    let (c, s) = cos_sin_turn(u[1]);
    let z = (1.0 - u[0]).max(0.0).sqrt();
    let (b1, b2) = basis(n);
    b1 * (r * c) + b2 * (r * s) + n * z
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The share of `count` cosine-distributed directions about `n` that point above the
    /// horizon.
    fn above_horizon(n: Vec3, count: u32, seed: u64, pixel: u32) -> f64 {
        (0..count)
            .filter(|&i| cosine_direction(n, sample_point(seed, pixel, 0, i)).y > 0.0)
            .count() as f64
            / count as f64
    }

    #[test]
    fn the_turn_polynomials_are_cosine_and_sine() {
        for i in 0..=4096 {
            let t = (i as f32 / 4096.0).min(0.999_999_94);
            let (c, s) = cos_sin_turn(t);
            let a = std::f64::consts::TAU * t as f64;
            assert!((c as f64 - a.cos()).abs() < 3e-7, "cos at {t}: {c}");
            assert!((s as f64 - a.sin()).abs() < 3e-7, "sin at {t}: {s}");
        }
    }

    #[test]
    fn directions_are_unit_and_in_the_hemisphere() {
        for n in [
            Vec3::Y,
            -Vec3::Y,
            Vec3::Z,
            -Vec3::Z,
            Vec3::new(0.3, -0.5, 0.81).normalize(),
        ] {
            let (b1, b2) = basis(n);
            for (a, b) in [(b1, b2), (b1, n), (b2, n)] {
                assert!(a.dot(b).abs() < 1e-6, "{n}: {a} · {b}");
            }
            assert!((b1.length() - 1.0).abs() < 1e-6 && (b2.length() - 1.0).abs() < 1e-6);
            for i in 0..256 {
                let d = cosine_direction(n, sample_point(7, 3, 1, i));
                assert!((d.length() - 1.0).abs() < 1e-5, "{d}");
                assert!(d.dot(n) >= 0.0, "{n}: {d}");
            }
        }
    }

    #[test]
    fn cosine_weighting_matches_closed_forms() {
        // A cosine-weighted hemisphere about a normal tilted θ from the zenith has
        // (1 + cos θ) / 2 of its weight above the horizon, and E[cos] = 2/3.
        for theta in [0.0f32, 0.4, 1.0, std::f32::consts::FRAC_PI_2, 2.2] {
            let n = Vec3::new(theta.sin(), theta.cos(), 0.0);
            let want = (1.0 + theta.cos() as f64) / 2.0;
            let got = above_horizon(n, 4096, 11, 12345);
            assert!((got - want).abs() < 0.01, "θ {theta}: {got} vs {want}");
        }
        let n = Vec3::new(0.2, 0.9, -0.3).normalize();
        let mean_cos: f64 = (0..4096)
            .map(|i| cosine_direction(n, sample_point(1, 9, 0, i)).dot(n) as f64)
            .sum::<f64>()
            / 4096.0;
        assert!((mean_cos - 2.0 / 3.0).abs() < 0.005, "{mean_cos}");
    }

    #[test]
    fn few_rays_stratify_better_than_independent_ones() {
        // 64 points (a pixel's 16 samples × 4 rays) on a vertical leaf: the pixels' shares of
        // sky-bound rays scatter far less about 1/2 than binomial noise (σ = 1/16).
        let n = Vec3::X;
        let errs: Vec<f64> = (0..200u32)
            .map(|p| (above_horizon(n, 64, 5, p) - 0.5).powi(2))
            .collect();
        let rms = (errs.iter().sum::<f64>() / errs.len() as f64).sqrt();
        assert!(rms < 0.5 / 16.0, "RMS error {rms}");
    }

    #[test]
    fn one_ray_in_every_n_traces_the_sun() {
        let every = SUN_SHADOW_EVERY;
        for (seed, pixel, side) in [(0, 0, 0), (7, 12345, 1), (u64::MAX, 9, 0)] {
            // Any run of `every` consecutive rays of a pixel's side holds exactly one.
            for start in [0u32, 3, 1000, u32::MAX - 2] {
                let n = (0..every)
                    .filter(|&k| traces_sun(seed, pixel, side, start.wrapping_add(k)))
                    .count();
                assert_eq!(n, 1, "seed {seed} pixel {pixel} side {side} from {start}");
            }
        }
        // Which one depends on the pixel: over many pixels each offset comes up.
        let firsts: std::collections::BTreeSet<u32> = (0..64u32)
            .map(|p| (0..every).find(|&k| traces_sun(5, p, 0, k)).unwrap())
            .collect();
        assert_eq!(firsts.len(), every as usize, "{firsts:?}");
    }

    #[test]
    fn the_default_shares_a_pixels_rays_among_its_samples() {
        let k: Vec<u32> = [1, 4, 16, 24, 32, 48, 64, 128, 4096]
            .iter()
            .map(|&n| rays_per_sample(n))
            .collect();
        assert_eq!(k, [8, 8, 8, 5, 4, 2, 2, 2, 2]);
        assert_eq!(rays_per_sample(0), DEFAULT_GATHER_RAYS);
    }

    #[test]
    fn one_ray_on_a_transmitting_leaf_alternates_sides() {
        // Each side gets every other sample of a pixel, so both hemispheres are gathered
        // (each counting twice) and neither side's light is lost.
        for (seed, pixel) in [(0u64, 0u32), (7, 12345), (u64::MAX, 9)] {
            for s in 0..8u32 {
                let (a, b) = (
                    split(1, true, seed, pixel, s),
                    split(1, true, seed, pixel, s + 1),
                );
                assert_eq!(a.0 + a.1, 1);
                assert_eq!(
                    (a.0, a.1),
                    (b.1, b.0),
                    "seed {seed} pixel {pixel} sample {s}"
                );
            }
        }
        // Which side comes first depends on the pixel.
        let firsts: std::collections::BTreeSet<(u32, u32)> =
            (0..32u32).map(|p| split(1, true, 5, p, 0)).collect();
        assert_eq!(firsts.len(), 2, "{firsts:?}");
    }

    #[test]
    fn points_depend_on_seed_pixel_and_side_only() {
        let p = sample_point(3, 77, 0, 5);
        assert_eq!(p, sample_point(3, 77, 0, 5));
        assert_ne!(p, sample_point(4, 77, 0, 5));
        assert_ne!(p, sample_point(3, 78, 0, 5));
        assert_ne!(p, sample_point(3, 77, 1, 5));
        assert_ne!(p, sample_point(3, 77, 0, 6));
        assert!(p.iter().all(|v| (0.0..1.0).contains(v)));
        assert_eq!(split(8, true, 3, 77, 0), (4, 4));
        assert_eq!(split(5, true, 3, 77, 0), (3, 2));
        assert_eq!(split(5, false, 3, 77, 0), (5, 0));
        assert_eq!(split(1, false, 3, 77, 0), (1, 0));
        assert_eq!((side_weight(1, true), side_weight(1, false)), (2.0, 1.0));
        assert_eq!(side_weight(2, true), 1.0);
        assert_eq!(pixel_key(3, 2, 10), 23);
    }
}
