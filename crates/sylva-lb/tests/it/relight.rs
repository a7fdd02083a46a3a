//! Relighting (paper 004, SPEC §3) on the real solver: base solutions, their combinations,
//! their file, and their compression.

use std::sync::OnceLock;

use sylva_lb::lattice::{unit, Q};
use sylva_lb::relight::{
    compress, compress_channels, relit_error, sky_directions, solve_basis, solve_basis_jobs,
    Ambient, BasisAssembly, BasisJob, BasisOptions, BasisSet, BasisWeights, Codec, CompressTarget,
    CompressedBasis, CompressedChannels, Footprint, Precision, Region, RelightError,
    COMPRESSED_EXTENSION,
};
use sylva_lb::shapes::Shape;
use sylva_lb::{
    solve_lighting, Boundary, DensityGrid, Dims, Element, GridFile, LightingGrid, MediumParams,
    Preset, SolveOptions,
};

const STEPS: usize = 60;

/// A crown with a brown trunk under green leaves.
fn grid() -> DensityGrid {
    Shape::Crown.grid(Dims::new(20, 22, 18).unwrap())
}

fn options(ambient: Ambient) -> BasisOptions {
    BasisOptions {
        solve: SolveOptions {
            max_steps: STEPS,
            tolerance: None,
            extrapolate: false,
            coarse_start: false,
        },
        ambient,
    }
}

/// Leaf parameters: anisotropic (g = -0.12, 0.091, -0.333), f_0 zeroed on green and brown.
fn medium() -> MediumParams {
    Preset::Leaf.params()
}

/// The basis set of [`grid`], solved once (B_0 solved too, for the linearity test).
fn solved() -> &'static BasisSet {
    static SET: OnceLock<BasisSet> = OnceLock::new();
    SET.get_or_init(|| {
        BasisSet::solve(&grid(), &medium(), &options(Ambient::Solve), &mut |_| {})
            .unwrap()
            .0
    })
}

fn direct(grid: &DensityGrid, travel: [f64; 3]) -> LightingGrid {
    let opts = SolveOptions {
        max_steps: STEPS,
        tolerance: None,
        extrapolate: false,
        coarse_start: false,
    };
    let b = Boundary::sun(travel, 1.0);
    solve_lighting(grid, &medium(), b, &opts, &mut |_, _, _| {})
        .unwrap()
        .0
}

fn unit_vec(d: [f64; 3]) -> [f64; 3] {
    let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    d.map(|c| c / l)
}

fn close(a: f32, b: f32, rel: f32, floor: f32) -> bool {
    (a - b).abs() <= rel * a.abs().max(b.abs()).max(floor)
}

#[test]
fn ambient_basis_is_the_sum_of_the_others() {
    // Linearity (the f_0 zeroing included): B_0 solved with f_i = 1 equals Σ_{j≥1} B_j.
    let set = solved();
    let mut worst = 0.0f32;
    for c in 0..3 {
        for s in 0..set.dims.sites() {
            let sum: f64 = (1..Q).map(|j| set.channel(j, c)[s] as f64).sum();
            let b0 = set.channel(0, c)[s];
            worst = worst.max((b0 - sum as f32).abs() / b0.abs().max(1e-3));
        }
    }
    assert!(worst < 1e-5, "B_0 vs Σ B_j: worst relative {worst}");
    assert!(set.channel(0, 1).iter().any(|&v| v > 1.0));

    // The default sums it: the same B_1..B_18, and B_0 their sum.
    let summed = BasisSet::solve(&grid(), &medium(), &options(Ambient::Sum), &mut |_| {})
        .unwrap()
        .0;
    for j in 1..Q {
        for c in 0..3 {
            assert_eq!(summed.channel(j, c), set.channel(j, c));
        }
    }
    for c in 0..3 {
        for s in 0..set.dims.sites() {
            assert!(close(
                summed.channel(0, c)[s],
                set.channel(0, c)[s],
                1e-5,
                1e-3
            ));
        }
    }
}

