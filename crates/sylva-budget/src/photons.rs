//! The Monte Carlo budget: photons of unit total power enter the plot's top uniformly along
//! the sun's direction and are followed until the sky or an absorber takes them. At a leaf a
//! photon is reflected with probability r, transmitted with probability t (both Lambertian,
//! about the face it leaves from), else absorbed by the canopy; at the soil (y = 0) it is
//! reflected with probability ρ (Lambertian, upwards), else absorbed by the soil; leaving
//! through the top it is reflected light. In a cyclic plot a photon leaving through a side
//! re-enters through the opposite one in the same direction; in an isolated plot it is lost
//! sideways. This is 003's photon tracer (sylva-spp's `trees::photons`) extended with the
//! soil, the sides and the fates a budget needs.
//!
//! **BRF** (the bidirectional reflectance factor towards a view direction v) by local
//! estimates: at every scattering event the photon's expected contribution towards v is
//! added, whatever its fate: the probability density of leaving towards v (r |n·v|/π on the
//! leaf's lit side, t |n·v|/π through it, ρ cos θ_v/π off the soil) times whether a ray from
//! there towards v reaches the sky (through the cyclic sides). With unit power over the plot's
//! area A the radiance leaving the top towards v is Σ p_v T_v / (N A cos θ_v), and the BRF, π
//! times it over the irradiance 1/A, is π Σ p_v T_v / (N cos θ_v).
//!
//! Analog tallies: every fraction is a mean over independent photons, and its standard
//! error comes from the spread of the means of the chunks of [`CHUNK`] photons. Chunks are
//! seeded from the run's seed, the band and the chunk's index, so a result depends on the
//! seed only, never on the thread count.

pub use crate::angles::{Angles, SunAngles, ViewAngles};
use crate::brf_image::{BrfImage, BrfImageSpec, ImageTally};
use crate::stand::Stand;
use crate::{Band, BudgetError};
use glam::Vec3;
use rayon::prelude::*;
use serde::Serialize;
use sylva_core::SplitMix64;
use sylva_trace::{Ray, SceneAccel, TraceStats, TraversalConfig};

/// Photons per chunk: the unit of parallel work, seeding and the error estimate.
pub const CHUNK: u64 = 4096;
/// A photon still bouncing after this many events (scatterings and side crossings) is
/// counted as unfinished.
pub const MAX_EVENTS: u32 = 100_000;

/// What to simulate.
#[derive(Debug, Clone, PartialEq)]
pub struct BudgetConfig {
    /// Photons per band.
    pub photons: u64,
    pub seed: u64,
    pub sun: SunAngles,
    /// Directions to estimate the BRF towards (none: no BRF).
    pub views: Vec<ViewAngles>,
    /// Also the BRF as an image towards one view ([`crate::brf_image`]).
    pub image: Option<BrfImageSpec>,
}

/// Views a run may estimate the BRF towards (each adds a ray per scattering event).
pub const MAX_VIEWS: usize = 64;

impl BudgetConfig {
    pub fn validate(&self) -> Result<(), BudgetError> {
        if !(2 * CHUNK..=1_000_000_000_000).contains(&self.photons) {
            return Err(BudgetError::invalid(
                "--photons",
                self.photons,
                format!(
                    "must be {} to 10^12 (two chunks of {CHUNK} at least, for the error estimate)",
                    2 * CHUNK
                ),
            ));
        }
        if self.views.len() > MAX_VIEWS {
            return Err(BudgetError::invalid(
                "--brf",
                format!("{} directions", self.views.len()),
                format!("at most {MAX_VIEWS} (each adds a ray per scattering event)"),
            ));
        }
        for v in &self.views {
            v.validate_view()?;
        }
        if let Some(image) = &self.image {
            image.validate()?;
        }
        self.sun.validate_sun()
    }
}

/// The BRF towards one view direction.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ViewBrf {
    pub view: ViewAngles,
    pub brf: Fraction,
}

/// A fraction of the incoming sunlight and its standard error.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Fraction {
    pub value: f64,
    pub std_error: f64,
}

