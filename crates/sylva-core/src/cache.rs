//! The one cache of computed results (lighting grids, relighting bases, global grids).
//!
//! * **Keys.** A [`CacheKey`] is derived from one `#[derive(Serialize)]` struct holding every
//!   input of the result: its postcard bytes, after the key scheme's version and the entry's
//!   [`CacheKind`] (name and version), hashed with xxh3-64. A new input is a new field, so it
//!   cannot be forgotten the way a field fed by hand into a hasher can; two kinds never share
//!   a key, and bumping a kind's version retires all its entries at once. postcard's encoding
//!   is fixed by its specification (little-endian, varint lengths), so a key does not depend on
//!   the Rust release or the platform.
//! * **Entries.** An entry is a file `<stem>-<key>.<ext>` in the [`Cache`]'s directory, in
//!   one of sylva's checked formats ([`crate::container`]), with the key in its metadata
//!   ([`KEY_METADATA`]) so a renamed or stale file is refused, not misread.
//! * **Outcomes.** [`Cache::get_or_compute`] reports a hit, a miss, or a bad entry (damaged,
//!   stale, unreadable: the reason names the file), which is recomputed and replaced. A
//!   failed write (a read-only directory, a full disk) is a warning carried with the value:
//!   the result was computed and is good, it is only not kept.

use std::fmt;
use std::path::{Path, PathBuf};

use serde::Serialize;
use xxhash_rust::xxh3::Xxh3;

/// Metadata key holding an entry's key (16 hex digits).
pub const KEY_METADATA: &str = "cache_key";

/// Version of the key derivation itself (what precedes the input, the serializer, the hash).
const KEY_SCHEME: u32 = 1;

/// What a cache entry holds: a name, and a version bumped whenever what an entry of that name
/// holds changes for the same inputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct CacheKind {
    pub name: &'static str,
    pub version: u32,
}

/// The key of a cache entry: xxh3-64 of the kind and the serialized inputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct CacheKey(u64);

/// A postcard output that hashes the bytes instead of keeping them.
struct HashFlavor(Xxh3);

impl postcard::ser_flavors::Flavor for HashFlavor {
    type Output = u64;

    fn try_extend(&mut self, data: &[u8]) -> postcard::Result<()> {
        self.0.update(data);
        Ok(())
    }

    fn try_push(&mut self, data: u8) -> postcard::Result<()> {
        self.0.update(&[data]);
        Ok(())
    }

    fn finalize(self) -> postcard::Result<u64> {
        Ok(self.0.digest())
    }
}

impl CacheKey {
    /// The key of `input`, an entry of `kind`.
    ///
    /// # Panics
    /// If `input`'s `Serialize` cannot be encoded by postcard (a sequence of unknown length,
    /// which derived impls never produce): a defect of the key struct, not of any input.
    pub fn new<T: Serialize + ?Sized>(kind: CacheKind, input: &T) -> CacheKey {
        CacheKey(
            postcard::serialize_with_flavor(&(KEY_SCHEME, kind, input), HashFlavor(Xxh3::new()))
                .expect("derived Serialize impls encode with postcard"),
        )
    }

    /// The key's 64 bits.
    pub fn value(self) -> u64 {
        self.0
    }

    /// A key from its 64 bits, as [`CacheKey::value`] gave them (a key recorded inside an
    /// entry and read back with it).
    pub fn from_value(value: u64) -> CacheKey {
        CacheKey(value)
    }

    /// The metadata entry that records the key in a cache entry.
    pub fn metadata(self) -> (String, String) {
        (KEY_METADATA.to_string(), self.to_string())
    }

    /// Checks the key an entry at `path` records (`found`, its [`KEY_METADATA`] value);
    /// `Err` says why the entry is not this key's, naming the file.
    pub fn check(self, path: &Path, found: Option<&str>) -> Result<(), String> {
        let want = self.to_string();
        match found {
            Some(k) if k == want => Ok(()),
            Some(k) => Err(format!(
                "{} is stale: its cache key is {k}, expected {want}",
                path.display()
            )),
            None => Err(format!(
                "{} has no cache key: not a cache entry",
                path.display()
            )),
        }
    }
}

impl fmt::Display for CacheKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:016x}", self.0)
    }
}

