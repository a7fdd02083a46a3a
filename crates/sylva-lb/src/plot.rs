//! The LB over a cyclic plot on a reflecting soil: the lattice side of the canopy radiation
//! budget (issue 29). A plot stands for an infinite stand, so light leaving a side re-enters
//! on the opposite one; the soil reflects what arrives on it, Lambertian, back into the
//! lattice; and the budget needs what crosses the top and the floor and what the medium
//! absorbs, per step, in steady state.
//!
//! All three are done between steps on the current state, so the vector kernel runs
//! unchanged (one step per sweep: [`Lattice::step`], no temporal blocking):
//!
//! * **Cyclic sides** ([`Lattice::wrap_sides`]): a site of the x or z shell holds, for the next
//!   step, the post-collision values of the interior site one period over, which is what that
//!   site's periodic image would stream into the interior. Shell sites never collide, so they
//!   stream exactly those values.
//! * **Soil** ([`Lattice::emit_floor`]): the floor row's upward directions carry the soil's
//!   radiance (as [`crate::Floor`]), set from what arrived in the step before.
//! * **Tallies** ([`Lattice::plot_flows`], [`Lattice::absorbed_per_step`]): the post-collision
//!   values that stream out through the top and onto the floor, and the `f_0` the medium
//!   zeroes.

use crate::lattice::{C, Q};
use crate::solver::{Boundary, ColourSource, Floor, Lattice, SolveError};
use crate::{DensityGrid, MediumParams};
use rayon::prelude::*;

/// The interior coordinate a shell coordinate stands for in a cyclic lattice of `n` sites
/// (`n - 2` interior ones): 0 is the last interior site, `n - 1` the first.
#[inline]
fn wrap(v: usize, n: usize) -> usize {
    if v == 0 {
        n - 2
    } else if v == n - 1 {
        1
    } else {
        v
    }
}

/// Directions that stream upwards (`c_y = 1`) and downwards (`c_y = -1`).
fn vertical(sign: i32) -> impl Iterator<Item = usize> {
    (1..Q).filter(move |&m| C[m][1] == sign)
}

/// What one step moves across the faces of a cyclic plot.
#[derive(Debug, Clone, PartialEq)]
pub struct PlotFlows {
    /// Out through the top, into the sky.
    pub top: f64,
    /// Onto the floor, per interior column (`(x - 1) · (nz - 2) + z - 1`), the columns of the
    /// shell wrapped.
    pub floor: Vec<f64>,
}

impl PlotFlows {
    pub fn floor_total(&self) -> f64 {
        self.floor.iter().sum()
    }

    /// Adds `top` and, per column, `floor` (which may be empty: nothing).
    fn add(&mut self, top: f64, floor: &[f64]) {
        self.top += top;
        for (a, f) in self.floor.iter_mut().zip(floor) {
            *a += f;
        }
    }
}

impl Lattice {
    /// Interior columns of the floor, `(nx - 2) · (nz - 2)`.
    pub fn floor_columns(&self) -> usize {
        (self.dims.nx - 2) * (self.dims.nz - 2)
    }

    /// `f` after collision (and the volume source) at interior site (x, y, z) of `state`,
    /// without the dense product where the site is empty and sources nothing.
    fn post_values(&self, state: &[f32], x: usize, y: usize, z: usize) -> [f64; Q] {
        let i = self.dims.index(x, y, z);
        let sourced = self.source.as_ref().is_some_and(|s| s.strength[i] != 0.0);
        if self.codes[i] == 0.0 && !sourced {
            let at = self.state_index(x, y, z, 0);
            let stride = self.state_index(x, y, z, 1) - at;
            return std::array::from_fn(|m| state[at + m * stride] as f64);
        }
        self.post_collision(state, x, y, z).0
    }

