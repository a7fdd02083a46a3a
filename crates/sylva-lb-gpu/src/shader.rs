//! WGSL generation for the LB kernels.
//!
//! The shaders are generated for one state layout (how the 19 directions are split over
//! storage bindings) and one storage precision, so every load and store names its binding
//! and direction offset as constants: neighbour indices are computed on the fly from the
//! site's coordinates, nothing is looked up. The collision applies sylva-lb's cubic
//! factorisation of Ω ([`sylva_lb::kernel::CubicOmega`]) with coefficients the host
//! uploads; the WGSL holds no physics of its own.
//!
//! Scheme ("pull"): the state buffer holds post-collision values `P`. A thread owns one
//! interior site s, gathers `f_m(s) = P_m(s - c_m)` (the CPU solver's state at s, in
//! registers), adds them up for the convergence monitor, collides and writes the 19
//! results to its own site of the other buffer. Reads are shifted by at most one site,
//! writes are aligned, and consecutive threads own consecutive z, so both coalesce. Shell
//! sites are never written: they keep the boundary, and flows into them are dropped.

use std::fmt::Write as _;

use sylva_lb::lattice::{C, Q};

/// Threads per workgroup (a power of two: the monitor reduces it as a tree).
pub const WORKGROUP_THREADS: u32 = 128;

/// Threads per reduction workgroup; the host sums its outputs in f64.
pub const REDUCE_THREADS: u32 = 256;

/// How the state is laid out: direction m lives in binding `m / per_part` at element offset
/// `(m % per_part) · n`, site index `(x · ny + y) · nz + z`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layout {
    /// Directions per storage binding (1..=19).
    pub per_part: usize,
    /// Store the state as f16 (needs `SHADER_F16`); arithmetic stays f32.
    pub f16: bool,
    /// Workgroup shape along z and y.
    pub wg_z: u32,
    pub wg_y: u32,
    /// The step adds a volume source (`sylva_lb::VolumeSource`): a strength per site and a
    /// profile per direction for green and brown sites.
    pub source: bool,
}

impl Layout {
    pub fn parts(&self) -> usize {
        Q.div_ceil(self.per_part)
    }

    /// The binding and element-offset multiplier (of `n`) of direction m.
    pub fn place(&self, m: usize) -> (usize, usize) {
        (m / self.per_part, m % self.per_part)
    }

    /// Directions held by part p.
    pub fn directions_in(&self, p: usize) -> usize {
        (Q - p * self.per_part).min(self.per_part)
    }

    fn elem(&self) -> &'static str {
        if self.f16 {
            "f16"
        } else {
            "f32"
        }
    }
}

/// Workgroup shape for rows of `nz` sites: a warp-wide run along z where the row allows
/// (coalesced 128-byte segments), the rest of the group along y.
pub fn workgroup_shape(nz: usize) -> (u32, u32) {
    let z = (nz.next_power_of_two() as u32).clamp(4, 32);
    (z, WORKGROUP_THREADS / z)
}

const PARAMS: &str = "
struct Params {
    nx: u32,
    ny: u32,
    nz: u32,
    n: u32,
    keep_green: f32,
    keep_brown: f32,
    pad0: f32,
    pad1: f32,
    green: array<vec4<f32>, 5>,
    brown: array<vec4<f32>, 5>,
    // The volume source's share per direction on green and brown sites.
    source_green: array<vec4<f32>, 5>,
    source_brown: array<vec4<f32>, 5>,
}
@group(0) @binding(0) var<uniform> P: Params;
";

/// Source index of direction m for the thread at site `s` (coordinates x, y, z), in terms
/// of the strides `sx = ny · nz` and `sy = nz`: `s - c_m`.
fn source_expr(m: usize) -> String {
    let mut e = String::from("s");
    for (axis, stride) in ["sx", "sy", "1u"].iter().enumerate() {
        match C[m][axis] {
            1 => write!(e, " - {stride}").unwrap(),
            -1 => write!(e, " + {stride}").unwrap(),
            _ => {}
        }
    }
    e
}

fn element_expr(layout: &Layout, m: usize, buf: &str, site: &str) -> String {
    let (part, k) = layout.place(m);
    if k == 0 {
        format!("{buf}{part}[{site}]")
    } else {
        format!("{buf}{part}[{k}u * P.n + {site}]")
    }
}

fn header(layout: &Layout) -> String {
    let mut s = String::new();
    if layout.f16 {
        s.push_str("enable f16;\n");
    }
    s.push_str(PARAMS);
    s
}

/// The step kernel: gather, monitor, collide, store; one partial sum per workgroup.
pub fn step_shader(layout: &Layout) -> String {
    step_shader_with(layout, true)
}

