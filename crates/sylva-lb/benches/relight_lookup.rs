//! Relit lookups of one sun (three-basis combination plus ambient) at random points near the
//! medium: the uncompressed basis set against each codec. The basis is the built-in crown at
//! 40³ (solved in the setup, a few seconds); `examples/relight_measure.rs` measures a real
//! model's bytes and errors.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use sylva_lb::relight::{
    compress, compress_channels, BasisOptions, BasisSet, BasisWeights, Codec, CompressTarget,
    Footprint, Precision, Region,
};
use sylva_lb::shapes::Shape;
use sylva_lb::{Dims, Preset};

fn lookups(c: &mut Criterion) {
    let grid = Shape::Crown.grid(Dims::cube(40).unwrap());
    let (basis, _) = BasisSet::solve(
        &grid,
        &Preset::Leaf.params(),
        &BasisOptions::papers(grid.dims),
        &mut |_| {},
    )
    .unwrap();
    let region = Region::near_medium(&grid, 1);
    let sites = region.sites();
    let mut r = sylva_core::SplitMix64::new(1);
    let points: Vec<[f32; 3]> = (0..4096)
        .map(|_| {
            let s = sites[(r.next_u64() % sites.len() as u64) as usize];
            let (x, y, z) = grid.dims.coords(s);
            [x, y, z].map(|v| v as f32 + r.next_f64() as f32)
        })
        .collect();
    let w = BasisWeights::three_basis([0.3, -0.9, 0.2])
        .unwrap()
        .with_ambient(0.2)
        .unwrap();

    let mut group = c.benchmark_group("relight_lookup");
    group.throughput(Throughput::Elements(points.len() as u64));
    group.bench_function("uncompressed", |b| {
        b.iter(|| points.iter().map(|&p| basis.sample(p, &w)[1]).sum::<f32>())
    });
    for (name, codec, precision) in [
        (
            "haar_4e-3_packed",
            Codec::Haar { threshold: 4e-3 },
            Precision::Packed,
        ),
        (
            "colour_4e-3_packed",
            Codec::ColourHaar { threshold: 4e-3 },
            Precision::Packed,
        ),
        (
            "colour_4e-3_f16",
            Codec::ColourHaar { threshold: 4e-3 },
            Precision::F16,
        ),
        ("pca_8_f16", Codec::Pca { rank: 8 }, Precision::F16),
    ] {
        let target = CompressTarget {
            precision,
            ..CompressTarget::new(codec)
        };
        let small = compress(&basis, &region, &target).unwrap();
        let pw = small.project(&w);
        group.bench_function(name, |b| {
            b.iter(|| {
                points
                    .iter()
                    .map(|&p| small.sample_grid(p, &pw)[1])
                    .sum::<f32>()
            })
        });
    }
    group.finish();
}

/// One sun's combination of compressed parts (colour + Haar, packed; three sun parts and a
/// sky part as the physical light reads them): looked up through the footprint kernel, against
/// decoded once at every site (`decode_combined_into`, timed on its own) and looked up
/// trilinearly in the decoded grid.
fn decoded(c: &mut Criterion) {
    let grid = Shape::Crown.grid(Dims::cube(40).unwrap());
    let (basis, _) = BasisSet::solve(
        &grid,
        &Preset::Leaf.params(),
        &BasisOptions::papers(grid.dims),
        &mut |_| {},
    )
    .unwrap();
    let dims = grid.dims;
    let channels = basis.channels();
    let region = Region::near_medium(&grid, 1);
    let target = CompressTarget {
        precision: Precision::Packed,
        ..CompressTarget::new(Codec::ColourHaar { threshold: 4e-3 })
    };
    let set = compress_channels(
        dims,
        channels.len(),
        &|ch, s| channels[ch][s],
        &vec![1.0; channels.len()],
        &region,
        &target,
    )
    .unwrap();
    let w = set.project(&[
        (3, [0.5, 0.45, 0.4]),
        (7, [0.3, 0.3, 0.28]),
        (8, [0.2, 0.2, 0.18]),
        (0, [0.2, 0.2, 0.2]),
    ]);
    let sites = region.sites();
    let mut r = sylva_core::SplitMix64::new(1);
    let points: Vec<[f32; 3]> = (0..4096)
        .map(|_| {
            let s = sites[(r.next_u64() % sites.len() as u64) as usize];
            let (x, y, z) = dims.coords(s);
            [x, y, z].map(|v| v as f32 + r.next_f64() as f32)
        })
        .collect();
    let mut out = vec![[0.0f32; 3]; dims.sites()];
    set.decode_combined_into(&w, &mut out);

    let mut group = c.benchmark_group("relight_decoded");
    group.throughput(Throughput::Elements(points.len() as u64));
    group.bench_function("kernel_lookup", |b| {
        b.iter(|| {
            points
                .iter()
                .map(|&g| set.sample_grid(g, &w)[1])
                .sum::<f32>()
        })
    });
    group.bench_function("decoded_lookup", |b| {
        b.iter(|| {
            points
                .iter()
                .map(|&g| {
                    let fp = Footprint::at(dims, g);
                    let (s, t) = (fp.sites(dims), fp.weights());
                    (0..8).map(|k| out[s[k]][1] * t[k]).sum::<f32>()
                })
                .sum::<f32>()
        })
    });
    group.throughput(Throughput::Elements(dims.sites() as u64));
    group.bench_function("decode_every_site", |b| {
        b.iter(|| {
            let mut grid = vec![[0.0f32; 3]; dims.sites()];
            set.decode_combined_into(&w, &mut grid);
            grid[grid.len() / 2][1]
        })
    });
    group.finish();
}

criterion_group!(benches, lookups, decoded);
criterion_main!(benches);