/// One band's budget: fractions of the sunlight entering the plot's top.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BandBudget {
    pub band: String,
    /// Absorbed by the leaves (fAPAR in a PAR band).
    pub canopy_absorbed: Fraction,
    /// Left through the top: the stand's albedo.
    pub reflected: Fraction,
    /// Arriving at the soil, every arrival counted (the downward flux at the ground).
    pub ground_arrived: Fraction,
    /// Arriving at the soil before meeting anything: the direct transmission.
    pub ground_direct: Fraction,
    /// Absorbed by the soil.
    pub soil_absorbed: Fraction,
    /// Lost through the sides (isolated plots only).
    pub side_lost: Fraction,
    /// Still bouncing after [`MAX_EVENTS`] events.
    pub unfinished: Fraction,
    /// Leaf interactions per photon.
    pub leaf_events: f64,
    /// 1 − the sum of the fates: 0 up to rounding (every photon ends in exactly one fate).
    pub balance: f64,
    /// The BRF towards each of the run's views.
    pub brf: Vec<ViewBrf>,
    /// The BRF image, where the run asked for one (not in the JSON: `--brf-image` writes it).
    #[serde(skip)]
    pub image: Option<BrfImage>,
    pub photons: u64,
    pub rays: u64,
    pub seconds: f64,
}

/// Per-chunk sums (fates are counts; arrivals may exceed the photons).
#[derive(Default, Clone)]
struct Counts {
    /// Σ π p_v T_v / cos θ_v per view.
    brf: Vec<f64>,
    canopy: u64,
    reflected: u64,
    arrived: u64,
    direct: u64,
    soil: u64,
    side: u64,
    unfinished: u64,
    leaf_events: u64,
    rays: u64,
}

impl Counts {
    fn fields(&self) -> [u64; 7] {
        [
            self.canopy,
            self.reflected,
            self.arrived,
            self.direct,
            self.soil,
            self.side,
            self.unfinished,
        ]
    }
}

/// A direction cosine-distributed about unit `n`.
fn lambert(n: Vec3, rng: &mut SplitMix64) -> Vec3 {
    let a = if n.x.abs() > 0.9 { Vec3::Y } else { Vec3::X };
    let u = n.cross(a).normalize();
    let v = n.cross(u);
    let u1 = rng.next_f64();
    let phi = std::f64::consts::TAU * rng.next_f64();
    let r = u1.sqrt();
    let (x, y, z) = (r * phi.cos(), r * phi.sin(), (1.0 - u1).max(0.0).sqrt());
    (u * x as f32 + v * y as f32 + n * z as f32).normalize()
}

