//! `sylva`: renders forests with lattice-Boltzmann global illumination.
//!
//! Thin: argument parsing and progress display only; each command lives in
//! `commands/<name>.rs` and calls into the library crates.

mod commands;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "sylva",
    version,
    about = "Render forest ecosystems with lattice-Boltzmann global illumination",
    long_about = "sylva lights plants and forests with a lattice-Boltzmann photon-transport \
solver (leaf transparency, light scattered between leaves and trees) and renders them with a \
ray tracer. Run `sylva <command> --help` for each command's options."
)]
struct Cli {
    /// Worker threads, 1 to 256 (default: all cores). Results do not depend on it.
    // Signed, and negative numbers taken as values: `--threads -1` gets the range message
    // below instead of clap's "unexpected argument '-1'".
    #[arg(long, global = true, allow_negative_numbers = true)]
    threads: Option<i64>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Inspect scenes: `sylva scene info SCENE [--json]`, `sylva scene list`, `sylva scene source`.
    Scene(commands::scene::SceneArgs),
    /// The species library: `sylva species list`, `sylva species show NAME`.
    Species(commands::species::SpeciesArgs),
    /// Turn a model (species name, Arbaro file, OBJ, glTF or GLB) into an LB density grid
    /// (.sgrid) and a preview: `sylva voxelize red_maple --grid 128 -o maple.sgrid`.
    Voxelize(commands::voxelize::VoxelizeArgs),
    /// Lattice-Boltzmann lighting: solve a grid, describe grid files.
    Lb(commands::lb::LbArgs),
    /// Plane-parallel scattering (paper 003): radiance in slabs, Tables 1 and 2, and Table 3
    /// on a scene's trees (`spp trees`).
    Spp(commands::spp::SppArgs),
    /// The canopy radiation budget of an abstract stand (crowns of flat leaves or a
    /// homogeneous layer, in a cyclic plot) or of a scene: per band the sunlight absorbed by
    /// the canopy, reflected, transmitted to the ground and absorbed by it, fAPAR and the BRF
    /// (per view, or as an image), e.g. `sylva budget crowns --sun-zenith 30` or `sylva
    /// budget demo --cyclic` (docs/budget.md).
    Budget(commands::budget::BudgetArgs),
    /// Write a scene for other renderers: OBJ (flattened) or Mitsuba 3 (instanced), e.g.
    /// `sylva export demo --format mitsuba -o out/`.
    Export(commands::export::ExportArgs),
    /// Render a scene (default: the built-in demo) to sylva-out/<scene>.png: sunlight, shadows,
    /// light through leaves and LB indirect light, e.g. `sylva render beech --rpp 4 --hdr`;
    /// the sun of a place and moment with `--lat 48.1 --lon 11.6 --date 2026-06-21 --time 14:30`.
    Render(commands::render::RenderArgs),
    /// Precompute every model's base solutions, compressed and cached: afterwards the sun
    /// moves with no LB solve, e.g. `sylva basis canopy` (`--device gpu` solves on the GPU;
    /// `mpirun -np N sylva basis` across processes, with the `mpi` feature). The physical
    /// light's 25 sun parts and 3 diffuse parts per model (the default), or with `--light
    /// paper` 004's 19 bases and the scene's coarse global grid (docs/relight.md).
    Basis(commands::basis::BasisArgs),
    /// Relight a scene over a moving sun (004 Table 1): numbered PNGs, an animated PNG and
    /// per-frame times, e.g. `sylva relight catalpa --suns 24`; or the sun's path over a day
    /// at a place, a frame per step named by its local time, e.g. `sylva relight demo --lat
    /// 48.1 --lon 11.6 --date 2026-06-21 --from 05:00 --to 21:00 --step 15m` (NREL's SPA;
    /// north is -z, east +x). The physical light from its base solutions (`sylva basis`; the
    /// default), or 004's paper light with `--light paper`.
    Relight(commands::relight::RelightArgs),
    /// Measure speed on this machine: `bench lb` (LB solver against copy bandwidth),
    /// `bench scene` (generation and scene building), `bench voxelize`, `bench trace`
    /// (acceleration build and frame time), `bench spp`, `bench relight` (moving the sun).
    Bench(commands::bench::BenchArgs),
    /// The forest in a browser: drag the sun (or set date, time and place), orbit, pan and
    /// zoom; the light follows with no LB solve, e.g. `sylva view catalpa` then open the
    /// printed URL (docs/view.md; a remote machine through an SSH tunnel).
    View(commands::view::ViewCommandArgs),
}