    /// Makes the x and z sides cyclic for the next step: every shell site of those sides
    /// (rows 1 to `ny - 2`) takes the post-collision values of the interior site one period
    /// over. Call after every step (and once before the first, where the state is not zero).
    pub fn wrap_sides(&mut self) {
        let (nx, ny, nz) = (self.dims.nx, self.dims.ny, self.dims.nz);
        let state = &self.states[self.current];
        // Each plane's side sites: the whole plane on the x sides, the two z ends elsewhere.
        let values: Vec<Vec<(usize, [f32; Q])>> = (0..nx)
            .into_par_iter()
            .map(|x| {
                let ghost = |y: usize, z: usize| {
                    let post = self.post_values(state, wrap(x, nx), y, wrap(z, nz));
                    (self.state_index(x, y, z, 0), post.map(|v| v as f32))
                };
                let side = x == 0 || x == nx - 1;
                let mut out = Vec::with_capacity((ny - 2) * if side { nz } else { 2 });
                for y in 1..ny - 1 {
                    if side {
                        out.extend((0..nz).map(|z| ghost(y, z)));
                    } else {
                        out.extend([ghost(y, 0), ghost(y, nz - 1)]);
                    }
                }
                out
            })
            .collect();
        let stride = self.state_index(0, 0, 0, 1) - self.state_index(0, 0, 0, 0);
        let state = &mut self.states[self.current];
        for (at, post) in values.iter().flatten() {
            for (m, v) in post.iter().enumerate() {
                state[at + m * stride] = *v;
            }
        }
    }

    /// Sets the floor's radiance for the next step in the current state: per interior column
    /// (as [`PlotFlows::floor`]) the radiance `L` of the soil there, so that the floor site
    /// sends `4 L w_m` (in all, `L`) along each upward direction ([`Floor::value`]); the
    /// shell's columns take the column one period over.
    pub fn emit_floor(&mut self, radiance: &[f64]) {
        let (nx, nz) = (self.dims.nx, self.dims.nz);
        assert_eq!(
            radiance.len(),
            self.floor_columns(),
            "one radiance per column"
        );
        let boundary = self.boundary;
        let up: Vec<usize> = vertical(1).collect();
        let values: Vec<[f32; 5]> = radiance
            .iter()
            .map(|&l| std::array::from_fn(|k| Floor::value(l as f32, up[k], &boundary)))
            .collect();
        let stride = self.state_index(0, 0, 0, 1) - self.state_index(0, 0, 0, 0);
        let starts: Vec<usize> = (0..nx).map(|x| self.state_index(x, 0, 0, 0)).collect();
        let state = &mut self.states[self.current];
        for (x, &start) in starts.iter().enumerate() {
            let row = (wrap(x, nx) - 1) * (nz - 2);
            for z in 0..nz {
                let v = &values[row + wrap(z, nz) - 1];
                for (k, &m) in up.iter().enumerate() {
                    state[start + m * stride + z] = v[k];
                }
            }
        }
    }

    /// What the next step moves out through the top and onto the floor (the columns where
    /// it lands, wrapped): the post-collision values of the top and bottom interior rows
    /// along the directions that leave them.
    pub fn plot_flows(&self) -> PlotFlows {
        let (nx, ny, nz) = (self.dims.nx, self.dims.ny, self.dims.nz);
        let state = &self.states[self.current];
        // Per plane: the top's outflow and the bottom row's downward values with the column
        // each lands on, summed afterwards in plane order (the same for any thread count).
        let planes: Vec<(f64, Vec<(usize, f64)>)> = (1..nx - 1)
            .into_par_iter()
            .map(|x| {
                let mut top = 0.0;
                let mut down = Vec::with_capacity((nz - 2) * 5);
                for z in 1..nz - 1 {
                    let post = self.post_values(state, x, ny - 2, z);
                    top += vertical(1).map(|m| post[m]).sum::<f64>();
                    let post = self.post_values(state, x, 1, z);
                    for m in vertical(-1) {
                        let tx = wrap((x as i32 + C[m][0]) as usize, nx);
                        let tz = wrap((z as i32 + C[m][2]) as usize, nz);
                        down.push(((tx - 1) * (nz - 2) + tz - 1, post[m]));
                    }
                }
                (top, down)
            })
            .collect();
        let mut floor = vec![0.0; self.floor_columns()];
        let mut top = 0.0;
        for (t, down) in planes {
            top += t;
            for (column, v) in down {
                floor[column] += v;
            }
        }
        PlotFlows { top, floor }
    }

