//! Prints each built-in species' triangle count, generation time and size (calibration aid).
use sylva_grow::Species;
fn main() {
    for s in Species::all_builtin() {
        let t = std::time::Instant::now();
        let m = s.generate_mesh().unwrap();
        let dt = t.elapsed();
        let b = m.bounds();
        let leaves = m.triangles_with_material(1);
        println!(
            "{:18} tris {:8} (wood {:7}, leaf {:7}) ref {:?} ratio {:.3} size {:?} {:.0} ms",
            s.name,
            m.triangle_count(),
            m.triangle_count() - leaves,
            leaves,
            s.reference_triangles,
            s.reference_triangles
                .map(|r| m.triangle_count() as f64 / r as f64)
                .unwrap_or(0.0),
            b.size(),
            dt.as_secs_f64() * 1e3
        );
    }
}
