//! Species generation and scene building (the speed targets: under 1 s per species,
//! under 5 s for the beech scene on a 2-core machine).

use criterion::{criterion_group, criterion_main, Criterion};
use std::hint::black_box;
use sylva_grow::Species;
use sylva_scene::SceneDesc;

fn species(c: &mut Criterion) {
    let mut g = c.benchmark_group("species");
    g.sample_size(10);
    for s in Species::all_builtin() {
        g.bench_function(s.name.clone(), |b| {
            b.iter(|| black_box(s.build_model().unwrap()))
        });
    }
    g.finish();
}

fn scenes(c: &mut Criterion) {
    let mut g = c.benchmark_group("scene");
    g.sample_size(10);
    g.bench_function("beech_build", |b| {
        b.iter(|| black_box(sylva_scene::load("beech").unwrap()))
    });
    let desc = SceneDesc::load("beech").unwrap();
    g.bench_function("beech_place_instances", |b| {
        b.iter(|| black_box(desc.place_instances().unwrap()))
    });
    g.finish();
}

criterion_group!(benches, species, scenes);
criterion_main!(benches);
