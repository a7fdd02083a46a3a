//! Image files: 8-bit sRGB PNG and linear 32-bit float EXR, each written to a temporary file
//! and renamed, so an interrupted render never leaves a half-written image.

use std::io::Cursor;
use std::path::{Path, PathBuf};

use image::{ImageFormat, Rgb32FImage, RgbImage};

#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error("{path}: cannot encode the animation: {source}")]
    Animation {
        path: PathBuf,
        source: png::EncodingError,
    },
    #[error("{path}: an animation needs at least one frame and a delay of 1 to 65535 ms")]
    Frames { path: PathBuf },
    #[error("{path}: {width}×{height} image needs {want} pixels, got {got}")]
    Size {
        path: PathBuf,
        width: u32,
        height: u32,
        want: usize,
        got: usize,
    },
    #[error("{path}: cannot encode the image: {source}")]
    Encode {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error("{path}: cannot read the OpenEXR layers: {message}")]
    Read { path: PathBuf, message: String },
    #[error("cannot write {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// A sequence's frames would not fit on the disk.
    #[error(
        "{frames} frames of {width}x{height} need up to {} on disk under {} (the linear \
         frames held there for the sequence's one exposure, {} each, then the PNGs and the \
         animation), but only {} is free: ask for fewer --suns or a smaller --width/--height",
        sylva_core::format_bytes(*needed),
        at.display(),
        sylva_core::format_bytes(*width as u64 * *height as u64 * 12),
        sylva_core::format_bytes(*free)
    )]
    Disk {
        at: PathBuf,
        frames: usize,
        width: u32,
        height: u32,
        needed: u64,
        free: u64,
    },
    /// A file of the command's output set (named twice, an input, or not written).
    #[error(transparent)]
    Set(#[from] sylva_core::OutputError),
}

fn check_size(path: &Path, width: u32, height: u32, got: usize) -> Result<(), OutputError> {
    let want = width as usize * height as usize;
    if want == 0 || got != want {
        return Err(OutputError::Size {
            path: path.into(),
            width,
            height,
            want,
            got,
        });
    }
    Ok(())
}

/// Row-major 8-bit sRGB pixels as PNG bytes.
pub fn encode_png(
    path: &Path,
    width: u32,
    height: u32,
    pixels: &[[u8; 3]],
) -> Result<Vec<u8>, OutputError> {
    check_size(path, width, height, pixels.len())?;
    let img = RgbImage::from_raw(width, height, pixels.as_flattened().to_vec())
        .expect("size checked above");
    let mut bytes = Cursor::new(Vec::new());
    img.write_to(&mut bytes, ImageFormat::Png)
        .map_err(|source| OutputError::Encode {
            path: path.into(),
            source,
        })?;
    Ok(bytes.into_inner())
}

/// Row-major linear RGB pixels as 32-bit float OpenEXR bytes.
pub fn encode_exr(
    path: &Path,
    width: u32,
    height: u32,
    pixels: &[[f32; 3]],
) -> Result<Vec<u8>, OutputError> {
    check_size(path, width, height, pixels.len())?;
    let img = Rgb32FImage::from_raw(width, height, pixels.as_flattened().to_vec())
        .expect("size checked above");
    let mut bytes = Cursor::new(Vec::new());
    img.write_to(&mut bytes, ImageFormat::OpenExr)
        .map_err(|source| OutputError::Encode {
            path: path.into(),
            source,
        })?;
    Ok(bytes.into_inner())
}

fn write_encoded(path: &Path, bytes: &[u8]) -> Result<(), OutputError> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|source| OutputError::Io {
            path: dir.into(),
            source,
        })?;
    }
    sylva_core::atomic_write(path, bytes).map_err(|source| OutputError::Io {
        path: path.into(),
        source,
    })
}

/// Row-major 8-bit sRGB pixels → PNG at `path` (parent directories created).
pub fn write_png(
    path: &Path,
    width: u32,
    height: u32,
    pixels: &[[u8; 3]],
) -> Result<(), OutputError> {
    check_size(path, width, height, pixels.len())?;
    let img = RgbImage::from_raw(width, height, pixels.as_flattened().to_vec())
        .expect("size checked above");
    let mut bytes = Cursor::new(Vec::new());
    img.write_to(&mut bytes, ImageFormat::Png)
        .map_err(|source| OutputError::Encode {
            path: path.into(),
            source,
        })?;
    write_encoded(path, bytes.get_ref())
}

/// Row-major linear RGB pixels → 32-bit float OpenEXR at `path`.
pub fn write_exr(
    path: &Path,
    width: u32,
    height: u32,
    pixels: &[[f32; 3]],
) -> Result<(), OutputError> {
    check_size(path, width, height, pixels.len())?;
    let img = Rgb32FImage::from_raw(width, height, pixels.as_flattened().to_vec())
        .expect("size checked above");
    let mut bytes = Cursor::new(Vec::new());
    img.write_to(&mut bytes, ImageFormat::OpenExr)
        .map_err(|source| OutputError::Encode {
            path: path.into(),
            source,
        })?;
    write_encoded(path, bytes.get_ref())
}

