//! Built-in species: triangle counts against paper 000 Table 2 (and 003's 18K-triangle tree),
//! determinism, materials, form.

use sylva_geom::{
    is_opaque, LeafOptics, MaterialKind, FOREST_LEAF_TRANSMISSION, KNAPP_CARTER_LEAF,
};
use sylva_grow::species::{BUILTIN_NAMES, DOGROSE_LEAF, DOGROSE_LEAF_TRANSMISSION};
use sylva_grow::weber_penn::{self, Params, LEAF, WOOD};
use sylva_grow::Species;

fn pool(threads: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
}

#[test]
fn triangle_counts_match_table_2_within_ten_percent() {
    let table = [
        ("red_maple", 115_529),
        ("ohio_buckeye", 168_520),
        ("paper_birch", 372_896),
        ("southern_catalpa", 155_342),
        ("american_beech", 496_719),
    ];
    for (name, reference) in table {
        let s = Species::builtin(name).unwrap();
        assert_eq!(s.reference_triangles, Some(reference));
        let n = s.generate_mesh().unwrap().triangle_count() as f64;
        let ratio = n / reference as f64;
        assert!(
            (0.9..=1.1).contains(&ratio),
            "{name}: {n} triangles vs {reference} in Table 2 (ratio {ratio:.3})"
        );
    }
}

#[test]
fn sparse_maple_is_red_maple_thinned_to_the_003_tree() {
    use sylva_grow::species::PAPER_003_TREE_TRIANGLES;
    let sparse = Species::builtin("sparse_maple").unwrap();
    let maple = Species::builtin("red_maple").unwrap();
    assert_eq!(sparse.reference_triangles, Some(PAPER_003_TREE_TRIANGLES));
    // The same model but for the branch counts.
    let mut p = maple.params.clone();
    p.set("1Branches", 20.0).unwrap();
    p.set("2Branches", 12.0).unwrap();
    assert_eq!(sparse.params, p);
    assert_eq!(sparse.seed, maple.seed);
    let (s, m) = (
        sparse.generate_mesh().unwrap(),
        maple.generate_mesh().unwrap(),
    );
    // 003 §4.2: "18K triangles".
    let ratio = s.triangle_count() as f64 / PAPER_003_TREE_TRIANGLES as f64;
    assert!(
        (0.9..=1.1).contains(&ratio),
        "{} triangles",
        s.triangle_count()
    );
    // A seventh of the leaves in the same crown envelope: a sparse, open crown.
    let (ls, lm) = (
        s.triangles_with_material(LEAF),
        m.triangles_with_material(LEAF),
    );
    assert!(
        ls * 6 < lm && ls * 8 > lm,
        "{ls} against {lm} leaf triangles"
    );
    let (bs, bm) = (s.bounds().size(), m.bounds().size());
    for k in 0..3 {
        assert!(
            (bs[k] / bm[k] - 1.0).abs() < 0.15,
            "crown {bs} against red_maple's {bm}"
        );
    }
}

#[test]
fn generation_is_deterministic_on_one_and_two_threads() {
    for name in ["american_beech", "dogrose"] {
        let s = Species::builtin(name).unwrap();
        let one = pool(1).install(|| s.generate_mesh().unwrap());
        let two = pool(2).install(|| s.generate_mesh().unwrap());
        assert_eq!(one.triangle_count(), two.triangle_count(), "{name}");
        assert_eq!(one.geometry_hash(), two.geometry_hash(), "{name}");
        // A different seed grows a different tree.
        let mut other = s.clone();
        other.seed += 1;
        assert_ne!(
            other.generate_mesh().unwrap().geometry_hash(),
            one.geometry_hash(),
            "{name}"
        );
    }
}

