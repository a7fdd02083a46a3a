use sylva_spp::tables::*;
fn main() {
    let args: Vec<f64> = std::env::args().skip(1).map(|a| a.parse().unwrap()).collect();
    let mut p = RmsProtocol::paper();
    if args.len() >= 2 { p.max_depth = args[0]; p.depth_step = args[1]; }
    if args.len() >= 3 { p.incidences_deg = (0..(args[2] as usize)).map(|k| k as f64 * 15.0).collect(); }
    for (gi, &g) in TABLE1_G.iter().enumerate() {
        for (ai, &a) in ALBEDOS.iter().enumerate() {
            let s = rms_sums(a, g, 10.0, &p).unwrap();
            let n = s.samples as f64;
            println!("a {a:4} g {g:4}: paper S {:4.1} R {:4.1} | A {:5.1} {:5.1} | B {:5.2} {:5.2} | B4pi {:5.1} {:5.1} | E {:5.1} {:5.1}",
              100.0*PAPER_TABLE1[gi][ai].0, 100.0*PAPER_TABLE1[gi][ai].1,
              100.0*s.simplified(), 100.0*s.refined(),
              100.0*(s.squared_simplified/n).sqrt(), 100.0*(s.squared_refined/n).sqrt(),
              400.0*std::f64::consts::PI*(s.squared_simplified/n).sqrt(), 400.0*std::f64::consts::PI*(s.squared_refined/n).sqrt(),
              100.0*s.rel_simplified/n, 100.0*s.rel_refined/n);
        }
    }
}
