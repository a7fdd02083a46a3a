//! `sylva basis SCENE`: precomputes every model's base solutions and caches them; afterwards
//! `sylva relight` (and `sylva render --basis always`) move the sun with no LB solve. The
//! physical light (the default): per model 25 sun parts and 3 diffuse parts, 28 solves, and
//! with several instances the forest grid's parts (`sylva_pipeline::physical`). The paper
//! light (`--light paper`): 19 base solutions (paper 004 §3.1: 54 solves per model, `B_0`
//! summed), compressed, and the scene's coarse global grid. Under `mpirun` the solves are jobs
//! handed out across the ranks; rank 0 alone prints and writes the cache, which holds what one
//! process writes.

use std::time::Instant;

use anyhow::Result;
use clap::Args;
use sylva_light::report::LightEvent;
use sylva_light::{Light, Progress, Silent};
use sylva_pipeline::{
    basis_jobs, basis_scene_line, costly_grid_warning, load_scene, precompute_physical,
    precompute_relighting, BasisUse, LbPlan, PhysicalBasisPlan, RelightingAt, Runner,
};

use super::progress::Bars;
use super::render::{
    light_settings, say_report, BasisArg, GridArgs, LbArgs, RelightLightArg, RelitArgs, SCENE_HELP,
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
    // The plan's sun weights and ambient are the frames' business, not the solves'.
    let settings = light_settings(
        a.light.light.clone(),
        BasisArg::Auto,
        &RelitArgs::default(),
        &a.grid,
    );
    let light_name = settings.name(true)?;
    let physical = light_name == "physical";
    let mut scene = load_scene(&a.scene, None)?;
    scene
        .set_leaf_optics(a.lb.leaf_optics.into())
        .map_err(anyhow::Error::msg)?;
    let plan = settings
        .plan(true, a.keep_raw, light_name)?
        .expect("forced plans exist");
    let grid = a.lb.lb_grid.unwrap_or(scene.lb.grid as usize);
    if a.list_jobs {
        if root {
            basis_jobs(&scene, physical, grid, &mut |line| println!("{line}"))?;
        }
        return Ok(());
    }
    let say = |s: String| {
        if root {
            println!("{s}")
        }
    };
    say(basis_scene_line(&scene, grid));
    let light = if physical {
        Light::Physical
    } else {
        Light::Paper
    };
    let forest = settings.forest_grid(light)?;
    if let (Some(w), true) = (
        costly_grid_warning(&scene, Some(&plan), forest.as_ref(), light)?,
        root,
    ) {
        eprintln!("{w}");
    }
    let solver = super::device::open_solver(a.lb.device, a.lb.precision)?;
    let solver = super::device::on_schedule(solver, a.lb.lb_schedule)?;
    say(super::device::solver_line(&*solver));
    let lb = LbPlan {
        solver: &*solver,
        grid: a.lb.lb_grid,
        cache_dir: (!a.lb.no_cache).then_some(a.lb.cache_dir.as_path()),
        light,
    };
    let progress = Bars::new(|r: LightEvent| say_report(&r, true, &|s| println!("{s}")));
    let progress: &dyn Progress = if root { &progress } else { &Silent };
    let models = scene.models.len();
    let summary = if physical {
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
        let codec = plan.physical.map_or("uncompressed".into(), |t| t.name());
        done.filter(|_| root)
            .map(|d| d.summary(models, &codec, t0.elapsed().as_secs_f64()))
    } else {
        // Only the root needs the sets: it prints their size.
        let done = precompute_relighting(&scene, &lb, &plan, runner, RelightingAt::Root, progress)?;
        root.then(|| {
            let done = done.expect("a forced plan solves what is missing");
            done.summary(
                models,
                &plan.target.codec.name(),
                t0.elapsed().as_secs_f64(),
            )
        })
    };
    let Some(summary) = summary else {
        return Ok(());
    };
    if runner.processes() > 1 {
        say(format!(
            "MPI: base solutions solved across {} ranks",
            runner.processes()
        ));
    }
    println!("{summary}");
    Ok(())
}
