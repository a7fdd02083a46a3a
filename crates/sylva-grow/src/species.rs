//! Species: Weber & Penn parameters plus the leaf and bark look. The built-in species are the
//! trees of the papers (000 Table 2, a pine for 000 Fig. 3b, the dogrose of 002 §3.2.2, and a
//! red maple thinned to the 18K triangles of 003's Table 3 tree), each with its own generated
//! leaf and bark textures.

use crate::textures::{bark_texture, leaf_texture, BarkPattern, LeafOutline};
use crate::weber_penn::{self, GenerateError, Params, LEAF, WOOD};
use std::sync::Arc;
use sylva_geom::{
    LeafOptics, Material, MaterialKind, Measured, Mesh, Model, Optics, KNAPP_CARTER_LEAF,
};

/// A plant species: how to grow it and how it looks.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Species {
    /// Identifier (`red_maple`).
    pub name: String,
    /// Human name (`red maple`).
    pub display_name: String,
    pub params: Params,
    /// Seed of the generator: one species, one tree.
    pub seed: u64,
    pub leaf_outline: LeafOutline,
    /// Leaf colour, sRGB.
    pub leaf_color: [u8; 3],
    /// The leaf's measured mean reflectance and transmittance per colour (linear R, G, B):
    /// the texture only shapes its pattern (docs/light.md, "Leaf optics").
    #[serde(serialize_with = "serialize_measured")]
    pub leaf: Measured,
    /// Where [`Species::leaf`] comes from.
    pub leaf_source: String,
    pub bark_pattern: BarkPattern,
    /// Bark colour, sRGB.
    pub bark_color: [u8; 3],
    /// Triangles per instance reported by the source, where it reports one.
    pub reference_triangles: Option<usize>,
    /// Where the species comes from.
    pub source: String,
}

/// Names of the built-in species, in the order `sylva species list` prints them.
pub const BUILTIN_NAMES: &[&str] = &[
    "red_maple",
    "ohio_buckeye",
    "paper_birch",
    "southern_catalpa",
    "american_beech",
    "pine",
    "dogrose",
    "sparse_maple",
];

/// `"Red Maple"`, `"red-maple"` → `"red_maple"`.
pub fn normalize_name(name: &str) -> String {
    name.trim()
        .to_ascii_lowercase()
        .chars()
        .map(|c| if c == ' ' || c == '-' { '_' } else { c })
        .collect()
}

fn params(values: &[(&str, f64)]) -> Params {
    let mut p = Params::default();
    for (name, value) in values {
        p.set(name, *value)
            .unwrap_or_else(|e| panic!("built-in species parameter: {e}"));
    }
    p
}

impl Species {
    /// A built-in species by name (any case; spaces or dashes for underscores).
    pub fn builtin(name: &str) -> Option<Species> {
        let n = normalize_name(name);
        let s = match n.as_str() {
            "red_maple" => red_maple(),
            "ohio_buckeye" => ohio_buckeye(),
            "paper_birch" => paper_birch(),
            "southern_catalpa" => southern_catalpa(),
            "american_beech" => american_beech(),
            "pine" => pine(),
            "dogrose" | "dog_rose" => dogrose(),
            "sparse_maple" => sparse_maple(),
            _ => return None,
        };
        Some(s)
    }

    pub fn all_builtin() -> Vec<Species> {
        BUILTIN_NAMES
            .iter()
            .map(|n| Species::builtin(n).expect("listed"))
            .collect()
    }

    /// A species from parameters alone (an Arbaro file): the leaf outline comes from
    /// `LeafShape`, colours are a generic summer green and brown bark.
    pub fn from_params(name: &str, params: Params, seed: u64, source: String) -> Species {
        Species {
            name: name.to_string(),
            display_name: name.replace('_', " "),
            leaf_outline: LeafOutline::from_index(params.general.leaf_shape as u32),
            params,
            seed,
            leaf_color: [75, 125, 45],
            leaf: KNAPP_CARTER_LEAF,
            leaf_source: KNAPP_CARTER_SOURCE.into(),
            bark_pattern: BarkPattern::Furrowed,
            bark_color: [105, 85, 65],
            reference_triangles: None,
            source,
        }
    }

