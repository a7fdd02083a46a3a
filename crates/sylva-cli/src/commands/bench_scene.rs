//! `sylva bench scene`: times generating each built-in species and building a scene.

use super::scene::{emit, outln};
use std::time::Instant;
use sylva_grow::Species;

#[derive(clap::Args)]
pub struct BenchSceneArgs {
    /// Scene to build (a file or a built-in scene).
    #[arg(default_value = "beech")]
    pub scene: String,
    /// Runs per measurement; the median is reported.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub runs: u32,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Peak resident memory of this process (VmHWM), where /proc exists.
pub fn peak_rss_bytes() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

pub fn run(args: BenchSceneArgs) -> anyhow::Result<()> {
    let mut o = String::new();
    let threads = rayon::current_num_threads();
    let mut species = Vec::new();
    for s in Species::all_builtin() {
        let mut times = Vec::new();
        let mut tris = 0;
        for _ in 0..args.runs {
            let t = Instant::now();
            let m = s.build_model()?;
            times.push(t.elapsed().as_secs_f64());
            tris = m.triangle_count();
        }
        species.push((s.name.clone(), tris, median(times)));
    }
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..args.runs {
        let t = Instant::now();
        let scene = sylva_scene::load(&args.scene)?;
        times.push(t.elapsed().as_secs_f64());
        last = Some(scene);
    }
    let scene = last.expect("runs ≥ 1");
    let stats = sylva_scene::SceneStats::of(&scene);
    let build = median(times);
    let peak = peak_rss_bytes();
    if args.json {
        let v = serde_json::json!({
            "threads": threads,
            "runs": args.runs,
            "species": species.iter().map(|(n, t, s)| serde_json::json!({
                "name": n, "triangles": t, "median_s": s,
            })).collect::<Vec<_>>(),
            "scene": {
                "name": stats.name,
                "build_median_s": build,
                "instances": stats.instances,
                "unique_triangles": stats.unique_triangles,
                "instanced_triangles": stats.instanced_triangles,
                "memory_bytes": stats.memory_bytes,
            },
            "peak_rss_bytes": peak,
        });
        outln!(o, "{}", serde_json::to_string_pretty(&v)?);
        return emit(&o);
    }
    outln!(
        o,
        "species generation (median of {} runs, {threads} threads):",
        args.runs
    );
    for (n, t, s) in &species {
        outln!(o, "  {n:<18} {t:>9} triangles  {:>8.1} ms", s * 1e3);
    }
    outln!(o,
        "scene {}: built in {:.3} s (median), {} instances, {} unique / {} instanced triangles, {} in models",
        stats.name,
        build,
        stats.instances,
        stats.unique_triangles,
        stats.instanced_triangles,
        sylva_core::format_bytes(stats.memory_bytes)
    );
    if let Some(p) = peak {
        outln!(o, "peak resident memory {}", sylva_core::format_bytes(p));
    }
    emit(&o)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_of_odd_and_even() {
        assert_eq!(median(vec![3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(vec![4.0, 1.0, 3.0, 2.0]), 2.5);
    }

    #[test]
    fn runs_on_a_small_scene_and_rejects_unknown_ones() {
        let ok = run(BenchSceneArgs {
            scene: "catalpa".into(),
            runs: 1,
            json: true,
        });
        assert!(ok.is_ok(), "{ok:?}");
        let e = run(BenchSceneArgs {
            scene: "no_such_scene".into(),
            runs: 1,
            json: false,
        })
        .unwrap_err();
        assert!(e.to_string().contains("no_such_scene"), "{e}");
    }
}
