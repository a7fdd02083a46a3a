//! A scaling model of the frame split ([`crate::frame`]) from measured per-tile costs: how
//! long a frame takes on N ranks with the paper's fixed strips (000 §4.3: the image split along its vertical axis,
//! no load balancing) and with the pipeline's units handed out on demand, leaving out
//! communication (measured separately: `bench trace` under `mpirun`).

use sylva_render::render::TILE;
use sylva_render::Region;

use crate::frame::UnitLayout;

/// Seconds to render each 8×8 tile of an image, row by row (`columns × rows`).
#[derive(Debug, Clone, PartialEq)]
pub struct TileCosts {
    pub columns: u32,
    pub rows: u32,
    pub seconds: Vec<f64>,
}

/// The model's frame times for one rank count.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SplitTimes {
    pub ranks: usize,
    /// Fixed strips of image rows, one per rank: the most expensive strip.
    pub strips: f64,
    /// Units handed out on demand: the last rank to finish.
    pub on_demand: f64,
}

impl TileCosts {
    pub fn total(&self) -> f64 {
        self.seconds.iter().sum()
    }

    fn at(&self, column: u32, row: u32) -> f64 {
        self.seconds[(row * self.columns + column) as usize]
    }

    /// Pixel rows `y0..y1` (a tile row's cost spread evenly over its pixel rows).
    fn rows_cost(&self, y0: f64, y1: f64) -> f64 {
        let mut sum = 0.0;
        for row in 0..self.rows {
            let (r0, r1) = ((row * TILE) as f64, ((row + 1) * TILE) as f64);
            let overlap = (y1.min(r1) - y0.max(r0)).max(0.0);
            if overlap > 0.0 {
                let cost: f64 = (0..self.columns).map(|c| self.at(c, row)).sum();
                sum += cost * overlap / TILE as f64;
            }
        }
        sum
    }

    /// The frame on `ranks` ranks of one thread each: fixed strips of `height / ranks` pixel
    /// rows, and the units [`UnitLayout::choose`] picks, each taken by the first rank to be
    /// free (in unit order, as rank 0 hands them out).
    pub fn split(&self, ranks: usize) -> SplitTimes {
        let height = (self.rows * TILE) as f64;
        let strips = (0..ranks)
            .map(|k| {
                let y0 = height * k as f64 / ranks as f64;
                let y1 = height * (k + 1) as f64 / ranks as f64;
                self.rows_cost(y0, y1)
            })
            .fold(0.0, f64::max);
        let region = Region::full(self.columns * TILE, self.rows * TILE);
        let layout = UnitLayout::choose(region, ranks, 1);
        let mut free = vec![0f64; ranks];
        for i in 0..layout.units() {
            let u = layout.unit(i);
            let (c0, c1) = (u.x0 / TILE, (u.x0 + u.width).div_ceil(TILE));
            let (r0, r1) = (u.y0 / TILE, (u.y0 + u.height).div_ceil(TILE));
            let cost: f64 = (r0..r1)
                .flat_map(|r| (c0..c1).map(move |c| (c, r)))
                .map(|(c, r)| self.at(c, r))
                .sum();
            let first = (0..ranks)
                .min_by(|&a, &b| free[a].total_cmp(&free[b]))
                .expect("a rank");
            free[first] += cost;
        }
        SplitTimes {
            ranks,
            strips,
            on_demand: free.into_iter().fold(0.0, f64::max),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn costs(columns: u32, rows: u32, f: impl Fn(u32, u32) -> f64) -> TileCosts {
        TileCosts {
            columns,
            rows,
            seconds: (0..rows)
                .flat_map(|r| (0..columns).map(move |c| (c, r)))
                .map(|(c, r)| f(c, r))
                .collect(),
        }
    }

    #[test]
    fn uniform_costs_split_evenly_both_ways() {
        let c = costs(16, 16, |_, _| 1.0);
        for ranks in [1, 2, 4, 8] {
            let s = c.split(ranks);
            let ideal = 256.0 / ranks as f64;
            assert!((s.strips - ideal).abs() < 1e-9, "{s:?}");
            assert!((s.on_demand - ideal).abs() < 1e-9, "{s:?}");
        }
        // Strips that cut tile rows share their cost by pixel rows.
        let s = c.split(3);
        assert!((s.strips - 256.0 / 3.0).abs() < 1e-9, "{s:?}");
    }

    #[test]
    fn strips_pay_for_an_expensive_band_and_demand_does_not() {
        // The lower half costs 9 times the upper (a forest below the sky).
        let c = costs(16, 16, |_, r| if r >= 8 { 9.0 } else { 1.0 });
        let total = c.total();
        let s = c.split(2);
        assert!((s.strips - 0.9 * total).abs() < 1e-9, "{s:?}");
        // On demand (units of one tile here: 256 tiles, 2 ranks) the imbalance is at most
        // one unit.
        assert_eq!(UnitLayout::choose(Region::full(128, 128), 2, 1).edge, 1);
        assert!(s.on_demand >= total / 2.0 - 1e-9, "{s:?}");
        assert!(s.on_demand <= total / 2.0 + 9.0, "{s:?}");
    }
}