/// The step kernel, with the monitor's per-workgroup sum (`monitor`) or without it (no
/// shared memory, no barriers: for steps whose total nobody reads).
pub fn step_shader_with(layout: &Layout, monitor: bool) -> String {
    let parts = layout.parts();
    let t = layout.elem();
    let mut s = header(layout);
    s.push_str("@group(0) @binding(1) var<storage, read> codes: array<f32>;\n");
    s.push_str("@group(0) @binding(2) var<storage, read_write> partials: array<f32>;\n");
    for p in 0..parts {
        writeln!(
            s,
            "@group(0) @binding({}) var<storage, read> src{p}: array<{t}>;",
            3 + p
        )
        .unwrap();
    }
    for p in 0..parts {
        writeln!(
            s,
            "@group(0) @binding({}) var<storage, read_write> dst{p}: array<{t}>;",
            3 + parts + p
        )
        .unwrap();
    }
    if layout.source {
        writeln!(
            s,
            "@group(0) @binding({}) var<storage, read> source_strength: array<f32>;",
            3 + 2 * parts
        )
        .unwrap();
    }
    let (wz, wy) = (layout.wg_z, layout.wg_y);
    if monitor {
        writeln!(
            s,
            "var<workgroup> scratch: array<f32, {WORKGROUP_THREADS}>;"
        )
        .unwrap();
    }
    writeln!(
        s,
        "@compute @workgroup_size({wz}, {wy}, 1)\n\
         fn step(@builtin(global_invocation_id) gid: vec3<u32>,\n\
                 @builtin(local_invocation_index) li: u32,\n\
                 @builtin(workgroup_id) wid: vec3<u32>,\n\
                 @builtin(num_workgroups) nwg: vec3<u32>) {{\n\
         let z = gid.x;\n\
         let y = gid.y;\n\
         let x = gid.z;\n\
         var total = 0.0;\n\
         if (x >= 1u && x + 1u < P.nx && y >= 1u && y + 1u < P.ny && z >= 1u && z + 1u < P.nz) {{\n\
         let sy = P.nz;\n\
         let sx = P.ny * P.nz;\n\
         let s = (x * P.ny + y) * P.nz + z;"
    )
    .unwrap();
    for m in 0..Q {
        writeln!(
            s,
            "let fi{m} = f32({});",
            element_expr(layout, m, "src", &source_expr(m))
        )
        .unwrap();
    }
    let sum: Vec<String> = (0..Q).map(|m| format!("fi{m}")).collect();
    writeln!(s, "total = {};", sum.join(" + ")).unwrap();
    for m in 0..Q {
        writeln!(s, "var r{m} = fi{m};").unwrap();
    }
    s.push_str("let code = codes[s];\nif (code != 0.0) {\n");
    s.push_str(COLLIDE);
    s.push_str("}\n");
    if layout.source {
        // Added to every post-collision value, after f_0's scaling, as the CPU kernel does
        // (empty sites hold no strength).
        s.push_str("let strength = source_strength[s];\nlet source_brown = code < 0.0;\n");
        for m in 0..Q {
            writeln!(
                s,
                "r{m} = r{m} + strength * select(P.source_green[{}][{}], P.source_brown[{}][{}], source_brown);",
                m / 4,
                m % 4,
                m / 4,
                m % 4
            )
            .unwrap();
        }
    }
    for m in 0..Q {
        writeln!(s, "{} = {t}(r{m});", element_expr(layout, m, "dst", "s")).unwrap();
    }
    if !monitor {
        // `total` stays unread; the partial of this workgroup is not written.
        s.push_str(
            "}
_ = total;
_ = li;
_ = wid;
_ = nwg;
}
",
        );
        return s;
    }
    s.push_str(
        "}
    // The monitor: this workgroup's interior total, reduced as a tree in a fixed order.
    scratch[li] = total;
    workgroupBarrier();
",
    );
    writeln!(
        s,
        "    for (var w = {}u; w > 0u; w = w >> 1u) {{
        if (li < w) {{
            scratch[li] = scratch[li] + scratch[li + w];
        }}
        workgroupBarrier();
    }}
    if (li == 0u) {{
        partials[wid.x + nwg.x * (wid.y + nwg.y * wid.z)] = scratch[0];
    }}
}}",
        WORKGROUP_THREADS / 2
    )
    .unwrap();
    s
}