#[test]
fn exact_mode_equals_a_direct_solve() {
    let g = grid();
    let set = solved();
    for d in [
        [0.3, -0.9, 0.3],
        [-0.5, -0.7, 0.5],
        [0.0, -1.0, 0.0],
        [0.8, 0.1, -0.59],
        [-0.2, -0.35, -0.9],
    ] {
        let d = unit_vec(d);
        let want = direct(&g, d);
        // Normalised (free space 1): the direct solve divided by Σ max(0, n_i·d), as the
        // renderer normalises it.
        let free: f32 = Boundary::sun(d, 1.0).values.iter().sum();
        let got = set.relight(&BasisWeights::exact(d).unwrap()).unwrap();
        // Raw: the boundary itself as weights.
        let raw = set
            .relight(&BasisWeights::from_boundary(&Boundary::sun(d, 1.0)).unwrap())
            .unwrap();
        for c in 0..3 {
            for s in 0..g.dims.sites() {
                let w = want.colours[c][s];
                assert!(
                    close(got.colours[c][s] * free, w, 1e-5, 1e-3),
                    "{d:?} colour {c} site {s}: {} vs {w}",
                    got.colours[c][s] * free
                );
                assert!(close(raw.colours[c][s], w, 1e-5, 1e-3));
            }
        }
        // The medium casts a shadow, so the test compares more than free space.
        let min = want.colours[1]
            .iter()
            .cloned()
            .fold(f32::INFINITY, f32::min);
        assert!(min < 0.5 * free, "{d:?}: no shade ({min} of {free})");
    }
}

#[test]
fn three_basis_at_a_lattice_direction_is_that_basis() {
    let set = solved();
    for j in 1..Q {
        let w = BasisWeights::three_basis(unit(j)).unwrap();
        let lit = set.relight(&w).unwrap();
        for c in 0..3 {
            assert_eq!(lit.colours[c], set.channel(j, c), "B_{j}");
        }
        // Between lattice directions it is a convex combination of the face's three.
        let amb = w.with_ambient(0.5).unwrap();
        let lit = set.relight(&amb).unwrap();
        for s in (0..set.dims.sites()).step_by(37) {
            let want = set.channel(j, 2)[s] + 0.5 / 18.0 * set.channel(0, 2)[s];
            assert!(close(lit.colours[2][s], want, 1e-6, 1e-3));
        }
    }
}

#[test]
fn free_space_is_one_and_ambient_adds_its_scale() {
    let empty = DensityGrid::empty(Dims::new(9, 11, 8).unwrap());
    let opts = BasisOptions {
        solve: SolveOptions::papers(empty.dims),
        ambient: Ambient::Sum,
    };
    let (set, reports) = BasisSet::solve(&empty, &medium(), &opts, &mut |_| {}).unwrap();
    assert_eq!(reports.len(), 18);
    for j in 0..Q {
        let want = if j == 0 { 18.0 } else { 1.0 };
        for c in 0..3 {
            assert!(set.channel(j, c).iter().all(|&v| (v - want).abs() < 1e-5));
        }
    }
    for d in sky_directions(7).into_iter().chain([[0.0, 1.0, 0.0]]) {
        for w in [
            BasisWeights::exact(d).unwrap(),
            BasisWeights::three_basis(d).unwrap(),
        ] {
            let a = 0.3;
            let w = w.with_ambient(a).unwrap();
            assert!((w.free_space() - 1.3).abs() < 1e-12);
            let lit = set.relight(&w).unwrap();
            for c in 0..3 {
                assert!(lit.colours[c].iter().all(|&v| (v - 1.3).abs() < 1e-5));
            }
            let p = set.placement().grid_coords([0.1, 0.2, 0.3]);
            assert!(set.sample(p, &w).iter().all(|&v| (v - 1.3).abs() < 1e-5));
        }
    }
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let set = BasisSet::solve(&grid(), &medium(), &options(Ambient::Sum), &mut |_| {})
                    .unwrap()
                    .0;
                let lit = set
                    .relight(&BasisWeights::exact([0.2, -0.9, 0.1]).unwrap())
                    .unwrap();
                let region = Region::near_medium(&grid(), 1);
                let target = CompressTarget::new(Codec::PcaHaar {
                    rank: 6,
                    threshold: 2e-3,
                });
                let small = compress(&set, &region, &target).unwrap();
                let w: Vec<BasisWeights> = sky_directions(5)
                    .iter()
                    .map(|&d| BasisWeights::three_basis(d).unwrap())
                    .collect();
                let err = relit_error(&set, &small, &region, &w, 3000, 7).unwrap();
                (set, lit, small, err)
            })
    };
    let (a, b) = (run(1), run(2));
    assert!(a.0 == b.0, "basis sets differ");
    assert!(a.1 == b.1, "relit grids differ");
    assert!(a.2 == b.2, "compressed sets differ");
    assert_eq!(a.3, b.3);
}

