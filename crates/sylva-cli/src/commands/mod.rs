//! One module per `sylva` command.

use std::process::ExitCode;

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
pub mod progress;
pub mod relight;
pub mod render;
pub mod scene;
pub mod species;
pub mod spp;
pub mod spp_trees;
pub mod voxelize;