    /// The tree's mesh (wood = material 0, leaves = material 1).
    pub fn generate_mesh(&self) -> Result<Mesh, GenerateError> {
        weber_penn::generate(&self.params, self.seed)
    }

    /// Bark (index 0) and leaf (index 1) materials with their textures, the leaf's optics
    /// formed from its measured values ([`LeafOptics::Measured`]; a scene's
    /// `set_leaf_optics` re-forms them for another mode). Bark has no measured values yet:
    /// its reflectance is its texture's colour.
    pub fn materials(&self) -> Result<Vec<Material>, GenerateError> {
        let tex_seed = (self.seed as u32).wrapping_mul(2654435761);
        let bark = Arc::new(bark_texture(self.bark_pattern, self.bark_color, tex_seed));
        let leaf = Arc::new(leaf_texture(
            self.leaf_outline,
            self.leaf_color,
            tex_seed ^ 0x5a5a,
        ));
        let leaf_optics =
            Optics::measured_leaf(self.leaf, LeafOptics::Measured, leaf.mean_opaque_albedo())
                .map_err(|e| GenerateError::Optics(format!("{} leaf: {e}", self.name)))?;
        let mut m = vec![
            Material {
                name: format!("{} bark", self.display_name),
                kind: MaterialKind::Wood,
                base_color: bark.mean_opaque_linear(),
                texture: Some(bark),
                two_sided: false,
                optics: Optics::OPAQUE,
            },
            Material {
                name: format!("{} leaf", self.display_name),
                kind: MaterialKind::Leaf,
                base_color: leaf.mean_opaque_linear(),
                texture: Some(leaf),
                two_sided: true,
                optics: leaf_optics,
            },
        ];
        debug_assert_eq!(m[WOOD as usize].kind, MaterialKind::Wood);
        debug_assert_eq!(m[LEAF as usize].kind, MaterialKind::Leaf);
        m.shrink_to_fit();
        Ok(m)
    }

    /// The species with leaves measured as `leaf`, from `source`.
    pub fn with_leaf(self, leaf: Measured, source: &str) -> Species {
        Species {
            leaf,
            leaf_source: source.to_string(),
            ..self
        }
    }

    /// Mesh + materials.
    pub fn build_model(&self) -> Result<Model, GenerateError> {
        let mut mesh = self.generate_mesh()?;
        mesh.positions.shrink_to_fit();
        mesh.normals.shrink_to_fit();
        mesh.uvs.shrink_to_fit();
        mesh.indices.shrink_to_fit();
        mesh.material_ids.shrink_to_fit();
        Ok(Model::new(self.name.clone(), mesh, self.materials()?))
    }
}

fn builtin(
    name: &str,
    params: Params,
    seed: u64,
    leaf: (LeafOutline, [u8; 3]),
    bark: (BarkPattern, [u8; 3]),
    reference_triangles: Option<usize>,
    source: &str,
) -> Species {
    Species {
        name: name.to_string(),
        display_name: name.replace('_', " "),
        params,
        seed,
        leaf_outline: leaf.0,
        leaf_color: leaf.1,
        leaf: KNAPP_CARTER_LEAF,
        leaf_source: KNAPP_CARTER_SOURCE.into(),
        bark_pattern: bark.0,
        bark_color: bark.1,
        reference_triangles,
        source: source.to_string(),
    }
}

const TABLE2: &str = "paper 000 Table 2 (beech scene)";

/// The source of [`KNAPP_CARTER_LEAF`], as `species show` prints it.
pub const KNAPP_CARTER_SOURCE: &str = "paper 000 Table 1: Knapp & Carter's leaves, R = bs, T = fs \
     (000 §3: one set for all species, their variation across 26 species being small)";

fn serialize_measured<S: serde::Serializer>(m: &Measured, s: S) -> Result<S::Ok, S::Error> {
    use serde::ser::SerializeStruct;
    let mut st = s.serialize_struct("Measured", 2)?;
    st.serialize_field("reflectance", &m.reflectance)?;
    st.serialize_field("transmittance", &m.transmittance)?;
    st.end()
}