    /// Streams `light` (per interior site index, the values it sends along each direction,
    /// as a volume source's post-collision values) to the neighbours for the next step:
    /// into the current state where they land inside (the sides wrapped), and returned as
    /// flows where they leave through the top or land on the floor.
    pub fn inject(&mut self, light: &[(usize, [f32; Q])]) -> PlotFlows {
        let (nx, ny, nz) = (self.dims.nx, self.dims.ny, self.dims.nz);
        let mut flows = PlotFlows {
            top: 0.0,
            floor: vec![0.0; self.floor_columns()],
        };
        for &(site, values) in light {
            let (x, y, z) = self.dims.coords(site);
            debug_assert!(!self.dims.on_shell(x, y, z), "light starts inside");
            for (m, &v) in values.iter().enumerate().skip(1) {
                if v == 0.0 {
                    continue;
                }
                let c = C[m];
                let tx = wrap((x as i32 + c[0]) as usize, nx);
                let ty = (y as i32 + c[1]) as usize;
                let tz = wrap((z as i32 + c[2]) as usize, nz);
                if ty == ny - 1 {
                    flows.top += v as f64;
                } else if ty == 0 {
                    flows.floor[(tx - 1) * (nz - 2) + tz - 1] += v as f64;
                } else {
                    let i = self.state_index(tx, ty, tz, m);
                    self.states[self.current][i] += v;
                }
            }
        }
        flows
    }

    /// What the next step's collisions absorb over the interior (the `f_0` zeroed).
    pub fn absorbed_per_step(&self) -> f64 {
        let (nx, ny, nz) = (self.dims.nx, self.dims.ny, self.dims.nz);
        let state = &self.states[self.current];
        let planes: Vec<f64> = (1..nx - 1)
            .into_par_iter()
            .map(|x| {
                let mut sum = 0.0;
                for y in 1..ny - 1 {
                    for z in 1..nz - 1 {
                        if self.codes[self.dims.index(x, y, z)] != 0.0 {
                            let (post, raw_f0) = self.post_collision(state, x, y, z);
                            sum += raw_f0 - post[0];
                        }
                    }
                }
                sum
            })
            .collect();
        planes.iter().sum()
    }
}

/// Light the caller traces on its first flight through the plant itself, so that the
/// lattice's few directions do not stand in for it (a Lambertian soil's light, the light a
/// leaf scatters once): what the leaves it meets first scatter (per interior site, along
/// each direction, as [`Lattice::inject`] takes it), what they absorb, what escapes through
/// the top and what lands on the floor (per column, as [`PlotFlows::floor`]; empty: none)
/// without meeting a leaf.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FirstFlight {
    pub scattered: Vec<(usize, [f32; Q])>,
    pub absorbed: f64,
    pub escaped: f64,
    pub floor: Vec<f64>,
}

impl FirstFlight {
    /// All the light it accounts for.
    pub fn total(&self) -> f64 {
        let scattered: f64 = self
            .scattered
            .iter()
            .map(|(_, v)| v.iter().map(|&x| x as f64).sum::<f64>())
            .sum();
        scattered + self.absorbed + self.escaped + self.floor.iter().sum::<f64>()
    }
}

/// How light other than the volume source enters the lattice.
pub enum SoilLight<'a> {
    /// The soil's light from the floor's sites, along the upward lattice directions
    /// ([`Lattice::emit_floor`]).
    Floor,
    /// Traced first flights: `soil` maps the soil's radiance per column in a step to its
    /// flight; `steady` is sent unchanged every step (the sun's light once scattered).
    Traced {
        soil: &'a (dyn Fn(&[f64]) -> FirstFlight + Sync),
        steady: &'a FirstFlight,
    },
}

/// The light of a plot solve besides the lattice's own.
pub struct PlotLight<'a> {
    /// A volume source (the sun's first collision), if any.
    pub source: Option<ColourSource>,
    /// The soil's albedo: it reflects, Lambertian, what lands on it.
    pub soil_albedo: f64,
    /// The uncollided sunlight landing on the soil per interior column, traced by the
    /// caller.
    pub ground_direct: &'a [f64],
    /// How the soil's light (and any other traced light) enters the lattice.
    pub soil: SoilLight<'a>,
}

