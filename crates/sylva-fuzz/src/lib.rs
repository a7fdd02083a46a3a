//! Fuzz targets for every parser sylva reads user files with, calling the same library entry
//! points the commands use. Each target takes arbitrary bytes and must return (an error is
//! fine) without a panic, an abort, a hang or an unbounded allocation.
//!
//! The libFuzzer binaries (`fuzz_targets/`, feature `libfuzzer`) are built and run by
//! `tools/fuzz/run`; the corpora in `corpus/<target>/` replay through the same functions as
//! ordinary tests (`cargo test -p sylva-fuzz`), so every input that ever failed stays a
//! regression test. See `docs/reliability.md`.

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};

/// A target: arbitrary bytes in; whether they parsed.
pub type Target = fn(&[u8]) -> bool;

/// The targets, by the names of their binaries and corpus folders.
pub const TARGETS: &[(&str, Target)] = &[
    ("scene_toml", scene_toml),
    ("obj_mtl", obj_mtl),
    ("gltf", gltf),
    ("arbaro_xml", arbaro_xml),
    ("sgrid", sgrid),
    ("raw_grid", raw_grid),
    ("canopy_toml", canopy_toml),
];

/// Separates the OBJ text from the MTL text in an `obj_mtl` input.
pub const MTL_SEPARATOR: &[u8] = b"\n#--- m.mtl ---\n";

/// A scratch folder, removed when its thread ends (a test's thread; a libFuzzer process exits
/// without that, and `tools/fuzz/run` removes its folders).
struct ScratchDir(PathBuf);