/// What a lookup found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CacheOutcome {
    /// A valid entry.
    Hit,
    /// No entry: computed.
    Miss,
    /// An entry that cannot be used (the reason names the file): computed again.
    BadEntry(String),
}

/// An entry read by [`Cache::lookup`].
#[derive(Debug)]
pub enum Lookup<T> {
    Hit(T),
    Miss,
    Bad(String),
}

/// A value from [`Cache::get_or_compute`].
#[derive(Debug)]
pub struct Cached<T> {
    pub value: T,
    pub outcome: CacheOutcome,
    /// Why the computed value could not be stored (it is still good).
    pub write_warning: Option<String>,
}

impl<T> Cached<T> {
    /// The warning to show, if any: why the entry could not be used (`redone` says what was
    /// done instead, e.g. "voxelized again"), else why the value could not be stored.
    pub fn warning(&self, redone: &str) -> Option<String> {
        match &self.outcome {
            CacheOutcome::BadEntry(reason) => Some(format!("{reason}; {redone}")),
            _ => self.write_warning.clone(),
        }
    }
}

/// A cache directory. It need not exist: it is created on the first store.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Cache {
    dir: PathBuf,
}

impl Cache {
    pub fn new(dir: impl Into<PathBuf>) -> Cache {
        Cache { dir: dir.into() }
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The entry of `key`: `<stem>-<key>.<ext>` in the directory.
    pub fn entry(&self, stem: &str, key: CacheKey, ext: &str) -> PathBuf {
        self.dir.join(format!("{stem}-{key}.{ext}"))
    }

    /// Reads the entry at `path` with `read` (which checks the key and everything else it
    /// needs; `Err` is why the entry is unusable, naming the file). No file: a miss.
    pub fn lookup<T>(
        &self,
        path: &Path,
        read: impl FnOnce(&Path) -> Result<T, String>,
    ) -> Lookup<T> {
        match path.try_exists() {
            Ok(false) => Lookup::Miss,
            Ok(true) => match read(path) {
                Ok(v) => Lookup::Hit(v),
                Err(reason) => Lookup::Bad(reason),
            },
            Err(e) => Lookup::Bad(format!("cannot read {}: {e}", path.display())),
        }
    }

    /// Stores an entry at `path` with `write`, which must write atomically (every
    /// [`crate::container`] writer does). Creates the directory. Returns a warning, naming
    /// the file, when it could not: the value is not kept, nothing else is wrong.
    pub fn store(
        &self,
        path: &Path,
        write: impl FnOnce(&Path) -> Result<(), String>,
    ) -> Option<String> {
        if let Err(e) = std::fs::create_dir_all(&self.dir) {
            return Some(format!(
                "cannot create the cache directory {}: {e}; the result is not cached",
                self.dir.display()
            ));
        }
        write(path).err().map(|e| {
            format!(
                "cannot write the cache entry {}: {e}; the result is not cached",
                path.display()
            )
        })
    }

    /// The value at `path` when a valid entry holds it ([`Cache::lookup`] with `read`);
    /// otherwise `compute`d and stored with `write` ([`Cache::store`]). Only `compute`'s
    /// error is an error.
    pub fn get_or_compute<T, E>(
        &self,
        path: &Path,
        read: impl FnOnce(&Path) -> Result<T, String>,
        compute: impl FnOnce() -> Result<T, E>,
        write: impl FnOnce(&T, &Path) -> Result<(), String>,
    ) -> Result<Cached<T>, E> {
        let outcome = match self.lookup(path, read) {
            Lookup::Hit(value) => {
                return Ok(Cached {
                    value,
                    outcome: CacheOutcome::Hit,
                    write_warning: None,
                })
            }
            Lookup::Miss => CacheOutcome::Miss,
            Lookup::Bad(reason) => CacheOutcome::BadEntry(reason),
        };
        let value = compute()?;
        let write_warning = self.store(path, |p| write(&value, p));
        Ok(Cached {
            value,
            outcome,
            write_warning,
        })
    }
}

/// For the tests of key structs: asserts that each of `variants` (a key struct with one field changed, named) has a key of
/// `kind` of its own: different from `base`'s and from every other variant's.
pub fn assert_each_field_changes_the_key<T: Serialize>(
    kind: CacheKind,
    base: &T,
    variants: &[(&str, T)],
) {
    let mut seen = vec![("base", CacheKey::new(kind, base))];
    for (field, v) in variants {
        let key = CacheKey::new(kind, v);
        if let Some((other, _)) = seen.iter().find(|(_, k)| *k == key) {
            panic!("{}: changing {field} gives the key of {other}", kind.name);
        }
        seen.push((field, key));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::container::{read_container, write_container};

    const KIND: CacheKind = CacheKind {
        name: "test",
        version: 1,
    };
    const MAGIC: &[u8; 8] = b"SYLVATST";

    #[derive(Serialize)]
    struct Inputs {
        grid: usize,
        name: String,
        sun: [i64; 3],
        scale: f32,
        texture: Option<Vec<u8>>,
    }

    fn inputs() -> Inputs {
        Inputs {
            grid: 32,
            name: "ab".into(),
            sun: [1, 2, 3],
            scale: 0.0,
            texture: None,
        }
    }

    #[test]
    fn every_field_kind_and_version_changes_the_key() {
        let base = CacheKey::new(KIND, &inputs());
        assert_eq!(base, CacheKey::new(KIND, &inputs()), "deterministic");
        let changed: [(&str, Inputs); 6] = [
            (
                "grid",
                Inputs {
                    grid: 33,
                    ..inputs()
                },
            ),
            (
                "name",
                Inputs {
                    name: "a".into(),
                    ..inputs()
                },
            ),
            (
                "sun",
                Inputs {
                    sun: [1, 2, 4],
                    ..inputs()
                },
            ),
            (
                "scale",
                Inputs {
                    scale: -0.0,
                    ..inputs()
                },
            ),
            (
                "texture",
                Inputs {
                    texture: Some(vec![]),
                    ..inputs()
                },
            ),
            (
                "texture bytes",
                Inputs {
                    texture: Some(vec![0]),
                    ..inputs()
                },
            ),
        ];
        for (field, v) in changed {
            assert_ne!(CacheKey::new(KIND, &v), base, "{field}");
        }
        let other = CacheKind {
            name: "other",
            ..KIND
        };
        assert_ne!(CacheKey::new(other, &inputs()), base);
        let newer = CacheKind { version: 2, ..KIND };
        assert_ne!(CacheKey::new(newer, &inputs()), base);
        // Strings are length-prefixed: ("ab", "c") and ("a", "bc") differ.
        assert_ne!(
            CacheKey::new(KIND, &("ab", "c")),
            CacheKey::new(KIND, &("a", "bc"))
        );
    }

    #[test]
    fn key_is_xxh3_of_the_postcard_bytes() {
        // Pinned: a key must not change with the Rust release or platform, only with the
        // scheme (which would bump KEY_SCHEME).
        let bytes = postcard::to_allocvec(&(KEY_SCHEME, KIND, &inputs())).unwrap();
        let key = CacheKey::new(KIND, &inputs());
        assert_eq!(key.value(), xxhash_rust::xxh3::xxh3_64(&bytes));
        assert_eq!(key.to_string().len(), 16);
        // The published xxh3-64 of the empty input (xxHash's test vectors).
        assert_eq!(xxhash_rust::xxh3::xxh3_64(b""), 0x2d06_8005_38d3_94c2);
    }

    fn write(v: &u32, path: &Path, key: CacheKey) -> Result<(), String> {
        write_container(path, MAGIC, 1, &[key.metadata()], &v.to_le_bytes())
            .map_err(|e| e.to_string())
    }

    fn read(path: &Path, key: CacheKey) -> Result<u32, String> {
        let c = read_container(path, MAGIC, 1, "test entry").map_err(|e| e.to_string())?;
        key.check(path, c.metadata_value(KEY_METADATA))?;
        let b: [u8; 4] = c
            .payload
            .try_into()
            .map_err(|_| "not 4 bytes".to_string())?;
        Ok(u32::from_le_bytes(b))
    }

    fn get(cache: &Cache, key: CacheKey, value: u32, computed: &mut u32) -> Cached<u32> {
        let path = cache.entry("model", key, "bin");
        cache
            .get_or_compute(
                &path,
                |p| read(p, key),
                || {
                    *computed += 1;
                    Ok::<_, ()>(value)
                },
                |v, p| write(v, p, key),
            )
            .unwrap()
    }

    #[test]
    fn get_or_compute_hits_misses_and_replaces_bad_entries() {
        let dir = tempfile::tempdir().unwrap();
        let cache = Cache::new(dir.path().join("cache"));
        let key = CacheKey::new(KIND, &inputs());
        let mut computed = 0;

        let first = get(&cache, key, 7, &mut computed);
        assert_eq!(
            (first.value, first.outcome, computed),
            (7, CacheOutcome::Miss, 1)
        );
        assert_eq!(first.write_warning, None);
        let again = get(&cache, key, 8, &mut computed);
        assert_eq!(
            (again.value, again.outcome, computed),
            (7, CacheOutcome::Hit, 1)
        );

        // A damaged entry is reported naming the file, recomputed and replaced.
        let path = cache.entry("model", key, "bin");
        let mut bytes = std::fs::read(&path).unwrap();
        let last = bytes.len() - 1;
        bytes[last] ^= 1;
        std::fs::write(&path, &bytes).unwrap();
        let bad = get(&cache, key, 9, &mut computed);
        assert_eq!((bad.value, computed), (9, 2));
        match &bad.outcome {
            CacheOutcome::BadEntry(reason) => {
                assert!(reason.contains(&path.display().to_string()), "{reason}")
            }
            o => panic!("{o:?}"),
        }
        assert_eq!(get(&cache, key, 10, &mut computed).value, 9);

        // An entry of another key under this key's name is stale, not misread.
        let other = CacheKey::new(
            KIND,
            &Inputs {
                grid: 1,
                ..inputs()
            },
        );
        write(&5, &path, other).unwrap();
        let stale = get(&cache, key, 11, &mut computed);
        assert_eq!(stale.value, 11);
        assert!(
            matches!(&stale.outcome, CacheOutcome::BadEntry(r) if r.contains("stale")),
            "{:?}",
            stale.outcome
        );
    }

    #[test]
    fn a_failed_write_is_a_warning_and_the_value_is_returned() {
        let dir = tempfile::tempdir().unwrap();
        // A directory that cannot be created (a file is in the way) fails every write, as a
        // read-only directory does, whoever runs the test.
        let blocker = dir.path().join("file");
        std::fs::write(&blocker, b"x").unwrap();
        let cache = Cache::new(blocker.join("cache"));
        let key = CacheKey::new(KIND, &inputs());
        let mut computed = 0;
        let got = get(&cache, key, 3, &mut computed);
        assert_eq!((got.value, computed), (3, 1));
        assert_ne!(got.outcome, CacheOutcome::Hit);
        let warning = got.write_warning.expect("a warning");
        assert!(
            warning.contains(&cache.dir().display().to_string()),
            "{warning}"
        );

        // A directory that exists but whose entry cannot be written.
        let cache = Cache::new(dir.path());
        let path = cache.entry("model", key, "bin");
        std::fs::create_dir(&path).unwrap();
        let got = cache
            .get_or_compute(
                &path,
                |p| read(p, key),
                || Ok::<_, ()>(4),
                |v, p| write(v, p, key),
            )
            .unwrap();
        assert_eq!(got.value, 4);
        assert!(matches!(got.outcome, CacheOutcome::BadEntry(_)));
        let warning = got.write_warning.expect("a warning");
        assert!(warning.contains(&path.display().to_string()), "{warning}");
    }

    #[cfg(unix)]
    #[test]
    fn a_read_only_directory_is_a_warning() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let ro = dir.path().join("ro");
        std::fs::create_dir(&ro).unwrap();
        std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o555)).unwrap();
        // Root writes anyway; then there is nothing to test here.
        let writable = std::fs::write(ro.join("probe"), b"x").is_ok();
        let cache = Cache::new(&ro);
        let key = CacheKey::new(KIND, &inputs());
        let mut computed = 0;
        let got = get(&cache, key, 5, &mut computed);
        assert_eq!(got.value, 5);
        assert_eq!(got.write_warning.is_some(), !writable);
        std::fs::set_permissions(&ro, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
}