#[test]
fn any_backend_can_solve_and_its_failures_are_named() {
    let g = grid();
    // A backend is any function with solve_lighting's signature.
    let mut calls = Vec::new();
    let (set, reports) = solve_basis(
        &g,
        &medium(),
        &options(Ambient::Sum),
        |grid: &DensityGrid,
         m: &MediumParams,
         b: Boundary,
         o: &SolveOptions,
         p: &mut dyn FnMut(usize, usize, f64)| {
            calls.push(b);
            solve_lighting(grid, m, b, o, p)
        },
        &mut |_| {},
    )
    .unwrap();
    assert_eq!(calls, (1..Q).map(Boundary::basis).collect::<Vec<_>>());
    assert_eq!(
        reports.iter().map(|r| r.basis).collect::<Vec<_>>(),
        (1..Q).collect::<Vec<_>>()
    );
    assert!(set.channel(3, 0) == solved().channel(3, 0));

    let fails = |j: usize, what: &str| {
        solve_basis(
            &g,
            &medium(),
            &options(Ambient::Sum),
            |grid: &DensityGrid,
             m: &MediumParams,
             b: Boundary,
             o: &SolveOptions,
             p: &mut dyn FnMut(usize, usize, f64)| {
                let (mut lit, r) = solve_lighting(grid, m, b, o, p)?;
                if b == Boundary::basis(j) {
                    match what {
                        "error" => {
                            return Err(sylva_lb::SolveError::Steps);
                        }
                        "nan" => lit.colours[1][40] = f32::NAN,
                        _ => {
                            lit.colours[2].pop();
                        }
                    }
                }
                Ok((lit, r))
            },
            &mut |_| {},
        )
        .unwrap_err()
    };
    let e = fails(5, "error");
    assert!(matches!(e, RelightError::Solve { basis: 5, .. }), "{e}");
    assert!(e.to_string().contains("B_5"), "{e}");
    let e = fails(7, "nan");
    assert!(
        matches!(e, RelightError::SolverResult { basis: 7, .. }),
        "{e}"
    );
    assert!(e.to_string().contains("NaN"), "{e}");
    let e = fails(2, "short");
    assert!(
        matches!(e, RelightError::SolverResult { basis: 2, .. }),
        "{e}"
    );
}

#[test]
fn progress_counts_every_solve() {
    let g = Shape::Sphere.grid(Dims::cube(6).unwrap());
    let mut seen = Vec::new();
    let opts = BasisOptions {
        solve: SolveOptions {
            max_steps: 4,
            tolerance: None,
            extrapolate: false,
            coarse_start: false,
        },
        ambient: Ambient::Solve,
    };
    // One job per basis and colour (the leaf preset's three colours differ).
    BasisSet::solve(&g, &medium(), &opts, &mut |p| {
        assert_eq!((p.solves, p.max_steps), (57, 4));
        if p.step == 4 {
            seen.push((p.done, p.basis, p.colour));
        }
    })
    .unwrap();
    let want: Vec<(usize, usize, usize)> = (1..Q)
        .chain([0])
        .flat_map(|j| (0..3).map(move |c| (j, c)))
        .enumerate()
        .map(|(k, (j, c))| (k, j, c))
        .collect();
    assert_eq!(seen, want);
}