impl Drop for ScratchDir {
    fn drop(&mut self) {
        // Scratch: nothing to report if it is gone already.
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A folder of this thread for the files the file-based parsers read (per thread: the corpus
/// tests run in parallel in one process).
fn scratch() -> PathBuf {
    static NEXT: AtomicUsize = AtomicUsize::new(0);
    thread_local! {
        static DIR: ScratchDir = {
            let n = NEXT.fetch_add(1, Ordering::Relaxed);
            let d = std::env::temp_dir().join(format!("sylva-fuzz-{}-{n}", std::process::id()));
            std::fs::create_dir_all(&d).expect("scratch folder");
            ScratchDir(d)
        };
    }
    DIR.with(|d| d.0.clone())
}

/// Writes `bytes` to `name` in the scratch folder (plain write: it is scratch, not output).
fn put(name: &str, bytes: &[u8]) -> PathBuf {
    let p = scratch().join(name);
    std::fs::write(&p, bytes).expect("scratch file");
    p
}

/// A scene file as `SceneDesc::load_file` parses and checks it (models are not grown: that
/// is generation, not parsing, and any valid species list would take seconds).
pub fn scene_toml(data: &[u8]) -> bool {
    let Ok(text) = std::str::from_utf8(data) else {
        return false;
    };
    sylva_scene::SceneDesc::parse(text, "fuzz.toml", Some(&scratch())).is_ok()
}

/// A canopy file as `sylva budget` parses and checks it (the stand is not built: that is
/// generation, not parsing).
pub fn canopy_toml(data: &[u8]) -> bool {
    let Ok(text) = std::str::from_utf8(data) else {
        return false;
    };
    sylva_grow::stand::CanopySpec::parse(text).is_ok()
}

/// An OBJ file and the MTL file it may name (`mtllib m.mtl`), split at [`MTL_SEPARATOR`],
/// through `load_mesh_file` as a scene's `mesh = "m.obj"` reads it.
pub fn obj_mtl(data: &[u8]) -> bool {
    let (obj, mtl) = match data
        .windows(MTL_SEPARATOR.len())
        .position(|w| w == MTL_SEPARATOR)
    {
        Some(i) => (&data[..i], &data[i + MTL_SEPARATOR.len()..]),
        None => (data, &[][..]),
    };
    put("m.mtl", mtl);
    let p = put("m.obj", obj);
    sylva_io::import::load_mesh_file(&p, &Default::default()).is_ok()
}

/// A glTF document: GLB when it starts with the GLB magic, else JSON `.gltf`.
pub fn gltf(data: &[u8]) -> bool {
    let name = if data.starts_with(b"glTF") {
        "m.glb"
    } else {
        "m.gltf"
    };
    let p = put(name, data);
    sylva_io::import::load_mesh_file(&p, &Default::default()).is_ok()
}

/// An Arbaro species file, parsed and turned into generator parameters.
pub fn arbaro_xml(data: &[u8]) -> bool {
    let Ok(text) = std::str::from_utf8(data) else {
        return false;
    };
    sylva_grow::arbaro::parse(text, "fuzz.xml").is_ok()
}

/// A grid file (`lb info`, `lb solve --input`, the LB cache): header, metadata, payload,
/// checksum. Headers that declare huge grids must be refused before allocating.
///
/// A random checksum is almost never right, so the fuzzer would not get past it: when the
/// container header's reserved byte 28 is 0, the checksum is set to the one the bytes need
/// (the header fields, metadata and payload, the grid's header in it, are then fuzzed);
/// otherwise it is left as it is (the check itself is fuzzed).
pub fn sgrid(data: &[u8]) -> bool {
    let mut data = data.to_vec();
    if data.len() >= 32 && data[28] == 0 {
        let mut crc = crc32fast::Hasher::new();
        crc.update(&data[..24]);
        crc.update(&data[32..]);
        data[24..28].copy_from_slice(&crc.finalize().to_le_bytes());
    }
    let p = put("g.sgrid", &data);
    let header = sylva_lb::grid_file::read_header_verified(&p).is_ok();
    let file = sylva_lb::GridFile::read(&p);
    assert_eq!(
        header,
        file.is_ok(),
        "the header check and the full read disagree"
    );
    file.is_ok_and(|f| match f.kind {
        sylva_lb::GridKind::Density => f.into_density(&p).is_ok(),
        sylva_lb::GridKind::Lighting => true,
        sylva_lb::GridKind::Basis => sylva_lb::relight::BasisSet::from_grid_file(f, &p).is_ok(),
    })
}

/// A raw grid (`lb solve --raw`): the first three bytes give the edges (3 to 34 sites each:
/// the size is the caller's, so capped here) and the element type, the rest is the payload.
pub fn raw_grid(data: &[u8]) -> bool {
    let [a, b, c, rest @ ..] = data else {
        return false;
    };
    let edge = |x: u8| 3 + (x & 31) as usize;
    let Ok(dims) = sylva_lb::Dims::new(edge(*a), edge(*b), edge(*c)) else {
        return false;
    };
    let element = if c & 128 != 0 {
        sylva_lb::RawElement::F32
    } else {
        sylva_lb::RawElement::U8
    };
    sylva_lb::DensityGrid::from_raw(dims, rest, element).is_ok()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    /// Every corpus file through its target: the regression suite of everything fuzzing
    /// found, and a check that the seeds still parse or fail cleanly.
    #[test]
    fn corpora_replay_without_panics() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("corpus");
        for (name, target) in TARGETS {
            let dir = root.join(name);
            let mut files: Vec<_> = std::fs::read_dir(&dir)
                .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
                .map(|e| e.unwrap().path())
                .collect();
            files.sort();
            assert!(!files.is_empty(), "{name}: empty corpus");
            for f in files {
                target(&std::fs::read(&f).unwrap());
            }
        }
    }

    #[test]
    fn seeds_are_accepted() {
        // Files named seed-* are valid: the targets must get through the whole parser with
        // them, so the fuzzer starts from inputs that reach every stage.
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("corpus");
        for (name, target) in TARGETS {
            let seeds: Vec<_> = std::fs::read_dir(root.join(name))
                .unwrap()
                .map(|e| e.unwrap().path())
                .filter(|p| {
                    p.file_name()
                        .unwrap()
                        .to_string_lossy()
                        .starts_with("seed-")
                })
                .collect();
            assert!(!seeds.is_empty(), "{name}: no seeds");
            for p in seeds {
                assert!(target(&std::fs::read(&p).unwrap()), "{}", p.display());
            }
        }
    }
}