/// Oval crown, three-lobed toothed leaves, smooth grey bark.
fn red_maple() -> Species {
    let p = params(&[
        ("Shape", 1.0),
        ("BaseSize", 0.3),
        ("Scale", 15.0),
        ("ScaleV", 0.0),
        ("Levels", 3.0),
        ("Ratio", 0.018),
        ("RatioPower", 1.3),
        ("Flare", 0.6),
        ("Leaves", 29.0),
        ("LeafScale", 0.15),
        ("LeafScaleX", 1.0),
        ("LeafBend", 0.4),
        ("AttractionUp", 0.6),
        ("0CurveRes", 8.0),
        ("0CurveV", 20.0),
        ("1DownAngle", 55.0),
        ("1DownAngleV", -30.0),
        ("1Rotate", 140.0),
        ("1Branches", 45.0),
        ("1Length", 0.4),
        ("1LengthV", 0.05),
        ("1CurveRes", 5.0),
        ("1Curve", -20.0),
        ("1CurveV", 50.0),
        ("1SegSplits", 0.15),
        ("1SplitAngle", 25.0),
        ("2DownAngle", 40.0),
        ("2DownAngleV", 10.0),
        ("2Rotate", 140.0),
        ("2Branches", 35.0),
        ("2Length", 0.5),
        ("2LengthV", 0.1),
        ("2CurveRes", 3.0),
        ("2Curve", -10.0),
        ("2CurveV", 60.0),
        ("3DownAngle", 35.0),
        ("3DownAngleV", 15.0),
        ("3Rotate", 140.0),
    ]);
    builtin(
        "red_maple",
        p,
        11,
        (LeafOutline::Palmate, [82, 128, 40]),
        (BarkPattern::Smooth, [128, 124, 118]),
        Some(115_529),
        TABLE2,
    )
}

/// Small rounded tree, five-leaflet palmate leaves, grey-brown furrowed bark.
fn ohio_buckeye() -> Species {
    let p = params(&[
        ("Shape", 1.0),
        ("BaseSize", 0.25),
        ("Scale", 11.0),
        ("Levels", 3.0),
        ("Ratio", 0.022),
        ("RatioPower", 1.3),
        ("Flare", 0.5),
        ("Leaves", 60.0),
        ("LeafScale", 0.2),
        ("LeafScaleX", 1.0),
        ("LeafBend", 0.5),
        ("AttractionUp", 0.5),
        ("0CurveRes", 6.0),
        ("0CurveV", 25.0),
        ("1DownAngle", 60.0),
        ("1DownAngleV", -30.0),
        ("1Rotate", 140.0),
        ("1Branches", 40.0),
        ("1Length", 0.45),
        ("1LengthV", 0.05),
        ("1CurveRes", 5.0),
        ("1Curve", -25.0),
        ("1CurveV", 60.0),
        ("1SegSplits", 0.2),
        ("1SplitAngle", 30.0),
        ("2DownAngle", 40.0),
        ("2DownAngleV", 10.0),
        ("2Rotate", 140.0),
        ("2Branches", 30.0),
        ("2Length", 0.5),
        ("2LengthV", 0.1),
        ("2CurveRes", 3.0),
        ("2Curve", 10.0),
        ("2CurveV", 60.0),
        ("3DownAngle", 40.0),
        ("3DownAngleV", 10.0),
        ("3Rotate", 140.0),
    ]);
    builtin(
        "ohio_buckeye",
        p,
        23,
        (LeafOutline::PalmatelyCompound, [58, 102, 36]),
        (BarkPattern::Furrowed, [112, 100, 86]),
        Some(168_520),
        TABLE2,
    )
}

