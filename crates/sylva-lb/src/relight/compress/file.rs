//! The compressed basis file (`.scbasis`): a [`CompressedBasis`] as it is held in memory, in
//! sylva's checked container (`sylva_core::container`: header, CRC-32, atomic writes).
//!
//! Metadata: the medium and solve schedule (as in basis grid files), the codec, precision and
//! far threshold, and whatever the caller adds (a cache key, the model's name). Payload,
//! little-endian: dims (3 × u32), bounds (6 × f32), the map back to channels (tag 0 identity,
//! or 1 linear: rank, 57 means, 57 × rank components), then the fields (tag 0 dense: field
//! count and the values; or 1 Haar: field count, blocks per axis, block starts, counts per
//! block and field, and the coefficients split or packed). Reading checks every length and
//! index a lookup follows, so a damaged file is refused naming the problem, never a panic.

use std::path::Path;

use sylva_core::container::{read_container, write_container, ByteReader, ByteWriter};

use super::haar::HaarFields;
use super::{
    Codec, CompressTarget, CompressedBasis, CompressedChannels, DenseFields, Encoded, Precision,
    Store, Transform, Values,
};
use crate::grid::{Bounds, Dims};
use crate::relight::basis::{basis_metadata, parse_basis_metadata};
use crate::relight::{RelightError, CHANNELS};

/// Extension of compressed basis files.
pub const COMPRESSED_EXTENSION: &str = "scbasis";
const MAGIC: &[u8; 8] = b"SYLVACBS";
const VERSION: u32 = 1;
const WHAT: &str = "compressed relighting basis file";

impl CompressedBasis {
    /// Writes the set atomically; `extra` metadata (`key=value`) is stored beside the
    /// set's own.
    pub fn write(&self, path: &Path, extra: &[(String, String)]) -> Result<(), RelightError> {
        sylva_core::check_memory(&format!("writing {}", path.display()), self.bytes() * 2)?;
        let (metadata, payload) = self.encode(extra);
        write_container(path, MAGIC, VERSION, &metadata, &payload).map_err(|source| {
            RelightError::Write {
                path: path.into(),
                source,
            }
        })
    }

    /// Reads a file written by [`CompressedBasis::write`]: the set and the file's metadata.
    /// Truncated, corrupted (CRC) or inconsistent files are refused with an error naming the
    /// file and the problem.
    pub fn read(path: &Path) -> Result<(CompressedBasis, Vec<(String, String)>), RelightError> {
        let c = read_container(path, MAGIC, VERSION, WHAT)?;
        let set = decode(&c.metadata, &c.payload).map_err(|what| RelightError::Format {
            path: path.into(),
            what,
        })?;
        Ok((set, c.metadata))
    }

    /// The set as bytes, for sending it to another process: the metadata and payload of its
    /// file (without the file's header), so [`CompressedBasis::from_bytes`] gives back this
    /// set exactly and checks it as [`CompressedBasis::read`] checks a file.
    pub fn to_bytes(&self) -> Vec<u8> {
        let (metadata, payload) = self.encode(&[]);
        let mut w = ByteWriter::new();
        w.u64(metadata.len() as u64);
        for (k, v) in &metadata {
            w.u8s(k.as_bytes());
            w.u8s(v.as_bytes());
        }
        w.u8s(&payload);
        w.bytes
    }

    /// The set [`CompressedBasis::to_bytes`] encoded; inconsistent bytes are refused.
    pub fn from_bytes(bytes: &[u8]) -> Result<CompressedBasis, RelightError> {
        let bad = |what: String| RelightError::Mismatch(format!("{WHAT} bytes: {what}"));
        let mut r = ByteReader::new(bytes);
        let text = |r: &mut ByteReader, what: &str| -> Result<String, String> {
            String::from_utf8(r.u8s(what)?).map_err(|_| format!("{what} is not UTF-8"))
        };
        let n = r.u64("metadata count").map_err(bad)?;
        let mut metadata = Vec::new();
        for _ in 0..n {
            let k = text(&mut r, "metadata key").map_err(bad)?;
            let v = text(&mut r, "metadata value").map_err(bad)?;
            metadata.push((k, v));
        }
        let payload = r.u8s("payload").map_err(bad)?;
        r.finish().map_err(bad)?;
        decode(&metadata, &payload).map_err(bad)
    }