#[test]
fn every_builtin_keeps_leaf_and_wood_apart_with_textures() {
    for s in Species::all_builtin() {
        let m = s.build_model().unwrap();
        m.mesh.validate(m.materials.len()).unwrap();
        assert_eq!(m.materials.len(), 2);
        assert_eq!(m.materials[WOOD as usize].kind, MaterialKind::Wood);
        assert_eq!(m.materials[LEAF as usize].kind, MaterialKind::Leaf);
        assert!(m.materials[LEAF as usize].two_sided);
        let leaf_tex = m.materials[LEAF as usize].texture.as_ref().unwrap();
        let bark_tex = m.materials[WOOD as usize].texture.as_ref().unwrap();
        assert!(
            leaf_tex.opaque_fraction() < 0.9,
            "{}: leaf shape must be in alpha",
            s.name
        );
        assert_eq!(bark_tex.opaque_fraction(), 1.0);
        let leaves = m.mesh.triangles_with_material(LEAF);
        let wood = m.mesh.triangles_with_material(WOOD);
        // The smallest, `sparse_maple` (003's 18K-triangle tree), has about 10 K of each.
        assert!(
            leaves > 8_000 && wood > 8_000,
            "{}: {leaves} leaf, {wood} wood",
            s.name
        );
        // Leaf colour is green; wood is not.
        let lc = m.materials[LEAF as usize].base_color;
        assert!(lc[1] > lc[0] && lc[1] > lc[2], "{}: leaf {lc:?}", s.name);
        // Trees stand on the ground at the origin.
        assert!(m.bounds.min.y.abs() < 0.5, "{}: {:?}", s.name, m.bounds);
    }
}

#[test]
fn forms_read_as_their_species() {
    let size = |n: &str| {
        let m = Species::builtin(n).unwrap().generate_mesh().unwrap();
        m.bounds().size()
    };
    let rose = size("dogrose");
    assert!(rose.y > 1.0 && rose.y < 4.0, "a dogrose is a shrub: {rose}");
    assert!(rose.x > rose.y, "a dogrose spreads wider than tall: {rose}");
    let birch = size("paper_birch");
    assert!(
        birch.y > 1.5 * birch.x,
        "paper birch has a narrow crown: {birch}"
    );
    let catalpa = size("southern_catalpa");
    assert!(
        catalpa.x > catalpa.y,
        "catalpa has a broad crown: {catalpa}"
    );
    let beech = size("american_beech");
    assert!(beech.y > 15.0, "american beech is a tall tree: {beech}");
    // Birch bark is light, pine bark reddish brown.
    let bark =
        |n: &str| Species::builtin(n).unwrap().materials().unwrap()[WOOD as usize].base_color;
    let b = bark("paper_birch");
    assert!(b.iter().all(|&c| c > 0.4), "birch bark {b:?}");
    let p = bark("pine");
    assert!(p[0] > p[1] && p[1] > p[2], "pine bark {p:?}");
}

#[test]
fn names_are_forgiving_and_listed() {
    assert!(Species::builtin("Red Maple").is_some());
    assert!(Species::builtin("american-beech").is_some());
    assert!(Species::builtin("oak").is_none());
    assert_eq!(Species::all_builtin().len(), BUILTIN_NAMES.len());
}

#[test]
fn runaway_parameters_are_refused_not_allocated() {
    let mut p = Params::default();
    p.set("Levels", 4.0).unwrap();
    for l in 1..4 {
        p.set(&format!("{l}Branches"), 2000.0).unwrap();
        p.set(&format!("{l}Length"), 0.5).unwrap();
    }
    p.set("Leaves", 10000.0).unwrap();
    let e = weber_penn::generate_with_limit(&p, 1, 1_000_000).unwrap_err();
    assert!(e.to_string().contains("exceed 1000000 triangles"), "{e}");
}

