//! Tree statistics per built-in species: `cargo run --release -p sylva-trace --example kd_stats [SPECIES...]`.
use std::time::Instant;
use sylva_grow::Species;
use sylva_trace::ModelAccel;

fn main() {
    let names: Vec<String> = std::env::args().skip(1).collect();
    let names = if names.is_empty() {
        Species::all_builtin().into_iter().map(|s| s.name).collect()
    } else {
        names
    };
    for n in names {
        let model = Species::builtin(&n)
            .expect("species")
            .build_model()
            .expect("model");
        let t0 = Instant::now();
        let a = ModelAccel::build(&model);
        let s = a.tree().stats();
        println!(
            "{n}: {} tris, build {:.3} s, {} nodes, {} leaves ({} empty), {} refs ({:.2}/tri, {:.2}/non-empty leaf), depth {}, SAH {:.1}, {:.1} MiB",
            s.primitives, t0.elapsed().as_secs_f64(), s.nodes, s.leaves, s.empty_leaves, s.references,
            s.references as f64 / s.primitives as f64,
            s.references as f64 / (s.leaves - s.empty_leaves) as f64,
            s.max_depth, s.sah_cost, a.memory_bytes() as f64 / 1048576.0
        );
    }
}