    /// The metadata (the set's own, then `extra`) and the payload of its file.
    fn encode(&self, extra: &[(String, String)]) -> (Vec<(String, String)>, Vec<u8>) {
        let mut metadata = vec![
            ("format".to_string(), WHAT.to_string()),
            ("codec".to_string(), self.target.codec.name()),
            (
                "precision".to_string(),
                self.target.precision.name().to_string(),
            ),
            (
                "far_threshold".to_string(),
                self.target.far_threshold.to_string(),
            ),
        ];
        metadata.extend(basis_metadata(&self.medium, &self.options));
        metadata.extend(extra.iter().cloned());
        let mut w = ByteWriter::new();
        write_dims(&mut w, self.dims);
        for v in self.bounds.min.iter().chain(&self.bounds.max) {
            w.f32(*v);
        }
        self.encoded.write_to(&mut w);
        (metadata, w.bytes)
    }
}

/// The set [`CompressedBasis::encode`] made; `Err` says what is inconsistent.
fn decode(metadata: &[(String, String)], payload: &[u8]) -> Result<CompressedBasis, String> {
    let value = |k: &str| {
        metadata
            .iter()
            .find(|(m, _)| m == k)
            .map(|(_, v)| v.as_str())
    };
    let (medium, options) = parse_basis_metadata(&value)?;
    let get = |key: &str| value(key).ok_or_else(|| format!("metadata has no '{key}'"));
    let codec = Codec::parse(get("codec")?)?;
    let precision = Precision::parse(get("precision")?)
        .ok_or_else(|| "metadata 'precision' is not f16, f32 or packed".to_string())?;
    let far = get("far_threshold")?;
    let far_threshold = far
        .parse::<f64>()
        .map_err(|_| format!("metadata 'far_threshold' = '{far}' is not a number"))?;
    let target = CompressTarget {
        codec,
        precision,
        far_threshold,
    };
    target.validate().map_err(|e| e.to_string())?;
    let mut r = ByteReader::new(payload);
    let dims = read_dims(&mut r)?;
    let mut b = [0f32; 6];
    for v in &mut b {
        *v = r.f32("bounds")?;
    }
    if b.iter().any(|v| !v.is_finite()) || (0..3).any(|a| b[a] > b[a + 3]) {
        return Err(format!("bounds {b:?} are not a finite box"));
    }
    let bounds = Bounds {
        min: [b[0], b[1], b[2]],
        max: [b[3], b[4], b[5]],
    };
    let encoded = Encoded::read_from(&mut r, dims, CHANNELS, &target)?;
    r.finish()?;
    Ok(CompressedBasis {
        dims,
        bounds,
        medium,
        options,
        target,
        encoded,
    })
}

fn write_dims(w: &mut ByteWriter, dims: Dims) {
    for n in [dims.nx, dims.ny, dims.nz] {
        w.u32(n as u32);
    }
}

fn read_dims(r: &mut ByteReader) -> Result<Dims, String> {
    let mut n = [0usize; 3];
    for v in &mut n {
        *v = r.u32("grid size")? as usize;
    }
    Dims::new(n[0], n[1], n[2]).map_err(|e| e.to_string())
}

impl CompressedChannels {
    /// The set as bytes (its grid, channels, target and fields), for a cache file or another
    /// process: [`CompressedChannels::from_bytes`] gives back this set exactly.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut w = ByteWriter::new();
        write_dims(&mut w, self.dims);
        w.u32(self.encoded.channels as u32);
        w.u8s(self.target.codec.name().as_bytes());
        w.u8s(self.target.precision.name().as_bytes());
        w.u64(self.target.far_threshold.to_bits());
        self.encoded.write_to(&mut w);
        w.bytes
    }

    /// The set [`CompressedChannels::to_bytes`] encoded; inconsistent bytes are refused
    /// (every length and index a lookup follows is checked), the error saying what.
    pub fn from_bytes(bytes: &[u8]) -> Result<CompressedChannels, RelightError> {
        let bad = |what: String| RelightError::Mismatch(format!("compressed parts: {what}"));
        let mut r = ByteReader::new(bytes);
        let dims = read_dims(&mut r).map_err(bad)?;
        let channels = r.u32("channel count").map_err(bad)? as usize;
        if channels == 0 || !channels.is_multiple_of(3) {
            return Err(bad(format!(
                "{channels} channels: not three colours per part"
            )));
        }
        let text = |r: &mut ByteReader, what: &str| -> Result<String, String> {
            String::from_utf8(r.u8s(what)?).map_err(|_| format!("{what} is not UTF-8"))
        };
        let codec = Codec::parse(&text(&mut r, "codec").map_err(bad)?).map_err(bad)?;
        let precision = text(&mut r, "precision").map_err(bad)?;
        let precision = Precision::parse(&precision)
            .ok_or_else(|| bad(format!("precision '{precision}' is not f16, f32 or packed")))?;
        let far_threshold = f64::from_bits(r.u64("far threshold").map_err(bad)?);
        let target = CompressTarget {
            codec,
            precision,
            far_threshold,
        };
        target.validate_for(channels)?;
        let encoded = Encoded::read_from(&mut r, dims, channels, &target).map_err(bad)?;
        r.finish().map_err(bad)?;
        Ok(CompressedChannels {
            dims,
            target,
            encoded,
        })
    }
}

