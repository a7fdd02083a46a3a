//! A frame as jobs of a [`Runner`] ([`PreparedScene::render_split`]): the image is cut into
//! units (squares of whole 8×8 tiles on the image's tile grid), the runner hands them out
//! (under MPI on demand, by the root's work queue), each process renders its units as image
//! regions, and the root puts the pixels together.
//!
//! A region's pixels are bit-identical to the same pixels of a whole-image render (every
//! sample depends only on its pixel's place in the whole image, tiles stay on the whole
//! image's grid: `sylva_render::render`), so the gathered frame is the one-process frame
//! whatever the split, the process count or the thread counts.

use std::time::Instant;

use sylva_core::jobs::{from_root, Runner};
use sylva_core::wire::{Reader, WireError, Writer};
use sylva_light::Progress;
use sylva_render::render::{tile_count, TILE};
use sylva_render::stages::stage;
use sylva_render::{Frame, FrameTimings, Radiance, Region, RenderSettings};
use sylva_trace::TraceStats;

use crate::jobs::run_jobs;
use crate::{PipelineError, PreparedScene};

/// Units per rank the split aims at: enough that the last units to finish leave little
/// imbalance, few enough that each unit keeps a rank's threads busy.
const UNITS_PER_RANK: u64 = 64;

/// How a frame's region is cut into units of work: squares of `edge × edge` tiles on the
/// whole image's tile grid (clipped at the region's edges), numbered row by row.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UnitLayout {
    pub region: Region,
    /// Unit edge in tiles.
    pub edge: u32,
    /// The region's first tile column and row, and its tile columns and rows.
    first: (u32, u32),
    tiles: (u32, u32),
}

impl UnitLayout {
    pub fn new(region: Region, edge: u32) -> UnitLayout {
        assert!(edge > 0, "units of at least one tile");
        let (c0, r0) = (region.x0 / TILE, region.y0 / TILE);
        let c1 = (region.x0 + region.width).div_ceil(TILE);
        let r1 = (region.y0 + region.height).div_ceil(TILE);
        UnitLayout {
            region,
            edge,
            first: (c0, r0),
            tiles: (c1 - c0, r1 - r0),
        }
    }

    /// The split for `ranks` ranks of `threads` threads each: the largest unit edge of 8, 4,
    /// 2 or 1 tiles that gives every rank [`UNITS_PER_RANK`] units, but with several threads
    /// no unit of fewer than four tiles per thread (their last tiles leave threads idle).
    pub fn choose(region: Region, ranks: usize, threads: usize) -> UnitLayout {
        let min_edge = [1u32, 2, 4, 8]
            .into_iter()
            .find(|&e| (e * e) as usize > 4 * threads.saturating_sub(1))
            .unwrap_or(8);
        let want = UNITS_PER_RANK * ranks as u64;
        let edge = [8u32, 4, 2, 1]
            .into_iter()
            .filter(|&e| e >= min_edge)
            .find(|&e| UnitLayout::new(region, e).units() as u64 >= want)
            .unwrap_or(min_edge);
        UnitLayout::new(region, edge)
    }

    /// Units across and down.
    fn grid(&self) -> (u32, u32) {
        (
            self.tiles.0.div_ceil(self.edge),
            self.tiles.1.div_ceil(self.edge),
        )
    }

    pub fn units(&self) -> usize {
        let (ux, uy) = self.grid();
        ux as usize * uy as usize
    }

    /// Unit `i`'s pixels.
    pub fn unit(&self, i: usize) -> Region {
        let (ux, _) = self.grid();
        let (u, v) = ((i % ux as usize) as u32, (i / ux as usize) as u32);
        let r = self.region;
        let tx = self.first.0 + u * self.edge;
        let ty = self.first.1 + v * self.edge;
        let x0 = (tx * TILE).max(r.x0);
        let y0 = (ty * TILE).max(r.y0);
        let x1 = ((tx + self.edge) * TILE).min(r.x0 + r.width);
        let y1 = ((ty + self.edge) * TILE).min(r.y0 + r.height);
        Region {
            x0,
            y0,
            width: x1 - x0,
            height: y1 - y0,
        }
    }
}

