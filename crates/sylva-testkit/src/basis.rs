//! Relighting's basis cache, decoded for comparing two caches bit for bit.

use std::path::Path;

use sylva_lb::relight::CompressedBasis;
use sylva_lb::GridFile;

/// A decoded cache entry: file name, metadata, contents.
pub type BasisEntry = (String, Vec<(String, String)>, Vec<u8>);

/// The basis cache entries of `dir` by file name, decoded: the metadata but the solve time
/// (measured, so it differs from run to run) and the contents bit for bit (compressed sets as
/// they are sent between ranks, the uncompressed sets' channels, the global grid's file as it
/// is).
pub fn basis_cache_entries(dir: &Path) -> Vec<BasisEntry> {
    let measured = |meta: Vec<(String, String)>| -> Vec<(String, String)> {
        meta.into_iter()
            .filter(|(k, _)| k != "solve_seconds")
            .collect()
    };
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("listing {}: {e}", dir.display()))
        .map(|e| {
            let path = e.unwrap().path();
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            let (meta, bytes) = match path.extension().and_then(|e| e.to_str()) {
                Some("scbasis") => {
                    let (set, meta) = CompressedBasis::read(&path).unwrap();
                    (measured(meta), set.to_bytes())
                }
                Some("sbasis") => {
                    let file = GridFile::read(&path).unwrap();
                    let bits = file
                        .channels
                        .iter()
                        .flatten()
                        .flat_map(|v| v.to_bits().to_le_bytes())
                        .collect();
                    (measured(file.metadata), bits)
                }
                _ => (Vec::new(), std::fs::read(&path).unwrap()),
            };
            (name, meta, bytes)
        })
        .collect();
    v.sort();
    v
}