#[test]
fn jobs_run_anywhere_and_assemble_into_the_same_set() {
    let g = grid();
    let m = medium();
    let opts = options(Ambient::Sum);
    let jobs = BasisJob::all(&m, &opts);
    assert_eq!(jobs.len(), 54);
    assert_eq!(
        jobs[0],
        BasisJob {
            basis: 1,
            colour: 0
        }
    );
    assert_eq!(
        jobs[53],
        BasisJob {
            basis: 18,
            colour: 2
        }
    );
    // One job per call, in reverse order, each call lighting one colour.
    let mut assembly = BasisAssembly::new(g.dims, g.bounds, &m, &opts).unwrap();
    let mut distinct_colours = Vec::new();
    for job in jobs.iter().rev() {
        let out = solve_basis_jobs(
            &g,
            &m,
            &opts,
            &[*job],
            |grid: &DensityGrid,
             medium: &MediumParams,
             b: Boundary,
             o: &SolveOptions,
             p: &mut dyn FnMut(usize, usize, f64)| {
                let mut c = medium.colours.to_vec();
                c.dedup();
                distinct_colours.push(c.len());
                solve_lighting(grid, medium, b, o, p)
            },
            &mut |_, _| {},
        )
        .unwrap();
        assert_eq!(out.len(), 1);
        assert_eq!(out[0].0, *job);
        assert_eq!(out[0].2.steps, STEPS);
        assembly.insert(out[0].0, out[0].1.clone()).unwrap();
    }
    assert!(
        distinct_colours.iter().all(|&n| n == 1),
        "one colour per call"
    );
    assert!(assembly.missing().is_empty());
    let (whole, _) = BasisSet::solve(&g, &m, &opts, &mut |_| {}).unwrap();
    assert!(
        assembly.finish().unwrap() == whole,
        "bit-identical to one solve"
    );

    // A medium with two equal colours needs two jobs per basis; the third is copied.
    let mut twin = m.clone();
    twin.colours[2] = twin.colours[0];
    let jobs = BasisJob::all(&twin, &opts);
    assert_eq!(jobs.len(), 36);
    assert!(jobs.iter().all(|j| j.colour < 2));
    let (set, _) = BasisSet::solve(&g, &twin, &opts, &mut |_| {}).unwrap();
    assert!(set.channel(7, 2) == set.channel(7, 0));
    assert!(set.channel(7, 1) != set.channel(7, 0));

    // Mistakes are named.
    let run = |jobs: &[BasisJob]| {
        solve_basis_jobs(&g, &m, &opts, jobs, solve_lighting, &mut |_, _| {}).unwrap_err()
    };
    let e = run(&[]);
    assert!(e.to_string().contains("no basis jobs"), "{e}");
    let e = run(&[
        BasisJob {
            basis: 1,
            colour: 0,
        },
        BasisJob {
            basis: 2,
            colour: 0,
        },
    ]);
    assert!(e.to_string().contains("B_1 and B_2"), "{e}");
    let e = run(&[
        BasisJob {
            basis: 3,
            colour: 1,
        },
        BasisJob {
            basis: 3,
            colour: 1,
        },
    ]);
    assert!(e.to_string().contains("twice"), "{e}");
    let e = run(&[BasisJob {
        basis: 19,
        colour: 0,
    }]);
    assert!(e.to_string().contains("out of range"), "{e}");
    let mut a = BasisAssembly::new(g.dims, g.bounds, &m, &opts).unwrap();
    let job = BasisJob {
        basis: 4,
        colour: 1,
    };
    let e = a.insert(job, vec![1.0; 5]).unwrap_err();
    assert!(
        matches!(e, RelightError::SolverResult { basis: 4, .. }),
        "{e}"
    );
    let mut v = vec![0.5; g.dims.sites()];
    v[17] = f32::NAN;
    let e = a.insert(job, v).unwrap_err();
    assert!(e.to_string().contains("NaN"), "{e}");
    let e = a
        .insert(
            BasisJob {
                basis: 0,
                colour: 0,
            },
            vec![0.0; g.dims.sites()],
        )
        .unwrap_err();
    assert!(e.to_string().contains("not a job"), "{e}");
    a.insert(job, vec![0.5; g.dims.sites()]).unwrap();
    assert_eq!(a.missing().len(), 53);
    let e = a.finish().unwrap_err();
    assert!(e.to_string().contains("53 basis jobs"), "{e}");
}

#[test]
fn compressed_files_round_trip_and_bad_ones_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let set = solved();
    let region = Region::near_medium(&grid(), 1).with_floor(2);
    let extra = vec![("cache_key".to_string(), "00ff".to_string())];
    for (codec, precision) in [
        (Codec::Haar { threshold: 3e-3 }, Precision::F16),
        (Codec::Haar { threshold: 3e-3 }, Precision::F32),
        (Codec::Pca { rank: 5 }, Precision::F16),
        (
            Codec::PcaHaar {
                rank: 7,
                threshold: 2e-3,
            },
            Precision::Packed,
        ),
        (Codec::ColourHaar { threshold: 4e-3 }, Precision::Packed),
    ] {
        let target = CompressTarget {
            precision,
            ..CompressTarget::new(codec)
        };
        let c = compress(set, &region, &target).unwrap();
        let p = dir.path().join(format!("crown.{COMPRESSED_EXTENSION}"));
        c.write(&p, &extra).unwrap();
        let (back, meta) = CompressedBasis::read(&p).unwrap();
        assert!(back == c, "{codec:?} {precision:?} round trip");
        assert!(meta.contains(&extra[0]));
        // In memory (what MPI ranks send each other) too.
        let sent = CompressedBasis::from_bytes(&c.to_bytes()).unwrap();
        assert!(sent == c, "{codec:?} {precision:?} bytes round trip");
        let w = BasisWeights::three_basis([0.3, -0.8, 0.1])
            .unwrap()
            .with_ambient(0.3)
            .unwrap();
        let (pa, pb) = (c.project(&w), back.project(&w));
        for g in points(&region, 50) {
            assert_eq!(c.sample_grid(g, &pa), back.sample_grid(g, &pb));
        }
    }
    let c = compress(set, &region, &CompressTarget::recommended()).unwrap();
    let p = dir.path().join("good.scbasis");
    c.write(&p, &[]).unwrap();
    let bytes = std::fs::read(&p).unwrap();
    let bad = dir.path().join("bad.scbasis");
    let refused = |content: &[u8], want: &str| {
        std::fs::write(&bad, content).unwrap();
        let e = CompressedBasis::read(&bad).unwrap_err().to_string();
        assert!(e.contains("bad.scbasis") && e.contains(want), "{e}");
    };
    refused(&bytes[..bytes.len() - 10], "truncated");
    let mut flipped = bytes.clone();
    let at = flipped.len() - 7;
    flipped[at] ^= 2;
    refused(&flipped, "checksum");
    refused(b"", "truncated");
    // A basis grid file is not a compressed set.
    set.write(&bad, Element::F16).unwrap();
    let e = CompressedBasis::read(&bad).unwrap_err().to_string();
    assert!(e.contains("bad.scbasis") && e.contains("magic"), "{e}");
    // A well-formed file whose codec does not match its fields.
    let mut wrong = c.clone();
    wrong.target.codec = Codec::Haar { threshold: 0.004 };
    wrong.write(&bad, &[]).unwrap();
    let e = CompressedBasis::read(&bad).unwrap_err().to_string();
    assert!(e.contains("bad.scbasis") && e.contains("codec"), "{e}");
    // Bytes are checked like files: short, long, inconsistent.
    let sent = c.to_bytes();
    for (b, want) in [
        (&sent[..sent.len() - 3], "stated"),
        (&[sent.as_slice(), &[0]].concat()[..], "left over"),
        (&wrong.to_bytes()[..], "codec"),
    ] {
        let e = CompressedBasis::from_bytes(b).unwrap_err().to_string();
        assert!(
            e.contains("compressed relighting basis file bytes") && e.contains(want),
            "{e}"
        );
    }
}

