//! The instance generator: scatters plants over a rectangle with a minimum spacing (dart
//! throwing against everything placed so far), random rotation about the vertical and scale
//! jitter, all from one seed.

use std::collections::HashMap;
use sylva_grow::rng::Rng;

/// Most instances one generator may ask for.
pub const MAX_GENERATED: usize = 1_000_000;

/// A rectangle on the ground (x, z).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Area {
    pub min: [f32; 2],
    pub max: [f32; 2],
}

impl Area {
    pub fn square_metres(&self) -> f64 {
        ((self.max[0] - self.min[0]) as f64) * ((self.max[1] - self.min[1]) as f64)
    }

    pub fn contains(&self, x: f32, z: f32) -> bool {
        x >= self.min[0] && x <= self.max[0] && z >= self.min[1] && z <= self.max[1]
    }
}

/// How many instances: an exact count or a density per square metre.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Amount {
    Count(usize),
    PerSquareMetre(f64),
}

/// One generator of a scene file.
#[derive(Debug, Clone, PartialEq)]
pub struct ScatterSpec {
    pub amount: Amount,
    pub area: Area,
    /// No two instance origins closer than this (metres), also against earlier generators'.
    pub min_spacing: f32,
    /// Rotate each instance about +y by a uniform random angle.
    pub random_rotation: bool,
    /// Base scale of every instance.
    pub scale: f32,
    /// Scale is `scale · (1 + u)`, u uniform in [-jitter, jitter].
    pub scale_jitter: f32,
    pub seed: u64,
}