#[test]
fn taper_flare_and_zscale_shape_the_trunk() {
    let mut p = Params::default();
    p.set("Levels", 1.0).unwrap();
    p.set("Flare", 0.0).unwrap();
    p.set("0Taper", 0.0).unwrap();
    let cylinder = weber_penn::generate(&p, 1).unwrap();
    let b = cylinder.bounds();
    // Scale 10, 0Length 1, Ratio 0.015: a 10 m trunk of radius 0.15 m.
    assert!((b.size().y - 10.0).abs() < 1e-3, "{b:?}");
    assert!((b.size().x - 0.3).abs() < 0.01, "{b:?}");
    p.set("Flare", 2.0).unwrap();
    let flared = weber_penn::generate(&p, 1).unwrap().bounds();
    assert!(flared.size().x > 1.5 * b.size().x, "{flared:?}");
    p.set("ZScale", 2.0).unwrap();
    let tall = weber_penn::generate(&p, 1).unwrap().bounds();
    assert!((tall.size().y - 20.0).abs() < 1e-2, "{tall:?}");
    // A bare trunk carries no leaves until Leaves is set.
    assert_eq!(cylinder.triangles_with_material(LEAF), 0);
    p.set("Leaves", 50.0).unwrap();
    let leafy = weber_penn::generate(&p, 1).unwrap();
    assert_eq!(leafy.triangles_with_material(LEAF), 100);
}

#[test]
fn pruning_envelope_narrows_the_crown() {
    let mut p = Species::builtin("red_maple").unwrap().params;
    let wide = weber_penn::generate(&p, 3).unwrap().bounds().size();
    p.set("PruneRatio", 1.0).unwrap();
    p.set("PruneWidth", 0.2).unwrap();
    let pruned = weber_penn::generate(&p, 3).unwrap().bounds().size();
    assert!(pruned.x < 0.8 * wide.x, "{pruned} vs {wide}");
    // Leaf distribution shape matters: conical (0) puts fewer leaves near the base than
    // cylindrical (3).
    p.set("PruneRatio", 0.0).unwrap();
    p.set("LeafDistrib", 0.0).unwrap();
    let conical = weber_penn::generate(&p, 3)
        .unwrap()
        .triangles_with_material(LEAF);
    p.set("LeafDistrib", 3.0).unwrap();
    let cylindrical = weber_penn::generate(&p, 3)
        .unwrap()
        .triangles_with_material(LEAF);
    assert!(conical < cylindrical, "{conical} vs {cylindrical}");
}

mod any_valid_parameters {
    use proptest::prelude::*;
    use sylva_grow::weber_penn::{self, GenerateError, Params, GENERAL_SPECS, LEVEL_SPECS};

    /// A value inside `spec`'s range (whole where the parameter is), biased to moderate sizes
    /// for counts so most cases finish under the budget.
    fn value(spec: &weber_penn::ParamSpec, u: f64) -> f64 {
        let (lo, hi) = match spec.name {
            "Branches" => (0.0, 60.0),
            "Leaves" => (0.0, 80.0),
            "CurveRes" => (1.0, 12.0),
            "Scale" if spec.min > 0.0 && spec.max == 1000.0 => (0.5, 3.0),
            _ => (spec.min, spec.max),
        };
        let v = lo + (hi - lo) * u;
        if spec.integer {
            v.round().clamp(spec.min, spec.max)
        } else {
            v
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]
        /// Any in-range parameter set gives a valid mesh or a budget error, never a panic or
        /// non-finite geometry.
        #[test]
        fn valid_mesh_or_budget_error(
            general in proptest::collection::vec(0.0f64..1.0, GENERAL_SPECS.len()),
            levels in proptest::collection::vec(0.0f64..1.0, 4 * LEVEL_SPECS.len()),
            seed in 0u64..1000,
        ) {
            let mut p = Params::default();
            for (spec, u) in GENERAL_SPECS.iter().zip(&general) {
                let v = match spec.name {
                    "Scale" => 1.0 + 20.0 * u,
                    _ => value(spec, *u),
                };
                p.set(spec.name, v).unwrap();
            }
            for l in 0..4 {
                for (k, spec) in LEVEL_SPECS.iter().enumerate() {
                    let v = value(spec, levels[l * LEVEL_SPECS.len() + k]);
                    p.set(&format!("{l}{}", spec.name), v).unwrap();
                }
            }
            match weber_penn::generate_with_limit(&p, seed, 300_000) {
                Ok(mesh) => prop_assert!(mesh.validate(2).is_ok(), "{:?}", mesh.validate(2)),
                Err(GenerateError::TooManyTriangles { limit }) => prop_assert_eq!(limit, 300_000),
                Err(e) => prop_assert!(false, "unexpected error {e}"),
            }
        }
    }
}