/// The collision of one site, `r = f + ρ Ω f` with `f_0` scaled by `keep`, through the
/// cubic factorisation (the same sequence of operations as sylva-lb's `collide_lanes`).
const COLLIDE: &str = "
let brown = code < 0.0;
let rho = abs(code);
let keep = select(P.keep_green, P.keep_brown, brown);
let g0 = P.green[0]; let g1 = P.green[1]; let g2 = P.green[2]; let g3 = P.green[3]; let g4 = P.green[4];
let b0 = P.brown[0]; let b1 = P.brown[1]; let b2 = P.brown[2]; let b3 = P.brown[3]; let b4 = P.brown[4];
let k0 = select(g0, b0, brown);
let k1 = select(g1, b1, brown);
let k2 = select(g2, b2, brown);
let k3 = select(g3, b3, brown);
let k4 = select(g4, b4, brown);
let o00 = k0.x; let o0q = k0.y; let op0_axial = k0.z; let op0_diagonal = k0.w;
let a0 = k1.x; let alpha = k1.y; let cb1 = k1.z; let minus_beta = k1.w;
let c0 = k2.x; let gamma = k2.y; let d_half_even = k2.z; let delta = k2.w;
let epsilon = k3.x; let minus_epsilon = k3.y; let odd_axial = k3.z; let odd_b = k3.w;
let odd_c = k4.x; let odd_d_half = k4.y; let kappa = k4.z;

let s0 = fi1 + fi2; let s1 = fi3 + fi4; let s2 = fi5 + fi6;
let s3 = fi7 + fi8; let s4 = fi9 + fi10; let s5 = fi11 + fi12;
let s6 = fi13 + fi14; let s7 = fi15 + fi16; let s8 = fi17 + fi18;
let sum_axial = s0 + s1 + s2;
let u_xy = s3 + s4; let u_xz = s5 + s6; let u_yz = s7 + s8;
let sum_diagonal = u_xy + u_xz + u_yz;
let c_a = fma(cb1, sum_diagonal, fma(a0, sum_axial, op0_axial * fi0));
let c_d = fma(d_half_even, sum_diagonal, fma(c0, sum_axial, op0_diagonal * fi0));
let e0 = fma(minus_beta, u_yz, fma(alpha, s0, c_a));
let e1 = fma(minus_beta, u_xz, fma(alpha, s1, c_a));
let e2 = fma(minus_beta, u_xy, fma(alpha, s2, c_a));
let b_xy = fma(delta, u_xy, fma(gamma, sum_axial - s2, c_d));
let b_xz = fma(delta, u_xz, fma(gamma, sum_axial - s1, c_d));
let b_yz = fma(delta, u_yz, fma(gamma, sum_axial - s0, c_d));
let e3 = fma(epsilon, s3 - s4, b_xy);
let e4 = fma(minus_epsilon, s3 - s4, b_xy);
let e5 = fma(epsilon, s5 - s6, b_xz);
let e6 = fma(minus_epsilon, s5 - s6, b_xz);
let e7 = fma(epsilon, s7 - s8, b_yz);
let e8 = fma(minus_epsilon, s7 - s8, b_yz);
let ssum = sum_axial + sum_diagonal;

let d0 = fi1 - fi2; let d1 = fi3 - fi4; let d2 = fi5 - fi6;
let d3 = fi7 - fi8; let d4 = fi9 - fi10; let d5 = fi11 - fi12;
let d6 = fi13 - fi14; let d7 = fi15 - fi16; let d8 = fi17 - fi18;
let v_x = (d3 + d4) + (d5 + d6);
let v_y = (d3 - d4) + (d7 + d8);
let v_z = (d5 - d6) + (d7 - d8);
let o0 = fma(odd_b, v_x, odd_axial * d0);
let o1 = fma(odd_b, v_y, odd_axial * d1);
let o2 = fma(odd_b, v_z, odd_axial * d2);
let w_x = fma(odd_d_half, v_x, odd_c * d0);
let w_y = fma(odd_d_half, v_y, odd_c * d1);
let w_z = fma(odd_d_half, v_z, odd_c * d2);
let o3 = fma(kappa, d3, w_x + w_y);
let o4 = fma(kappa, d4, w_x - w_y);
let o5 = fma(kappa, d5, w_x + w_z);
let o6 = fma(kappa, d6, w_x - w_z);
let o7 = fma(kappa, d7, w_y + w_z);
let o8 = fma(kappa, d8, w_y - w_z);

r0 = fma(rho, fma(o00, fi0, o0q * ssum), fi0) * keep;
r1 = fma(rho, e0 + o0, fi1); r2 = fma(rho, e0 - o0, fi2);
r3 = fma(rho, e1 + o1, fi3); r4 = fma(rho, e1 - o1, fi4);
r5 = fma(rho, e2 + o2, fi5); r6 = fma(rho, e2 - o2, fi6);
r7 = fma(rho, e3 + o3, fi7); r8 = fma(rho, e3 - o3, fi8);
r9 = fma(rho, e4 + o4, fi9); r10 = fma(rho, e4 - o4, fi10);
r11 = fma(rho, e5 + o5, fi11); r12 = fma(rho, e5 - o5, fi12);
r13 = fma(rho, e6 + o6, fi13); r14 = fma(rho, e6 - o6, fi14);
r15 = fma(rho, e7 + o7, fi15); r16 = fma(rho, e7 - o7, fi16);
r17 = fma(rho, e8 + o8, fi17); r18 = fma(rho, e8 - o8, fi18);
";