/// The budget of every band of `bands` for `stand` traced through `accel` (built from the
/// stand's models and instances). `progress(n)` hears every finished chunk of `n` photons.
pub fn trace_budget(
    stand: &Stand,
    accel: &SceneAccel,
    bands: &[Band],
    cyclic: bool,
    cfg: &BudgetConfig,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<Vec<BandBudget>, BudgetError> {
    cfg.validate()?;
    if let Some(s) = &stand.surfaces {
        assert_eq!(
            s.len(),
            bands.len(),
            "a scene's surfaces for each of its bands"
        );
    }
    if let Some(image) = &cfg.image {
        sylva_core::check_memory(
            "the BRF images",
            image.memory_bytes(stand.half, bands.len()),
        )?;
    }
    bands
        .iter()
        .enumerate()
        .map(|(b, band)| {
            let t0 = std::time::Instant::now();
            let chunks = cfg.photons.div_ceil(CHUNK);
            let tally = cfg
                .image
                .map(|spec| ImageTally::new(&spec, stand.half, stand.top));
            let counts: Vec<Counts> = (0..chunks)
                .into_par_iter()
                .map(|c| {
                    let n = CHUNK.min(cfg.photons - c * CHUNK);
                    let seed = cfg.seed ^ (b as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15);
                    let mut rng = SplitMix64::for_chunk(seed, c);
                    let k = trace_chunk(
                        stand,
                        accel,
                        band,
                        cyclic,
                        b,
                        cfg,
                        tally.as_ref(),
                        n,
                        &mut rng,
                    );
                    progress(n);
                    k
                })
                .collect();
            let image = cfg
                .image
                .zip(tally)
                .map(|(spec, t)| t.finish(spec.view, cfg.photons))
                .transpose()?;
            Ok(summarise(
                band,
                &counts,
                cfg,
                image,
                t0.elapsed().as_secs_f64(),
            ))
        })
        .collect()
}

fn summarise(
    band: &Band,
    counts: &[Counts],
    cfg: &BudgetConfig,
    image: Option<BrfImage>,
    seconds: f64,
) -> BandBudget {
    let photons = cfg.photons;
    let n = photons as f64;
    let mean = |get: &dyn Fn(&Counts) -> f64| {
        let total: f64 = counts.iter().map(get).sum();
        let value = total / n;
        // The spread of the chunks' means about the whole mean, weighted by chunk size.
        let m = counts.len() as f64;
        let sizes: Vec<f64> = (0..counts.len())
            .map(|i| CHUNK.min(photons - i as u64 * CHUNK) as f64)
            .collect();
        let var: f64 = counts
            .iter()
            .zip(&sizes)
            .map(|(c, &s)| {
                let d = get(c) / s - value;
                s * s * d * d
            })
            .sum::<f64>()
            / (n * n)
            * m
            / (m - 1.0).max(1.0);
        Fraction {
            value,
            std_error: var.sqrt(),
        }
    };
    let f: Vec<Fraction> = (0..7)
        .map(|k| mean(&|c: &Counts| c.fields()[k] as f64))
        .collect();
    let brf = cfg
        .views
        .iter()
        .enumerate()
        .map(|(v, &view)| ViewBrf {
            view,
            brf: mean(&|c: &Counts| c.brf[v]),
        })
        .collect();
    let fates = f[0].value + f[1].value + f[4].value + f[5].value + f[6].value;
    BandBudget {
        band: band.name.clone(),
        canopy_absorbed: f[0],
        reflected: f[1],
        ground_arrived: f[2],
        ground_direct: f[3],
        soil_absorbed: f[4],
        side_lost: f[5],
        unfinished: f[6],
        leaf_events: counts.iter().map(|c| c.leaf_events).sum::<u64>() as f64 / n,
        balance: 1.0 - fates,
        brf,
        image,
        photons,
        rays: counts.iter().map(|c| c.rays).sum(),
        seconds,
    }
}

/// `n` photons of one band; the estimates towards the image's view also go to `image`.
#[allow(clippy::too_many_arguments)]
fn trace_chunk(
    stand: &Stand,
    accel: &SceneAccel,
    band: &Band,
    cyclic: bool,
    b: usize,
    cfg: &BudgetConfig,
    image: Option<&ImageTally>,
    n: u64,
    rng: &mut SplitMix64,
) -> Counts {
    let travel = cfg.sun.travel();
    let mut view_angles = cfg.views.clone();
    // The image's view: one of the run's views, or one more estimated for the image only.
    let image_view = cfg.image.map(|spec| {
        view_angles
            .iter()
            .position(|&v| v == spec.view)
            .unwrap_or_else(|| {
                view_angles.push(spec.view);
                view_angles.len() - 1
            })
    });
    let views: Vec<(Vec3, f32)> = view_angles
        .iter()
        .map(|v| {
            let v = v.towards();
            (v, v.y)
        })
        .collect();
    let tally = |j: usize, exit: Vec3, v: Vec3, estimate: f64| {
        if let (Some(img), Some(i)) = (image, image_view) {
            if i == j {
                img.add(exit, v, estimate);
            }
        }
    };
    let plot = PlotBox::of(stand);
    let rho = band.soil_albedo;
    let mut k = Counts {
        brf: vec![0.0; views.len()],
        ..Counts::default()
    };
    let mut stats = TraceStats::default();
    'photon: for _ in 0..n {
        let mut o = Vec3::new(
            (2.0 * rng.next_f64() as f32 - 1.0) * plot.hx,
            plot.top,
            (2.0 * rng.next_f64() as f32 - 1.0) * plot.hz,
        );
        let mut d = travel;
        let mut scattered = false;
        for _ in 0..MAX_EVENTS {
            // Where the photon leaves the plot's box: the soil, the top or a side.
            let e = plot.exits(o, d);
            k.rays += 1;
            let ray = Ray::segment(o, d, 0.0, e.end);
            if let Some(hit) = accel.closest_hit(&ray, TraversalConfig::default(), &mut stats) {
                let p = ray.at(hit.t);
                let model = stand.instances[hit.instance as usize].model as usize;
                let material = stand.models[model].mesh.material_ids[hit.triangle as usize];
                let (r, t) = stand.optics(b, band, model, material as usize);
                let ng = accel.geometric_normal(&hit);
                let facing = if ng.dot(d) < 0.0 { ng } else { -ng };
                k.leaf_events += 1;
                let eps = 1e-4 * p.abs().max_element().max(1.0);
                for (j, &(v, mu)) in views.iter().enumerate() {
                    let c = facing.dot(v);
                    let (share, side) = if c > 0.0 { (r, facing) } else { (t, -facing) };
                    if share > 0.0 && c != 0.0 {
                        let from = p + side * eps;
                        if let Some(exit) = reaches_sky(stand, accel, cyclic, from, v, &mut k.rays)
                        {
                            let estimate = share * c.abs() as f64 / mu as f64;
                            k.brf[j] += estimate;
                            tally(j, exit, v, estimate);
                        }
                    }
                }
                scattered = true;
                let x = rng.next_f64();
                let leave = if x < r {
                    facing
                } else if x < r + t {
                    -facing
                } else {
                    k.canopy += 1;
                    continue 'photon;
                };
                o = p + leave * eps;
                d = lambert(leave, rng);
                continue;
            }
            if e.end == e.soil {
                k.arrived += 1;
                if !scattered {
                    k.direct += 1;
                }
                let p = o + d * e.soil;
                let on_soil = Vec3::new(p.x, 0.0, p.z);
                if rho > 0.0 && !views.is_empty() {
                    // ρ cos θ_v / π towards v, times π / cos θ_v: ρ, where the view is open.
                    let from = on_soil;
                    for (j, &(v, _)) in views.iter().enumerate() {
                        if let Some(exit) = reaches_sky(stand, accel, cyclic, from, v, &mut k.rays)
                        {
                            k.brf[j] += rho;
                            tally(j, exit, v, rho);
                        }
                    }
                }
                if rng.next_f64() < rho {
                    scattered = true;
                    o = on_soil;
                    d = lambert(Vec3::Y, rng);
                    continue;
                }
                k.soil += 1;
                continue 'photon;
            }
            if e.end == e.top {
                k.reflected += 1;
                continue 'photon;
            }
            if !cyclic {
                k.side += 1;
                continue 'photon;
            }
            // Through a side: in again on the opposite one.
            o = plot.wrapped(o, d, &e);
        }
        k.unfinished += 1;
    }
    k
}