/// Per rank: units rendered and their seconds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RankWork {
    pub units: usize,
    pub seconds: f64,
}

/// A frame rendered as units of a [`Runner`], at the root.
#[derive(Debug, Clone)]
pub struct SplitFrame {
    /// The gathered frame. Its pass timings are the units' summed over all ranks and
    /// divided by the rank count (a rank's mean); its stats are summed.
    pub frame: Frame,
    pub layout: UnitLayout,
    /// Per rank, in rank order.
    pub ranks: Vec<RankWork>,
    /// Per unit: seconds to render it, and the rank that did.
    pub unit_seconds: Vec<(f64, usize)>,
    /// Rank 0's wall time from the start of the split to the gathered frame.
    pub wall_seconds: f64,
}

impl SplitFrame {
    /// `max / mean - 1` of the ranks' busy seconds: 0 when perfectly balanced.
    pub fn imbalance(&self) -> f64 {
        imbalance(&self.ranks.iter().map(|r| r.seconds).collect::<Vec<_>>())
    }
}

/// `max / mean - 1` of `seconds` (0 for none or all zero).
pub fn imbalance(seconds: &[f64]) -> f64 {
    let mean = seconds.iter().sum::<f64>() / seconds.len().max(1) as f64;
    let max = seconds.iter().cloned().fold(0.0, f64::max);
    if mean > 0.0 {
        max / mean - 1.0
    } else {
        0.0
    }
}

fn encode_unit(f: &Frame) -> Vec<u8> {
    let t = &f.timings;
    let s = &f.stats;
    let mut w = Writer::default();
    w.f64(t.primary_seconds)
        .f64(t.shadow_seconds)
        .f64(t.shading_seconds)
        .f64(t.fused_seconds)
        .f64(t.gpu_kernel_seconds)
        .u64(t.primary_rays)
        .u64(t.shadow_rays);
    for v in [
        s.rays,
        s.nodes,
        s.leaves,
        s.triangle_tests,
        s.instance_visits,
        s.restarts,
        s.alpha_rejects,
        s.occluder_cache_hits,
    ] {
        w.u64(v);
    }
    let mut values = Vec::with_capacity(f.pixels.len() * 12);
    for p in &f.pixels {
        for v in [p.local, p.indirect, p.albedo, p.sky] {
            values.extend_from_slice(&v.to_array());
        }
    }
    w.f32s(&values);
    w.0
}

fn decode_unit(data: &[u8], region: Region) -> Result<Frame, WireError> {
    let mut r = Reader::new(data, "rendered unit");
    let timings = FrameTimings {
        primary_seconds: r.f64()?,
        shadow_seconds: r.f64()?,
        shading_seconds: r.f64()?,
        fused_seconds: r.f64()?,
        gpu_kernel_seconds: r.f64()?,
        primary_rays: r.u64()?,
        shadow_rays: r.u64()?,
    };
    let stats = TraceStats {
        rays: r.u64()?,
        nodes: r.u64()?,
        leaves: r.u64()?,
        triangle_tests: r.u64()?,
        instance_visits: r.u64()?,
        restarts: r.u64()?,
        alpha_rejects: r.u64()?,
        occluder_cache_hits: r.u64()?,
    };
    let n = region.pixels() as usize;
    let values = r.f32s(n * 12)?;
    r.end()?;
    let v3 = |c: &[f32]| glam::Vec3::new(c[0], c[1], c[2]);
    let pixels = values
        .chunks_exact(12)
        .map(|c| Radiance {
            local: v3(&c[0..3]),
            indirect: v3(&c[3..6]),
            albedo: v3(&c[6..9]),
            sky: v3(&c[9..12]),
        })
        .collect();
    Ok(Frame {
        region,
        width: region.width,
        height: region.height,
        pixels,
        timings,
        stats,
    })
}