#[test]
fn basis_files_round_trip_and_bad_ones_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let set = solved();
    let p = dir.path().join("crown.sbasis");
    set.write(&p, Element::F32).unwrap();
    let back = BasisSet::read(&p).unwrap();
    assert!(&back == set, "f32 round trip");
    let p16 = dir.path().join("crown16.sbasis");
    set.write(&p16, Element::F16).unwrap();
    let back = BasisSet::read(&p16).unwrap();
    assert_eq!(back.medium, set.medium);
    assert_eq!(back.options, set.options);
    for (a, b) in back
        .channels()
        .iter()
        .flatten()
        .zip(set.channels().iter().flatten())
    {
        assert!(close(*a, *b, 1e-3, 1e-4));
    }
    assert!(
        std::fs::metadata(&p16).unwrap().len() < std::fs::metadata(&p).unwrap().len() / 2 + 4096
    );

    // Truncated and corrupted files name the file.
    let bytes = std::fs::read(&p).unwrap();
    let bad = dir.path().join("bad.sbasis");
    std::fs::write(&bad, &bytes[..bytes.len() - 100]).unwrap();
    let e = BasisSet::read(&bad).unwrap_err();
    assert!(
        e.to_string().contains("bad.sbasis") && e.to_string().contains("truncated"),
        "{e}"
    );
    let mut flipped = bytes.clone();
    let at = flipped.len() - 1000;
    flipped[at] ^= 0x40;
    std::fs::write(&bad, &flipped).unwrap();
    let e = BasisSet::read(&bad).unwrap_err();
    assert!(
        e.to_string().contains("bad.sbasis") && e.to_string().contains("checksum"),
        "{e}"
    );

    // A lighting grid is not a basis set.
    let lit = dir.path().join("lit.sgrid");
    GridFile::from_lighting(
        &set.relight(&BasisWeights::exact([0.0, -1.0, 0.0]).unwrap())
            .unwrap(),
        Element::F32,
        vec![],
    )
    .write(&lit)
    .unwrap();
    let e = BasisSet::read(&lit).unwrap_err();
    assert!(
        e.to_string().contains("lit.sgrid") && e.to_string().contains("lighting grid"),
        "{e}"
    );

    // Valid container, invalid content: metadata missing or wrong, values not finite.
    let mut file = set.to_grid_file(Element::F32);
    file.metadata.retain(|(k, _)| k != "medium.green");
    file.write(&bad).unwrap();
    let e = BasisSet::read(&bad).unwrap_err();
    assert!(
        e.to_string().contains("bad.sbasis") && e.to_string().contains("medium.green"),
        "{e}"
    );
    let mut file = set.to_grid_file(Element::F32);
    for (k, v) in &mut file.metadata {
        if k == "medium.red" {
            *v = "0.5,0.9,0".into();
        }
    }
    file.write(&bad).unwrap();
    let e = BasisSet::read(&bad).unwrap_err();
    assert!(
        e.to_string().contains("bad.sbasis") && e.to_string().contains("σ_t"),
        "{e}"
    );
    let mut file = set.to_grid_file(Element::F32);
    file.channels[10][5] = f32::INFINITY;
    file.write(&bad).unwrap();
    let e = BasisSet::read(&bad).unwrap_err();
    assert!(
        e.to_string().contains("bad.sbasis") && e.to_string().contains("B3 green"),
        "{e}"
    );
}

