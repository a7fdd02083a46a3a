//! The tree machinery on a "tree" shaped like a slab (the plane-parallel condition): square
//! leaves with random positions and orientations filling a wide, thin box, lit from above.
//! Prints, by depth below the top, the Monte Carlo leaf irradiance of the central meshes beside
//! the full plane-parallel model, the SPP model (both readings of its hemispheric totals) and
//! the eq. 29 depths against the Poisson expectation.
//!
//! `cargo run --release -p sylva-spp --example slab_tree [-- LEAVES PHOTONS]`

use glam::Vec3;
use sylva_spp::trees::beam::{count_depths, Beam};
use sylva_spp::trees::meshes::SceneMeshes;
use sylva_spp::trees::photons::{trace_photons, PhotonConfig};
use sylva_spp::trees::shading::TreeSpp;
use sylva_spp::trees::synthetic::{leaf_slab, single_instance};
use sylva_spp::{FullModel, Slab};
use sylva_trace::SceneAccel;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let leaves: usize = args.get(1).map_or(320_000, |s| s.parse().unwrap());
    let photons: u64 = args.get(2).map_or(4_000_000, |s| s.parse().unwrap());
    let (half, thickness, side, albedo) = (5.0f32, 1.0f32, 0.07f32, 0.95);
    let model = leaf_slab(half, 0.0, thickness, side, leaves, 7);
    let density = leaves as f64 / (4.0 * half as f64 * half as f64 * thickness as f64);
    // Mean surfaces crossed per unit length: n · side² · <|cos|> = n side² / 2.
    let sigma = density * (side as f64).powi(2) * 0.5;
    let tau = sigma * thickness as f64;
    println!("{leaves} leaves, optical thickness {tau:.2} (σ {sigma:.2} per m), albedo {albedo}");
    let models = vec![model];
    let accel = SceneAccel::from_parts(&models, &single_instance(), None).unwrap();
    let meshes = SceneMeshes::new(&models, &accel);
    let beam = Beam::covering(&accel, Vec3::NEG_Y).unwrap();
    let counts = count_depths(&accel, &meshes, &beam, side / 4.0, &|_| {}).unwrap();
    let tally = trace_photons(
        &accel,
        &meshes,
        &beam,
        &PhotonConfig::with_albedo(photons, 3, albedo),
        &|_| {},
    )
    .unwrap();
    let mm = &meshes.models[0];
    let full = FullModel::new(Slab::new(1.0, albedo, 0.0, tau, 1.0).unwrap()).unwrap();
    let spp = TreeSpp::new(albedo).unwrap();
    let bins = 10;
    let mut sum = vec![[0.0f64; 6]; bins];
    for m in 0..mm.leaf_count {
        let c = mm.centroid[m];
        if c.x.abs() > 0.4 * half || c.z.abs() > 0.4 * half || mm.area[m] <= 0.0 {
            continue;
        }
        let (Some(d), Some(w)) = (counts.depth(m), counts.thickness(m)) else {
            continue;
        };
        let b = (((thickness - c.y) / thickness * bins as f32) as usize).min(bins - 1);
        let e = tally.total_hits(m) as f64 * tally.power_per_photon / mm.area[m] as f64;
        let e0 = tally.first_hits[m] as f64 * tally.power_per_photon / mm.area[m] as f64;
        let s = &mut sum[b];
        s[0] += 1.0;
        s[1] += e;
        s[2] += e0;
        s[3] += d;
        s[4] += w;
        s[5] += mm.mean_abs_cos(m, Vec3::NEG_Y) as f64;
    }
    println!("  depth  meshes   MC E  MC dir |  d (eq.29)  τ(z)   w    | full φ/2+dir  SPP (E+ + E−)/2+dir  SPP E+ + E− + dir");
    for (b, s) in sum.iter().enumerate() {
        let n = s[0];
        if n == 0.0 {
            continue;
        }
        let zg = (b as f64 + 0.5) / bins as f64 * thickness as f64;
        let z = zg * sigma;
        let (d, w, cos) = (s[3] / n, s[4] / n, s[5] / n);
        let (fd, fu) = full.hemispheric_totals(z).unwrap();
        let direct = cos * (-z).exp();
        let (ep, em) = spp.diffuse(d, w).unwrap();
        println!(
            "  {zg:5.2}  {n:6}  {:6.4}  {:6.4} | {d:6.2}  {z:6.2}  {w:6.2} | {:9.4}  {:9.4}  {:9.4}",
            s[1] / n,
            s[2] / n,
            0.5 * (fd + fu) + direct,
            0.5 * (ep + em) + cos * (-d).exp(),
            ep + em + cos * (-d).exp(),
        );
    }
    println!(
        "photons: escaped {:.4}, absorbed {:.4}",
        tally.escaped as f64 / photons as f64,
        tally.absorbed_leaves as f64 / photons as f64
    );
}