/// Narrow oval crown with drooping twigs, small toothed leaves, white bark with lenticels.
fn paper_birch() -> Species {
    let p = params(&[
        ("Shape", 7.0),
        ("BaseSize", 0.3),
        ("Scale", 18.0),
        ("ScaleV", 0.0),
        ("Levels", 4.0),
        ("Ratio", 0.014),
        ("RatioPower", 1.2),
        ("Flare", 0.4),
        ("Leaves", 27.0),
        ("LeafScale", 0.085),
        ("LeafScaleX", 0.75),
        ("LeafBend", 0.3),
        ("AttractionUp", -0.4),
        ("0CurveRes", 8.0),
        ("0CurveV", 15.0),
        ("1DownAngle", 50.0),
        ("1DownAngleV", -20.0),
        ("1Rotate", 140.0),
        ("1Branches", 45.0),
        ("1Length", 0.3),
        ("1LengthV", 0.05),
        ("1CurveRes", 5.0),
        ("1Curve", -15.0),
        ("1CurveV", 40.0),
        ("2DownAngle", 45.0),
        ("2DownAngleV", 10.0),
        ("2Rotate", 140.0),
        ("2Branches", 22.0),
        ("2Length", 0.55),
        ("2LengthV", 0.1),
        ("2CurveRes", 3.0),
        ("2Curve", 20.0),
        ("2CurveV", 60.0),
        ("3DownAngle", 40.0),
        ("3DownAngleV", 10.0),
        ("3Rotate", 140.0),
        ("3Branches", 10.0),
        ("3Length", 0.45),
        ("3CurveRes", 2.0),
        ("3CurveV", 40.0),
    ]);
    builtin(
        "paper_birch",
        p,
        37,
        (LeafOutline::OvateSerrate, [92, 142, 52]),
        (BarkPattern::Birch, [228, 224, 214]),
        Some(372_896),
        TABLE2,
    )
}

/// Broad irregular crown, large heart-shaped light-green leaves, grey-brown bark.
fn southern_catalpa() -> Species {
    let p = params(&[
        ("Shape", 2.0),
        ("BaseSize", 0.3),
        ("Scale", 12.0),
        ("Levels", 3.0),
        ("Ratio", 0.025),
        ("RatioPower", 1.3),
        ("Flare", 0.6),
        ("Leaves", 36.0),
        ("LeafScale", 0.28),
        ("LeafScaleX", 0.85),
        ("LeafBend", 0.5),
        ("AttractionUp", 0.3),
        ("0CurveRes", 6.0),
        ("0CurveV", 30.0),
        ("0SegSplits", 0.4),
        ("0SplitAngle", 30.0),
        ("1DownAngle", 55.0),
        ("1DownAngleV", -20.0),
        ("1Rotate", 140.0),
        ("1Branches", 30.0),
        ("1Length", 0.5),
        ("1LengthV", 0.1),
        ("1CurveRes", 5.0),
        ("1Curve", -30.0),
        ("1CurveV", 80.0),
        ("1SegSplits", 0.1),
        ("1SplitAngle", 30.0),
        ("2DownAngle", 45.0),
        ("2DownAngleV", 10.0),
        ("2Rotate", 140.0),
        ("2Branches", 25.0),
        ("2Length", 0.45),
        ("2LengthV", 0.1),
        ("2CurveRes", 3.0),
        ("2Curve", 10.0),
        ("2CurveV", 60.0),
        ("3DownAngle", 45.0),
        ("3DownAngleV", 10.0),
        ("3Rotate", 140.0),
    ]);
    builtin(
        "southern_catalpa",
        p,
        41,
        (LeafOutline::Cordate, [112, 158, 60]),
        (BarkPattern::Furrowed, [138, 118, 94]),
        Some(155_342),
        TABLE2,
    )
}

