//! Criterion benches of the tracer on one generated tree (red maple, 114k triangles): kd-tree
//! build, closest-hit and any-hit queries for rays aimed at the crown, short vs unbounded
//! stack. The whole-scene figures come from `examples/trace_bench.rs`.

use criterion::{criterion_group, criterion_main, Criterion};
use glam::Vec3;
use std::hint::black_box;
use sylva_core::SplitMix64;
use sylva_grow::Species;
use sylva_trace::{ModelAccel, Ray, TraceStats, TraversalConfig};

fn rays(model: &sylva_geom::Model, n: usize) -> Vec<Ray> {
    let b = model.bounds;
    let c = (b.min + b.max) * 0.5;
    let r = (b.max - b.min).length();
    let mut rng = SplitMix64::new(1);
    let mut f = || rng.next_f64() as f32;
    (0..n)
        .map(|_| {
            let o = c + Vec3::new(f() - 0.5, f() * 0.3, f() - 0.5).normalize() * r;
            let t = b.min + (b.max - b.min) * Vec3::new(f(), f(), f());
            Ray::new(o, (t - o).normalize())
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let model = Species::builtin("red_maple")
        .unwrap()
        .build_model()
        .unwrap();
    let accel = ModelAccel::build(&model);
    let rays = rays(&model, 4096);
    let mut g = c.benchmark_group("red_maple");
    g.sample_size(10);
    g.bench_function("build", |b| b.iter(|| ModelAccel::build(black_box(&model))));
    for (name, cfg) in [
        ("closest_4096_stack5", TraversalConfig::default()),
        ("closest_4096_unbounded", TraversalConfig::UNBOUNDED),
    ] {
        g.bench_function(name, |b| {
            b.iter(|| {
                let mut st = TraceStats::default();
                rays.iter()
                    .filter(|r| accel.closest_hit(r, cfg, &mut st).is_some())
                    .count()
            })
        });
    }
    g.bench_function("any_4096_stack5", |b| {
        b.iter(|| {
            let mut st = TraceStats::default();
            rays.iter()
                .filter(|r| accel.any_hit(r, TraversalConfig::default(), &mut st))
                .count()
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
