use sylva_spp::tables::*;
fn main() {
    let args: Vec<f64> = std::env::args().skip(1).map(|a| a.parse().unwrap()).collect();
    let mut p = RmsProtocol::paper();
    p.max_depth = args[0]; p.depth_step = args[1];
    p.incidences_deg = (0..(args[2] as usize)).map(|k| k as f64 * 15.0).collect();
    let b = |s: &RmsSums| { let n = s.samples as f64; (100.0*(s.squared_simplified/n).sqrt(), 100.0*(s.squared_refined/n).sqrt()) };
    for (gi, &g) in TABLE1_G.iter().enumerate() {
        let mut line = format!("T1 g {g:4}:");
        for (ai, &a) in ALBEDOS.iter().enumerate() {
            let s = rms_sums(a, g, 10.0, &p).unwrap();
            let (x, y) = b(&s);
            line += &format!(" {x:4.1}/{y:4.1} ({:3.1}/{:3.1})", 100.0*PAPER_TABLE1[gi][ai].0, 100.0*PAPER_TABLE1[gi][ai].1);
        }
        println!("{line}");
    }
    for (wi, &w) in TABLE2_THICKNESS.iter().enumerate() {
        let mut line = format!("T2 w {w:4}:");
        for (ai, &a) in ALBEDOS.iter().enumerate() {
            let s = rms_sums(a, 0.0, w, &p).unwrap();
            let (x, y) = b(&s);
            line += &format!(" {x:4.1}/{y:4.1} ({:3.1})", 100.0*PAPER_TABLE2[wi][ai]);
        }
        println!("{line}");
    }
}
