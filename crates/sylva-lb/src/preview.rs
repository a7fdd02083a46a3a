//! PNG previews of grids: three orthogonal slices through the centre, side by side
//! (x-y at mid z, z-y at mid x, x-z at mid y), +y up.

use std::path::Path;

use sylva_core::colour::linear_to_srgb;

use crate::grid::{DensityGrid, Dims, LightingGrid};

/// Scale applied so every preview is at least this many pixels tall.
const MIN_HEIGHT: usize = 256;

fn layout(d: Dims) -> (usize, usize, usize) {
    let w = d.nx + d.nz + d.nx + 2 * 4;
    let h = d.ny.max(d.nz);
    let scale = MIN_HEIGHT.div_ceil(h).max(1);
    (w, h, scale)
}

/// An RGB preview image as PNG bytes; `site(x, y, z)` gives linear RGB in [0, 1].
fn render(d: Dims, site: impl Fn(usize, usize, usize) -> [f32; 3]) -> std::io::Result<Vec<u8>> {
    let (w, h, scale) = layout(d);
    let mut img = vec![[24u8, 24, 24]; w * h];
    let mut put = |px: usize, py: usize, c: [f32; 3]| {
        // +y up: row 0 of the image is the top.
        let idx = (h - 1 - py) * w + px;
        img[idx] = c.map(|v| (linear_to_srgb(v) * 255.0 + 0.5) as u8);
    };
    let (mz, mx, my) = (d.nz / 2, d.nx / 2, d.ny / 2);
    for x in 0..d.nx {
        for y in 0..d.ny {
            put(x, y, site(x, y, mz));
        }
    }
    let off = d.nx + 4;
    for z in 0..d.nz {
        for y in 0..d.ny {
            put(off + z, y, site(mx, y, z));
        }
    }
    let off = d.nx + d.nz + 8;
    for x in 0..d.nx {
        for z in 0..d.nz {
            put(off + x, z, site(x, my, z));
        }
    }
    let (sw, sh) = (w * scale, h * scale);
    let mut bytes = Vec::with_capacity(sw * sh * 3);
    for y in 0..sh {
        for x in 0..sw {
            bytes.extend_from_slice(&img[(y / scale) * w + x / scale]);
        }
    }
    let mut png = Vec::new();
    image::ImageEncoder::write_image(
        image::codecs::png::PngEncoder::new(&mut png),
        &bytes,
        sw as u32,
        sh as u32,
        image::ExtendedColorType::Rgb8,
    )
    .map_err(std::io::Error::other)?;
    Ok(png)
}

/// Lighting preview, scaled so the brightest interior site is white, written atomically.
pub fn write_lighting_preview(g: &LightingGrid, path: &Path) -> std::io::Result<()> {
    sylva_core::atomic_write(path, &lighting_preview_png(g)?)
}

/// The lighting preview's PNG bytes.
pub fn lighting_preview_png(g: &LightingGrid) -> std::io::Result<Vec<u8>> {
    let d = g.dims;
    let mut max = 0.0f32;
    for x in 1..d.nx - 1 {
        for y in 1..d.ny - 1 {
            for z in 1..d.nz - 1 {
                for v in g.at(x, y, z) {
                    max = max.max(v);
                }
            }
        }
    }
    let scale = if max > 0.0 { 1.0 / max } else { 1.0 };
    render(d, |x, y, z| g.at(x, y, z).map(|v| v * scale))
}

/// Density preview: leaf density green, wood brown.
pub fn write_density_preview(g: &DensityGrid, path: &Path) -> std::io::Result<()> {
    sylva_core::atomic_write(path, &density_preview_png(g)?)
}

/// The density preview's PNG bytes.
pub fn density_preview_png(g: &DensityGrid) -> std::io::Result<Vec<u8>> {
    render(g.dims, |x, y, z| {
        let i = g.dims.index(x, y, z);
        let (rho, wood) = (g.density[i], g.wood[i]);
        let leaf = [0.25, 0.8, 0.2];
        let bark = [0.55, 0.35, 0.15];
        [0, 1, 2].map(|c| rho * (leaf[c] * (1.0 - wood) + bark[c] * wood))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shapes::Shape;

    #[test]
    fn preview_is_a_png_of_the_expected_size() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("p.png");
        let d = Dims::new(16, 8, 12).unwrap();
        write_density_preview(&Shape::Crown.grid(d), &p).unwrap();
        let img = image::open(&p).unwrap();
        let (w, h, s) = layout(d);
        assert_eq!(
            (img.width() as usize, img.height() as usize),
            (w * s, h * s)
        );
    }
}
