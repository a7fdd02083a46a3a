//! `sylva relight SCENE --suns 24`: 004 Table 1's sequence. The sun moves over 90° about the
//! zenith; each frame relights every instance from its model's base solutions (no LB solve)
//! and renders. Numbered PNGs and an animated PNG, tone mapped with one exposure for the
//! whole sequence so frames compare, and the time of every frame. With `--lat --lon --date`
//! the suns are instead the sun's path over that day (`sylva_core::solar`: one frame per
//! `--step`, named by its clock time, the night's left out). Under `mpirun` the missing
//! base solutions are solved across the ranks and every frame is rendered across them
//! (`PreparedScene::render_split`); rank 0 writes the images, the same as one process's.

use std::path::{Path, PathBuf};

use anyhow::{bail, Result};
use clap::Args;
use sylva_core::limits::check_rays_per_pixel;
use sylva_core::OutputSet;
use sylva_io::export::available_disk_bytes;
use sylva_pipeline::sequence::{SequenceTimes, SunSequence};
use sylva_pipeline::{relight_light, Runner};
use sylva_render::sequence::{nearest_existing, Sequence};
use sylva_render::ToneMap;

use super::progress::bar;
use super::render::{
    prepare, FrameArgs, GridArgs, LbArgs, PrepareRequest, RelightLightArg, RelitArgs, ViewArgs,
    SCENE_HELP,
};
use super::sun_time::SunDayArgs;

/// What `sylva relight` uses: the frame's view, the LB grid and solver, how the bases
/// combine, the global grid and the sequence. The sun moves along its path (`--path-azimuth`),
/// so `--sun`, `--elevation` and `--azimuth` are refused, as is `--basis` (relighting always
/// uses them).
#[derive(Args, Debug)]
pub struct RelightArgs {
    #[arg(default_value = "demo", help = SCENE_HELP)]
    pub scene: String,
    #[command(flatten)]
    pub view: ViewArgs,
    #[command(flatten)]
    pub light: RelightLightArg,
    #[command(flatten)]
    pub lb: LbArgs,
    #[command(flatten)]
    pub relit: RelitArgs,
    #[command(flatten)]
    pub grid: GridArgs,
    /// The sun's path over a day at a place (--lat, --lon, --date, --from, --to, --step,
    /// --utc-offset), in place of 004's sequence.
    #[command(flatten)]
    pub day: SunDayArgs,
    /// Sun positions, evenly spaced over 90° about the zenith (004 Table 1: 24).
    #[arg(long, default_value_t = 24, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub suns: u32,
    /// Azimuth of the sun's path in degrees (from +x towards +z): the sun rises from 45°
    /// elevation opposite it, passes the zenith and sets to 45° at it. Default: the scene's
    /// sun azimuth.
    #[arg(long, allow_negative_numbers = true)]
    pub path_azimuth: Option<f64>,
    /// Output directory (default sylva-out/relight-<scene>): frame-00.png, … (with --date
    /// frame-HHMM.png by clock time, frame-0530.png) and <scene>.png, the animated PNG.
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Rays per pixel (default: the scene camera's).
    #[arg(long)]
    pub rpp: Option<u32>,
    /// Milliseconds each frame shows in the animation.
    #[arg(long, default_value_t = 125)]
    pub delay_ms: u32,
    /// Reinhard key, for the whole sequence.
    #[arg(long, default_value_t = 0.18)]
    pub key: f32,
    /// Reinhard white point (default: the sequence's brightest pixel).
    #[arg(long)]
    pub white: Option<f32>,
    /// Physical light: final-gather rays per camera sample on a plant, 0 to 256 (0: the LB
    /// light at the leaf itself, several times faster; docs/light.md, "The final gather").
    /// [default: 128 per pixel shared by its samples: 8 up to 16 rays/pixel, 4 at 32, 2 from
    /// 64 on]
    #[arg(
        long,
        allow_negative_numbers = true,
        value_parser = clap::value_parser!(u32).range(0..=i64::from(sylva_render::gather::MAX_GATHER_RAYS))
    )]
    pub gather_rays: Option<u32>,
}