/// One placed instance: ground position, rotation about +y, uniform scale.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    pub x: f32,
    pub z: f32,
    pub rotation_deg: f32,
    pub scale: f32,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LayoutError {
    #[error("area min {min:?} is not below max {max:?}")]
    EmptyArea { min: [f32; 2], max: [f32; 2] },
    #[error("{what} must be a finite number ≥ 0, got {value}")]
    Invalid { what: &'static str, value: f64 },
    /// A generator that would place nothing: an empty scene rendered without a word is a
    /// mistake, not a request.
    #[error("{amount} places no instance: give it at least one, or remove the generator")]
    NoInstance { amount: String },
    #[error("{requested} instances is more than the limit of {limit}")]
    TooMany { requested: f64, limit: usize },
    #[error("could place only {placed} of {requested} instances {spacing} m apart in a {area:.0} m² area; lower the count or the spacing")]
    TooDense {
        placed: usize,
        requested: usize,
        spacing: f32,
        area: f64,
    },
}

/// Everything placed so far, hashed on a grid for spacing checks.
#[derive(Debug, Default)]
pub struct Occupancy {
    cell: f32,
    grid: HashMap<(i32, i32), Vec<[f32; 2]>>,
}

impl Occupancy {
    /// `cell` should be about the largest spacing used; any positive value is correct.
    pub fn new(cell: f32) -> Occupancy {
        Occupancy {
            cell: if cell.is_finite() && cell > 0.0 {
                cell
            } else {
                1.0
            },
            grid: HashMap::new(),
        }
    }

    fn key(&self, x: f32, z: f32) -> (i32, i32) {
        (
            (x / self.cell).floor() as i32,
            (z / self.cell).floor() as i32,
        )
    }

    pub fn insert(&mut self, x: f32, z: f32) {
        let k = self.key(x, z);
        self.grid.entry(k).or_default().push([x, z]);
    }

    /// Whether (x, z) is at least `spacing` from every point.
    pub fn is_free(&self, x: f32, z: f32, spacing: f32) -> bool {
        if spacing <= 0.0 {
            return true;
        }
        let reach = (spacing / self.cell).ceil() as i32;
        let (kx, kz) = self.key(x, z);
        let s2 = spacing * spacing;
        for i in kx - reach..=kx + reach {
            for j in kz - reach..=kz + reach {
                if let Some(pts) = self.grid.get(&(i, j)) {
                    if pts
                        .iter()
                        .any(|p| (p[0] - x).powi(2) + (p[1] - z).powi(2) < s2)
                    {
                        return false;
                    }
                }
            }
        }
        true
    }
}

fn finite_nonneg(what: &'static str, v: f64) -> Result<(), LayoutError> {
    if v.is_finite() && v >= 0.0 {
        Ok(())
    } else {
        Err(LayoutError::Invalid { what, value: v })
    }
}

/// Places the instances of `spec`, respecting spacing against `occupied` (and adding them).
pub fn scatter(
    spec: &ScatterSpec,
    occupied: &mut Occupancy,
) -> Result<Vec<Placement>, LayoutError> {
    let a = spec.area;
    if !(a.min[0] < a.max[0] && a.min[1] < a.max[1])
        || a.min.iter().chain(&a.max).any(|v| !v.is_finite())
    {
        return Err(LayoutError::EmptyArea {
            min: a.min,
            max: a.max,
        });
    }
    finite_nonneg("min_spacing", spec.min_spacing as f64)?;
    finite_nonneg("scale_jitter", spec.scale_jitter as f64)?;
    if !(spec.scale.is_finite() && spec.scale > 0.0) {
        return Err(LayoutError::Invalid {
            what: "scale",
            value: spec.scale as f64,
        });
    }
    if spec.scale_jitter >= 1.0 {
        return Err(LayoutError::Invalid {
            what: "scale_jitter (must be below 1)",
            value: spec.scale_jitter as f64,
        });
    }
    let requested = match spec.amount {
        Amount::Count(n) => n as f64,
        Amount::PerSquareMetre(d) => {
            finite_nonneg("density", d)?;
            (d * a.square_metres()).round()
        }
    };
    if requested < 1.0 {
        return Err(LayoutError::NoInstance {
            amount: match spec.amount {
                Amount::Count(n) => format!("count = {n}"),
                Amount::PerSquareMetre(d) => format!(
                    "density = {d} over {:.0} m² ({:.2} instances, rounded to 0)",
                    a.square_metres(),
                    d * a.square_metres()
                ),
            },
        });
    }
    if requested > MAX_GENERATED as f64 {
        return Err(LayoutError::TooMany {
            requested,
            limit: MAX_GENERATED,
        });
    }
    let n = requested as usize;
    let mut rng = Rng::new(spec.seed);
    let mut out = Vec::with_capacity(n);
    let max_attempts = 200 * n + 1000;
    let mut attempts = 0;
    while out.len() < n && attempts < max_attempts {
        attempts += 1;
        let x = rng.range(a.min[0] as f64, a.max[0] as f64) as f32;
        let z = rng.range(a.min[1] as f64, a.max[1] as f64) as f32;
        if !occupied.is_free(x, z, spec.min_spacing) {
            continue;
        }
        let rotation_deg = if spec.random_rotation {
            rng.range(0.0, 360.0) as f32
        } else {
            0.0
        };
        let scale = spec.scale * (1.0 + rng.var(spec.scale_jitter as f64) as f32);
        occupied.insert(x, z);
        out.push(Placement {
            x,
            z,
            rotation_deg,
            scale,
        });
    }
    if out.len() < n {
        return Err(LayoutError::TooDense {
            placed: out.len(),
            requested: n,
            spacing: spec.min_spacing,
            area: a.square_metres(),
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn spec(n: usize, spacing: f32, seed: u64) -> ScatterSpec {
        ScatterSpec {
            amount: Amount::Count(n),
            area: Area {
                min: [-20.0, 5.0],
                max: [30.0, 25.0],
            },
            min_spacing: spacing,
            random_rotation: true,
            scale: 1.0,
            scale_jitter: 0.2,
            seed,
        }
    }

    fn check_spacing(pts: &[Placement], spacing: f32) {
        for (i, a) in pts.iter().enumerate() {
            for b in &pts[i + 1..] {
                let d = ((a.x - b.x).powi(2) + (a.z - b.z).powi(2)).sqrt();
                assert!(d >= spacing, "{a:?} and {b:?} are {d} apart");
            }
        }
    }

    proptest! {
        #[test]
        fn respects_spacing_area_and_jitter(n in 1usize..120, spacing in 0.0f32..2.0, seed in 0u64..1000) {
            let s = spec(n, spacing, seed);
            let pts = scatter(&s, &mut Occupancy::new(3.0)).unwrap();
            prop_assert_eq!(pts.len(), n);
            check_spacing(&pts, spacing);
            for p in &pts {
                prop_assert!(s.area.contains(p.x, p.z));
                prop_assert!((0.8..=1.2).contains(&p.scale));
                prop_assert!((0.0..360.0).contains(&p.rotation_deg));
            }
        }
    }

    #[test]
    fn spacing_holds_across_generators_and_seed_repeats() {
        let mut occ = Occupancy::new(2.0);
        let mut all = scatter(&spec(60, 2.0, 1), &mut occ).unwrap();
        all.extend(scatter(&spec(60, 2.0, 2), &mut occ).unwrap());
        check_spacing(&all, 2.0);
        let again = scatter(&spec(60, 2.0, 1), &mut Occupancy::new(2.0)).unwrap();
        assert_eq!(again, all[..60]);
        let other = scatter(&spec(60, 2.0, 3), &mut Occupancy::new(2.0)).unwrap();
        assert_ne!(other, again);
    }

    #[test]
    fn density_sets_the_count() {
        let mut s = spec(0, 1.0, 4);
        s.amount = Amount::PerSquareMetre(0.05); // 50 × 20 m² → 50
        assert_eq!(scatter(&s, &mut Occupancy::new(1.0)).unwrap().len(), 50);
    }

    #[test]
    fn a_generator_that_places_nothing_is_an_error() {
        let e = scatter(&spec(0, 1.0, 4), &mut Occupancy::new(1.0)).unwrap_err();
        assert!(matches!(e, LayoutError::NoInstance { .. }), "{e}");
        assert!(
            e.to_string().contains("count = 0 places no instance"),
            "{e}"
        );
        let mut s = spec(0, 1.0, 4);
        s.amount = Amount::PerSquareMetre(0.0001); // 1000 m² → 0.1, rounded to 0
        let e = scatter(&s, &mut Occupancy::new(1.0)).unwrap_err();
        assert!(e.to_string().contains("places no instance"), "{e}");
    }

    #[test]
    fn impossible_requests_are_errors() {
        // 1000 m² cannot hold 500 points 5 m apart (at most about 1000/(5²·0.87) ≈ 46).
        let e = scatter(&spec(500, 5.0, 1), &mut Occupancy::new(5.0)).unwrap_err();
        assert!(
            matches!(e, LayoutError::TooDense { requested: 500, .. }),
            "{e}"
        );
        let mut s = spec(10, 1.0, 1);
        s.area.max[0] = -30.0;
        assert!(matches!(
            scatter(&s, &mut Occupancy::new(1.0)),
            Err(LayoutError::EmptyArea { .. })
        ));
        let mut s = spec(10, 1.0, 1);
        s.amount = Amount::Count(MAX_GENERATED + 1);
        assert!(matches!(
            scatter(&s, &mut Occupancy::new(1.0)),
            Err(LayoutError::TooMany { .. })
        ));
        let mut s = spec(10, f32::NAN, 1);
        assert!(scatter(&s, &mut Occupancy::new(1.0)).is_err());
        s.min_spacing = 1.0;
        s.scale_jitter = 1.5;
        assert!(scatter(&s, &mut Occupancy::new(1.0)).is_err());
    }
}
