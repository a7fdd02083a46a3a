//! A sequence of frames (`sylva relight`) tone mapped with one exposure, in bounded memory:
//! each linear frame goes to an unnamed temporary file on disk as it is made (the system
//! removes it however the process ends) while the exposure's statistics add up; at the end
//! the frames are read back one at a time, tone mapped into numbered PNGs and streamed into
//! the animated PNG. Memory holds about two frames whatever their number; the disk holds
//! [`Sequence::disk_bytes`] at most.

use std::fs::File;
use std::io::{self, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use crate::output::{encode_png, OutputError};
use crate::tonemap::{srgb8, ToneAccumulator, ToneMap, ToneStats};

/// Bytes of one linear frame held on disk (three `f32` per pixel).
const HDR_PIXEL: u64 = 12;
/// The most bytes an 8-bit RGB PNG of a pixel takes (stored uncompressed), with a filter byte
/// per row and the chunks around it counted in [`png_bound`].
const LDR_PIXEL: u64 = 3;

/// The most bytes a `width` × `height` PNG takes: every row stored, a filter byte each, and the
/// zlib blocks and chunk headers around them.
fn png_bound(width: u32, height: u32) -> u64 {
    let raw = (width as u64 * LDR_PIXEL + 1) * height as u64;
    raw + raw / 65535 * 5 + 1024
}

/// `path`, or its nearest ancestor that exists (`.` at the last): where a file under `path`
/// would take its disk space from.
pub fn nearest_existing(path: &Path) -> PathBuf {
    let mut p = path;
    loop {
        if p.is_dir() {
            return p.to_path_buf();
        }
        match p.parent() {
            Some(d) if !d.as_os_str().is_empty() => p = d,
            _ => return PathBuf::from("."),
        }
    }
}

/// Frames of one size pushed one by one, written at the end with one exposure.
pub struct Sequence {
    width: u32,
    height: u32,
    frames: usize,
    spill: BufWriter<File>,
    pushed: usize,
    tone: ToneMap,
    acc: ToneAccumulator,
    /// Where the temporary frames are, for errors.
    dir: PathBuf,
}

/// What [`Sequence::finish`] wrote.
#[derive(Debug, Clone, Copy)]
pub struct SequenceReport {
    pub stats: ToneStats,
}

impl Sequence {
    /// The most disk space `frames` frames of `width` × `height` need at once: the linear
    /// frames (12 bytes a pixel, until the end), the numbered PNGs and the animation (each at
    /// most its pixels stored).
    pub fn disk_bytes(width: u32, height: u32, frames: usize) -> u64 {
        let px = width as u64 * height as u64;
        let frames = frames as u64;
        frames * px * HDR_PIXEL + 2 * frames * png_bound(width, height)
    }

    /// Refuses `frames` frames of `width` × `height` when their [`Sequence::disk_bytes`]
    /// (with a 1 % margin) exceed `free`, the bytes free on the disk under `at` (`None`:
    /// unknown, let through): frames are held there, not in memory, until the sequence's one
    /// exposure is known.
    pub fn check_disk(
        at: &Path,
        free: Option<u64>,
        width: u32,
        height: u32,
        frames: usize,
    ) -> Result<(), OutputError> {
        let needed = Sequence::disk_bytes(width, height, frames);
        match free {
            Some(free) if needed + needed / 100 > free => Err(OutputError::Disk {
                at: at.into(),
                frames,
                width,
                height,
                needed,
                free,
            }),
            _ => Ok(()),
        }
    }

    /// A sequence of `frames` frames, held in an unnamed temporary file in `dir` (an existing
    /// directory: the output's, or its nearest existing parent, on the disk the outputs go to).
    pub fn new(
        dir: &Path,
        width: u32,
        height: u32,
        frames: usize,
        tone: ToneMap,
    ) -> Result<Sequence, OutputError> {
        if frames == 0 || width == 0 || height == 0 {
            return Err(OutputError::Frames { path: dir.into() });
        }
        let spill = tempfile::tempfile_in(dir).map_err(|source| OutputError::Io {
            path: dir.into(),
            source,
        })?;
        Ok(Sequence {
            width,
            height,
            frames,
            spill: BufWriter::with_capacity(1 << 20, spill),
            pushed: 0,
            tone,
            acc: ToneAccumulator::default(),
            dir: dir.into(),
        })
    }

    fn io(&self, source: io::Error) -> OutputError {
        OutputError::Io {
            path: self.dir.join("(the sequence's temporary frames)"),
            source,
        }
    }

    /// Adds the next linear frame (row-major, `width` × `height` pixels) and lets it go.
    pub fn push(&mut self, hdr: &[[f32; 3]]) -> Result<(), OutputError> {
        let want = self.width as usize * self.height as usize;
        if hdr.len() != want || self.pushed == self.frames {
            return Err(OutputError::Size {
                path: self.dir.clone(),
                width: self.width,
                height: self.height,
                want,
                got: hdr.len(),
            });
        }
        self.acc.add(hdr);
        let bytes: &[u8] = bytemuck::cast_slice(hdr);
        if let Err(e) = self.spill.write_all(bytes) {
            return Err(self.io(e));
        }
        self.pushed += 1;
        Ok(())
    }

    /// Tone maps every frame with the sequence's one exposure and writes frame `k` to
    /// `frame_paths[k]` and all of them, `delay_ms` each, to the animated PNG `anim`, through
    /// `outputs` (nothing replaces an old file until the set is committed).
    pub fn finish(
        self,
        outputs: &mut sylva_core::OutputSet,
        frame_paths: &[PathBuf],
        anim: &Path,
        delay_ms: u32,
    ) -> Result<SequenceReport, OutputError> {
        if self.pushed != self.frames
            || frame_paths.len() != self.frames
            || !(1..=65535).contains(&delay_ms)
        {
            return Err(OutputError::Frames { path: anim.into() });
        }
        let stats = self.tone.measure_accumulated(&self.acc);
        let (width, height, frames, tone) = (self.width, self.height, self.frames, self.tone);
        let dir = self.dir.clone();
        let io_err = |source: io::Error| OutputError::Io {
            path: dir.join("(the sequence's temporary frames)"),
            source,
        };
        let mut spill = self
            .spill
            .into_inner()
            .map_err(|e| io_err(e.into_error()))?;
        let px = width as usize * height as usize;
        let mut hdr = vec![[0.0f32; 3]; px];
        // Frame k back from the disk, tone mapped.
        let mut ldr = move |k: usize| -> io::Result<Vec<[u8; 3]>> {
            spill.seek(SeekFrom::Start(k as u64 * px as u64 * HDR_PIXEL))?;
            spill.read_exact(bytemuck::cast_slice_mut(&mut hdr))?;
            Ok(tone
                .apply_with(&hdr, stats)
                .into_iter()
                .map(srgb8)
                .collect())
        };
        for (k, path) in frame_paths.iter().enumerate() {
            let px = ldr(k).map_err(io_err)?;
            outputs.write_bytes(path, &encode_png(path, width, height, &px)?)?;
        }
        let enc = io::Error::other::<png::EncodingError>;
        outputs.write(anim, |w| {
            let mut e = png::Encoder::new(w, width, height);
            e.set_color(png::ColorType::Rgb);
            e.set_depth(png::BitDepth::Eight);
            e.set_animated(frames as u32, 0).map_err(enc)?;
            e.set_frame_delay(delay_ms as u16, 1000).map_err(enc)?;
            let mut w = e.write_header().map_err(enc)?;
            for k in 0..frames {
                w.write_image_data(ldr(k)?.as_flattened()).map_err(enc)?;
            }
            w.finish().map_err(enc)
        })?;
        Ok(SequenceReport { stats })
    }
}

#[cfg(test)]
mod tests {
    /// The disk check refuses what does not fit with its margin and lets unknown free space
    /// through; the space is looked for under the nearest existing folder.
    #[test]
    fn disk_check_and_nearest_existing_folder() {
        let dir = tempfile::tempdir().unwrap();
        let under = dir.path().join("a/b/frame.png");
        assert_eq!(nearest_existing(&under), dir.path());
        assert_eq!(
            nearest_existing(Path::new("no/such/dir")),
            PathBuf::from(".")
        );
        let needed = Sequence::disk_bytes(64, 32, 10);
        assert!(Sequence::check_disk(dir.path(), None, 64, 32, 10).is_ok());
        assert!(Sequence::check_disk(dir.path(), Some(2 * needed), 64, 32, 10).is_ok());
        let e = Sequence::check_disk(dir.path(), Some(needed), 64, 32, 10).unwrap_err();
        assert!(matches!(e, OutputError::Disk { frames: 10, .. }), "{e}");
        assert!(e.to_string().contains("ask for fewer --suns"), "{e}");
    }

    use super::*;
    use crate::output::encode_apng;

    fn frames(n: usize, w: u32, h: u32) -> Vec<Vec<[f32; 3]>> {
        (0..n)
            .map(|k| {
                (0..w * h)
                    .map(|i| {
                        let v = ((i as usize * 5 + k * 11) % 17) as f32 * 0.21;
                        [v, 0.3 * v + k as f32 * 0.1, 0.05]
                    })
                    .collect()
            })
            .collect()
    }

    /// The streamed sequence is byte for byte what tone mapping all frames together in
    /// memory gives (the way `sylva relight` wrote it before it streamed).
    #[test]
    fn streamed_frames_and_animation_are_those_of_the_frames_in_memory() {
        let (w, h, n) = (7, 5, 4);
        let hdr = frames(n, w, h);
        let dir = tempfile::tempdir().unwrap();
        let tone = ToneMap::default();
        let mut seq = Sequence::new(dir.path(), w, h, n, tone).unwrap();
        for f in &hdr {
            seq.push(f).unwrap();
        }
        let paths: Vec<PathBuf> = (0..n)
            .map(|k| dir.path().join(format!("frame-{k:02}.png")))
            .collect();
        let anim = dir.path().join("anim.png");
        let mut set = sylva_core::OutputSet::new::<&Path>(&[]);
        seq.finish(&mut set, &paths, &anim, 125).unwrap();
        set.commit().unwrap();

        let all: Vec<[f32; 3]> = hdr.iter().flatten().copied().collect();
        let stats = tone.measure(&all);
        let ldr: Vec<Vec<[u8; 3]>> = hdr
            .iter()
            .map(|f| tone.apply_with(f, stats).into_iter().map(srgb8).collect())
            .collect();
        for (k, path) in paths.iter().enumerate() {
            let want = encode_png(path, w, h, &ldr[k]).unwrap();
            assert_eq!(std::fs::read(path).unwrap(), want, "frame {k}");
        }
        let want = encode_apng(&anim, w, h, &ldr, 125).unwrap();
        assert_eq!(std::fs::read(&anim).unwrap(), want);
        // Only the outputs remain: the temporary frames had no name.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), n + 1);
    }

    #[test]
    fn wrong_sizes_and_counts_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let mut seq = Sequence::new(dir.path(), 2, 2, 1, ToneMap::default()).unwrap();
        assert!(seq.push(&[[1.0; 3]; 3]).is_err());
        seq.push(&[[1.0; 3]; 4]).unwrap();
        assert!(seq.push(&[[1.0; 3]; 4]).is_err(), "one frame too many");
        let mut set = sylva_core::OutputSet::new::<&Path>(&[]);
        let anim = dir.path().join("a.png");
        assert!(seq.finish(&mut set, &[], &anim, 100).is_err());
    }

    #[test]
    fn disk_bytes_count_the_linear_frames_and_both_images() {
        let b = Sequence::disk_bytes(4000, 3000, 1000);
        // 12 bytes a pixel held, and at most 3 each for the PNG and the animation.
        let px = 4000u64 * 3000 * 1000;
        assert!(b >= 18 * px && b < 18 * px + px / 100, "{b}");
    }
}