/// Per-site totals `Σ_m f_m` of the CPU solver's state: streamed from the post-collision
/// buffer at interior sites, the shell's own (boundary) values on the shell. Summed in
/// direction order, as the CPU's `site_totals`.
pub fn gather_shader(layout: &Layout) -> String {
    let parts = layout.parts();
    let t = layout.elem();
    let mut s = header(layout);
    s.push_str("@group(0) @binding(1) var<storage, read_write> out: array<f32>;\n");
    for p in 0..parts {
        writeln!(
            s,
            "@group(0) @binding({}) var<storage, read> src{p}: array<{t}>;",
            2 + p
        )
        .unwrap();
    }
    let (wz, wy) = (layout.wg_z, layout.wg_y);
    writeln!(
        s,
        "@compute @workgroup_size({wz}, {wy}, 1)\n\
         fn gather(@builtin(global_invocation_id) gid: vec3<u32>) {{\n\
         let z = gid.x;\n\
         let y = gid.y;\n\
         let x = gid.z;\n\
         if (x >= P.nx || y >= P.ny || z >= P.nz) {{\n\
         return;\n\
         }}\n\
         let site = (x * P.ny + y) * P.nz + z;\n\
         let interior = x >= 1u && x + 1u < P.nx && y >= 1u && y + 1u < P.ny && z >= 1u && z + 1u < P.nz;\n\
         // Shell sites read themselves: their stride is zero.\n\
         let sy = select(0u, P.nz, interior);\n\
         let sx = select(0u, P.ny * P.nz, interior);\n\
         let u = select(0u, 1u, interior);\n\
         let s = site;\n\
         var acc = 0.0;"
    )
    .unwrap();
    for m in 0..Q {
        let src = source_expr(m).replace("1u", "u");
        writeln!(
            s,
            "acc = acc + f32({});",
            element_expr(layout, m, "src", &src)
        )
        .unwrap();
    }
    s.push_str("out[site] = acc;\n}\n");
    s
}

/// Sums each step's workgroup partials into [`REDUCE_THREADS`] values (one workgroup per
/// step), compensated so that large grids keep f32 rounding out of the monitor.
pub fn reduce_shader() -> String {
    format!(
        "struct Reduce {{
    count: u32,
    stride: u32,
}}
@group(0) @binding(0) var<uniform> R: Reduce;
@group(0) @binding(1) var<storage, read> partials: array<f32>;
@group(0) @binding(2) var<storage, read_write> sums: array<f32>;
@compute @workgroup_size({REDUCE_THREADS}, 1, 1)
fn reduce(@builtin(local_invocation_index) t: u32, @builtin(workgroup_id) wid: vec3<u32>) {{
    let base = wid.x * R.stride;
    var acc = 0.0;
    var comp = 0.0;
    for (var i = t; i < R.count; i = i + {REDUCE_THREADS}u) {{
        let y = partials[base + i] - comp;
        let next = acc + y;
        comp = (next - acc) - y;
        acc = next;
    }}
    sums[wid.x * {REDUCE_THREADS}u + t] = acc;
}}
"
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn source_index_undoes_the_velocity() {
        // s - c_m for c = (1, -1, 0): one plane back in x, one row forward in y.
        assert_eq!(source_expr(9), "s - sx + sy");
        assert_eq!(source_expr(0), "s");
        assert_eq!(source_expr(6), "s + 1u");
    }

    #[test]
    fn generated_shaders_parse_and_validate() {
        for layout in [
            Layout {
                per_part: 19,
                f16: false,
                wg_z: 32,
                wg_y: 4,
                source: false,
            },
            Layout {
                per_part: 1,
                f16: true,
                wg_z: 4,
                wg_y: 32,
                source: true,
            },
            Layout {
                per_part: 7,
                f16: false,
                wg_z: 16,
                wg_y: 8,
                source: true,
            },
        ] {
            for (name, src) in [
                ("step", step_shader(&layout)),
                ("step", step_shader_with(&layout, false)),
                ("gather", gather_shader(&layout)),
                ("reduce", reduce_shader()),
            ] {
                let module = naga::front::wgsl::parse_str(&src)
                    .unwrap_or_else(|e| panic!("{name} {layout:?}: {}", e.emit_to_string(&src)));
                naga::valid::Validator::new(
                    naga::valid::ValidationFlags::all(),
                    naga::valid::Capabilities::all(),
                )
                .validate(&module)
                .unwrap_or_else(|e| panic!("{name} {layout:?}: {e:?}"));
            }
        }
    }
}