/// Random points (grid coordinates) in a region, deterministic.
fn points(region: &Region, n: usize) -> Vec<[f32; 3]> {
    let sites = region.sites();
    let mut r = sylva_core::SplitMix64::new(11);
    (0..n)
        .map(|_| {
            let s = sites[(r.next_u64() % sites.len() as u64) as usize];
            let (x, y, z) = region.dims.coords(s);
            [x, y, z].map(|c| c as f32 + r.next_f64() as f32)
        })
        .collect()
}

fn combinations(n: usize) -> Vec<BasisWeights> {
    sky_directions(n)
        .iter()
        .enumerate()
        .map(|(i, &d)| {
            let w = if i % 2 == 0 {
                BasisWeights::three_basis(d)
            } else {
                BasisWeights::exact(d)
            };
            w.unwrap().with_ambient(0.2 * i as f64).unwrap()
        })
        .collect()
}

#[test]
fn lossless_settings_round_trip() {
    let set = solved();
    let all = Region::all(set.dims);
    for codec in [
        Codec::Haar { threshold: 0.0 },
        Codec::Pca { rank: 57 },
        Codec::PcaHaar {
            rank: 57,
            threshold: 0.0,
        },
        Codec::ColourHaar { threshold: 0.0 },
    ] {
        let target = CompressTarget {
            codec,
            precision: Precision::F32,
            far_threshold: 0.0,
        };
        let c = compress(set, &all, &target).unwrap();
        let back = c.decompress().unwrap();
        let scale = |ch: usize| if ch < 3 { 18.0 } else { 1.0 };
        for (ch, (a, b)) in back.channels().iter().zip(set.channels()).enumerate() {
            for (x, y) in a.iter().zip(b) {
                assert!(
                    (x - y).abs() < 2e-5 * scale(ch),
                    "{codec:?} channel {ch}: {x} vs {y}"
                );
            }
        }
        for w in combinations(6) {
            let pw = c.project(&w);
            for g in points(&all, 300) {
                let (x, y) = (c.sample_grid(g, &pw), set.sample(g, &w));
                for k in 0..3 {
                    assert!(
                        (x[k] - y[k]).abs() < 1e-4,
                        "{codec:?} at {g:?}: {x:?} vs {y:?}"
                    );
                }
            }
        }
    }
}

#[test]
fn footprint_decode_equals_full_decode() {
    let set = solved();
    let region = Region::near_medium(&grid(), 1);
    for (codec, precision) in [
        (Codec::Haar { threshold: 3e-3 }, Precision::F16),
        (Codec::Haar { threshold: 3e-3 }, Precision::Packed),
        (Codec::Pca { rank: 5 }, Precision::F16),
        (
            Codec::PcaHaar {
                rank: 5,
                threshold: 3e-3,
            },
            Precision::F32,
        ),
        (Codec::ColourHaar { threshold: 3e-3 }, Precision::Packed),
    ] {
        let target = CompressTarget {
            precision,
            ..CompressTarget::new(codec)
        };
        let c = compress(set, &region, &target).unwrap();
        let full = c.decompress().unwrap();
        for w in combinations(4) {
            let pw = c.project(&w);
            // Anywhere: the footprint kernel against the decoded block.
            for g in points(&Region::all(set.dims), 400) {
                let (a, b) = (c.sample_grid(g, &pw), c.sample_grid_by_full_decode(g, &pw));
                for k in 0..3 {
                    assert!(
                        (a[k] - b[k]).abs() < 1e-5,
                        "{codec:?} {g:?}: {a:?} vs {b:?}"
                    );
                }
            }
            // At sites: the whole decoded set (every site from the block that owns it),
            // relit uncompressed, equals the lookup relit in the reduced space.
            for s in (0..set.dims.sites()).step_by(7) {
                let (x, y, z) = set.dims.coords(s);
                let g = [x as f32, y as f32, z as f32];
                let (a, b) = (c.sample_grid(g, &pw), full.sample(g, &w));
                for k in 0..3 {
                    assert!(
                        close(a[k], b[k], 1e-4, 1.0),
                        "{codec:?} {g:?}: {a:?} vs {b:?}"
                    );
                }
            }
        }
        // Model space goes through the same placement as the uncompressed set.
        let p = [0.1, -0.3, 0.25];
        let w = BasisWeights::exact([0.1, -1.0, 0.2]).unwrap();
        let g = set.placement().grid_coords(p);
        assert_eq!(
            c.sample(p, &c.project(&w)),
            c.sample_grid(g, &c.project(&w))
        );
    }
}