/// Row-major linear images of one size, one per named layer → a multi-layer 32-bit float
/// OpenEXR at `path`, each layer one channel `Y` (spectral bands: a layer per band).
pub fn write_exr_layers(
    path: &Path,
    width: u32,
    height: u32,
    layers: &[(String, Vec<f32>)],
) -> Result<(), OutputError> {
    write_encoded(path, &encode_exr_layers(path, width, height, layers)?)
}

/// A multi-layer OpenEXR read back: each layer's name and its one channel, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct ExrLayers {
    pub width: u32,
    pub height: u32,
    pub layers: Vec<(String, Vec<f32>)>,
}

impl ExrLayers {
    /// The names of the layers, in the file's order.
    pub fn names(&self) -> Vec<&str> {
        self.layers.iter().map(|(n, _)| n.as_str()).collect()
    }

    /// Layer `name`'s pixels.
    pub fn layer(&self, name: &str) -> Option<&[f32]> {
        let (_, l) = self.layers.iter().find(|(n, _)| n == name)?;
        Some(l)
    }
}

/// Reads a file [`write_exr_layers`] wrote (or any OpenEXR whose layers have one channel
/// each, all one size): the inverse of the writer, for tools and tests.
pub fn read_exr_layers(path: &Path) -> Result<ExrLayers, OutputError> {
    use exr::prelude::{ReadChannels, ReadLayers};
    let bad = |message: String| OutputError::Read {
        path: path.into(),
        message,
    };
    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .all_layers()
        .all_attributes()
        .from_file(path)
        .map_err(|e| bad(e.to_string()))?;
    let mut size = None;
    let mut layers = Vec::new();
    for (k, layer) in image.layer_data.iter().enumerate() {
        let name = layer
            .attributes
            .layer_name
            .as_ref()
            .map_or_else(|| format!("layer {k}"), |n| n.to_string());
        let [channel] = layer.channel_data.list.as_slice() else {
            return Err(bad(format!(
                "layer {name} has {} channels, not one",
                layer.channel_data.list.len()
            )));
        };
        let s = (layer.size.0 as u32, layer.size.1 as u32);
        if *size.get_or_insert(s) != s {
            return Err(bad(format!(
                "layer {name} is {}x{}, not the first's size",
                s.0, s.1
            )));
        }
        layers.push((name, channel.sample_data.values_as_f32().collect()));
    }
    let (width, height) = size.ok_or_else(|| bad("no layers".into()))?;
    Ok(ExrLayers {
        width,
        height,
        layers,
    })
}

/// The bytes of [`write_exr_layers`]' file (`path` names it in errors), for an output set.
pub fn encode_exr_layers(
    path: &Path,
    width: u32,
    height: u32,
    layers: &[(String, Vec<f32>)],
) -> Result<Vec<u8>, OutputError> {
    use exr::prelude::{
        AnyChannel, AnyChannels, Encoding, FlatSamples, Image, ImageAttributes, IntegerBounds,
        Layer, LayerAttributes, Layers, Vec2, WritableImage,
    };
    for (_, pixels) in layers {
        check_size(path, width, height, pixels.len())?;
    }
    let size = Vec2(width as usize, height as usize);
    let layers: Layers<AnyChannels<FlatSamples>> = layers
        .iter()
        .map(|(name, pixels)| {
            Layer::new(
                size,
                LayerAttributes::named(name.as_str()),
                Encoding::SMALL_LOSSLESS,
                AnyChannels::sort(smallvec::smallvec![AnyChannel::new(
                    "Y",
                    FlatSamples::F32(pixels.clone())
                )]),
            )
        })
        .collect();
    let image = Image::from_layers(
        ImageAttributes::new(IntegerBounds::from_dimensions(size)),
        layers,
    );
    let mut bytes = Vec::new();
    image
        .write()
        .to_buffered(Cursor::new(&mut bytes))
        .map_err(|e| OutputError::Encode {
            path: path.into(),
            source: image::ImageError::Encoding(image::error::EncodingError::new(
                image::error::ImageFormatHint::Exact(ImageFormat::OpenExr),
                e,
            )),
        })?;
    Ok(bytes)
}

/// Row-major 8-bit sRGB frames of one size → an animated PNG (APNG) at `path`, each frame
/// shown `delay_ms`, looping forever. Viewers without APNG show the first frame.
pub fn write_apng(
    path: &Path,
    width: u32,
    height: u32,
    frames: &[Vec<[u8; 3]>],
    delay_ms: u32,
) -> Result<(), OutputError> {
    write_encoded(path, &encode_apng(path, width, height, frames, delay_ms)?)
}

