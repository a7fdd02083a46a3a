//! Builds a scene and prints its statistics and build time.
fn main() {
    let name = std::env::args().nth(1).unwrap_or_else(|| "beech".into());
    let t = std::time::Instant::now();
    let scene = sylva_scene::load(&name).unwrap_or_else(|e| panic!("{e}"));
    let dt = t.elapsed();
    println!(
        "{}",
        serde_json::to_string_pretty(&sylva_scene::SceneStats::of(&scene)).unwrap()
    );
    println!("build {:.2} s", dt.as_secs_f64());
}