#[test]
fn error_falls_with_rank_and_rises_with_threshold() {
    let set = solved();
    let region = Region::near_medium(&grid(), 1);
    let w: Vec<BasisWeights> = sky_directions(12)
        .iter()
        .map(|&d| BasisWeights::three_basis(d).unwrap())
        .collect();
    let error = |codec| {
        let c = compress(set, &region, &CompressTarget::new(codec)).unwrap();
        let e = relit_error(set, &c, &region, &w, 4000, 3).unwrap();
        (e.rmse, c.bytes())
    };
    let ranks: Vec<(f64, u64)> = [1, 2, 4, 8, 16]
        .map(|rank| error(Codec::Pca { rank }))
        .to_vec();
    for p in ranks.windows(2) {
        assert!(p[1].0 < p[0].0, "PCA rank: {ranks:?}");
        assert!(p[1].1 > p[0].1, "PCA bytes: {ranks:?}");
    }
    let haar: Vec<(f64, u64)> = [0.0, 1e-3, 4e-3, 1.6e-2]
        .map(|threshold| error(Codec::Haar { threshold }))
        .to_vec();
    for p in haar.windows(2) {
        assert!(p[1].0 > p[0].0, "Haar threshold: {haar:?}");
        assert!(p[1].1 < p[0].1, "Haar bytes: {haar:?}");
    }
    // f16 alone (threshold 0) is far below 1 % of free-space light.
    assert!(haar[0].0 < 1e-3, "{haar:?}");
    // Decorrelating the colours first stores fewer bytes at the same threshold; packing
    // coefficients into 16 bits fewer still, at a small cost in error.
    let packed = |codec| {
        let target = CompressTarget {
            precision: Precision::Packed,
            ..CompressTarget::new(codec)
        };
        let c = compress(set, &region, &target).unwrap();
        (
            relit_error(set, &c, &region, &w, 4000, 3).unwrap().rmse,
            c.bytes(),
        )
    };
    let colour = error(Codec::ColourHaar { threshold: 4e-3 });
    assert!(colour.1 < haar[2].1, "{colour:?} vs {haar:?}");
    let colour_packed = packed(Codec::ColourHaar { threshold: 4e-3 });
    assert!(
        colour_packed.1 < colour.1,
        "{colour_packed:?} vs {colour:?}"
    );
    assert!(
        colour_packed.0 < 2.0 * colour.0,
        "{colour_packed:?} vs {colour:?}"
    );
}

#[test]
fn bad_targets_are_refused() {
    let set = solved();
    let region = Region::all(set.dims);
    for codec in [
        Codec::Pca { rank: 0 },
        Codec::Pca { rank: 58 },
        Codec::Haar {
            threshold: f64::NAN,
        },
        Codec::PcaHaar {
            rank: 3,
            threshold: -1.0,
        },
    ] {
        let e = compress(set, &region, &CompressTarget::new(codec)).unwrap_err();
        assert!(matches!(e, RelightError::Target(_)), "{codec:?}: {e}");
    }
    let packed_pca = CompressTarget {
        precision: Precision::Packed,
        ..CompressTarget::new(Codec::Pca { rank: 4 })
    };
    assert!(matches!(
        compress(set, &region, &packed_pca),
        Err(RelightError::Target(_))
    ));
    let other = Region::all(Dims::cube(5).unwrap());
    assert!(matches!(
        compress(set, &other, &CompressTarget::new(Codec::Pca { rank: 2 })),
        Err(RelightError::Mismatch(_))
    ));
    let empty = Region::near_medium(&DensityGrid::empty(set.dims), 1);
    assert!(compress(set, &empty, &CompressTarget::new(Codec::Pca { rank: 2 })).is_err());
}

#[test]
#[should_panic(expected = "weights projected for a compressed set with another number of fields")]
fn weights_of_another_compressed_set_are_refused() {
    let set = solved();
    let region = Region::near_medium(&grid(), 1);
    let haar = compress(
        set,
        &region,
        &CompressTarget::new(Codec::Haar { threshold: 1e-2 }),
    )
    .unwrap();
    let pca = compress(set, &region, &CompressTarget::new(Codec::Pca { rank: 3 })).unwrap();
    let w = haar.project(&BasisWeights::exact([0.0, -1.0, 0.0]).unwrap());
    pca.sample_grid([3.0, 3.0, 3.0], &w);
}

