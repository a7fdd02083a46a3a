//! `sylva export SCENE --format obj|mitsuba -o DIR`: a scene for other renderers, chiefly to
//! check sylva against a path tracer (Mitsuba 3). See `docs/export.md`.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use clap::Args;
use sylva_core::thousands;
use sylva_io::export::{self, mitsuba, obj, Format};

use super::progress::bar;

#[derive(Args)]
pub struct ExportArgs {
    /// A scene file (TOML) or a built-in scene: demo, beech, catalpa, canopy, shade, cloud,
    /// teapot, demo_cloud, woodland.
    pub scene: String,
    /// `obj`: the flattened scene (every instance in world space) as one OBJ + MTL + PNG
    /// textures, ground included. `mitsuba`: a Mitsuba 3 scene.xml that keeps the instancing
    /// (one binary PLY per model and material), with sun, sky, ground, camera and integrator,
    /// and media (clouds) as heterogeneous volumes.
    #[arg(long, short = 'f', value_name = "FORMAT")]
    pub format: Format,
    /// Output directory; created if missing, files of the same name in it are replaced (all
    /// together once every file is written; none on an error).
    #[arg(long, short = 'o', value_name = "DIR")]
    pub output: PathBuf,
    /// Mitsuba: samples per pixel written as the XML's `spp` default (default: the scene's
    /// rays_per_pixel; `mitsuba -Dspp=N` overrides it when rendering).
    #[arg(long, value_name = "N")]
    pub spp: Option<u32>,
    /// Mitsuba: the volpath integrator's max_depth in scattering events (-1: unbounded; passes
    /// through a leaf's transparent texels do not count). A cloud needs -1: its light
    /// scatters hundreds of times.
    #[arg(
        long,
        default_value_t = 64,
        allow_negative_numbers = true,
        value_name = "N"
    )]
    pub max_depth: i32,
    /// Mitsuba: the sun's irradiance on a surface facing it (its colour is a 6500 K black
    /// body). The default π lights a white Lambertian surface facing the sun to radiance 1,
    /// like sylva's local shading with a sun of intensity 1.
    #[arg(long, value_name = "E")]
    pub sun_irradiance: Option<f32>,
    /// Leaves as measured or as their texture, as `render --leaf-optics` (export with the
    /// same choice as the render compared against).
    #[arg(long, value_enum, default_value = "measured")]
    pub leaf_optics: super::render::LeafOpticsArg,
    /// A scene with `[bands]`: export band group G (bands 3G+1 to 3G+3 in the red, green and
    /// blue channels, as `sylva render` draws them; docs/render.md, "Spectral bands").
    /// Without it such a scene is exported in RGB.
    #[arg(long, value_name = "G")]
    pub band_group: Option<usize>,
}

/// False once Ctrl-C arrived (sylva-core's one handler, installed by `main`): the writers
/// stop at their next progress report, and the atomic writer removes the partial file (a
/// 50 GB temporary OBJ would otherwise stay).
fn keep_going() -> bool {
    !sylva_core::interrupt::interrupted()
}

pub fn run(args: ExportArgs) -> Result<()> {
    // Fail on a bad or unwritable output directory before the (possibly long) scene build;
    // the writers check each of their files again, against the scene's inputs, before the
    // first is written.
    export::prepare_dir(&args.output)?;
    let main_file = match args.format {
        Format::Obj => obj::OBJ_FILE,
        Format::Mitsuba => mitsuba::XML_FILE,
    };
    sylva_core::OutputSet::new::<&std::path::Path>(&[]).plan(&[args.output.join(main_file)])?;
    let t0 = Instant::now();
    let mut scene = sylva_scene::load(&args.scene)?;
    match args.band_group {
        Some(g) => eprintln!(
            "{}",
            super::render::apply_band_group(&mut scene, g, args.leaf_optics)
                .map_err(|e| e.context(format!("--band-group {g}")))?
        ),
        None if scene.bands.is_some() => eprintln!(
            "{}: exported in RGB; --band-group G exports its bands (three a group)",
            scene.origin
        ),
        None => {}
    }
    scene
        .set_leaf_optics(args.leaf_optics.into())
        .map_err(anyhow::Error::msg)?;
    let triangles = scene.instanced_triangles();
    eprintln!(
        "scene '{}': {} instances, {} instanced triangles (built in {:.1} s)",
        scene.name,
        thousands(scene.instances.len() as u64),
        thousands(triangles),
        t0.elapsed().as_secs_f64()
    );
    let t1 = Instant::now();
    if args.format == Format::Obj && !scene.media.is_empty() {
        eprintln!(
            "warning: OBJ holds no participating media: {} left out (the mitsuba format writes them)",
            scene.media.iter().map(|m| format!("'{}'", m.name)).collect::<Vec<_>>().join(", ")
        );
    }
    let result = match args.format {
        Format::Obj => {
            if obj::is_large(triangles) {
                let estimate = obj::estimate_size(&scene);
                if let Some(w) = obj::size_warning(triangles, estimate) {
                    eprintln!("warning: {w}");
                }
            }
            let pb = bar(scene.instances.len() as u64, "instances");
            let r = obj::write(&scene, &args.output, &mut |n| {
                pb.set_position(n);
                keep_going()
            });
            pb.finish_and_clear();
            r
        }
        Format::Mitsuba => {
            let mut opts = mitsuba::MitsubaOptions::for_scene(&scene);
            if let Some(spp) = args.spp {
                opts.spp = spp;
            }
            opts.max_depth = args.max_depth;
            if let Some(e) = args.sun_irradiance {
                opts.sun_irradiance = e;
            }
            let pb = bar(scene.models.len() as u64, "models");
            let r = mitsuba::write(&scene, &args.output, &opts, &mut |n| {
                pb.set_position(n);
                keep_going()
            });
            pb.finish_and_clear();
            r
        }
    };
    let written = match result {
        Err(_) if sylva_core::interrupt::interrupted() => anyhow::bail!(
            "{}: export interrupted (Ctrl-C): no file was replaced, the partial ones were removed",
            args.output.display()
        ),
        r => r?,
    };
    println!(
        "{}",
        written.summary(args.format, &args.output, t1.elapsed().as_secs_f64())
    );
    Ok(())
}