/// When a plot solve stops.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlotOptions {
    /// Stop once what leaves through the top and onto the floor changes by at most this
    /// share of a step's input (the source and the soil's light) from one step to the next,
    /// four steps in a row, ...
    pub tolerance: f64,
    /// ... and the interior's total by at most this share: then what enters and what
    /// leaves a step agree to it. Looser than `tolerance`: light the lattice sends along a
    /// horizontal direction through a sparse layer circles the cyclic plot for thousands
    /// of steps before a leaf stops it, so the total settles long after the faces' flows
    /// do, while the light still gathering there is about this share of a step's input.
    pub balance: f64,
    /// Give up (and say so) after this many steps.
    pub max_steps: usize,
}

impl Default for PlotOptions {
    fn default() -> PlotOptions {
        PlotOptions {
            tolerance: 1e-6,
            balance: 1e-3,
            max_steps: 50_000,
        }
    }
}

/// The steady state of one colour over a cyclic plot, per step (so, for a source that is a
/// share of the sunlight per step, shares of the sunlight).
#[derive(Debug, Clone, PartialEq)]
pub struct PlotSolution {
    /// Put in by the volume source.
    pub sourced: f64,
    /// Sent up by the soil.
    pub emitted: f64,
    /// Light besides the volume source that entered in a step: the soil's from the floor,
    /// or all the traced light ([`SoilLight::Traced`]).
    pub entered: f64,
    /// Absorbed by the medium.
    pub absorbed: f64,
    /// Out through the top.
    pub top: f64,
    /// Onto the floor, per interior column ([`PlotFlows::floor`]).
    pub floor: Vec<f64>,
    pub steps: usize,
    /// Whether the tolerance was met within `max_steps`.
    pub converged: bool,
    /// The last step's change of the interior's total over the step's input.
    pub residual: f64,
    /// The last step's change of the faces' flows over the step's input.
    pub faces_change: f64,
}

impl PlotSolution {
    pub fn floor_total(&self) -> f64 {
        self.floor.iter().sum()
    }

    /// `(in - out) / in` over one step: 0 in an exact steady state.
    pub fn imbalance(&self) -> f64 {
        let input = self.sourced + self.entered;
        let output = self.absorbed + self.top + self.floor_total();
        if input > 0.0 {
            (input - output) / input
        } else {
            0.0
        }
    }
}