/// Whether `command` runs across MPI ranks, and its name for messages.
fn distributed(command: &Command) -> Result<(), &'static str> {
    match command {
        Command::Render(_) | Command::Basis(_) | Command::Relight(_) => Ok(()),
        Command::Bench(b) if b.is_trace() => Ok(()),
        Command::Bench(_) => Err("bench (other than bench trace)"),
        Command::Scene(_) => Err("scene"),
        Command::Species(_) => Err("species"),
        Command::Voxelize(_) => Err("voxelize"),
        Command::Lb(_) => Err("lb"),
        Command::Spp(_) => Err("spp"),
        Command::Budget(_) => Err("budget"),
        Command::Export(_) => Err("export"),
        Command::View(_) => Err("view"),
    }
}

/// Runs `command`; its LB solves and frames go through `runner` (this process, or every
/// rank of an MPI job).
fn run(command: Command, runner: &dyn sylva_core::jobs::Runner) -> anyhow::Result<()> {
    match command {
        Command::Lb(a) => commands::lb::run(a),
        Command::Voxelize(a) => commands::voxelize::run(a),
        Command::Spp(a) => commands::spp::run(a),
        Command::Budget(a) => commands::budget::run(a),
        Command::Scene(a) => commands::scene::run(a),
        Command::Species(a) => commands::species::run(a),
        Command::Bench(a) => commands::bench::run(a, runner),
        Command::Export(a) => commands::export::run(a),
        Command::Render(a) => commands::render::run(a, runner),
        Command::Basis(a) => commands::basis::run(a, runner),
        Command::Relight(a) => commands::relight::run(a, runner),
        Command::View(a) => commands::view::run(a),
    }
}

fn main() -> std::process::ExitCode {
    // Before any thread exists: it may set an environment variable.
    sylva_wgpu::quiet_headless_probing();
    // `sylva lb info x.sgrid | head -1`: a closed pipe ends the process quietly, as it does
    // other Unix tools, instead of a panic in println.
    #[cfg(unix)]
    // SAFETY: restoring the default action of a signal before any thread exists.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    // Ctrl-C while outputs are written removes the temporaries and replaces nothing.
    sylva_core::interrupt::install();
    let cli = Cli::parse();
    let threads = match cli
        .threads
        .map(sylva_core::limits::check_threads)
        .transpose()
    {
        Ok(t) => t,
        Err(e) => return commands::finish(Err(anyhow::anyhow!(e))),
    };
    // One of several processes started by mpirun: the command must split its work.
    let ranks = sylva_mpi::launch::launched_size().filter(|&n| n > 1);
    if let Some(n) = ranks {
        if let Err(what) = distributed(&cli.command) {
            return commands::finish(Err(anyhow::anyhow!(
                "started by mpirun as one of {n} processes, but `sylva {what}` does not split \
                 its work across processes: run it without mpirun (render, basis, relight and bench trace do)"
            )));
        }
        if !cfg!(feature = "mpi") {
            return commands::finish(Err(anyhow::anyhow!(
                "started by mpirun as one of {n} processes, but this sylva was built without \
                 MPI: every process would render the whole image. Build it with \
                 `cargo build --release --features mpi` (README: Across machines with MPI)"
            )));
        }
    }
    // Under mpirun, the ranks on one machine share its cores unless told otherwise.
    let threads = threads.or_else(|| {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        sylva_mpi::launch::shared_threads(ranks, sylva_mpi::launch::local_size(), cores)
    });
    if let Some(n) = threads {
        if let Err(e) = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
        {
            return commands::finish(Err(e.into()));
        }
    }
    if ranks.is_some() {
        return run_mpi(cli.command);
    }
    commands::finish(run(cli.command, &sylva_core::jobs::Local))
}

/// Runs a command as one MPI rank: a failure on any rank is printed there and ends the
/// whole job (MPI_Abort), so no rank waits forever for it.
#[cfg(feature = "mpi")]
fn run_mpi(command: Command) -> std::process::ExitCode {
    use sylva_mpi::Comm;
    let mpi = match sylva_mpi::mpi::Mpi::init() {
        Ok(m) => m,
        Err(e) => return commands::finish(Err(anyhow::Error::new(e).context("starting MPI"))),
    };
    match run(command, &sylva_mpi::QueueRunner::new(&mpi)) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            let (rank, size) = (mpi.rank(), mpi.size());
            // One write for the whole report: eprintln! writes a formatted line in pieces,
            // and mpirun relays each as it comes, so its abort banner could split the line.
            let mut report = commands::error_report(&format!("error: rank {rank} of {size}: "), &e);
            report.push_str(&format!(
                "sylva: rank {rank} failed; aborting the MPI job\n"
            ));
            {
                use std::io::Write;
                let mut err = std::io::stderr().lock();
                // Nothing better to do if stderr is gone: the abort below still ends the job.
                let _ = err.write_all(report.as_bytes());
                let _ = err.flush();
            }
            mpi.abort(1)
        }
    }
}

