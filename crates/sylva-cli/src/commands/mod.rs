//! One module per `sylva` command.

use std::process::ExitCode;
use std::sync::OnceLock;

use sylva_render::StageClock;

/// The clock of `sylva render`'s stage summary and `bench trace --json`: installed on first
/// use as the process's global `tracing` subscriber. The binary installs it, not a library:
/// libraries only open spans.
pub fn stage_clock() -> &'static StageClock {
    static CLOCK: OnceLock<StageClock> = OnceLock::new();
    CLOCK.get_or_init(|| {
        use tracing_subscriber::layer::SubscriberExt;
        let clock = StageClock::new();
        let subscriber = tracing_subscriber::registry().with(clock.clone());
        // Fails only if another subscriber is installed; then nothing is timed.
        let _ = tracing::subscriber::set_global_default(subscriber);
        clock
    })
}

/// Prints an error chain the way users expect (`error: ...` then `caused by: ...`) and maps it
/// to the exit code.
pub fn finish(result: anyhow::Result<()>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            for cause in e.chain().skip(1) {
                eprintln!("  caused by: {cause}");
            }
            ExitCode::FAILURE
        }
    }
}

pub mod basis;
pub mod bench;
pub mod bench_relight;
pub mod bench_scene;
pub mod bench_spp;
pub mod bench_trace;
pub mod bench_voxel;
pub mod device;
pub mod export;
pub mod lb;
pub mod output;
pub mod progress;
pub mod relight;
pub mod render;
pub mod scene;
pub mod species;
pub mod spp;
pub mod spp_trees;
pub mod voxelize;
