//! `sylva voxelize`: a model → its LB density grid (.sgrid) and a PNG preview; also the model
//! loading and voxelizing that `sylva lb solve --model/--scene` shares.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use sylva_core::{companion_path, OutputSet};
use sylva_geom::Model;
use sylva_lb::preview::density_preview_png;
use sylva_lb::report::write_with_preview;
use sylva_lb::{DensityGrid, Element, GridFile};
use sylva_voxel::{cell_size, grid_metadata, voxelize, Occupancy, VoxelizeOptions, DEFAULT_GRID};

use super::progress::bar;

#[derive(Args)]
pub struct VoxelizeArgs {
    /// The model: a built-in species name (see `sylva species list`), an Arbaro species file
    /// (.xml), or a mesh (.obj, .gltf, .glb).
    model: String,
    /// Output density grid (default sylva-out/<model>-<N>.sgrid).
    #[arg(short, long)]
    output: Option<PathBuf>,
    /// Sites along the model's longest edge, the boundary shell included: the N of an
    /// N³-class grid, 4 to 2048. The other edges get as many sites as the model's shape needs.
    #[arg(long, default_value_t = DEFAULT_GRID)]
    grid: usize,
    /// Store the grid as f16 (half the size; densities are multiples of 1/27, so f16 keeps
    /// them to 3 significant digits).
    #[arg(long)]
    f16: bool,
    /// Preview image: three central slices, leaf density green, wood brown (default: the
    /// output path with .png).
    #[arg(long)]
    png: Option<PathBuf>,
    /// Count leaf triangles wherever they are, ignoring the transparent parts of their
    /// textures.
    #[arg(long)]
    no_alpha: bool,
    /// What a site's density is: area (the probability that light crossing the cell meets a
    /// leaf or bark, from their area; docs/light.md) or subcells (the share of 3×3×3
    /// sub-cells a triangle meets, 000 §4.2).
    #[arg(long, value_enum, default_value = "area")]
    occupancy: OccupancyArg,
}

/// `--occupancy`.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum OccupancyArg {
    Area,
    Subcells,
}

impl From<OccupancyArg> for Occupancy {
    fn from(a: OccupancyArg) -> Occupancy {
        match a {
            OccupancyArg::Area => Occupancy::Area,
            OccupancyArg::Subcells => Occupancy::SubCells,
        }
    }
}

/// A voxelized model and what was spent making it.
pub struct Voxelized {
    pub grid: DensityGrid,
    /// The model's name.
    pub name: String,
    pub metadata: Vec<(String, String)>,
    pub triangles: usize,
    /// Cell edge in model units.
    pub cell: f32,
    pub load_s: f64,
    pub voxelize_s: f64,
}

/// Voxelizes `model` (named `spec` on the command line) with `n` sites along its longest edge,
/// with a progress bar; the metadata records where the grid came from.
pub fn voxelize_model(
    model: &Model,
    spec: &str,
    n: usize,
    alpha_test: bool,
    occupancy: Occupancy,
) -> Result<Voxelized> {
    let t = Instant::now();
    let pb = bar(1, "voxelize");
    pb.set_message(format!("{} triangles", model.triangle_count()));
    let opts = VoxelizeOptions {
        grid: n,
        alpha_test,
        occupancy,
    };
    let grid = voxelize(model, &opts).with_context(|| format!("voxelizing '{spec}'"))?;
    pb.finish_and_clear();
    Ok(Voxelized {
        metadata: grid_metadata(model, spec, &opts, &grid),
        cell: cell_size(&grid),
        grid,
        name: model.name.clone(),
        triangles: model.triangle_count(),
        load_s: 0.0,
        voxelize_s: t.elapsed().as_secs_f64(),
    })
}

/// Loads `spec` (species name or model file) with a progress bar and voxelizes it.
pub fn load_and_voxelize(
    spec: &str,
    n: usize,
    alpha_test: bool,
    occupancy: Occupancy,
) -> Result<Voxelized> {
    let t = Instant::now();
    let model = load_model_with_bar(spec)?;
    let load_s = t.elapsed().as_secs_f64();
    let mut v = voxelize_model(&model, spec, n, alpha_test, occupancy)?;
    v.load_s = load_s;
    Ok(v)
}

/// [`sylva_scene::load_model`] under a progress bar.
pub fn load_model_with_bar(spec: &str) -> Result<Model> {
    let pb = bar(1, "model");
    pb.set_message(format!("loading {spec}"));
    let model = sylva_scene::load_model(spec)?;
    pb.finish_and_clear();
    Ok(model)
}

pub fn run(a: VoxelizeArgs) -> Result<()> {
    let t0 = Instant::now();
    // Before the work: the grid and its preview must differ, replace no input (the model
    // file is protected once read) and be writable. Default names wait for the model's name.
    OutputSet::check_named(a.output.as_deref(), a.png.as_deref(), "png")?;
    let v = load_and_voxelize(&a.model, a.grid, !a.no_alpha, a.occupancy.into())?;
    let name = sylva_core::file_stem(&v.name, "model");
    let output = a
        .output
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("sylva-out/{name}-{}.sgrid", a.grid)));
    let png = companion_path(&output, a.png.as_deref(), "png");
    let mut file = GridFile::from_density(&v.grid, v.metadata.clone());
    if a.f16 {
        file.element = Element::F16;
    }
    let mut outputs = OutputSet::new::<&std::path::Path>(&[]);
    outputs.plan(&[&output, &png])?;
    let preview = density_preview_png(&v.grid);
    write_with_preview(&file, preview, &mut outputs, &output, &png)?;
    outputs.commit()?;
    let b = v.grid.bounds;
    println!("voxelized {name}: {} triangles", v.triangles);
    println!("  {}", v.grid.summary());
    println!(
        "  site centres span ({:.3}, {:.3}, {:.3}) .. ({:.3}, {:.3}, {:.3}), cell {}",
        b.min[0], b.min[1], b.min[2], b.max[0], b.max[1], b.max[2], v.cell
    );
    println!(
        "  time: model {:.3} s, voxelize {:.3} s ({:.1} M triangles/s, {} threads), total {:.3} s",
        v.load_s,
        v.voxelize_s,
        v.triangles as f64 / v.voxelize_s / 1e6,
        rayon::current_num_threads(),
        t0.elapsed().as_secs_f64()
    );
    println!("wrote {} and {}", output.display(), png.display());
    Ok(())
}