impl Encoded {
    /// The map back to channels (tag 0 identity, or 1 linear: rank, the channels' means, the
    /// components), then the fields (tag 0 dense, or 1 Haar).
    fn write_to(&self, w: &mut ByteWriter) {
        match &self.transform {
            Transform::Identity => w.u8(0),
            Transform::Linear {
                mean,
                components,
                rank,
            } => {
                w.u8(1);
                w.u32(*rank as u32);
                w.f32s(mean);
                w.f32s(components);
            }
        }
        match &self.store {
            Store::Dense(d) => {
                w.u8(0);
                w.u32(d.fields as u32);
                d.values.write_to(w);
            }
            Store::Haar(h) => {
                w.u8(1);
                h.write_to(w);
            }
        }
    }

    /// Reads what [`Encoded::write_to`] wrote for `channels` channels of a `dims` grid,
    /// compressed to `target`; `Err` says what is inconsistent.
    fn read_from(
        r: &mut ByteReader,
        dims: Dims,
        channels: usize,
        target: &CompressTarget,
    ) -> Result<Encoded, String> {
        let (transform, store) = read_fields(r, dims, channels, target)?;
        Ok(Encoded {
            channels,
            transform,
            store,
        })
    }
}

fn read_fields(
    r: &mut ByteReader,
    dims: Dims,
    channels: usize,
    target: &CompressTarget,
) -> Result<(Transform, Store), String> {
    let transform = match r.u8("channel map")? {
        0 => Transform::Identity,
        1 => {
            let rank = r.u32("rank")? as usize;
            if !(1..=channels).contains(&rank) {
                return Err(format!("rank {rank} is not in 1..={channels}"));
            }
            let mean = r.f32s("channel means")?;
            let components = r.f32s("components")?;
            if mean.len() != channels || components.len() != channels * rank {
                return Err(format!(
                    "{} means and {} components for rank {rank}",
                    mean.len(),
                    components.len()
                ));
            }
            if mean.iter().chain(&components).any(|v| !v.is_finite()) {
                return Err("a mean or component is not finite".into());
            }
            Transform::Linear {
                mean,
                components,
                rank,
            }
        }
        t => return Err(format!("unknown channel map {t}")),
    };
    let fields = match &transform {
        Transform::Identity => channels,
        Transform::Linear { rank, .. } => *rank,
    };
    let store = match r.u8("field store")? {
        0 => {
            let stored = r.u32("field count")? as usize;
            let values = Values::read_from(r, "field values")?;
            if stored != fields || values.len() != fields * dims.sites() {
                return Err(format!(
                    "{} values of {stored} fields; a {dims} grid of {fields} fields needs {}",
                    values.len(),
                    fields * dims.sites()
                ));
            }
            Store::Dense(DenseFields {
                dims,
                fields,
                values,
            })
        }
        1 => Store::Haar(HaarFields::read_from(r, dims, fields)?),
        t => return Err(format!("unknown field store {t}")),
    };
    let consistent = match (target.codec, &transform, &store) {
        (Codec::Haar { .. }, Transform::Identity, Store::Haar(_)) => true,
        (Codec::Pca { rank }, Transform::Linear { rank: k, .. }, Store::Dense(_)) => rank == *k,
        (Codec::PcaHaar { rank, .. }, Transform::Linear { rank: k, .. }, Store::Haar(_)) => {
            rank == *k
        }
        (Codec::ColourHaar { .. }, Transform::Linear { rank, .. }, Store::Haar(_)) => {
            *rank == channels
        }
        _ => false,
    };
    if !consistent {
        return Err(format!(
            "the stored fields do not match the codec {}",
            target.codec.name()
        ));
    }
    Ok((transform, store))
}
