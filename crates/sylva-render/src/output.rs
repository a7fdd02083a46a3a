//! Image files: 8-bit sRGB PNG and linear 32-bit float EXR, each written to a temporary file
//! and renamed, so an interrupted render never leaves a half-written image.

use std::io::Cursor;
use std::path::{Path, PathBuf};

use image::{ImageFormat, Rgb32FImage, RgbImage};

#[derive(Debug, thiserror::Error)]
pub enum OutputError {
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
    #[error("cannot write {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
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
