//! Abstract canopies, the kind radiation-transfer intercomparisons use (docs/budget.md): a
//! TOML description (the plot, crowns of flat leaves or a homogeneous layer, the leaves, the
//! bands) and its leaves as meshes.
//!
//! Crowns come as a few distinct crown models ([`unit_model`]) and their placements
//! ([`placements`]: random sequential addition without overlap in the plot, distances
//! wrapping in a cyclic one, each crown one of the models turned at random about the
//! vertical); a layer is one model over the whole plot. Every leaf is a flat disc (a regular
//! octagon of the disc's area) or square, its centre uniform in the crown or layer and its
//! normal uniform over the sphere, so the leaf projection function G is 1/2 in every
//! direction. The plot is `[-x/2, x/2] × [-z/2, z/2]` around the origin, the soil at y = 0.
//!
//! ```toml
//! name = "crowns"
//! seed = 1
//! [plot]
//! size = [100.0, 100.0]      # x and z, metres
//! cyclic = true              # light leaving a side re-enters on the opposite side
//! [crowns]
//! shape = "sphere"           # or "ellipsoid" (half_height is then the vertical semi-axis)
//! radius = 2.5               # horizontal radius, m
//! centre_height = 6.0        # m above the soil
//! lai = 5.0                  # crown LAI: one-sided leaf area over the crown's cross-section
//! cover = 0.3                # fraction of the plot under crowns
//! [leaves]
//! shape = "disc"             # or "square"
//! size = 0.1                 # disc diameter or square side, m
//! [[bands]]
//! name = "red"
//! leaf_reflectance = 0.07
//! leaf_transmittance = 0.06
//! soil_albedo = 0.12
//! par = true                 # counts towards fAPAR
//! ```
//!
//! A homogeneous layer replaces `[crowns]` with `[layer] lai = 3.0, height = 2.0`.

use glam::{Quat, Vec3};
use serde::Deserialize;
use std::path::Path;
use sylva_core::SplitMix64;
use sylva_geom::{Instance, Material, MaterialKind, Mesh, Model, Optics};
use thiserror::Error;