impl PreparedScene {
    /// Renders `settings` as units of `runner` (every process calls it with the same scene
    /// and settings; that is checked): `Some` of the gathered frame at the root, `None`
    /// elsewhere. In one process the frame is [`PreparedScene::render`]'s, as one unit; across
    /// processes its units are rendered on the CPU (the GPU frame kernel takes whole images)
    /// and the root reports tiles to `progress` as they arrive.
    pub fn render_split(
        &self,
        runner: &dyn Runner,
        settings: &RenderSettings,
        progress: &dyn Progress,
    ) -> Result<Option<SplitFrame>, PipelineError> {
        let region = settings.region;
        if runner.processes() == 1 {
            let t0 = Instant::now();
            let frame = self.render(settings, progress)?;
            let seconds = t0.elapsed().as_secs_f64();
            let tiles = (region.width.max(region.height)).div_ceil(TILE).max(1);
            return Ok(Some(SplitFrame {
                frame,
                layout: UnitLayout::new(region, tiles),
                ranks: vec![RankWork { units: 1, seconds }],
                unit_seconds: vec![(seconds, 0)],
                wall_seconds: seconds,
            }));
        }
        let _span = tracing::info_span!(stage::FRAME).entered();
        let scene = &self.scene;
        runner.agree(
            "the frame",
            &format!(
                "{} ({} models, {} instances) {settings:?}",
                scene.name,
                scene.models.len(),
                scene.instances.len()
            ),
        )?;
        if !region.fits(settings.camera.width, settings.camera.height) {
            return Err(sylva_render::RenderError::Region {
                region,
                width: settings.camera.width,
                height: settings.camera.height,
            }
            .into());
        }
        // The root picks the split; the others take it.
        let edge = from_root(
            runner,
            "the frame's units",
            || {
                Ok::<_, PipelineError>(
                    UnitLayout::choose(region, runner.processes(), rayon::current_num_threads())
                        .edge,
                )
            },
            |e| u64::from(*e).to_le_bytes().to_vec(),
            |data| {
                let mut r = Reader::new(data, "unit edge");
                let e = r.u64()?;
                r.end()?;
                u32::try_from(e)
                    .ok()
                    .filter(|&e| e > 0)
                    .ok_or_else(|| WireError(format!("a unit edge of {e} tiles")).into())
            },
        )?;
        let layout = UnitLayout::new(region, edge);

        let t0 = Instant::now();
        self.decode_light_for(settings);
        let renderer = self.renderer();
        let root = runner.is_root();
        if root {
            progress.start("render", 3 * tile_count(region));
        }
        let outcome = run_jobs(
            runner,
            layout.units(),
            &mut |i| {
                let unit = RenderSettings {
                    region: layout.unit(i),
                    ..*settings
                };
                let frame = renderer.render(&unit, &|_| {})?;
                Ok(encode_unit(&frame))
            },
            &|i| progress.advance(3 * tile_count(layout.unit(i))),
        );
        if root {
            progress.finish();
        }
        let Some(results) = outcome? else {
            return Ok(None);
        };

        let mut pixels = vec![Radiance::default(); region.pixels() as usize];
        let mut timings = FrameTimings::default();
        let mut stats = TraceStats::default();
        let mut ranks = vec![
            RankWork {
                units: 0,
                seconds: 0.0
            };
            runner.processes()
        ];
        for (i, done) in results.iter().enumerate() {
            let u = layout.unit(i);
            let f = decode_unit(&done.bytes, u)?;
            for (row, values) in f.pixels.chunks_exact(u.width as usize).enumerate() {
                let y = (u.y0 - region.y0) as usize + row;
                let start = y * region.width as usize + (u.x0 - region.x0) as usize;
                pixels[start..start + values.len()].copy_from_slice(values);
            }
            timings.primary_seconds += f.timings.primary_seconds;
            timings.shadow_seconds += f.timings.shadow_seconds;
            timings.shading_seconds += f.timings.shading_seconds;
            timings.fused_seconds += f.timings.fused_seconds;
            timings.gpu_kernel_seconds += f.timings.gpu_kernel_seconds;
            timings.primary_rays += f.timings.primary_rays;
            timings.shadow_rays += f.timings.shadow_rays;
            stats += f.stats;
            if let Some(r) = ranks.get_mut(done.process) {
                r.units += 1;
                r.seconds += done.seconds;
            }
        }
        let n = runner.processes() as f64;
        timings.primary_seconds /= n;
        timings.shadow_seconds /= n;
        timings.shading_seconds /= n;
        timings.fused_seconds /= n;
        timings.gpu_kernel_seconds /= n;
        Ok(Some(SplitFrame {
            frame: Frame {
                region,
                width: region.width,
                height: region.height,
                pixels,
                timings,
                stats,
            },
            layout,
            unit_seconds: results.iter().map(|d| (d.seconds, d.process)).collect(),
            ranks,
            wall_seconds: t0.elapsed().as_secs_f64(),
        }))
    }
}
#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_cover_the_region_once_on_the_image_tile_grid() {
        let (w, h) = (77u32, 45u32);
        for region in [
            Region::full(w, h),
            Region {
                x0: 13,
                y0: 5,
                width: 50,
                height: 33,
            },
        ] {
            for edge in [1, 2, 3, 8] {
                let l = UnitLayout::new(region, edge);
                let mut count = vec![0u8; (w * h) as usize];
                let mut tiles = 0;
                for i in 0..l.units() {
                    let u = l.unit(i);
                    assert!(u.width > 0 && u.height > 0);
                    // Unit edges fall on tile edges, except at the region's.
                    assert!(u.x0.is_multiple_of(TILE) || u.x0 == region.x0);
                    assert!(u.y0.is_multiple_of(TILE) || u.y0 == region.y0);
                    tiles += tile_count(u);
                    for y in u.y0..u.y0 + u.height {
                        for x in u.x0..u.x0 + u.width {
                            count[(y * w + x) as usize] += 1;
                        }
                    }
                }
                // Splitting never splits a tile.
                assert_eq!(tiles, tile_count(region), "edge {edge}");
                for y in 0..h {
                    for x in 0..w {
                        let inside = (region.x0..region.x0 + region.width).contains(&x)
                            && (region.y0..region.y0 + region.height).contains(&y);
                        assert_eq!(count[(y * w + x) as usize], inside as u8);
                    }
                }
            }
        }
    }

    #[test]
    fn the_split_gives_each_rank_enough_units_of_enough_tiles() {
        // 896×448 (beech): 112 × 56 tiles.
        let beech = Region::full(896, 448);
        assert_eq!(UnitLayout::choose(beech, 1, 1).edge, 8); // 98 units
        assert_eq!(UnitLayout::choose(beech, 2, 1).edge, 4); // 392
        assert_eq!(UnitLayout::choose(beech, 16, 1).edge, 2); // 1568
        assert_eq!(UnitLayout::choose(beech, 64, 1).edge, 1);
        // Two threads need units of at least 8 tiles, sixteen of at least 64.
        assert_eq!(UnitLayout::choose(beech, 64, 2).edge, 4);
        assert_eq!(UnitLayout::choose(beech, 64, 16).edge, 8);
        let tiny = Region::full(20, 20);
        assert_eq!(UnitLayout::choose(tiny, 3, 1).units(), 9);
    }

    #[test]
    fn imbalance_is_max_over_mean() {
        assert_eq!(imbalance(&[1.0, 1.0]), 0.0);
        assert!((imbalance(&[1.0, 3.0]) - 0.5).abs() < 1e-12);
        assert_eq!(imbalance(&[]), 0.0);
    }
}