#[test]
fn every_species_leaf_is_measured_and_averages_to_it() {
    for name in BUILTIN_NAMES {
        let s = Species::builtin(name).unwrap();
        // 000 Table 1 for the forest species (000 Table 2's and the pine of 000 Fig. 3b),
        // the dogrose's own from 002 Table 1.
        let want = if *name == "dogrose" {
            DOGROSE_LEAF
        } else {
            KNAPP_CARTER_LEAF
        };
        assert_eq!(s.leaf, want, "{name}");
        assert!(s.leaf.validate(name).is_ok());
        let mats = s.materials().unwrap();
        let leaf = &mats[LEAF as usize];
        assert_eq!(leaf.optics.measured, Some(want));
        // Over the leaf's opaque texels, decoded as the renderer decodes them, the mean
        // reflectance and transmittance are the measured ones.
        let tex = leaf.texture.as_ref().unwrap();
        let mut sums = [[0f64; 3]; 2];
        let mut n = 0usize;
        for p in tex.pixels.iter().filter(|p| is_opaque(**p)) {
            for c in 0..3 {
                let t = sylva_core::colour::srgb_to_linear(p[c] as f32 / 255.0);
                sums[0][c] += (t * leaf.optics.reflect[c]) as f64;
                sums[1][c] += (t * leaf.optics.transmit[c]) as f64;
            }
            n += 1;
        }
        for (c, (sum_r, sum_t)) in sums[0].iter().zip(sums[1]).enumerate() {
            let (r, t) = (sum_r / n as f64, sum_t / n as f64);
            let (wr, wt) = (want.reflectance[c] as f64, want.transmittance[c] as f64);
            assert!((r - wr).abs() < 1e-6 * wr, "{name} R[{c}]: {r} vs {wr}");
            assert!((t - wt).abs() < 1e-6 * wt, "{name} T[{c}]: {t} vs {wt}");
        }
        // Bark has no measured value: its reflectance is its texture's colour.
        assert_eq!(mats[WOOD as usize].optics, sylva_geom::Optics::OPAQUE);
    }
}

#[test]
fn texture_mode_gives_back_the_leaves_of_before() {
    // Before issue 29 a species' leaf reflected its texture colour and transmitted its T/R
    // of it: FOREST_LEAF_TRANSMISSION for the forest species (bit for bit), the dogrose's
    // (1 + g) / (1 − g) of 002 Table 1 (to f32 rounding: R and T are formed from g first).
    for name in BUILTIN_NAMES {
        let mut leaf = Species::builtin(name).unwrap().materials().unwrap()[LEAF as usize].clone();
        leaf.set_leaf_optics(LeafOptics::Texture).unwrap();
        assert_eq!(leaf.optics.reflect, [1.0; 3], "{name}");
        if *name == "dogrose" {
            for (c, (got, want)) in leaf
                .optics
                .transmit
                .iter()
                .zip(DOGROSE_LEAF_TRANSMISSION)
                .enumerate()
            {
                assert!((got - want).abs() < 1e-6 * want, "{c}: {got} vs {want}");
            }
        } else {
            assert_eq!(leaf.optics.transmit, FOREST_LEAF_TRANSMISSION, "{name}");
        }
    }
}

#[test]
fn the_dogrose_leaf_is_002_table_1() {
    // g = (T − R) / (T + R) and σ_a = 0.125 (1 − R − T) give back the table's values.
    let (g, sigma_a) = ([-0.231, 0.103, -0.750], [0.109, 0.091, 0.118]);
    for c in 0..3 {
        let (r, t) = (
            DOGROSE_LEAF.reflectance[c] as f64,
            DOGROSE_LEAF.transmittance[c] as f64,
        );
        assert!(((t - r) / (t + r) - g[c]).abs() < 1e-6, "g[{c}]");
        assert!(
            (0.125 * (1.0 - r - t) - sigma_a[c]).abs() < 1e-6,
            "σ_a[{c}]"
        );
    }
}