/// Why a canopy was refused: one line naming the file or setting and the problem.
#[derive(Debug, Error)]
pub enum StandError {
    #[error("{path}: {message}")]
    File { path: String, message: String },
    #[error("{at}{message}")]
    Toml { at: String, message: String },
    #[error("{what} = {value}: {why}")]
    Invalid {
        what: String,
        value: String,
        why: String,
    },
    #[error(transparent)]
    Memory(#[from] sylva_core::MemoryError),
}

impl StandError {
    pub fn invalid(what: impl Into<String>, value: impl ToString, why: impl Into<String>) -> Self {
        StandError::Invalid {
            what: what.into(),
            value: value.to_string(),
            why: why.into(),
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum CrownShape {
    Sphere,
    Ellipsoid,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LeafShape {
    /// A regular octagon of the disc's area.
    Disc,
    Square,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Plot {
    /// Extent along x and z, metres.
    #[serde(default = "default_plot")]
    pub size: [f64; 2],
    /// Light leaving a side re-enters on the opposite side (an infinite stand); false: it is
    /// lost (an isolated plot).
    #[serde(default = "yes")]
    pub cyclic: bool,
}

fn default_plot() -> [f64; 2] {
    [100.0, 100.0]
}

fn yes() -> bool {
    true
}

impl Default for Plot {
    fn default() -> Self {
        Plot {
            size: default_plot(),
            cyclic: true,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Crowns {
    #[serde(default = "sphere")]
    pub shape: CrownShape,
    /// Horizontal radius, m.
    pub radius: f64,
    /// Vertical semi-axis of an ellipsoid, m (a sphere's is its radius).
    pub half_height: Option<f64>,
    /// Height of the crown's centre above the soil, m.
    pub centre_height: f64,
    /// One-sided leaf area over the crown's horizontal cross-section (π r²).
    pub lai: f64,
    /// Fraction of the plot's area under crowns (their vertical projections).
    pub cover: f64,
}

fn sphere() -> CrownShape {
    CrownShape::Sphere
}

impl Crowns {
    pub fn half_height(&self) -> f64 {
        match self.shape {
            CrownShape::Sphere => self.radius,
            CrownShape::Ellipsoid => self.half_height.unwrap_or(self.radius),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Layer {
    /// One-sided leaf area per unit ground area.
    pub lai: f64,
    /// Thickness of the layer, m (it stands on the soil).
    pub height: f64,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Leaves {
    #[serde(default = "disc")]
    pub shape: LeafShape,
    /// Disc diameter or square side, m.
    #[serde(default = "leaf_size")]
    pub size: f64,
}

fn disc() -> LeafShape {
    LeafShape::Disc
}

fn leaf_size() -> f64 {
    0.1
}

impl Default for Leaves {
    fn default() -> Self {
        Leaves {
            shape: LeafShape::Disc,
            size: leaf_size(),
        }
    }
}

impl Leaves {
    /// One leaf's (one-sided) area, m².
    pub fn area(&self) -> f64 {
        match self.shape {
            LeafShape::Disc => std::f64::consts::PI * 0.25 * self.size * self.size,
            LeafShape::Square => self.size * self.size,
        }
    }

    /// How far a leaf reaches from its centre, m.
    pub fn reach(&self) -> f64 {
        match self.shape {
            LeafShape::Disc => 0.5 * self.size * octagon_scale(),
            LeafShape::Square => self.size * std::f64::consts::FRAC_1_SQRT_2,
        }
    }
}

/// Circumradius of the regular octagon of a unit-radius disc's area: π = 4 R² sin(π/4)·... =
/// (8/2) R² sin(2π/8).
pub fn octagon_scale() -> f64 {
    (std::f64::consts::PI / (4.0 * std::f64::consts::FRAC_1_SQRT_2)).sqrt()
}

/// One spectral band: the leaves' and the soil's optics in it.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Band {
    pub name: String,
    /// Hemispherical reflectance of a leaf (Lambertian, either face).
    pub leaf_reflectance: f64,
    /// Hemispherical transmittance of a leaf (Lambertian).
    pub leaf_transmittance: f64,
    /// Lambertian albedo of the soil.
    pub soil_albedo: f64,
    /// Counts towards fAPAR (photosynthetically active radiation, 400-700 nm).
    #[serde(default)]
    pub par: bool,
    /// The band's share of the sun's irradiance within the PAR bands (fAPAR's weights).
    #[serde(default = "one")]
    pub weight: f64,
}

fn one() -> f64 {
    1.0
}

impl Band {
    /// Red and near-infrared leaves of issue 29's validation cases (r, t about 0.07, 0.06 and
    /// 0.45, 0.4) over a soil of albedo `soil` in both.
    pub fn red_nir(soil: f64) -> Vec<Band> {
        vec![
            Band {
                name: "red".into(),
                leaf_reflectance: 0.07,
                leaf_transmittance: 0.06,
                soil_albedo: soil,
                par: true,
                weight: 1.0,
            },
            Band {
                name: "nir".into(),
                leaf_reflectance: 0.45,
                leaf_transmittance: 0.40,
                soil_albedo: soil,
                par: false,
                weight: 1.0,
            },
        ]
    }
}

/// A stand to take the budget of.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CanopySpec {
    #[serde(default = "stand_name")]
    pub name: String,
    /// Seed of the crowns' placement and of every leaf's position and orientation.
    #[serde(default = "seed")]
    pub seed: u64,
    /// `[plot]`, also read as `[domain]` (the name radiation-transfer intercomparisons and
    /// issue 29 give it).
    #[serde(default, alias = "domain")]
    pub plot: Plot,
    pub crowns: Option<Crowns>,
    pub layer: Option<Layer>,
    #[serde(default)]
    pub leaves: Leaves,
    /// Default: red and near-infrared over a soil of albedo 0.12.
    #[serde(default)]
    pub bands: Vec<Band>,
}

fn stand_name() -> String {
    "stand".into()
}

fn seed() -> u64 {
    1
}

/// Leaf triangles a stand may hold (discs are 6 triangles, squares 2), across its distinct
/// models: about 100 bytes each with their kd-tree.
pub const MAX_TRIANGLES: u64 = 60_000_000;

/// Crowns a stand may place (each a placement test against its neighbours and an instance).
pub const MAX_CROWNS: u64 = 1_000_000;

/// Random sequential placement of equal discs jams near this cover (Feder 1980: 0.547).
pub const JAMMING_COVER: f64 = 0.547;

impl CanopySpec {
    /// Reads and checks a canopy file.
    pub fn load(path: &Path) -> Result<CanopySpec, StandError> {
        let file = |message: String| StandError::File {
            path: path.display().to_string(),
            message,
        };
        let text = std::fs::read_to_string(path).map_err(|e| file(e.to_string()))?;
        CanopySpec::from_text(path, &text)
    }

    /// Parses the text of canopy file `path` (read already), its errors naming the file.
    pub fn from_text(path: &Path, text: &str) -> Result<CanopySpec, StandError> {
        CanopySpec::parse(text).map_err(|e| StandError::File {
            path: path.display().to_string(),
            message: e.to_string(),
        })
    }

    /// Whether TOML `text` reads as a canopy file (it has `[crowns]` or `[layer]`) rather
    /// than a scene.
    pub fn is_canopy_text(text: &str) -> bool {
        text.parse::<toml::Table>()
            .is_ok_and(|t| t.contains_key("crowns") || t.contains_key("layer"))
    }

    /// A built-in stand, or the canopy file `name` (relative to `base`, when given).
    pub fn find(name: &str, base: Option<&Path>) -> Result<CanopySpec, StandError> {
        if let Some(spec) = CanopySpec::builtin(name) {
            return Ok(spec);
        }
        let path = base.map_or_else(|| Path::new(name).to_path_buf(), |d| d.join(name));
        if !path.is_file() {
            return Err(StandError::File {
                path: path.display().to_string(),
                message: format!(
                    "no such canopy file, and not a built-in stand ({})",
                    CanopySpec::BUILTIN.join(", ")
                ),
            });
        }
        CanopySpec::load(&path)
    }

    /// Parses and checks TOML text.
    pub fn parse(text: &str) -> Result<CanopySpec, StandError> {
        let mut spec: CanopySpec = toml::from_str(text).map_err(|e| {
            let line = e
                .span()
                .map(|r| text[..r.start.min(text.len())].matches('\n').count() + 1);
            StandError::Toml {
                at: line.map_or(String::new(), |l| format!("line {l}: ")),
                message: e.message().trim().to_string(),
            }
        })?;
        if spec.bands.is_empty() {
            spec.bands = Band::red_nir(0.12);
        }
        spec.validate()?;
        Ok(spec)
    }

    /// The built-in stands: `crowns` (issue 29's validation stand: spheres of crown LAI 5 at
    /// cover 0.3 over 100 m × 100 m) and `layer` (a homogeneous layer of LAI 3, 2 m thick, on a
    /// 10 m cyclic plot), both in the default bands (red and near-infrared, soil 0.12).
    pub fn builtin(name: &str) -> Option<CanopySpec> {
        let text = match name {
            "crowns" => BUILTIN_CROWNS,
            "layer" => BUILTIN_LAYER,
            _ => return None,
        };
        Some(CanopySpec::parse(text).expect("built-in canopies are valid"))
    }

    pub const BUILTIN: [&'static str; 2] = ["crowns", "layer"];

    /// Every setting within its range: one error naming the first that is not.
    pub fn validate(&self) -> Result<(), StandError> {
        let positive = |what: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(StandError::invalid(what, v, "must be a positive number"))
            }
        };
        positive("plot.size[0]", self.plot.size[0])?;
        positive("plot.size[1]", self.plot.size[1])?;
        positive("leaves.size", self.leaves.size)?;
        match (&self.crowns, &self.layer) {
            (Some(_), Some(_)) => {
                return Err(StandError::invalid(
                    "canopy",
                    "[crowns] and [layer]",
                    "give one of them, not both",
                ))
            }
            (None, None) => {
                return Err(StandError::invalid(
                    "canopy",
                    "no [crowns] or [layer]",
                    "give crowns (radius, centre_height, lai, cover) or a layer (lai, height)",
                ))
            }
            (Some(c), None) => {
                positive("crowns.radius", c.radius)?;
                positive("crowns.half_height", c.half_height())?;
                positive("crowns.lai", c.lai)?;
                if !(c.centre_height.is_finite() && c.centre_height >= c.half_height()) {
                    return Err(StandError::invalid(
                        "crowns.centre_height",
                        c.centre_height,
                        format!(
                            "a crown reaches {} m below its centre: it must not go into the soil",
                            c.half_height()
                        ),
                    ));
                }
                if !(c.cover.is_finite() && c.cover > 0.0 && c.cover <= 1.0) {
                    return Err(StandError::invalid(
                        "crowns.cover",
                        c.cover,
                        "must be in (0, 1]",
                    ));
                }
                if c.cover > JAMMING_COVER {
                    return Err(StandError::invalid(
                        "crowns.cover",
                        c.cover,
                        format!("non-overlapping crowns placed at random cannot reach it (random placement jams near {JAMMING_COVER})"),
                    ));
                }
                if self.leaves.reach() >= c.radius.min(c.half_height()) {
                    return Err(StandError::invalid(
                        "leaves.size",
                        self.leaves.size,
                        "a leaf must be smaller than its crown",
                    ));
                }
                let [x, z] = self.plot.size;
                if 2.0 * c.radius > x.min(z) {
                    return Err(StandError::invalid(
                        "crowns.radius",
                        c.radius,
                        format!("a crown must fit the {x} m × {z} m plot"),
                    ));
                }
            }
            (None, Some(l)) => {
                positive("layer.lai", l.lai)?;
                positive("layer.height", l.height)?;
                if 2.0 * self.leaves.reach() >= l.height {
                    return Err(StandError::invalid(
                        "layer.height",
                        l.height,
                        format!(
                            "must exceed a leaf's extent ({:.3} m)",
                            2.0 * self.leaves.reach()
                        ),
                    ));
                }
            }
        }
        let mut names = std::collections::HashSet::new();
        for b in &self.bands {
            let what = |k: &str| format!("bands.{}.{k}", b.name);
            if b.name.trim().is_empty() {
                return Err(StandError::invalid(
                    "bands.name",
                    "\"\"",
                    "a band needs a name",
                ));
            }
            if !names.insert(b.name.clone()) {
                return Err(StandError::invalid(
                    "bands.name",
                    &b.name,
                    "names a band twice",
                ));
            }
            for (k, v) in [
                ("leaf_reflectance", b.leaf_reflectance),
                ("leaf_transmittance", b.leaf_transmittance),
                ("soil_albedo", b.soil_albedo),
            ] {
                if !(v.is_finite() && (0.0..=1.0).contains(&v)) {
                    return Err(StandError::invalid(what(k), v, "must be in [0, 1]"));
                }
            }
            if b.leaf_reflectance + b.leaf_transmittance > 1.0 {
                return Err(StandError::invalid(
                    what("leaf_reflectance + leaf_transmittance"),
                    b.leaf_reflectance + b.leaf_transmittance,
                    "must not exceed 1 (a leaf cannot give out more light than it receives)",
                ));
            }
            if !(b.weight.is_finite() && b.weight > 0.0) {
                return Err(StandError::invalid(
                    what("weight"),
                    b.weight,
                    "must be a positive number",
                ));
            }
        }
        if let Some(c) = &self.crowns {
            // In floating point: a plot of any size gives a finite count to compare.
            let crowns = c.cover * self.plot.size[0] * self.plot.size[1]
                / (std::f64::consts::PI * c.radius * c.radius);
            if crowns > MAX_CROWNS as f64 {
                return Err(StandError::invalid(
                    "crowns",
                    format!("{crowns:.3e} crowns"),
                    format!("more than {MAX_CROWNS}: use a smaller plot or larger crowns (a cyclic plot stands for an infinite stand already)"),
                ));
            }
        }
        let triangles = self.triangles();
        if triangles > MAX_TRIANGLES {
            return Err(StandError::invalid(
                "canopy",
                if triangles == u64::MAX {
                    "more than 1.8e19 leaf triangles".to_string()
                } else {
                    format!("{triangles} leaf triangles")
                },
                format!("more than {MAX_TRIANGLES}: use larger leaves, a smaller plot or fewer crown variants"),
            ));
        }
        Ok(())
    }

    /// Leaves per crown (or in the layer).
    pub fn leaves_per_unit(&self) -> u64 {
        let area = self.leaves.area();
        match (&self.crowns, &self.layer) {
            (Some(c), _) => {
                (c.lai * std::f64::consts::PI * c.radius * c.radius / area).round() as u64
            }
            (_, Some(l)) => (l.lai * self.plot.size[0] * self.plot.size[1] / area).round() as u64,
            _ => 0,
        }
    }

    /// Crowns on the plot: the cover's share of its area over one crown's cross-section.
    pub fn crown_count(&self) -> u64 {
        self.crowns.as_ref().map_or(0, |c| {
            (c.cover * self.plot.size[0] * self.plot.size[1]
                / (std::f64::consts::PI * c.radius * c.radius))
                .round()
                .max(1.0) as u64
        })
    }

    /// Distinct crown models (the crowns are their instances, each turned at random).
    pub fn crown_variants(&self) -> u64 {
        self.crown_count().clamp(1, CROWN_VARIANTS)
    }

    /// Leaf triangles of the distinct models.
    pub fn triangles(&self) -> u64 {
        let per_leaf = match self.leaves.shape {
            LeafShape::Disc => 6,
            LeafShape::Square => 2,
        };
        let units = if self.crowns.is_some() {
            self.crown_variants()
        } else {
            1
        };
        units
            .saturating_mul(self.leaves_per_unit())
            .saturating_mul(per_leaf)
    }
}

/// Distinct crowns generated at most; more crowns instance them.
pub const CROWN_VARIANTS: u64 = 16;

const BUILTIN_CROWNS: &str = r#"
name = "crowns"
seed = 1
[plot]
size = [100.0, 100.0]
[crowns]
shape = "sphere"
radius = 2.5
centre_height = 6.0
lai = 5.0
cover = 0.3
[leaves]
shape = "disc"
size = 0.1
"#;

const BUILTIN_LAYER: &str = r#"
name = "layer"
seed = 1
[plot]
size = [10.0, 10.0]
[layer]
lai = 3.0
height = 2.0
[leaves]
shape = "disc"
size = 0.1
"#;

/// Crown models (or 1 for a layer) a stand is made of.
pub fn unit_count(spec: &CanopySpec) -> usize {
    if spec.crowns.is_some() {
        spec.crown_variants() as usize
    } else {
        1
    }
}

/// Model `k` of [`unit_count`]: crown variant `k` around its centre, or the layer.
pub fn unit_model(spec: &CanopySpec, k: usize) -> Model {
    let leaves = spec.leaves_per_unit();
    match (&spec.crowns, &spec.layer) {
        (Some(c), _) => crown_model(
            spec,
            c.radius,
            c.half_height(),
            leaves,
            SplitMix64::for_chunk(spec.seed, k as u64).next_u64(),
        ),
        (_, Some(l)) => layer_model(spec, l.height, leaves, spec.seed),
        _ => unreachable!("a validated canopy has crowns or a layer"),
    }
}

/// The instances inside the plot: each crown (a model of [`unit_model`], turned at random)
/// at its placed centre, or the layer at the origin.
pub fn placements(spec: &CanopySpec) -> Result<Vec<Instance>, StandError> {
    let Some(c) = &spec.crowns else {
        return Ok(vec![Instance {
            model: 0,
            position: Vec3::ZERO,
            rotation_deg: 0.0,
            scale: 1.0,
        }]);
    };
    let centres = place_crowns(spec, c.radius, spec.crown_count())?;
    let variants = spec.crown_variants();
    let mut rng = SplitMix64::new(spec.seed ^ 0x7075_726e);
    Ok(centres
        .iter()
        .enumerate()
        .map(|(k, p)| Instance {
            model: (k as u64 % variants) as u32,
            position: Vec3::new(p[0] as f32, c.centre_height as f32, p[1] as f32),
            rotation_deg: (rng.next_f64() * 360.0) as f32,
            scale: 1.0,
        })
        .collect())
}

/// Height above every leaf, m.
pub fn top(spec: &CanopySpec) -> f64 {
    match (&spec.crowns, &spec.layer) {
        (Some(c), _) => c.centre_height + c.half_height() + spec.leaves.reach(),
        (_, Some(l)) => l.height,
        _ => 0.0,
    }
}

fn leaf_material() -> Material {
    Material {
        name: "leaf".into(),
        kind: MaterialKind::Leaf,
        base_color: [0.1, 0.3, 0.05],
        texture: None,
        two_sided: true,
        optics: Optics::FOREST_LEAF,
    }
}

/// A unit vector uniform over the sphere.
fn isotropic(u1: f64, u2: f64) -> Vec3 {
    let z = 2.0 * u1 - 1.0;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * std::f64::consts::PI * u2;
    Vec3::new((r * phi.cos()) as f32, z as f32, (r * phi.sin()) as f32)
}

/// Adds one leaf centred on `c` with unit normal `n`, turned by `spin` in its plane.
fn push_leaf(mesh: &mut Mesh, shape: LeafShape, size: f64, c: Vec3, n: Vec3, spin: f32) {
    let rot = Quat::from_rotation_arc(Vec3::Y, n) * Quat::from_rotation_y(spin);
    let corners: Vec<Vec3> = match shape {
        LeafShape::Square => {
            let h = 0.5 * size as f32;
            [(-h, -h), (h, -h), (h, h), (-h, h)]
                .iter()
                .map(|&(x, z)| c + rot * Vec3::new(x, 0.0, z))
                .collect()
        }
        LeafShape::Disc => {
            let r = (0.5 * size * octagon_scale()) as f32;
            (0..8)
                .map(|k| {
                    let a = k as f32 * std::f32::consts::FRAC_PI_4;
                    c + rot * Vec3::new(r * a.cos(), 0.0, r * a.sin())
                })
                .collect()
        }
    };
    let ids: Vec<u32> = corners
        .iter()
        .map(|&p| mesh.push_vertex(p, n, [0.0, 0.0]))
        .collect();
    for k in 1..ids.len() - 1 {
        mesh.push_triangle(ids[0], ids[k], ids[k + 1], 0);
    }
}

/// One crown's leaves around the origin (its centre): `count` leaves uniform in the
/// ellipsoid of horizontal radius `radius` and vertical semi-axis `half_height`.
fn crown_model(spec: &CanopySpec, radius: f64, half_height: f64, count: u64, seed: u64) -> Model {
    let mut rng = SplitMix64::new(seed);
    let mut mesh = Mesh::default();
    let leaves = &spec.leaves;
    let mut placed = 0;
    while placed < count {
        let (x, y, z) = (
            2.0 * rng.next_f64() - 1.0,
            2.0 * rng.next_f64() - 1.0,
            2.0 * rng.next_f64() - 1.0,
        );
        if x * x + y * y + z * z > 1.0 {
            continue;
        }
        let c = Vec3::new(
            (x * radius) as f32,
            (y * half_height) as f32,
            (z * radius) as f32,
        );
        let n = isotropic(rng.next_f64(), rng.next_f64());
        let spin = (rng.next_f64() * std::f64::consts::TAU) as f32;
        push_leaf(&mut mesh, leaves.shape, leaves.size, c, n, spin);
        placed += 1;
    }
    Model::new("crown", mesh, vec![leaf_material()])
}

/// The layer's leaves over the whole plot: centres uniform in x and z and, in y, within
/// `[reach, height − reach]` so that no leaf pierces the soil or rises over the layer.
fn layer_model(spec: &CanopySpec, height: f64, count: u64, seed: u64) -> Model {
    let mut rng = SplitMix64::new(seed);
    let mut mesh = Mesh::default();
    let [hx, hz] = [0.5 * spec.plot.size[0], 0.5 * spec.plot.size[1]];
    let reach = spec.leaves.reach();
    for _ in 0..count {
        let c = Vec3::new(
            ((2.0 * rng.next_f64() - 1.0) * hx) as f32,
            (reach + rng.next_f64() * (height - 2.0 * reach)) as f32,
            ((2.0 * rng.next_f64() - 1.0) * hz) as f32,
        );
        let n = isotropic(rng.next_f64(), rng.next_f64());
        let spin = (rng.next_f64() * std::f64::consts::TAU) as f32;
        push_leaf(&mut mesh, spec.leaves.shape, spec.leaves.size, c, n, spin);
    }
    Model::new("layer", mesh, vec![leaf_material()])
}

/// The shortest distance between two points of the cyclic plot (or the plain one).
pub fn plot_distance(a: [f64; 2], b: [f64; 2], size: [f64; 2], cyclic: bool) -> f64 {
    let d = |k: usize| {
        let d = (a[k] - b[k]).abs();
        if cyclic {
            d.min(size[k] - d)
        } else {
            d
        }
    };
    d(0).hypot(d(1))
}

/// Crown centres (x, z) placed one after another at random, each refused when it would
/// overlap one placed before.
pub fn place_crowns(
    spec: &CanopySpec,
    radius: f64,
    count: u64,
) -> Result<Vec<[f64; 2]>, StandError> {
    let [sx, sz] = spec.plot.size;
    let cyclic = spec.plot.cyclic;
    // An isolated plot keeps whole crowns inside it.
    let margin = if cyclic { 0.0 } else { radius };
    let mut rng = SplitMix64::new(spec.seed ^ 0x5eed_c0de);
    let mut centres: Vec<[f64; 2]> = Vec::with_capacity(count as usize);
    // A uniform grid of cells no smaller than a crown's diameter: a new crown can only
    // overlap crowns in its own and the neighbouring cells.
    // (At most 2048 a side: larger cells only hold more crowns.)
    let cells = [
        ((sx / (2.0 * radius)).floor() as usize).clamp(1, 2048),
        ((sz / (2.0 * radius)).floor() as usize).clamp(1, 2048),
    ];
    let mut grid: Vec<Vec<u32>> = vec![Vec::new(); cells[0] * cells[1]];
    let cell_of = |p: [f64; 2]| {
        [
            (((p[0] + 0.5 * sx) / sx * cells[0] as f64) as usize).min(cells[0] - 1),
            (((p[1] + 0.5 * sz) / sz * cells[1] as f64) as usize).min(cells[1] - 1),
        ]
    };
    let attempts = 20_000 + 2_000 * count;
    let mut tried = 0u64;
    while (centres.len() as u64) < count {
        tried += 1;
        if tried > attempts {
            return Err(StandError::invalid(
                "crowns.cover",
                spec.crowns.as_ref().map_or(0.0, |c| c.cover),
                format!(
                    "only {} of {count} non-overlapping crowns of radius {radius} m found room in the {sx} m × {sz} m plot after {attempts} tries",
                    centres.len()
                ),
            ));
        }
        let p = [
            (rng.next_f64() - 0.5) * (sx - 2.0 * margin),
            (rng.next_f64() - 0.5) * (sz - 2.0 * margin),
        ];
        let [cx, cz] = cell_of(p);
        let mut free = true;
        'near: for dx in [cells[0] - 1, 0, 1] {
            for dz in [cells[1] - 1, 0, 1] {
                let (ix, iz) = ((cx + dx) % cells[0], (cz + dz) % cells[1]);
                for &k in &grid[ix * cells[1] + iz] {
                    if plot_distance(p, centres[k as usize], spec.plot.size, cyclic) < 2.0 * radius
                    {
                        free = false;
                        break 'near;
                    }
                }
            }
        }
        if free {
            grid[cx * cells[1] + cz].push(centres.len() as u32);
            centres.push(p);
        }
    }
    Ok(centres)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn built_in_stands_parse_and_count_their_leaves() {
        let c = CanopySpec::builtin("crowns").unwrap();
        // 0.3 × 10⁴ m² / (π 2.5²) = 152.8 crowns; 5 × π 2.5² / (π 0.05²) = 12,500 leaves.
        assert_eq!(c.crown_count(), 153);
        assert_eq!(c.leaves_per_unit(), 12_500);
        assert_eq!(c.triangles(), 16 * 12_500 * 6);
        let l = CanopySpec::builtin("layer").unwrap();
        assert_eq!(
            l.leaves_per_unit(),
            (300.0 / (std::f64::consts::PI * 0.0025)).round() as u64
        );
        assert_eq!(l.bands.len(), 2);
        assert!(CanopySpec::builtin("nothing").is_none());
    }

    #[test]
    fn domain_is_another_name_for_the_plot() {
        let plot = "[plot]\nsize = [20.0, 10.0]\ncyclic = false\n";
        let layer = "[layer]\nlai = 2.0\nheight = 1.0\n";
        let a = CanopySpec::parse(&format!("{plot}{layer}")).unwrap();
        let b = CanopySpec::parse(&format!("{}{layer}", plot.replace("plot", "domain"))).unwrap();
        assert_eq!(a, b);
        assert!(!b.plot.cyclic && b.plot.size == [20.0, 10.0]);
        let both = format!("{plot}{}{layer}", plot.replace("plot", "domain"));
        let e = CanopySpec::parse(&both).unwrap_err().to_string();
        assert!(e.contains("duplicate") && !e.contains('\n'), "{e}");
    }

    #[test]
    fn the_octagon_has_the_disc_area() {
        let r = octagon_scale();
        let area = 4.0 * r * r * (std::f64::consts::FRAC_PI_4).sin();
        assert!((area - std::f64::consts::PI).abs() < 1e-12);
    }

    #[test]
    fn bad_canopies_are_one_line_errors() {
        // The built-in crowns with their (default) bands written out.
        let base = &format!(
            "{BUILTIN_CROWNS}[[bands]]\nname = \"red\"\nleaf_reflectance = 0.07\nleaf_transmittance = 0.06\nsoil_albedo = 0.12\npar = true\n[[bands]]\nname = \"nir\"\nleaf_reflectance = 0.45\nleaf_transmittance = 0.40\nsoil_albedo = 0.12\n"
        );
        assert_eq!(
            CanopySpec::parse(base).unwrap(),
            CanopySpec::builtin("crowns").unwrap()
        );
        let cases = [
            (
                base.replace("leaf_reflectance = 0.45", "leaf_reflectance = 0.75"),
                "must not exceed 1",
            ),
            (
                base.replace("soil_albedo = 0.12\npar", "soil_albedo = -0.1\npar"),
                "must be in [0, 1]",
            ),
            (base.replace("lai = 5.0", "lai = 0.0"), "crowns.lai"),
            (base.replace("cover = 0.3", "cover = 0.6"), "jams near"),
            (base.replace("cover = 0.3", "cover = nan"), "crowns.cover"),
            (
                base.replace("centre_height = 6.0", "centre_height = 1.0"),
                "into the soil",
            ),
            (
                base.replace("size = 0.1", "size = 6.0"),
                "smaller than its crown",
            ),
            (
                base.replace(
                    "radius = 2.5\ncentre_height = 6.0",
                    "radius = 60.0\ncentre_height = 70.0",
                ),
                "fit the",
            ),
            (
                base.replace("name = \"nir\"", "name = \"red\""),
                "names a band twice",
            ),
            (
                base.replace("shape = \"sphere\"", "shape = \"cube\""),
                "unknown variant",
            ),
            (
                base.replace("lai = 5.0", "lai = 5.0\nheight = 3.0"),
                "unknown field",
            ),
            (
                format!("{base}\n[layer]\nlai = 1.0\nheight = 1.0\n"),
                "not both",
            ),
            ("name = \"x\"\n".to_string(), "no [crowns] or [layer]"),
            (base.replace("size = 0.1", "size = 0.001"), "leaf triangles"),
            (
                base.replace("size = [100.0, 100.0]", "size = [1e6, 1e6]"),
                "more than 1000000",
            ),
            (
                base.replace("size = [100.0, 100.0]", "size = [1e30, 1e30]"),
                "more than 1000000",
            ),
        ];
        for (text, needle) in cases {
            let e = CanopySpec::parse(&text).unwrap_err().to_string();
            assert!(e.contains(needle), "{needle}: {e}");
            assert!(!e.contains('\n'), "{e}");
        }
    }
}
