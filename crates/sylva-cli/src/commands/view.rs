//! `sylva view SCENE`: the forest in a browser, the sun dragged over it (`sylva_view`). The
//! scene is prepared with its base solutions (solved with progress if missing: the page
//! shows the lines too) while the server already answers; the URL with its token is
//! printed. `sylva bench view` drives the same server as the page does and measures it.

use std::path::PathBuf;

use anyhow::{anyhow, Result};
use clap::Args;
use sylva_pipeline::{relight_light, Local};
use sylva_view::{ReadyScene, ServeOptions, Server, WorkerOptions};

use super::render::{
    prepare, FrameArgs, GridArgs, LbArgs, PrepareRequest, RelightLightArg, RelitArgs, Say,
    ViewArgs, SCENE_HELP,
};

/// What `sylva view` and `sylva bench view` share: the scene and how it is lit and shown.
#[derive(Args, Debug, Clone)]
pub struct ViewSceneArgs {
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
    /// Final-gather rays per sample of the refined frames, 0 to 256 (the page changes it).
    #[arg(
        long,
        default_value_t = sylva_render::ShadingParams::default().gather_rays,
        allow_negative_numbers = true,
        value_parser = clap::value_parser!(u32).range(0..=i64::from(sylva_render::gather::MAX_GATHER_RAYS))
    )]
    pub gather_rays: u32,
    /// Samples per pixel a refined frame accumulates once input stops (1 to 1024).
    #[arg(long, default_value_t = 16, value_parser = clap::value_parser!(u32).range(1..=1024))]
    pub samples: u32,
    /// The most pixels of a frame a page may ask for (1024 to 16777216).
    #[arg(long, default_value_t = 1920 * 1200, value_parser = clap::value_parser!(u64).range(1024..=16_777_216))]
    pub max_pixels: u64,
}

impl ViewSceneArgs {
    fn worker(&self, output_dir: PathBuf) -> WorkerOptions {
        WorkerOptions {
            max_pixels: self.max_pixels,
            max_samples: self.samples,
            output_dir,
            ..WorkerOptions::default()
        }
    }

    /// Prepares the scene with its base solutions (the sun moves without an LB solve),
    /// telling `status` what it does.
    fn prepare(
        self,
        say: Say,
        status: &(dyn Fn(String) + Sync),
        lat: f64,
        lon: f64,
    ) -> Result<ReadyScene, String> {
        let p = prepare(
            &FrameArgs::relit(
                &self.scene,
                &self.view,
                &self.light.light,
                Some(self.gather_rays),
                (&self.lb, &self.relit, &self.grid),
            ),
            PrepareRequest {
                need_lb: true,
                rays_per_pixel: Some(2),
                output_images: 1,
                say,
                force_basis: true,
                echo: Some(status),
                ..PrepareRequest::default()
            },
            &Local,
        )
        .map_err(|e| super::error_report("", &e).trim_end().to_string())?;
        Ok(ReadyScene::new(p.scene, (p.width, p.height), (lat, lon)))
    }
}

#[derive(Args, Debug)]
pub struct ViewCommandArgs {
    #[command(flatten)]
    pub scene: ViewSceneArgs,
    /// Address to listen on. Anything but a loopback address lets other machines reach the
    /// viewer (they still need the URL's token); to view a remote machine, prefer an SSH
    /// tunnel (README: Viewer).
    #[arg(long, default_value = "127.0.0.1")]
    pub host: String,
    /// Port to listen on (0: any free port).
    #[arg(long, default_value_t = 8080)]
    pub port: u16,
    /// Where "save PNG/EXR" writes (default sylva-out).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Latitude the page's time-of-day control starts from (degrees, north positive).
    #[arg(long, default_value_t = 48.1, allow_negative_numbers = true)]
    pub lat: f64,
    /// Longitude the page's time-of-day control starts from (degrees, east positive).
    #[arg(long, default_value_t = 11.6, allow_negative_numbers = true)]
    pub lon: f64,
}

pub fn run(a: ViewCommandArgs) -> Result<()> {
    relight_light(a.scene.light.light.as_deref())?;
    let output = a.output.clone().unwrap_or_else(|| "sylva-out".into());
    let warning = sylva_view::server::check_options(&a.host, &output, (a.lat, a.lon))
        .map_err(anyhow::Error::msg)?;
    if let Some(w) = warning {
        eprintln!("warning: {w}");
    }
    let opts = ServeOptions {
        host: a.host.clone(),
        port: a.port,
        token: None,
        worker: a.scene.worker(output),
    };
    // From here Ctrl-C marks the process interrupted instead of ending it, so the server
    // closes its pages and a frame being saved is finished or removed
    // (sylva_core::interrupt). Before the URL is printed: a user may press it at once.
    let _staging = sylva_core::interrupt::StagingGuard::new();
    let (scene, lat, lon) = (a.scene, a.lat, a.lon);
    let server = Server::start(opts, move |status| {
        scene.prepare(Say::Stdout, status, lat, lon)
    })
    .map_err(|e| match e {
        sylva_view::ViewError::Bind { .. } => {
            anyhow!("{e} (--port picks another port; 0 any free one)")
        }
        e => e.into(),
    })?;
    let shown = if a.host == "0.0.0.0" || a.host == "::" {
        "127.0.0.1"
    } else {
        a.host.as_str()
    };
    println!(
        "sylva view: open {} (Ctrl-C stops the server)",
        server.url(shown)
    );
    server.run_until(sylva_core::interrupt::interrupted)?;
    println!("sylva view: stopped");
    Ok(())
}

#[derive(Args, Debug)]
pub struct BenchViewArgs {
    #[command(flatten)]
    pub scene: ViewSceneArgs,
    /// Seconds of dragging the sun per run.
    #[arg(long, default_value_t = 5.0, allow_negative_numbers = true)]
    pub drag_seconds: f64,
    /// Drags measured, each followed by its refined frame.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub runs: u32,
    /// Sun elevation while dragging (degrees).
    #[arg(long, default_value_t = 40.0, allow_negative_numbers = true)]
    pub sun_elevation: f64,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

pub fn bench(a: BenchViewArgs) -> Result<()> {
    relight_light(a.scene.light.light.as_deref())?;
    // Checked before the scene is prepared.
    let plan = sylva_view::bench::ViewBenchPlan {
        width: a.scene.view.width.unwrap_or(512),
        height: a.scene.view.height.unwrap_or(512),
        drag_seconds: a.drag_seconds,
        sweep_deg: 60.0,
        elevation_deg: a.sun_elevation,
        gather_rays: a.scene.gather_rays,
        runs: a.runs,
        timeout: std::time::Duration::from_secs(120),
    };
    plan.check().map_err(anyhow::Error::msg)?;
    let say = if a.json { Say::Stderr } else { Say::Stdout };
    let opts = ServeOptions {
        host: "127.0.0.1".into(),
        port: 0,
        token: None,
        worker: a.scene.worker(std::env::temp_dir()),
    };
    let scene = a.scene;
    let mut server = Server::start(opts, move |status| scene.prepare(say, status, 48.1, 11.6))?;
    server.wait_ready()?;
    let report = sylva_view::bench::run(server.addr(), server.token(), &plan)?;
    server.shutdown();
    if a.json {
        println!("{}", super::output::pretty_json(&report)?);
    } else {
        print!("{report}");
    }
    Ok(())
}
