//! The limits sylva enforces on its inputs, in one place: scene files, command-line options,
//! grid files and model files all check against these, so one quantity has one range.
//! `docs/reliability.md` lists them with the reasons.

use std::ops::RangeInclusive;

/// Sites along each edge of an LB grid (solver, grid files, raw input, built-in shapes). The
/// outer shell is the boundary, so 3 is the smallest grid with an interior; 2048³ sites would
/// take 1.2 TB to solve, so memory refuses far sooner on most machines.
pub const GRID_EDGE: RangeInclusive<usize> = 3..=2048;

/// Sites along a model's longest edge when it is voxelized (`--grid` of `voxelize` and
/// `lb solve --model/--scene`, `--lb-grid`, a scene file's `[lb] grid`): the shell on both
/// sides leaves at least two interior sites.
pub const MODEL_GRID: RangeInclusive<usize> = 4..=2048;

/// Sites along each edge of a generated medium's grid (a scene's `[[media]] grid`): 16 leaves
/// the cumulus generator room for its shell and a few cells of cloud; 1024³ sites is a 4 GiB
/// density grid before its two LB solves.
pub const MEDIUM_GRID: RangeInclusive<usize> = 16..=1024;

/// Pixels along each edge of an image (scene files and `--width/--height`).
pub const IMAGE_EDGE: RangeInclusive<u32> = 1..=16384;

/// Rays per pixel (`--rpp`, a scene camera's `rays_per_pixel`).
pub const RAYS_PER_PIXEL: RangeInclusive<u32> = 1..=1024;

/// Worker threads (`--threads`): far more threads than cores only add start-up time (10 000
/// took a minute to start).
pub const THREADS: RangeInclusive<usize> = 1..=256;

/// Monte Carlo photons (`spp slab --photons`): 10¹² take most of a day on two cores.
pub const PHOTONS: RangeInclusive<u64> = 1..=1_000_000_000_000;

/// Text inputs: scene files (TOML), Arbaro species files (XML), MTL files.
pub const TEXT_FILE_BYTES: u64 = 64 << 20;

/// Binary and large inputs: OBJ, glTF and GLB files, glTF buffers, textures.
pub const MODEL_FILE_BYTES: u64 = 4 << 30;

/// `"4 to 2048"`: a range as error messages write it.
pub fn describe<T: std::fmt::Display>(r: &RangeInclusive<T>) -> String {
    format!("{} to {}", r.start(), r.end())
}

/// `--threads`: a worker thread count in [`THREADS`] (signed, so `-1` gets this message).
pub fn check_threads(n: i64) -> Result<usize, String> {
    match usize::try_from(n) {
        Ok(k) if THREADS.contains(&k) => Ok(k),
        _ => Err(format!("--threads {n}: must be {}", describe(&THREADS))),
    }
}

/// `--rpp`: rays per pixel in [`RAYS_PER_PIXEL`]; `None` (the scene camera's) passes.
pub fn check_rays_per_pixel(rpp: Option<u32>) -> Result<(), String> {
    match rpp {
        Some(r) if !RAYS_PER_PIXEL.contains(&r) => Err(format!(
            "--rpp {r}: rays per pixel must be {}",
            describe(&RAYS_PER_PIXEL)
        )),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn model_grids_are_grids() {
        // A voxelized model's grid must be a valid LB grid along every edge.
        assert!(GRID_EDGE.contains(MODEL_GRID.start()) && GRID_EDGE.contains(MODEL_GRID.end()));
        assert_eq!(describe(&MODEL_GRID), "4 to 2048");
        assert_eq!(
            check_rays_per_pixel(Some(0)).unwrap_err(),
            "--rpp 0: rays per pixel must be 1 to 1024"
        );
        assert!(check_rays_per_pixel(Some(1024)).is_ok() && check_rays_per_pixel(None).is_ok());
        assert_eq!(
            check_threads(-1).unwrap_err(),
            "--threads -1: must be 1 to 256"
        );
        assert_eq!(check_threads(256), Ok(256));
    }
}