/// Any parts of three colours compress as a basis set does: here the first three base
/// solutions (9 channels) as parts, each colour weighed on its own.
#[test]
fn compressed_channels_of_any_parts_round_trip() {
    let set = solved();
    let ch = set.channels();
    let dims = set.dims;
    let all = Region::all(dims);
    let scales = [18.0, 18.0, 18.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0];
    let value = |c: usize, s: usize| ch[c][s];
    let terms = [(0usize, [0.02f32, 0.03, 0.01]), (2, [0.7, 0.5, 0.9])];
    // Σ_part w[c] · channel(3 part + c), trilinear at grid point g: the reference.
    let direct = |g: [f32; 3]| {
        let fp = Footprint::at(dims, g);
        let (sites, wt) = (fp.sites(dims), fp.weights());
        let mut out = [0.0f32; 3];
        for k in 0..8 {
            for &(p, w) in &terms {
                for c in 0..3 {
                    out[c] += wt[k] * w[c] * ch[3 * p + c][sites[k]];
                }
            }
        }
        out
    };
    for codec in [
        Codec::Haar { threshold: 0.0 },
        Codec::Pca { rank: 9 },
        Codec::PcaHaar {
            rank: 9,
            threshold: 0.0,
        },
        Codec::ColourHaar { threshold: 0.0 },
    ] {
        let target = CompressTarget {
            codec,
            precision: Precision::F32,
            far_threshold: 0.0,
        };
        let c = compress_channels(dims, 9, &value, &scales, &all, &target).unwrap();
        assert_eq!(c.channels(), 9);
        let back = c.decompress().unwrap();
        for (k, got) in back.iter().enumerate() {
            for (x, y) in got.iter().zip(&ch[k]) {
                assert!((x - y).abs() < 2e-5 * scales[k / 3] as f32, "{codec:?} {k}");
            }
        }
        let pw = c.project(&terms);
        for g in points(&all, 300) {
            let (a, b) = (c.sample_grid(g, &pw), direct(g));
            for k in 0..3 {
                assert!(
                    (a[k] - b[k]).abs() < 1e-4,
                    "{codec:?} {g:?}: {a:?} vs {b:?}"
                );
            }
        }
        let bytes = c.to_bytes();
        assert!(CompressedChannels::from_bytes(&bytes).unwrap() == c);
        for cut in [0, bytes.len() / 3, bytes.len() - 1] {
            let e = CompressedChannels::from_bytes(&bytes[..cut]).unwrap_err();
            assert!(e.to_string().contains("compressed parts"), "{e}");
        }
    }
    // Two sets on one grid looked up together (one footprint, one Haar kernel) give the sum
    // of their lookups.
    let rest = |c: usize, s: usize| ch[9 + c][s];
    let lossy = |codec| CompressTarget::new(codec);
    for (a, b) in [
        (
            Codec::ColourHaar { threshold: 4e-3 },
            Codec::Haar { threshold: 1e-2 },
        ),
        (
            Codec::ColourHaar { threshold: 4e-3 },
            Codec::Pca { rank: 4 },
        ),
    ] {
        let x = compress_channels(dims, 9, &value, &scales, &all, &lossy(a)).unwrap();
        let y = compress_channels(dims, 9, &rest, &[1.0; 9], &all, &lossy(b)).unwrap();
        let (wx, wy) = (x.project(&terms), y.project(&[(1, [0.3, 0.2, 0.1])]));
        for g in points(&all, 300) {
            let both = x.sample_grid_with(&wx, &y, &wy, g);
            let (p, q) = (x.sample_grid(g, &wx), y.sample_grid(g, &wy));
            for k in 0..3 {
                assert!((both[k] - (p[k] + q[k])).abs() < 1e-5, "{a:?} {b:?} {g:?}");
            }
        }
    }
    // A rank above the channels, or channels that are not three colours per part.
    let pca = |rank| CompressTarget::new(Codec::Pca { rank });
    let e = compress_channels(dims, 9, &value, &scales, &all, &pca(10)).unwrap_err();
    assert!(matches!(e, RelightError::Target(_)), "{e}");
    let e = compress_channels(dims, 8, &value, &scales[..8], &all, &pca(2)).unwrap_err();
    assert!(matches!(e, RelightError::Mismatch(_)), "{e}");
    let e = compress_channels(dims, 9, &value, &[0.0; 9], &all, &pca(2)).unwrap_err();
    assert!(e.to_string().contains("scale"), "{e}");
}
