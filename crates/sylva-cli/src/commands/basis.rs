//! `sylva basis SCENE`: precomputes every model's base solutions and caches them; afterwards
//! `sylva relight` (and `sylva render --basis always`) move the sun with no LB solve. The
//! physical light (the default): per model 13 sun parts and 3 diffuse parts, 16 solves, and
//! with several instances the forest grid's parts (`sylva_pipeline::physical`). The paper
//! light (`--light paper`): 19 base solutions (paper 004 §3.1: 54 solves per model, `B_0`
//! summed), compressed, and the scene's coarse global grid. Under `mpirun` the solves are jobs
//! handed out across the ranks; rank 0 alone prints and writes the cache, which holds what one
//! process writes.

use std::time::Instant;

use anyhow::Result;
use clap::Args;
use sylva_light::relight::GlobalGridOptions;
use sylva_light::{Progress, Silent};
use sylva_pipeline::{
    load_scene, precompute_physical, precompute_relighting, BasisUse, LbPlan, PhysicalBasisPlan,
    RelightingAt, Runner,
};

use super::progress::{Bars, Report};
use super::render::{
    costly_grid_warning, relight_light, relight_plan, report_line, BasisArg, GridArgs, LbArgs,
    RelightLightArg, RelitArgs, SCENE_HELP,
};

/// What `sylva basis` uses: the scene, the LB grid, cache and solver (`--device gpu` solves
/// on the GPU), the compression (`--codec`, `--basis-precision`) and the global grid
/// (`--no-global`, `--global-grid`). Nothing of a frame: those options are refused.
#[derive(Args, Debug)]
pub struct BasisArgs {
    #[arg(default_value = "demo", help = SCENE_HELP)]
    pub scene: String,
    #[command(flatten)]
    pub light: RelightLightArg,
    #[command(flatten)]
    pub lb: LbArgs,
    #[command(flatten)]
    pub grid: GridArgs,
    /// Also keep each model's uncompressed basis in the cache (57 × 4 bytes per site), which
    /// `sylva bench relight` measures compression against.
    #[arg(long)]
    pub keep_raw: bool,
    /// Print the independent solve jobs (model, base solution, colour) and stop: the work
    /// list a distributed precompute hands out.
    #[arg(long)]
    pub list_jobs: bool,
}

pub fn run(a: BasisArgs, runner: &dyn Runner) -> Result<()> {
    let t0 = Instant::now();
    let root = runner.is_root();
    let light = relight_light(a.light.light.as_deref())?;
    let physical = light == "physical";
    let scene = load_scene(&a.scene, None)?;
    // The plan's sun weights and ambient are the frames' business, not the solves'.
    let plan = relight_plan(
        BasisArg::Auto,
        &RelitArgs::default(),
        &a.grid,
        true,
        a.keep_raw,
        light,
    )?
    .expect("forced plans exist");
    let grid = a.lb.lb_grid.unwrap_or(scene.lb.grid as usize);
    if a.list_jobs && physical {
        if root {
            println!("model\tpart");
            for m in 0..scene.models.len() {
                for part in 0..sylva_light::relight::physical::PARTS {
                    println!("{m}\t{part}");
                }
            }
        }
        return Ok(());
    }
    if a.list_jobs {
        if !root {
            return Ok(());
        }
        println!("model\tbasis\tcolour");
        for (m, model) in scene.models.iter().enumerate() {
            let plan = sylva_light::relight::BasisPlan::new(model, grid, scene.model_preset(m))?;
            for job in plan.jobs() {
                println!("{m}\t{}\t{}", job.basis, job.colour);
            }
        }
        return Ok(());
    }
    let say = |s: String| {
        if root {
            println!("{s}")
        }
    };
    say(format!(
        "scene {}: {} models, {} instances; LB grid {grid}, preset {}",
        scene.name,
        scene.models.len(),
        scene.instances.len(),
        scene.lb.preset
    ));
    let (light, forest) = match physical {
        true => (
            sylva_light::Light::Physical,
            (!a.grid.no_global).then_some(GlobalGridOptions {
                sites: a.grid.global_grid,
            }),
        ),
        false => (sylva_light::Light::Paper, None),
    };
    if let (Some(w), true) = (
        costly_grid_warning(&scene, Some(&plan), forest.as_ref(), light)?,
        root,
    ) {
        eprintln!("{w}");
    }
    let solver = super::device::open_solver(a.lb.device, a.lb.precision)?;
    say(format!("LB solver: {}", solver.describe()));
    let lb = LbPlan {
        solver: &*solver,
        grid: a.lb.lb_grid,
        cache_dir: (!a.lb.no_cache).then_some(a.lb.cache_dir.as_path()),
        light,
    };
    let progress = Bars::new(|r: Report| {
        let (line, warning) = report_line(r);
        if let Some(w) = warning {
            eprintln!("{w}");
        }
        println!("{line}");
    });
    let progress: &dyn Progress = if root { &progress } else { &Silent };
    if physical {
        let done = precompute_physical(
            &scene,
            &lb,
            &PhysicalBasisPlan {
                basis: BasisUse::Always,
                target: plan.physical,
                keep_raw: false,
            },
            forest.as_ref(),
            runner,
            progress,
        )?;
        let Some(done) = done.filter(|_| root) else {
            return Ok(());
        };
        if runner.processes() > 1 {
            say(format!(
                "MPI: base solutions solved across {} ranks",
                runner.processes()
            ));
        }
        let bytes: u64 = done.bases.iter().flatten().map(|b| b.bytes()).sum();
        println!(
            "{} of {} models from the cache; physical bases {} in all ({} parts per model, \
             {}; {} uncompressed){}; {:.1} s",
            done.cached,
            scene.models.len(),
            sylva_core::format_bytes(bytes),
            sylva_light::relight::physical::PARTS,
            plan.physical.map_or("uncompressed".into(), |t| t.name()),
            sylva_core::format_bytes(done.raw_bytes),
            if done.forest.is_some() {
                ", forest grid parts solved"
            } else {
                ""
            },
            t0.elapsed().as_secs_f64()
        );
        return Ok(());
    }
    // Only the root needs the sets: it prints their size.
    let done = precompute_relighting(&scene, &lb, &plan, runner, RelightingAt::Root, progress)?;
    if !root {
        return Ok(());
    }
    let done = done.expect("a forced plan solves what is missing");
    if runner.processes() > 1 {
        say(format!(
            "MPI: base solutions solved across {} ranks",
            runner.processes()
        ));
    }
    let bytes: u64 = done.compressed.iter().flatten().map(|b| b.bytes()).sum();
    println!(
        "{} of {} models from the cache; compressed bases {} in all ({}); {:.1} s",
        done.cached,
        scene.models.len(),
        sylva_core::format_bytes(bytes),
        plan.target.codec.name(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}
