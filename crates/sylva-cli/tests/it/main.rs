//! The `sylva` binary's integration tests, one test binary (one link instead of ten): each
//! module runs the built binary as a user would, per command. `tests/mpi_cli.rs` stays a
//! binary of its own (feature `mpi`, run under `mpirun` by CI).

#[path = "../common/mod.rs"]
mod common;

mod budget_cli;
mod export_cli;
mod gpu_cli;
mod hostile_cli;
mod import_cli;
mod lb_cli;
mod relight_cli;
mod render_cli;
mod scene_cli;
mod spp_cli;
mod view_browser;
mod view_cli;
mod voxelize_cli;