/// The bytes of [`write_apng`]'s animated PNG (`path` names it in errors), for an output set.
pub fn encode_apng(
    path: &Path,
    width: u32,
    height: u32,
    frames: &[Vec<[u8; 3]>],
    delay_ms: u32,
) -> Result<Vec<u8>, OutputError> {
    if frames.is_empty() || !(1..=65535).contains(&delay_ms) {
        return Err(OutputError::Frames { path: path.into() });
    }
    for f in frames {
        check_size(path, width, height, f.len())?;
    }
    let enc = |source| OutputError::Animation {
        path: path.into(),
        source,
    };
    let mut bytes = Vec::new();
    {
        let mut e = png::Encoder::new(&mut bytes, width, height);
        e.set_color(png::ColorType::Rgb);
        e.set_depth(png::BitDepth::Eight);
        e.set_animated(frames.len() as u32, 0).map_err(enc)?;
        e.set_frame_delay(delay_ms as u16, 1000).map_err(enc)?;
        let mut w = e.write_header().map_err(enc)?;
        for f in frames {
            w.write_image_data(f.as_flattened()).map_err(enc)?;
        }
        w.finish().map_err(enc)?;
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub/a.png");
        let px: Vec<[u8; 3]> = (0..12u8).map(|i| [i, 20 * i, 255 - i]).collect();
        write_png(&path, 4, 3, &px).unwrap();
        let back = image::open(&path).unwrap().to_rgb8();
        assert_eq!(back.dimensions(), (4, 3));
        assert_eq!(back.as_raw(), px.as_flattened());
        // No temporary file left beside it.
        assert_eq!(
            std::fs::read_dir(path.parent().unwrap()).unwrap().count(),
            1
        );
    }

    #[test]
    fn apng_holds_every_frame() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("anim.png");
        let frames: Vec<Vec<[u8; 3]>> = (0..5u8)
            .map(|f| (0..6u8).map(|i| [f, 40 * i, 255 - f * i]).collect())
            .collect();
        write_apng(&path, 3, 2, &frames, 120).unwrap();
        let decoder =
            png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()));
        let mut reader = decoder.read_info().unwrap();
        let actl = reader.info().animation_control.expect("an animated PNG");
        assert_eq!((actl.num_frames, actl.num_plays), (5, 0));
        let mut buf = vec![0u8; reader.output_buffer_size().unwrap()];
        for f in &frames {
            let info = reader.next_frame(&mut buf).unwrap();
            assert_eq!((info.width, info.height), (3, 2));
            assert_eq!(&buf[..18], f.as_flattened());
        }
        // The first frame is also the still image other viewers show.
        let still = image::open(&path).unwrap().to_rgb8();
        assert_eq!(still.as_raw(), frames[0].as_flattened());
        let e = write_apng(&path, 3, 2, &[], 100).unwrap_err();
        assert!(e.to_string().contains("anim.png"), "{e}");
        let e = write_apng(&path, 3, 2, &frames[..1], 0).unwrap_err();
        assert!(e.to_string().contains("delay"), "{e}");
        let e = write_apng(&path, 4, 2, &frames, 100).unwrap_err();
        assert!(e.to_string().contains("8 pixels"), "{e}");
    }

    #[test]
    fn exr_round_trip_is_exact() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.exr");
        let px: Vec<[f32; 3]> = (0..6)
            .map(|i| [i as f32 * 0.1, 1e-4 * i as f32, 37.5 + i as f32])
            .collect();
        write_exr(&path, 3, 2, &px).unwrap();
        let back = image::open(&path).unwrap().to_rgb32f();
        assert_eq!(back.as_raw(), px.as_flattened());
    }

    #[test]
    fn exr_layers_round_trip_with_their_names() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bands.exr");
        let layers = vec![
            ("red".to_string(), vec![0.0, 0.25, 1e-6, 3.5, -1.0, 7.0]),
            ("nir".to_string(), vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]),
        ];
        write_exr_layers(&path, 3, 2, &layers).unwrap();
        let back = read_exr_layers(&path).unwrap();
        assert_eq!((back.width, back.height), (3, 2));
        assert_eq!(back.names(), ["red", "nir"]);
        assert_eq!(back.layers, layers);
        assert_eq!(back.layer("nir"), Some(&layers[1].1[..]));
        // An RGB file has three channels in its one layer; a truncated file is no OpenEXR.
        let rgb = dir.path().join("rgb.exr");
        write_exr(&rgb, 1, 1, &[[0.5; 3]]).unwrap();
        let e = read_exr_layers(&rgb).unwrap_err().to_string();
        assert!(e.contains("rgb.exr") && e.contains("3 channels"), "{e}");
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
        let e = read_exr_layers(&path).unwrap_err().to_string();
        assert!(e.contains("bands.exr") && !e.contains('\n'), "{e}");
    }

    #[test]
    fn wrong_size_and_unwritable_paths_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let e = write_png(&dir.path().join("x.png"), 4, 4, &[[0; 3]; 3]).unwrap_err();
        assert!(
            e.to_string().contains("x.png") && e.to_string().contains("16"),
            "{e}"
        );
        let file = dir.path().join("file");
        std::fs::write(&file, b"x").unwrap();
        let e = write_exr(&file.join("y.exr"), 1, 1, &[[0.0; 3]]).unwrap_err();
        assert!(e.to_string().contains("file"), "{e}");
    }
}