/// Tall broad dense crown, elliptic toothed leaves, smooth grey bark.
fn american_beech() -> Species {
    let p = params(&[
        ("Shape", 1.0),
        ("BaseSize", 0.2),
        ("Scale", 20.0),
        ("Levels", 4.0),
        ("Ratio", 0.02),
        ("RatioPower", 1.3),
        ("Lobes", 3.0),
        ("LobeDepth", 0.05),
        ("Flare", 0.8),
        ("Leaves", 18.5),
        ("LeafScale", 0.12),
        ("LeafScaleX", 0.55),
        ("LeafBend", 0.4),
        ("AttractionUp", 0.3),
        ("0CurveRes", 10.0),
        ("0CurveV", 20.0),
        ("0SegSplits", 0.2),
        ("0SplitAngle", 20.0),
        ("1DownAngle", 60.0),
        ("1DownAngleV", -30.0),
        ("1Rotate", 140.0),
        ("1Branches", 50.0),
        ("1Length", 0.35),
        ("1LengthV", 0.05),
        ("1CurveRes", 6.0),
        ("1Curve", -20.0),
        ("1CurveV", 50.0),
        ("2DownAngle", 45.0),
        ("2DownAngleV", 10.0),
        ("2Rotate", 140.0),
        ("2Branches", 25.0),
        ("2Length", 0.5),
        ("2LengthV", 0.1),
        ("2CurveRes", 4.0),
        ("2Curve", -10.0),
        ("2CurveV", 60.0),
        ("3DownAngle", 45.0),
        ("3DownAngleV", 10.0),
        ("3Rotate", 140.0),
        ("3Branches", 5.0),
        ("3Length", 0.4),
        ("3CurveRes", 1.0),
        ("3CurveV", 30.0),
    ]);
    builtin(
        "american_beech",
        p,
        53,
        (LeafOutline::OvateSerrate, [72, 124, 44]),
        (BarkPattern::Smooth, [150, 150, 144]),
        Some(496_719),
        TABLE2,
    )
}

/// Conical conifer with whorled branches and needle fascicles, reddish plated bark.
fn pine() -> Species {
    let p = params(&[
        ("Shape", 0.0),
        ("BaseSize", 0.35),
        ("Scale", 20.0),
        ("Levels", 3.0),
        ("Ratio", 0.017),
        ("RatioPower", 1.4),
        ("Flare", 0.4),
        ("Leaves", 60.0),
        ("LeafScale", 0.16),
        ("LeafScaleX", 0.6),
        ("LeafBend", 0.2),
        ("0CurveRes", 8.0),
        ("0CurveV", 8.0),
        ("1DownAngle", 80.0),
        ("1DownAngleV", -20.0),
        ("1Rotate", 137.5),
        ("1Branches", 90.0),
        ("1Length", 0.35),
        ("1LengthV", 0.04),
        ("1CurveRes", 4.0),
        ("1Curve", 20.0),
        ("1CurveV", 20.0),
        ("2DownAngle", 50.0),
        ("2DownAngleV", 10.0),
        ("2Rotate", -90.0),
        ("2Branches", 30.0),
        ("2Length", 0.3),
        ("2LengthV", 0.05),
        ("2CurveRes", 2.0),
        ("2CurveV", 30.0),
        ("3DownAngle", 30.0),
        ("3DownAngleV", 10.0),
        ("3Rotate", 137.5),
    ]);
    builtin(
        "pine",
        p,
        67,
        (LeafOutline::Needles, [44, 84, 40]),
        (BarkPattern::Plated, [122, 76, 50]),
        None,
        "paper 000 Fig. 3b (beech trees replaced by pines)",
    )
}

/// Multi-stemmed arching shrub about 2 m high with pinnate leaves (Rosa canina).
fn dogrose() -> Species {
    let p = params(&[
        ("Shape", 3.0),
        ("BaseSize", 0.1),
        ("Scale", 2.2),
        ("Levels", 3.0),
        ("Ratio", 0.012),
        ("RatioPower", 1.2),
        ("Flare", 0.0),
        ("Leaves", 20.0),
        ("LeafScale", 0.1),
        ("LeafScaleX", 0.8),
        ("LeafBend", 0.6),
        ("0CurveRes", 6.0),
        ("0Curve", 50.0),
        ("0CurveV", 20.0),
        ("0BaseSplits", 6.0),
        ("0SplitAngle", 22.0),
        ("0SplitAngleV", 10.0),
        ("0Taper", 0.8),
        ("1DownAngle", 50.0),
        ("1DownAngleV", 10.0),
        ("1Rotate", 140.0),
        ("1Branches", 14.0),
        ("1Length", 0.35),
        ("1LengthV", 0.05),
        ("1CurveRes", 3.0),
        ("1Curve", 20.0),
        ("1CurveV", 30.0),
        ("2DownAngle", 40.0),
        ("2DownAngleV", 10.0),
        ("2Rotate", -90.0),
        ("2Branches", 8.0),
        ("2Length", 0.5),
        ("2CurveRes", 2.0),
        ("3DownAngle", 45.0),
        ("3DownAngleV", 10.0),
        ("3Rotate", 140.0),
    ]);
    builtin(
        "dogrose",
        p,
        79,
        (LeafOutline::Pinnate, [66, 118, 44]),
        (BarkPattern::Smooth, [96, 104, 58]),
        None,
        "paper 002 §3.2.2 (Xfrog dogrose, Rosa canina)",
    )
    .with_leaf(DOGROSE_LEAF, DOGROSE_SOURCE)
}