/// Solves colour `colour` of `medium` over `grid` as a cyclic plot (x and z) with nothing
/// coming in through the top: light enters through `light`'s source, its traced light and
/// the soil, which reflects (Lambertian) what arrives per column, from the lattice and from
/// the uncollided sun. Calls `progress(step, residual)` after every step.
pub fn solve_cyclic_plot(
    grid: &DensityGrid,
    medium: &MediumParams,
    colour: usize,
    light: PlotLight,
    opts: PlotOptions,
    progress: &mut dyn FnMut(usize, f64),
) -> Result<PlotSolution, SolveError> {
    let PlotLight {
        source,
        soil_albedo,
        ground_direct,
        soil: soil_light,
    } = light;
    let dims = grid.dims;
    if dims.nx < 4 || dims.ny < 3 || dims.nz < 4 {
        return Err(SolveError::Floor(format!(
            "a cyclic plot needs at least 2 interior sites along x and z, not a {dims} grid"
        )));
    }
    if !(soil_albedo.is_finite() && (0.0..=1.0).contains(&soil_albedo)) {
        return Err(SolveError::Floor(format!(
            "soil albedo {soil_albedo} must be in [0, 1]"
        )));
    }
    let columns = (dims.nx - 2) * (dims.nz - 2);
    if ground_direct.len() != columns {
        return Err(SolveError::Floor(format!(
            "{} direct values for {columns} columns",
            ground_direct.len()
        )));
    }
    let mut lattice = Lattice::new(grid, medium, colour, Boundary { values: [0.0; Q] })?;
    let sourced: f64 = source.as_ref().map_or(0.0, |source| {
        let (green, brown) = (
            source.green.iter().map(|&v| v as f64).sum::<f64>(),
            source.brown.iter().map(|&v| v as f64).sum::<f64>(),
        );
        source
            .strength
            .iter()
            .zip(&grid.density)
            .zip(&grid.wood)
            .map(|((&s, &rho), &wood)| {
                let brown_site = rho > 0.0 && wood as f64 > medium.brown_threshold;
                s as f64 * if brown_site { brown } else { green }
            })
            .sum()
    });
    lattice.set_source(source);
    let reflect = |arrived: &[f64]| -> Vec<f64> {
        arrived
            .iter()
            .zip(ground_direct)
            .map(|(a, d)| soil_albedo * (a + d))
            .collect()
    };
    let zero = vec![0.0; columns];
    let none = || PlotFlows {
        top: 0.0,
        floor: zero.clone(),
    };
    let steady_total = match &soil_light {
        SoilLight::Traced { steady, .. } => steady.total(),
        SoilLight::Floor => 0.0,
    };
    // Sends a step's soil light (from the floor's sites, or traced and injected with the
    // steady light); returns what that adds to the step's top and floor flows, what the
    // leaves it meets first absorb, and how much light it brings in all (a soil flight
    // accounts for all the soil's light).
    let send = |lattice: &mut Lattice, radiance: &[f64]| -> (PlotFlows, f64, f64) {
        let emitted: f64 = radiance.iter().sum();
        match &soil_light {
            SoilLight::Floor => {
                lattice.emit_floor(radiance);
                (none(), 0.0, emitted)
            }
            // The floor's sites keep the zero boundary they started with.
            SoilLight::Traced { soil, steady } => {
                let mut all = none();
                let mut absorbed = 0.0;
                for flight in [&soil(radiance), *steady] {
                    let flows = lattice.inject(&flight.scattered);
                    all.add(flows.top + flight.escaped, &flows.floor);
                    all.add(0.0, &flight.floor);
                    absorbed += flight.absorbed;
                }
                (all, absorbed, emitted + steady_total)
            }
        }
    };
    let mut radiance = reflect(&zero);
    let (mut soil_out, mut soil_absorbed, mut sent) = send(&mut lattice, &radiance);
    lattice.wrap_sides();
    let mut previous: Option<(f64, f64)> = None;
    let mut residual = f64::INFINITY;
    let mut faces_change = f64::INFINITY;
    let mut steps = 0;
    let mut converged = false;
    // The change is measured one step late; a few quiet steps in a row guard against a
    // pause while light crosses an empty layer.
    let mut quiet = 0;
    let mut flows = lattice.plot_flows();
    while steps < opts.max_steps {
        // All the light that enters this step, the traced light's whole included (most of it
        // may never reach the lattice).
        let input = sourced + sent;
        let total = lattice.step();
        steps += 1;
        // What the soil sent last step that landed on the floor or left counts with this
        // step's flows.
        flows.add(0.0, &soil_out.floor);
        radiance = reflect(&flows.floor);
        (soil_out, soil_absorbed, sent) = send(&mut lattice, &radiance);
        lattice.wrap_sides();
        flows = lattice.plot_flows();
        let faces = flows.top + flows.floor_total() + soil_out.top + soil_out.floor_total();
        if let Some((p_total, p_faces)) = previous {
            let share = |d: f64| if input > 0.0 { d.abs() / input } else { 0.0 };
            residual = share(total - p_total);
            faces_change = share(faces - p_faces);
            progress(steps, residual);
            if faces_change <= opts.tolerance && residual <= opts.balance {
                quiet += 1;
                if quiet >= 4 {
                    converged = true;
                    break;
                }
            } else {
                quiet = 0;
            }
        }
        previous = Some((total, faces));
    }
    // The steady state's flows of one step: the lattice's from the current state, the soil
    // light's from the send that made it.
    flows.add(soil_out.top, &soil_out.floor);
    Ok(PlotSolution {
        sourced,
        emitted: radiance.iter().sum(),
        entered: sent,
        absorbed: lattice.absorbed_per_step() + soil_absorbed,
        top: flows.top,
        floor: flows.floor,
        steps,
        converged,
        residual,
        faces_change,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::light::{medium_for, PlantOptics};
    use crate::{Bounds, Dims};

    fn medium(albedo: f64) -> MediumParams {
        medium_for(&PlantOptics {
            leaf_reflectance: [0.5 * albedo; 3],
            leaf_transmittance: [0.5 * albedo; 3],
            bark_reflectance: [0.0; 3],
        })
        .unwrap()
    }

    /// A medium of `rho` at the sites `dense` picks, and a source of 1 per occupied site
    /// spread evenly over the moving directions.
    fn case(
        dims: Dims,
        dense: impl Fn(usize, usize, usize) -> bool,
    ) -> (DensityGrid, ColourSource) {
        let mut density = vec![0.0f32; dims.sites()];
        for (i, d) in density.iter_mut().enumerate() {
            let (x, y, z) = dims.coords(i);
            if !dims.on_shell(x, y, z) && dense(x, y, z) {
                *d = 0.3;
            }
        }
        let strength: Vec<f32> = density
            .iter()
            .map(|&d| if d > 0.0 { 1.0 } else { 0.0 })
            .collect();
        let even = std::array::from_fn(|m| if m == 0 { 0.0 } else { 1.0 / 18.0 });
        let grid = DensityGrid::new(dims, Bounds::UNIT, density, vec![0.0; dims.sites()]).unwrap();
        (
            grid,
            ColourSource {
                strength,
                green: even,
                brown: even,
            },
        )
    }

    fn solve(grid: &DensityGrid, source: ColourSource, albedo: f64, soil: f64) -> PlotSolution {
        let columns = (grid.dims.nx - 2) * (grid.dims.nz - 2);
        solve_cyclic_plot(
            grid,
            &medium(albedo),
            0,
            PlotLight {
                source: Some(source),
                soil_albedo: soil,
                ground_direct: &vec![0.0; columns],
                soil: SoilLight::Floor,
            },
            PlotOptions {
                tolerance: 1e-8,
                balance: 1e-7,
                max_steps: 20_000,
            },
            &mut |_, _| {},
        )
        .unwrap()
    }

    #[test]
    fn injected_light_lands_where_it_streams_around_the_plot() {
        // Light sent from a site in the plot's corner next to the floor: what goes down lands
        // on the floor's wrapped columns, what crosses a side comes in on the opposite one,
        // and nothing is lost or made.
        let dims = Dims::new(6, 5, 7).unwrap();
        let (grid, _) = case(dims, |_, _, _| false);
        let mut lattice =
            Lattice::new(&grid, &medium(0.5), 0, Boundary { values: [0.0; Q] }).unwrap();
        let values: [f32; Q] = std::array::from_fn(|m| m as f32);
        let site = dims.index(1, 1, 1);
        let flows = lattice.inject(&[(site, values)]);
        let (nx, nz) = (dims.nx, dims.nz);
        let mut landed = flows.top + flows.floor_total();
        for m in 1..Q {
            let c = C[m];
            if c[1] != 0 {
                continue;
            }
            let tx = wrap((1 + c[0]) as usize, nx);
            let tz = wrap((1 + c[2]) as usize, nz);
            assert_eq!(lattice.f(tx, 1, tz, m), values[m], "direction {m}");
            landed += values[m] as f64;
        }
        for m in 1..Q {
            if C[m][1] == 1 {
                let (tx, tz) = (
                    wrap((1 + C[m][0]) as usize, nx),
                    wrap((1 + C[m][2]) as usize, nz),
                );
                assert_eq!(lattice.f(tx, 2, tz, m), values[m], "direction {m}");
                landed += values[m] as f64;
            }
        }
        // (0, -1, 0) lands on column (1, 1), (-1, -1, 0) on the last column of x.
        let column = |x: usize, z: usize| (x - 1) * (nz - 2) + z - 1;
        assert_eq!(flows.floor[column(1, 1)], values[4] as f64);
        assert_eq!(flows.floor[column(nx - 2, 1)], values[8] as f64);
        assert_eq!(flows.top, 0.0);
        let sent: f64 = values.iter().skip(1).map(|&v| v as f64).sum();
        assert_eq!(landed, sent);
    }

    #[test]
    fn steady_state_balances_what_enters_and_leaves() {
        // A blob of scattering medium over a grey soil: per step the source and the soil's
        // light equal what the medium absorbs and what leaves through the top and onto the
        // floor, each tallied on its own.
        let dims = Dims::new(12, 10, 9).unwrap();
        let (grid, source) = case(dims, |x, y, z| {
            (3..8).contains(&x) && (4..7).contains(&y) && z < 5
        });
        let s = solve(&grid, source, 0.8, 0.5);
        assert!(s.converged, "{} steps, residual {}", s.steps, s.residual);
        assert!(s.imbalance().abs() < 1e-4, "imbalance {}", s.imbalance());
        // The soil sends back half of what lands on it.
        assert!((s.emitted - 0.5 * s.floor_total()).abs() < 1e-5 * s.emitted);
        assert!(s.absorbed > 0.0 && s.top > 0.0 && s.floor_total() > 0.0);
    }

    #[test]
    fn a_homogeneous_layer_gives_every_column_the_same_light() {
        // Medium that fills whole rows of a cyclic plot: nothing varies along x or z, so every
        // column receives the same light, to rounding. Open sides would darken the edges.
        let dims = Dims::new(9, 8, 11).unwrap();
        let (grid, source) = case(dims, |_, y, _| (3..6).contains(&y));
        let s = solve(&grid, source, 0.9, 0.3);
        let mean = s.floor_total() / s.floor.len() as f64;
        for (c, v) in s.floor.iter().enumerate() {
            assert!(
                (v - mean).abs() < 1e-5 * mean,
                "column {c}: {v} against {mean}"
            );
        }
    }

    #[test]
    fn shifting_the_medium_around_the_plot_shifts_the_light() {
        // Cyclic sides make the plot a torus: moving the medium by (3, 2) columns moves the
        // floor's light by the same, and changes no total.
        let dims = Dims::new(10, 8, 9).unwrap();
        let (nx, nz) = (dims.nx - 2, dims.nz - 2);
        let blob =
            |x: usize, y: usize, z: usize| x <= 3 && (2..5).contains(&y) && (2..=4).contains(&z);
        let (a_grid, a_src) = case(dims, blob);
        let (b_grid, b_src) = case(dims, |x, y, z| {
            // Site x of the shifted medium is site x - 3 (cyclically) of the first.
            let back = |v: usize, n: usize, by: usize| (v - 1 + n - by) % n + 1;
            blob(back(x, nx, 3), y, back(z, nz, 2))
        });
        let a = solve(&a_grid, a_src, 0.7, 0.4);
        let b = solve(&b_grid, b_src, 0.7, 0.4);
        assert!((a.absorbed - b.absorbed).abs() < 1e-5 * a.absorbed);
        assert!((a.top - b.top).abs() < 1e-5 * a.top);
        for x in 0..nx {
            for z in 0..nz {
                let (va, vb) = (
                    a.floor[x * nz + z],
                    b.floor[((x + 3) % nx) * nz + (z + 2) % nz],
                );
                assert!(
                    (va - vb).abs() < 1e-5 * a.floor_total() / (nx * nz) as f64,
                    "({x}, {z}): {va} {vb}"
                );
            }
        }
    }

    #[test]
    fn a_white_soil_under_a_lossless_medium_sends_everything_to_the_sky() {
        // Nothing absorbs: in steady state all the source's light leaves through the top.
        let dims = Dims::new(8, 9, 8).unwrap();
        let (grid, source) = case(dims, |x, y, _| (3..6).contains(&y) && x < 5);
        let s = solve(&grid, source, 1.0, 1.0);
        assert!(s.converged);
        assert!(
            s.absorbed.abs() < 1e-6 * s.sourced,
            "absorbed {}",
            s.absorbed
        );
        assert!(
            (s.top - s.sourced).abs() < 1e-3 * s.sourced,
            "top {} of {}",
            s.top,
            s.sourced
        );
    }
}