/// The plot's box: `[-hx, hx] × [0, top] × [-hz, hz]`.
pub(crate) struct PlotBox {
    pub(crate) hx: f32,
    pub(crate) hz: f32,
    pub(crate) top: f32,
}

/// Where a ray leaves a [`PlotBox`]: through the soil, the top or a side (∞ where it does
/// not), and the first of them.
pub(crate) struct Exits {
    pub(crate) soil: f32,
    pub(crate) top: f32,
    pub(crate) x: f32,
    pub(crate) z: f32,
    pub(crate) end: f32,
}

impl PlotBox {
    pub(crate) fn of(stand: &Stand) -> PlotBox {
        PlotBox {
            hx: stand.half[0] as f32,
            hz: stand.half[1] as f32,
            top: stand.top as f32,
        }
    }

    pub(crate) fn exits(&self, o: Vec3, d: Vec3) -> Exits {
        let soil = if d.y < 0.0 { -o.y / d.y } else { f32::INFINITY };
        let top = if d.y > 0.0 {
            (self.top - o.y) / d.y
        } else {
            f32::INFINITY
        };
        let side = |p: f32, v: f32, h: f32| {
            if v > 0.0 {
                (h - p) / v
            } else if v < 0.0 {
                (-h - p) / v
            } else {
                f32::INFINITY
            }
        };
        let (x, z) = (
            side(o.x, d.x, self.hx).max(0.0),
            side(o.z, d.z, self.hz).max(0.0),
        );
        Exits {
            soil,
            top,
            x,
            z,
            end: soil.min(top).min(x).min(z),
        }
    }