#[cfg(not(feature = "mpi"))]
fn run_mpi(_command: Command) -> std::process::ExitCode {
    unreachable!("refused above without the mpi feature")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every `sylva …` line in a code block of README.md and docs/*.md (`cargo run --release
    /// --` and `mpirun … target/release/sylva` read as `sylva`), its comment and redirection
    /// cut: the file and line, and the arguments.
    fn documented_commands() -> Vec<(String, Vec<String>)> {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let mut files = vec![root.join("README.md")];
        let mut docs: Vec<_> = std::fs::read_dir(root.join("docs"))
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == "md"))
            .collect();
        docs.sort();
        files.extend(docs);
        let mut commands = Vec::new();
        for file in files {
            let text = std::fs::read_to_string(&file).unwrap();
            let mut in_code = false;
            for (n, line) in text.lines().enumerate() {
                if line.trim_start().starts_with("```") {
                    in_code = !in_code;
                    continue;
                }
                if !in_code {
                    continue;
                }
                let line = line.split(" #").next().unwrap().trim();
                let line = line.split(['>', '|']).next().unwrap().trim();
                let line = line.strip_prefix("$ ").unwrap_or(line);
                let line = match (
                    line.find("target/release/sylva "),
                    line.strip_prefix("cargo run --release -- "),
                ) {
                    (_, Some(rest)) => format!("sylva {rest}"),
                    (Some(i), None) if line.starts_with("mpirun") => {
                        line["target/release/".len() + i..].to_string()
                    }
                    _ => line.to_string(),
                };
                // Synopses (`[--json]`, `...`) and placeholders are not commands to type.
                let synopsis = ["$", "…", "...", "["].iter().any(|c| line.contains(c));
                if !line.starts_with("sylva ") || synopsis {
                    continue;
                }
                let args = line.split_whitespace().map(str::to_string).collect();
                commands.push((format!("{}:{}", file.display(), n + 1), args));
            }
        }
        commands
    }

    /// Issue 31 item 10: what the docs tell a user to type parses (every command and option
    /// exists, every value is of its kind), and every built-in scene they name exists.
    #[test]
    fn documented_commands_parse_and_name_scenes_that_exist() {
        let commands = documented_commands();
        assert!(commands.len() > 80, "found {} commands", commands.len());
        let mut failures = Vec::new();
        for (place, args) in &commands {
            if let Err(e) = Cli::try_parse_from(args) {
                failures.push(format!("{place}: `{}`: {}", args.join(" "), e.kind()));
            }
            // The scene argument of the commands that take one: a file or a built-in name.
            let takes_scene = ["render", "basis", "relight", "export", "info", "source"];
            let scene_at = match args.get(1).map(String::as_str) {
                Some("bench") => matches!(
                    args.get(2).map(String::as_str),
                    Some("trace" | "relight" | "scene")
                )
                .then_some(3),
                Some("scene") => Some(3),
                Some(c) if takes_scene.contains(&c) => Some(2),
                _ => None,
            };
            if let Some(name) = scene_at.and_then(|i| args.get(i)) {
                let placeholder = name.chars().all(|c| c.is_ascii_uppercase());
                let file = placeholder || name.contains('.') || name.contains('/');
                if !file
                    && !name.starts_with('-')
                    && sylva_scene::builtin_scenes::source(name).is_none()
                {
                    failures.push(format!("{place}: no built-in scene '{name}'"));
                }
            }
        }
        assert!(failures.is_empty(), "{}", failures.join("\n"));
    }

    /// The scene list in the help and README's table of scenes name every built-in scene.
    #[test]
    fn the_help_and_readme_list_every_built_in_scene() {
        let readme = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../README.md");
        let readme = std::fs::read_to_string(readme).unwrap();
        for name in sylva_scene::builtin_scenes::NAMES {
            let row = format!("| `{name}` |");
            assert!(readme.contains(&row), "README's scene table omits '{name}'");
        }
        use clap::CommandFactory;
        let mut cli = Cli::command();
        let render = cli.find_subcommand_mut("render").unwrap();
        let scene = render
            .get_arguments()
            .find(|a| a.get_id() == "scene")
            .unwrap();
        let help = scene.get_help().unwrap().to_string();
        let listed: Vec<&str> = help
            .split(|c: char| !(c.is_alphanumeric() || c == '_'))
            .collect();
        for name in sylva_scene::builtin_scenes::NAMES {
            assert!(
                listed.contains(name),
                "the scene's help omits '{name}': {help}"
            );
        }
    }
}
