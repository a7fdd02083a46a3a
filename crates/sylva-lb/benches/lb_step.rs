//! One LB step on a dense 64³ medium (every site collides) and on an empty one (streaming
//! only), for comparing kernel changes. The full benchmark with the bandwidth ratio is
//! `sylva bench lb`.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use sylva_lb::{Boundary, DensityGrid, Dims, Lattice, Preset};

fn step(c: &mut Criterion) {
    let dims = Dims::cube(64).unwrap();
    let mut group = c.benchmark_group("lb_step_64");
    group.throughput(Throughput::Elements(dims.sites() as u64));
    for (name, rho) in [("dense", 1.0f32), ("empty", 0.0)] {
        let mut grid = DensityGrid::empty(dims);
        grid.density.fill(rho);
        let mut lattice = Lattice::new(
            &grid,
            &Preset::Leaf.params(),
            1,
            Boundary::sun([0.3, -0.9, 0.3], 1.0),
        )
        .unwrap();
        group.bench_function(name, |b| b.iter(|| lattice.step()));
    }
    group.finish();
}

criterion_group!(benches, step);
criterion_main!(benches);