    /// Where a ray leaving through a side at `e.end` comes in again: on the opposite side,
    /// the crossed coordinate set to that side exactly.
    pub(crate) fn wrapped(&self, o: Vec3, d: Vec3, e: &Exits) -> Vec3 {
        let mut p = o + d * e.end;
        if e.end == e.x {
            p.x = if d.x > 0.0 { -self.hx } else { self.hx };
        }
        if e.end == e.z {
            p.z = if d.z > 0.0 { -self.hz } else { self.hz };
        }
        Vec3::new(
            p.x.clamp(-self.hx, self.hx),
            p.y.clamp(0.0, self.top),
            p.z.clamp(-self.hz, self.hz),
        )
    }
}

/// Where a ray from `o` along `d` (upwards) leaves the plot's box through its top (or, in
/// an isolated plot, through a side) without meeting a leaf, crossing the cyclic sides;
/// `None` where a leaf stops it.
fn reaches_sky(
    stand: &Stand,
    accel: &SceneAccel,
    cyclic: bool,
    mut o: Vec3,
    d: Vec3,
    rays: &mut u64,
) -> Option<Vec3> {
    let plot = PlotBox::of(stand);
    let mut stats = TraceStats::default();
    for _ in 0..MAX_EVENTS {
        let e = plot.exits(o, d);
        *rays += 1;
        if accel.any_hit(
            &Ray::segment(o, d, 0.0, e.end),
            TraversalConfig::default(),
            &mut stats,
        ) {
            return None;
        }
        if e.end == e.top || !cyclic {
            return Some(o + d * e.end);
        }
        o = plot.wrapped(o, d, &e);
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::CanopySpec;

    fn layer(lai: f64, size: f64) -> (CanopySpec, Stand, SceneAccel) {
        let spec = CanopySpec::parse(&format!(
            "[plot]\nsize = [{size}, {size}]\n[layer]\nlai = {lai}\nheight = 1.0\n[leaves]\nsize = 0.04\n"
        ))
        .unwrap();
        let stand = Stand::build(&spec).unwrap();
        let accel = SceneAccel::from_parts(&stand.models, &stand.instances, None).unwrap();
        (spec, stand, accel)
    }

    fn band(r: f64, t: f64, soil: f64) -> Band {
        Band {
            name: "b".into(),
            leaf_reflectance: r,
            leaf_transmittance: t,
            soil_albedo: soil,
            par: false,
            weight: 1.0,
        }
    }

    fn config(photons: u64, zenith: f64) -> BudgetConfig {
        BudgetConfig {
            photons,
            seed: 7,
            sun: SunAngles {
                zenith_deg: zenith,
                azimuth_deg: 30.0,
            },
            views: Vec::new(),
            image: None,
        }
    }

    /// E_3(x) = ∫_1^∞ e^(−x s) / s³ ds, by the midpoint rule in u = 1/s.
    fn e3(x: f64) -> f64 {
        let n = 200_000;
        (0..n)
            .map(|i| {
                let u = (i as f64 + 0.5) / n as f64;
                u * (-x / u).exp() / n as f64
            })
            .sum()
    }

    #[test]
    fn black_leaves_let_through_beers_law_and_the_soil_reflects_through_the_gaps() {
        // Black leaves of random orientation (G = 1/2): the direct transmission is
        // exp(−L / (2 cos θ)); light the soil reflects escapes without meeting a leaf with
        // probability 2 E_3(L/2) (cosine-weighted gaps), and black leaves absorb the rest.
        let (_, stand, accel) = layer(2.0, 3.0);
        let lai = stand.lai;
        for zenith in [0.0, 45.0, 70.0] {
            let cfg = config(120 * CHUNK, zenith);
            let soil = 0.5;
            let b = trace_budget(&stand, &accel, &[band(0.0, 0.0, soil)], true, &cfg, &|_| {})
                .unwrap()
                .remove(0);
            let mu = zenith.to_radians().cos();
            let direct = (-0.5 * lai / mu).exp();
            let err = (b.ground_direct.value - direct).abs();
            assert!(
                err < 0.005 && err < 4.0 * b.ground_direct.std_error + 0.002,
                "θ {zenith}: T {} ± {} against {direct}",
                b.ground_direct.value,
                b.ground_direct.std_error
            );
            // Only direct light reaches the soil, and only once.
            assert_eq!(b.ground_arrived, b.ground_direct);
            let up = 2.0 * e3(0.5 * lai);
            let want = soil * direct * up;
            assert!(
                (b.reflected.value - want).abs() < 4.0 * b.reflected.std_error + 0.002,
                "θ {zenith}: R {} ± {} against {want}",
                b.reflected.value,
                b.reflected.std_error
            );
            assert!(
                (b.soil_absorbed.value - (1.0 - soil) * direct).abs()
                    < 4.0 * b.soil_absorbed.std_error + 0.002
            );
            assert!(b.balance.abs() < 1e-12 && b.side_lost.value == 0.0);
        }
    }

    #[test]
    fn the_brf_of_black_leaves_over_a_soil_is_the_soil_seen_through_both_gaps() {
        // Black leaves, a Lambertian soil of albedo ρ: the BRF towards v is ρ times the gap
        // fraction towards the sun times that towards v (views far from the sun's direction,
        // where the two gaps are independent); towards the sun itself the gaps coincide and
        // the BRF is higher (the hot spot).
        let (_, stand, accel) = layer(1.5, 3.0);
        let lai = stand.lai;
        let mut cfg = config(60 * CHUNK, 30.0);
        let views = [(60.0, 210.0), (45.0, 120.0), (30.0, 30.0)];
        cfg.views = views
            .iter()
            .map(|&(z, a)| ViewAngles {
                zenith_deg: z,
                azimuth_deg: a,
            })
            .collect();
        let soil = 0.4;
        let b = trace_budget(&stand, &accel, &[band(0.0, 0.0, soil)], true, &cfg, &|_| {})
            .unwrap()
            .remove(0);
        let gap = |z: f64| (-0.5 * lai / z.to_radians().cos()).exp();
        for (v, &(z, _)) in b.brf.iter().zip(&views).take(2) {
            let want = soil * gap(30.0) * gap(z);
            assert!(
                (v.brf.value - want).abs() < 4.0 * v.brf.std_error + 0.003,
                "view {z}: BRF {} ± {} against {want}",
                v.brf.value,
                v.brf.std_error
            );
        }
        let hot = b.brf[2].brf.value;
        assert!(
            hot > 1.5 * soil * gap(30.0) * gap(30.0),
            "hot spot {hot} against {}",
            soil * gap(30.0) * gap(30.0)
        );
        // The views add rays but change no fate.
        let plain = trace_budget(
            &stand,
            &accel,
            &[band(0.0, 0.0, soil)],
            true,
            &config(60 * CHUNK, 30.0),
            &|_| {},
        )
        .unwrap()
        .remove(0);
        assert_eq!(plain.reflected, b.reflected);
        assert!(b.rays > plain.rays);
    }

    #[test]
    fn lossless_leaves_over_a_white_soil_send_everything_back_to_the_sky() {
        // Nothing absorbs, and in a cyclic plot nothing leaves through the sides: every
        // photon ends in the sky.
        let (_, stand, accel) = layer(1.5, 2.0);
        let cfg = config(4 * CHUNK, 40.0);
        let b = trace_budget(&stand, &accel, &[band(0.6, 0.4, 1.0)], true, &cfg, &|_| {})
            .unwrap()
            .remove(0);
        assert_eq!(b.reflected.value, 1.0);
        assert_eq!(b.canopy_absorbed.value + b.soil_absorbed.value, 0.0);
        assert!(b.leaf_events > 1.0 && b.ground_arrived.value > 0.5);
        // The same plot isolated loses light through its sides.
        let iso = trace_budget(&stand, &accel, &[band(0.6, 0.4, 1.0)], false, &cfg, &|_| {})
            .unwrap()
            .remove(0);
        assert!(iso.side_lost.value > 0.1, "{}", iso.side_lost.value);
        assert!((iso.reflected.value + iso.side_lost.value - 1.0).abs() < 1e-12);
    }

    #[test]
    fn the_soil_absorbs_its_share_of_what_arrives() {
        // Every arrival at the soil is absorbed with probability 1 − ρ.
        let (_, stand, accel) = layer(1.0, 2.0);
        let cfg = config(40 * CHUNK, 30.0);
        let b = trace_budget(&stand, &accel, &[band(0.45, 0.4, 0.3)], true, &cfg, &|_| {})
            .unwrap()
            .remove(0);
        let want = 0.7 * b.ground_arrived.value;
        assert!(
            (b.soil_absorbed.value - want).abs() < 4.0 * b.soil_absorbed.std_error,
            "{} vs {want}",
            b.soil_absorbed.value
        );
        assert!(b.balance.abs() < 1e-12);
    }

    #[test]
    fn results_depend_on_the_seed_only() {
        let (spec, stand, accel) = layer(1.0, 2.0);
        // With a BRF image: its tallies, too, must not depend on the order chunks finish.
        let cfg = BudgetConfig {
            image: Some(crate::BrfImageSpec {
                view: ViewAngles {
                    zenith_deg: 40.0,
                    azimuth_deg: 10.0,
                },
                side: 8,
            }),
            ..config(3 * CHUNK + 11, 20.0)
        };
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| trace_budget(&stand, &accel, &spec.bands, true, &cfg, &|_| {}).unwrap())
        };
        let (mut a, mut b) = (run(1), run(3));
        for x in a.iter_mut().chain(b.iter_mut()) {
            x.seconds = 0.0;
        }
        assert!(a[0].image.as_ref().is_some_and(|i| i.mean() > 0.0));
        assert_eq!(a, b);
        let other = BudgetConfig {
            seed: 8,
            ..cfg.clone()
        };
        let c = trace_budget(&stand, &accel, &spec.bands, true, &other, &|_| {}).unwrap();
        assert_ne!(a[0].reflected, c[0].reflected);
    }

    #[test]
    fn the_sun_and_the_views_turn_as_a_scenes_sun() {
        // Azimuth from +x towards +z (sylva_core::Sun::from_angles): at 90° the sun stands
        // towards +z, so its light travels towards −z.
        let d = SunAngles {
            zenith_deg: 60.0,
            azimuth_deg: 90.0,
        }
        .travel();
        assert!(d.x.abs() < 1e-6 && (d.y + 0.5).abs() < 1e-6 && (d.z + 0.866_025_4).abs() < 1e-6);
        let v = ViewAngles {
            zenith_deg: 60.0,
            azimuth_deg: 90.0,
        }
        .towards();
        assert!(
            (v + d).length() < 1e-6,
            "the hot spot's view looks back along the sunlight"
        );
        assert!(SunAngles {
            zenith_deg: f64::NAN,
            azimuth_deg: 0.0
        }
        .travel()
        .is_nan());
    }

    #[test]
    fn bad_settings_are_errors() {
        let (spec, stand, accel) = layer(1.0, 2.0);
        for cfg in [
            config(10, 30.0),
            config(4 * CHUNK, 90.0),
            config(4 * CHUNK, f64::NAN),
        ] {
            let e = trace_budget(&stand, &accel, &spec.bands, true, &cfg, &|_| {}).unwrap_err();
            assert!(!e.to_string().contains('\n'));
        }
    }
}