pub fn run(a: RelightArgs, runner: &dyn Runner) -> Result<()> {
    let root = runner.is_root();
    // The physical and the paper light have base solutions: another is refused before the
    // scene loads.
    relight_light(a.light.light.as_deref())?;
    check_rays_per_pixel(a.rpp).map_err(anyhow::Error::msg)?;
    if !(1..=65535).contains(&a.delay_ms) {
        bail!("--delay-ms {}: 1 to 65535", a.delay_ms);
    }
    if let Some(az) = a.path_azimuth {
        if !az.is_finite() {
            bail!("--path-azimuth {az}: not a number");
        }
    }
    let tm = ToneMap {
        key: a.key,
        white: a.white,
    };
    tm.validate().map_err(anyhow::Error::msg)?;
    // The day's path, its night left out, before any work (a sun that never rises is an
    // error).
    let day = match a.day.path()? {
        Some(path) => Some((path, path.day()?)),
        None => None,
    };
    if let (Some(dir), true) = (&a.output, root) {
        // A folder that is a file or takes no files fails now, not after the basis solves
        // (the frame names are checked in full below, once the scene is known).
        OutputSet::new::<&Path>(&[]).plan(&[dir.join("frame-00.png")])?;
    }
    // The disk the sequence needs is checked once the image size is known, before any LB
    // work; memory holds one frame at a time (and the one read back at the end).
    let disk = nearest_existing(a.output.as_deref().unwrap_or(Path::new("sylva-out")));
    let frames = day.as_ref().map_or(a.suns as usize, |(_, d)| d.up.len());
    let check = |w: u32, h: u32| match root {
        true => Ok(Sequence::check_disk(
            &disk,
            available_disk_bytes(&disk),
            w,
            h,
            frames,
        )?),
        false => Ok(()),
    };
    let p = prepare(
        // Its own options, with the scene's sun (the path replaces it).
        &FrameArgs::relit(
            &a.scene,
            &a.view,
            &a.light.light,
            a.gather_rays,
            (&a.lb, &a.relit, &a.grid),
        ),
        PrepareRequest {
            need_lb: true,
            rays_per_pixel: a.rpp,
            output_images: 2,
            force_basis: true,
            check_size: Some(&check),
            ..PrepareRequest::default()
        },
        runner,
    )?;
    let mut prepared = p.scene;
    let rpp = a.rpp.unwrap_or(prepared.scene.camera.rays_per_pixel);
    let camera = prepared.camera(p.width, p.height);
    let settings = prepared.settings(camera, rpp, a.view.seed);
    let suns = match day {
        Some((path, day)) => SunSequence::day(path, day),
        None => {
            let azimuth = a.path_azimuth;
            let azimuth = azimuth.unwrap_or_else(|| prepared.scene.sun.azimuth_deg());
            SunSequence::zenith(a.suns as usize, azimuth)
        }
    };
    // The frames and the animation replace their old versions together (or none do), and
    // bad output names fail before the long work.
    let stem = sylva_core::file_stem(&prepared.scene.name, "scene");
    let dir =
        (a.output.clone()).unwrap_or_else(|| PathBuf::from(format!("sylva-out/relight-{stem}")));
    let frame_paths: Vec<PathBuf> = (suns.labels.iter())
        .map(|l| dir.join(format!("frame-{l}.png")))
        .collect();
    let anim = dir.join(format!("{stem}.png"));
    let mut outputs = OutputSet::new::<&Path>(&[]);
    // Rank 0 keeps the frames, on disk (an unnamed file the system removes however this
    // ends) until the sequence's exposure is known.
    let mut sequence = None;
    if root {
        outputs.plan(&frame_paths)?;
        outputs.plan(&[&anim])?;
        let (w, h, n) = (p.width, p.height, suns.suns.len());
        sequence = Some(Sequence::new(&nearest_existing(&dir), w, h, n, tm)?);
        let ranks = match runner.processes() {
            1 => String::new(),
            n => format!(", {n} MPI ranks"),
        };
        let path = suns.describe();
        let gather = sylva_pipeline::report::gather_note(&settings.shading);
        println!("{n} suns {path}; {w}x{h} at {rpp} rays/pixel{gather}{ranks}");
    }
    if let (Some(note), true) = (suns.night_note(), root) {
        println!("note: {note}");
    }
    let pb = match root {
        true => bar(suns.suns.len() as u64, "relight"),
        false => indicatif::ProgressBar::hidden(),
    };
    let mut times = SequenceTimes::default();
    for (k, &sun) in suns.suns.iter().enumerate() {
        let Some(frame) = prepared.relight_frame(runner, &settings, sun)? else {
            continue;
        };
        pb.suspend(|| println!("  frame {k:2}{}: {frame}", suns.at(k)));
        times.push(&frame);
        if let Some(s) = sequence.as_mut() {
            s.push(&frame.hdr)?;
        }
        pb.inc(1);
    }
    pb.finish_and_clear();
    let Some(sequence) = sequence else {
        return Ok(());
    };
    sequence.finish(&mut outputs, &frame_paths, &anim, a.delay_ms)?;
    outputs.commit()?;
    let name = |p: &PathBuf| {
        p.file_name()
            .unwrap_or_default()
            .to_string_lossy()
            .to_string()
    };
    println!(
        "wrote {} frames ({} … {}) and the animation {} to {}",
        times.seconds.len(),
        name(&frame_paths[0]),
        name(&frame_paths[frame_paths.len() - 1]),
        name(&anim),
        dir.display()
    );
    println!("{times}");
    Ok(())
}