/// Triangles of 003's Table 3 tree (§4.2: "The tree model consisted of 18K triangles").
pub const PAPER_003_TREE_TRIANGLES: usize = 18_000;

/// `red_maple` thinned to 003 §4.2's tree size: the same Weber & Penn model, seed, size, crown
/// envelope, leaves and bark, with fewer branches (`1Branches` 45 → 20, `2Branches` 35 → 12),
/// so the tree has about 18K triangles (003 Table 3's tree) and a sparse, open crown: about a
/// seventh of `red_maple`'s leaves in the same 11 m wide, 17 m high envelope.
fn sparse_maple() -> Species {
    let mut s = red_maple();
    for (name, value) in [("1Branches", 20.0), ("2Branches", 12.0)] {
        s.params
            .set(name, value)
            .unwrap_or_else(|e| panic!("built-in species parameter: {e}"));
    }
    Species {
        name: "sparse_maple".into(),
        display_name: "sparse maple".into(),
        reference_triangles: Some(PAPER_003_TREE_TRIANGLES),
        source: "paper 003 §4.2 (the 18K-triangle tree of Table 3): red_maple with fewer branches"
            .into(),
        ..s
    }
}

/// The dogrose's leaf (002 Table 1, derived from Knapp & Carter as 000 derives its own): the
/// albedo `R + T = 1 − σ_a / 0.125` from its `σ_a` = (0.109, 0.091, 0.118) (000 §3 scales
/// absorptance by 0.125), split by its asymmetry `g = (T − R) / (T + R)` = (−0.231, 0.103,
/// −0.750): `R = (R + T)(1 − g) / 2`, `T = (R + T)(1 + g) / 2`.
pub const DOGROSE_LEAF: Measured = {
    let albedo = [
        1.0 - 0.109 / 0.125,
        1.0 - 0.091 / 0.125,
        1.0 - 0.118 / 0.125,
    ];
    let g = [-0.231, 0.103, -0.750];
    Measured {
        reflectance: [
            albedo[0] * (1.0 - g[0]) / 2.0,
            albedo[1] * (1.0 - g[1]) / 2.0,
            albedo[2] * (1.0 - g[2]) / 2.0,
        ],
        transmittance: [
            albedo[0] * (1.0 + g[0]) / 2.0,
            albedo[1] * (1.0 + g[1]) / 2.0,
            albedo[2] * (1.0 + g[2]) / 2.0,
        ],
    }
};

/// The source of [`DOGROSE_LEAF`], as `species show` prints it.
pub const DOGROSE_SOURCE: &str = "paper 002 Table 1 (dogrose, from Knapp & Carter): \
     R + T = 1 − σ_a / 0.125, split by g = (T − R) / (T + R)";

/// The dogrose's leaf transmittance / reflectance before issue 29, `(1 + g) / (1 - g)` from
/// the asymmetry `g` = (-0.231, 0.103, -0.750) of 002 Table 1: what `--leaf-optics texture`
/// reproduces from [`DOGROSE_LEAF`].
pub const DOGROSE_LEAF_TRANSMISSION: [f32; 3] = [
    (1.0 - 0.231) / (1.0 + 0.231),
    (1.0 + 0.103) / (1.0 - 0.103),
    (1.0 - 0.750) / (1.0 + 0.750),
];
