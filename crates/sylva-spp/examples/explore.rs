use sylva_spp::tables::*;
fn main() {
    let args: Vec<usize> = std::env::args().skip(1).map(|a| a.parse().unwrap()).collect();
    let mut p = RmsProtocol::paper();
    p.streams = args[0]; p.azimuths = args[1];
    let t = std::time::Instant::now();
    let a = table1(&p).unwrap();
    let b = table2(&p).unwrap();
    for r in &a { println!("T1 {:?} {} {:.5} {:.5}", r.albedo, r.g, r.simplified, r.refined); }
    for r in &b { println!("T2 {:?} {} {:.5} {:.5}", r.albedo, r.thickness, r.simplified, r.refined); }
    eprintln!("{:?}", t.elapsed());
}
