use sylva_spp::*;
fn main() {
    for &(a, g, deg) in &[(0.9, 0.0, 0.0), (0.9, 0.0, 45.0), (0.5, 0.0, 0.0)] {
        let s = Slab::with_incidence_deg(1.0, a, g, 10.0, deg).unwrap();
        let f = FullModel::new(s).unwrap();
        let p = SppModel::new(s).unwrap();
        println!("albedo {a} g {g} deg {deg}: R full {:.4} spp {:.4}  T full {:.4} spp {:.4}  consts {:?}", f.reflectance(), p.reflectance(), f.diffuse_transmittance(), p.diffuse_transmittance(), p.constants());
        for &z in &[0.0, 0.5, 1.0, 2.0, 5.0] {
            let (fd, fu) = f.hemispheric_totals(z).unwrap();
            let (sd, su) = p.hemispheric_totals(z).unwrap();
            let mut line = format!("z {z}: E+ {fd:.4} {sd:.4}  E- {fu:.4} {su:.4} direct {:.4} |", s.direct(z));
            for &mu in &[0.9, 0.5, 0.1, -0.1, -0.5, -0.9] {
                let d = Direction::new(mu, 0.0).unwrap();
                line += &format!(" {:.4}/{:.4}/{:.4}", f.radiance(z, d).unwrap(), p.radiance(z, d).unwrap(), p.refined_radiance(z, d).unwrap());
            }
            println!("{line}");
        }
    }
}
