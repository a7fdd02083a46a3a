//! The hot loop: collide one row of sites and stream it into the next state.
//!
//! A row is the `nz` sites of one (x, y) pair; in the state each of its 19 directions is a
//! contiguous run of `nz` floats (layout `[x][y][m][z]`, 002 §3.1), with one padding float
//! before and after each run ([`run_stride`]). The padding takes the stores that a shift by
//! `c_z = ±1` pushes past either end of a run, so every chunk stores whole vectors and no
//! store ever reaches another run. A row is collided
//! [`LANES`] (AVX2) or [`LANES_AVX512`] sites at a time with the reduced Ω (see
//! [`ReducedOmega`]), and each direction's
//! result is stored straight into the neighbouring row of the next state, shifted by `c_m`.
//! Only interior sites are written: the shell keeps its boundary values. The first and last
//! chunk of a row, whose shifted stores could reach the shell, store lane by lane.

// Lane and direction loops index several arrays at once; indices read clearer than zips.
#![allow(clippy::needless_range_loop)]

use crate::collision::{ReducedOmega, PAIRS};

use crate::lattice::{C, Q};

/// Sites collided together by the AVX2 and portable kernels; 8 f32 fill one AVX2 register.
pub const LANES: usize = 8;

/// Sites collided together by the AVX-512 kernel: 16 f32 fill one AVX-512 register.
pub const LANES_AVX512: usize = 16;

/// Lanes of [`CubicOmega`]'s repeated coefficients: enough for the widest kernel, which reads
/// them as whole-register memory operands (a narrower kernel reads the first `L`).
const WIDEST: usize = LANES_AVX512;

/// Floats per run in the state: `nz` sites plus one padding float at each end (run data
/// starts at offset 1).
pub const fn run_stride(nz: usize) -> usize {
    nz + 2
}

/// How `a * b + c` is evaluated: fused where the CPU has FMA, plain otherwise.
pub trait MulAdd {
    fn mul_add(a: f32, b: f32, c: f32) -> f32;
}

/// `a * b + c` with two roundings: portable, vectorises on any SIMD.
pub struct Plain;
impl MulAdd for Plain {
    #[inline(always)]
    fn mul_add(a: f32, b: f32, c: f32) -> f32 {
        a * b + c
    }
}

/// One rounding; only used inside functions compiled with the `fma` target feature, where
/// `f32::mul_add` becomes a single instruction instead of a libm call.
pub struct Fused;
impl MulAdd for Fused {
    #[inline(always)]
    fn mul_add(a: f32, b: f32, c: f32) -> f32 {
        a.mul_add(b, c)
    }
}

/// Ω factored by the lattice's cubic symmetry, every coefficient repeated across the lanes.
///
/// Ω depends only on the angle between two directions, so the reduced matrices `E` (pair
/// sums) and `O` (pair differences) of [`ReducedOmega`] have a handful of distinct entries.
/// Pairs: X, Y, Z (axial) and XY±, XZ±, YZ± (diagonals `e_i ± e_j`). With `S_a` the sum of
/// the axial pair sums, `u_ij` the sum and `t_ij` the difference of a plane's two diagonal
/// pair sums, `U_d = Σ u`:
///
/// * `e_X = C_a + α s_X − β u_YZ`, with `C_a = E_X0 f_0 + a_0 S_a + b_1 U_d`;
/// * `e_XY± = C_d + γ (S_a − s_Z) + δ u_XY ± ε t_XY`, with `C_d = E_XY0 f_0 + c_0 S_a + d_½ U_d`;
///
/// and with the diagonal flux `v_x = d_XY+ + d_XY− + d_XZ+ + d_XZ−` (and likewise `v_y`,
/// `v_z` with the signs of the diagonals' components) and `W_i = C d_i + D_½ v_i`:
///
/// * `o_X = A d_X + B v_x`;
/// * `o_XY± = W_x ± W_y + κ d_XY±`.
///
/// About 75 operations per site instead of 361 for the dense matrix; checked against the
/// dense Ω in tests.
#[derive(Debug, Clone)]
pub struct CubicOmega {
    o00: [f32; WIDEST],
    o0q: [f32; WIDEST],
    op0_axial: [f32; WIDEST],
    op0_diagonal: [f32; WIDEST],
    a0: [f32; WIDEST],
    alpha: [f32; WIDEST],
    b1: [f32; WIDEST],
    minus_beta: [f32; WIDEST],
    c0: [f32; WIDEST],
    gamma: [f32; WIDEST],
    d_half_even: [f32; WIDEST],
    delta: [f32; WIDEST],
    epsilon: [f32; WIDEST],
    minus_epsilon: [f32; WIDEST],
    odd_axial: [f32; WIDEST],
    odd_b: [f32; WIDEST],
    odd_c: [f32; WIDEST],
    odd_d_half: [f32; WIDEST],
    kappa: [f32; WIDEST],
}

impl CubicOmega {
    pub fn new(r: &ReducedOmega) -> CubicOmega {
        // Pair indices: 0 X, 1 Y, 2 Z, 3 XY+, 4 XY-, 5 XZ+, 6 XZ-, 7 YZ+, 8 YZ-.
        let e = &r.even;
        let odd = |p: usize, q: usize| {
            crate::collision::ODD_PATTERN
                .iter()
                .position(|&t| t == (p as u8, q as u8))
                .map(|i| r.odd[i])
                .expect("structurally non-zero odd term")
        };
        let w = |v: f32| [v; WIDEST];
        let (a1, a0, b1, b0) = (e[0][0], e[0][1], e[0][3], e[0][7]);
        let (c1, c0) = (e[3][0], e[3][2]);
        let (d_same, d_perp, d_half) = (e[3][3], e[3][4], e[3][5]);
        let epsilon = 0.5 * (d_same - d_perp);
        let (od_same, od_half) = (odd(3, 3), odd(3, 5));
        CubicOmega {
            o00: w(r.o00),
            o0q: w(r.o0q),
            op0_axial: w(r.op0[0]),
            op0_diagonal: w(r.op0[3]),
            a0: w(a0),
            alpha: w(a1 - a0),
            b1: w(b1),
            minus_beta: w(-(b1 - b0)),
            c0: w(c0),
            gamma: w(c1 - c0),
            d_half_even: w(d_half),
            delta: w(0.5 * (d_same + d_perp) - d_half),
            epsilon: w(epsilon),
            minus_epsilon: w(-epsilon),
            odd_axial: w(odd(0, 0)),
            odd_b: w(odd(0, 3)),
            odd_c: w(odd(3, 0)),
            odd_d_half: w(od_half),
            kappa: w(od_same - 2.0 * od_half),
        }
    }

    /// The 19 scalar coefficients in [`CubicOmega::COEFFICIENT_NAMES`] order, for kernels
    /// outside this crate (the GPU backend uploads them instead of re-deriving Ω).
    pub fn coefficients(&self) -> [f32; 19] {
        [
            self.o00[0],
            self.o0q[0],
            self.op0_axial[0],
            self.op0_diagonal[0],
            self.a0[0],
            self.alpha[0],
            self.b1[0],
            self.minus_beta[0],
            self.c0[0],
            self.gamma[0],
            self.d_half_even[0],
            self.delta[0],
            self.epsilon[0],
            self.minus_epsilon[0],
            self.odd_axial[0],
            self.odd_b[0],
            self.odd_c[0],
            self.odd_d_half[0],
            self.kappa[0],
        ]
    }

    /// Names of [`CubicOmega::coefficients`], in order.
    pub const COEFFICIENT_NAMES: [&'static str; 19] = [
        "o00",
        "o0q",
        "op0_axial",
        "op0_diagonal",
        "a0",
        "alpha",
        "b1",
        "minus_beta",
        "c0",
        "gamma",
        "d_half_even",
        "delta",
        "epsilon",
        "minus_epsilon",
        "odd_axial",
        "odd_b",
        "odd_c",
        "odd_d_half",
        "kappa",
    ];
}

/// Per-colour constants of the collision.
pub struct RowParams<'a> {
    pub green: &'a CubicOmega,
    pub brown: &'a CubicOmega,
    /// The shell's fixed values, restored where a shifted store touched the shell.
    pub boundary: &'a [f32; Q],
    /// Multiplier of the post-collision `f_0` on green / brown sites (0 zeroes it).
    pub keep_f0_green: f32,
    pub keep_f0_brown: f32,
    /// A volume source on this row, if any.
    pub source: Option<RowSource<'a>>,
}

/// A volume source on one row ([`crate::solver::VolumeSource`]): every step, site `k` adds
/// `strength[k] · profile[m]` to its post-collision value of direction `m`, with the green or
/// brown profile by its site code.
pub struct RowSource<'a> {
    /// Per site of the row (`nz` values; 0 on empty and shell sites).
    pub strength: &'a [f32],
    pub green: &'a [f32; Q],
    pub brown: &'a [f32; Q],
}

/// Where a row's 19 results go: for each direction, the start of the target run in the next
/// state (already offset by `c_m`'s z component). Results whose target row is on the shell
/// go to a scratch "sink" instead (as in 002's kernel), so the stores need no branches.
pub struct RowTargets {
    pub run: [*mut f32; Q],
}

/// Reads L consecutive floats.
#[inline(always)]
unsafe fn load<const L: usize>(p: *const f32) -> [f32; L] {
    std::ptr::read_unaligned(p as *const [f32; L])
}

/// Lane-wise arithmetic on `[f32; L]`; each loop becomes one vector instruction.
#[inline(always)]
fn add<const L: usize>(a: [f32; L], b: [f32; L]) -> [f32; L] {
    let mut r = a;
    for l in 0..L {
        r[l] += b[l];
    }
    r
}

#[inline(always)]
fn sub<const L: usize>(a: [f32; L], b: [f32; L]) -> [f32; L] {
    let mut r = a;
    for l in 0..L {
        r[l] -= b[l];
    }
    r
}

/// `w * x` with a lane-broadcast weight.
#[inline(always)]
fn mul<const L: usize>(w: &[f32; WIDEST], x: [f32; L]) -> [f32; L] {
    let mut r = x;
    for l in 0..L {
        r[l] *= w[l];
    }
    r
}

/// `acc + w * x`.
#[inline(always)]
fn mad<A: MulAdd, const L: usize>(w: &[f32; WIDEST], x: [f32; L], acc: [f32; L]) -> [f32; L] {
    let mut r = acc;
    for l in 0..L {
        r[l] = A::mul_add(w[l], x[l], r[l]);
    }
    r
}

/// The 19 input vectors of a collision: a chunk of the state, or an earlier result.
///
/// Inputs and outputs are traits with `#[inline(always)]` methods, not closures: a closure is
/// a function of its own, compiled without the kernel's target features, and LLVM declined
/// to inline some of them into the 16-lane kernel (a call per direction, twice as slow).
trait Inputs<const L: usize> {
    fn get(&self, m: usize) -> [f32; L];
}

/// Where a collision's 19 result vectors go.
trait Outputs<const L: usize> {
    fn put(&mut self, m: usize, v: [f32; L]);
}

impl<const L: usize> Inputs<L> for [[f32; L]; Q] {
    #[inline(always)]
    fn get(&self, m: usize) -> [f32; L] {
        self[m]
    }
}

impl<const L: usize> Outputs<L> for [[f32; L]; Q] {
    #[inline(always)]
    fn put(&mut self, m: usize, v: [f32; L]) {
        self[m] = v;
    }
}

/// Sites `k0..k0 + L` of a row's 19 runs in the state.
struct StateChunk {
    src: *const f32,
    nz: usize,
    k0: usize,
}

impl<const L: usize> Inputs<L> for StateChunk {
    #[inline(always)]
    fn get(&self, m: usize) -> [f32; L] {
        // SAFETY: `collide_chunk`'s contract: `src` holds 19 padded runs of `nz` sites and
        // `k0 + L <= nz`.
        unsafe { load::<L>(self.src.add(m * run_stride(self.nz) + 1 + self.k0)) }
    }
}

/// Stores sites `k..k + L` of each direction into its target run ([`RowTargets`]).
struct TargetStores<'a> {
    targets: &'a RowTargets,
    k: usize,
}

impl<const L: usize> Outputs<L> for TargetStores<'_> {
    #[inline(always)]
    fn put(&mut self, m: usize, v: [f32; L]) {
        // SAFETY: `process_row_generic`'s contract: every target run is valid for writes at
        // offsets `-c_z ..= nz - 1 - c_z`, and `k + L <= nz`.
        unsafe { std::ptr::write_unaligned(self.targets.run[m].add(self.k) as *mut [f32; L], v) }
    }
}

/// Adds a row's volume source (if any) to every result before passing it on.
struct AddSource<'a, O, const L: usize> {
    out: &'a mut O,
    source: Option<(&'a RowSource<'a>, &'a [f32; L])>,
    code: &'a [f32; L],
}

impl<O: Outputs<L>, const L: usize> Outputs<L> for AddSource<'_, O, L> {
    #[inline(always)]
    fn put(&mut self, m: usize, v: [f32; L]) {
        let mut r = v;
        if let Some((source, strength)) = self.source {
            let (g, b) = (source.green[m], source.brown[m]);
            for l in 0..L {
                let profile = if self.code[l] < 0.0 { b } else { g };
                r[l] += strength[l] * profile;
            }
        }
        self.out.put(m, r)
    }
}

/// Emits `base(m) + rho · (Ω f)_m` for all 19 directions through `out` (direction 0 also
/// multiplied by `keep0`) and returns the lane-wise total density `Σ_m f_m`. See
/// [`CubicOmega`] for the factorisation; `f` is re-read from L1 rather than held in registers.
#[inline(always)]
fn collide_lanes<A: MulAdd, const L: usize>(
    om: &CubicOmega,
    rho: &[f32; L],
    keep0: &[f32; L],
    fin: &impl Inputs<L>,
    base: &impl Inputs<L>,
    out: &mut impl Outputs<L>,
) -> [f32; L] {
    let f0 = fin.get(0);
    let mut s = [[0.0f32; L]; PAIRS];
    for q in 0..PAIRS {
        s[q] = add(fin.get(2 * q + 1), fin.get(2 * q + 2));
    }
    let sum_axial = add(add(s[0], s[1]), s[2]);
    let (u_xy, u_xz, u_yz) = (add(s[3], s[4]), add(s[5], s[6]), add(s[7], s[8]));
    let sum_diagonal = add(add(u_xy, u_xz), u_yz);
    let c_a = mad::<A, L>(
        &om.b1,
        sum_diagonal,
        mad::<A, L>(&om.a0, sum_axial, mul(&om.op0_axial, f0)),
    );
    let c_d = mad::<A, L>(
        &om.d_half_even,
        sum_diagonal,
        mad::<A, L>(&om.c0, sum_axial, mul(&om.op0_diagonal, f0)),
    );
    #[inline(always)]
    fn even_axial<A: MulAdd, const L: usize>(
        om: &CubicOmega,
        c_a: [f32; L],
        sq: [f32; L],
        u_other: [f32; L],
    ) -> [f32; L] {
        mad::<A, L>(&om.minus_beta, u_other, mad::<A, L>(&om.alpha, sq, c_a))
    }
    #[inline(always)]
    fn plane_base<A: MulAdd, const L: usize>(
        om: &CubicOmega,
        c_d: [f32; L],
        sum_axial: [f32; L],
        s_other: [f32; L],
        u: [f32; L],
    ) -> [f32; L] {
        mad::<A, L>(
            &om.delta,
            u,
            mad::<A, L>(&om.gamma, sub(sum_axial, s_other), c_d),
        )
    }
    let (b_xy, b_xz, b_yz) = (
        plane_base::<A, L>(om, c_d, sum_axial, s[2], u_xy),
        plane_base::<A, L>(om, c_d, sum_axial, s[1], u_xz),
        plane_base::<A, L>(om, c_d, sum_axial, s[0], u_yz),
    );
    let e = [
        even_axial::<A, L>(om, c_a, s[0], u_yz),
        even_axial::<A, L>(om, c_a, s[1], u_xz),
        even_axial::<A, L>(om, c_a, s[2], u_xy),
        mad::<A, L>(&om.epsilon, sub(s[3], s[4]), b_xy),
        mad::<A, L>(&om.minus_epsilon, sub(s[3], s[4]), b_xy),
        mad::<A, L>(&om.epsilon, sub(s[5], s[6]), b_xz),
        mad::<A, L>(&om.minus_epsilon, sub(s[5], s[6]), b_xz),
        mad::<A, L>(&om.epsilon, sub(s[7], s[8]), b_yz),
        mad::<A, L>(&om.minus_epsilon, sub(s[7], s[8]), b_yz),
    ];
    let ssum = add(sum_axial, sum_diagonal);

    let mut d = [[0.0f32; L]; PAIRS];
    for q in 0..PAIRS {
        d[q] = sub(fin.get(2 * q + 1), fin.get(2 * q + 2));
    }
    let v_x = add(add(d[3], d[4]), add(d[5], d[6]));
    let v_y = add(sub(d[3], d[4]), add(d[7], d[8]));
    let v_z = add(sub(d[5], d[6]), sub(d[7], d[8]));
    #[inline(always)]
    fn odd_axial<A: MulAdd, const L: usize>(
        om: &CubicOmega,
        di: [f32; L],
        v: [f32; L],
    ) -> [f32; L] {
        mad::<A, L>(&om.odd_b, v, mul(&om.odd_axial, di))
    }
    #[inline(always)]
    fn w_axis<A: MulAdd, const L: usize>(om: &CubicOmega, di: [f32; L], v: [f32; L]) -> [f32; L] {
        mad::<A, L>(&om.odd_d_half, v, mul(&om.odd_c, di))
    }
    let (w_x, w_y, w_z) = (
        w_axis::<A, L>(om, d[0], v_x),
        w_axis::<A, L>(om, d[1], v_y),
        w_axis::<A, L>(om, d[2], v_z),
    );
    let o = [
        odd_axial::<A, L>(om, d[0], v_x),
        odd_axial::<A, L>(om, d[1], v_y),
        odd_axial::<A, L>(om, d[2], v_z),
        mad::<A, L>(&om.kappa, d[3], add(w_x, w_y)),
        mad::<A, L>(&om.kappa, d[4], sub(w_x, w_y)),
        mad::<A, L>(&om.kappa, d[5], add(w_x, w_z)),
        mad::<A, L>(&om.kappa, d[6], sub(w_x, w_z)),
        mad::<A, L>(&om.kappa, d[7], add(w_y, w_z)),
        mad::<A, L>(&om.kappa, d[8], sub(w_y, w_z)),
    ];

    let b0 = base.get(0);
    let mut r0 = [0.0f32; L];
    let mut total = [0.0f32; L];
    for l in 0..L {
        let c0 = A::mul_add(om.o00[l], f0[l], om.o0q[l] * ssum[l]);
        r0[l] = A::mul_add(rho[l], c0, b0[l]) * keep0[l];
        total[l] = f0[l] + ssum[l];
    }
    out.put(0, r0);
    for p in 0..PAIRS {
        let (bp, bm) = (base.get(2 * p + 1), base.get(2 * p + 2));
        let (mut plus, mut minus) = ([0.0f32; L], [0.0f32; L]);
        for l in 0..L {
            plus[l] = A::mul_add(rho[l], e[p][l] + o[p][l], bp[l]);
            minus[l] = A::mul_add(rho[l], e[p][l] - o[p][l], bm[l]);
        }
        out.put(2 * p + 1, plus);
        out.put(2 * p + 2, minus);
    }
    total
}

/// Collides interior sites `k0..k0 + L` of a row and hands each direction's result to
/// `out`. Returns the lane-wise total density before collision.
///
/// # Safety
/// `src` must be valid for `19 * nz` floats and `k0 + L <= nz`.
#[inline(always)]
unsafe fn collide_chunk<A: MulAdd, const L: usize>(
    src: *const f32,
    nz: usize,
    k0: usize,
    codes: &[f32],
    rp: &RowParams,
    out: &mut impl Outputs<L>,
) -> [f32; L] {
    let fin = StateChunk { src, nz, k0 };
    let code: &[f32; L] = codes[k0..k0 + L].try_into().expect("chunk");
    let strength = rp.source.as_ref().map(|source| {
        let strength: &[f32; L] = source.strength[k0..k0 + L].try_into().expect("chunk");
        (source, strength)
    });
    let mut out = AddSource {
        out,
        source: strength,
        code,
    };
    // Folds without early exit so they vectorise.
    let any_medium = code.iter().fold(false, |a, &c| a | (c != 0.0));
    let any_brown = code.iter().fold(false, |a, &c| a | (c < 0.0));
    if !any_medium {
        // Empty space, most of a forest grid, only streams.
        let mut total = [0.0f32; L];
        for m in 0..Q {
            let f: [f32; L] = fin.get(m);
            for l in 0..L {
                total[l] += f[l];
            }
            out.put(m, f);
        }
        return total;
    }
    let mut rho = [0.0f32; L];
    let mut keep0 = [1.0f32; L];
    for l in 0..L {
        rho[l] = code[l].max(0.0);
        let k = if code[l] < 0.0 { rp.keep_f0_brown } else { 1.0 };
        keep0[l] = if code[l] > 0.0 { rp.keep_f0_green } else { k };
    }
    if !any_brown {
        return collide_lanes::<A, L>(rp.green, &rho, &keep0, &fin, &fin, &mut out);
    }
    // Mixed chunk: green collision into `res`, then the brown one added on top.
    let mut res = [[0.0f32; L]; Q];
    let ones = [1.0f32; L];
    let total = collide_lanes::<A, L>(rp.green, &rho, &ones, &fin, &fin, &mut res);
    for l in 0..L {
        rho[l] = (-code[l]).max(0.0);
    }
    collide_lanes::<A, L>(rp.brown, &rho, &keep0, &fin, &res, &mut out);
    total
}

/// Collides and streams a whole interior row, `L` sites at a time; returns the total density
/// of its interior sites before the step.
///
/// Chunks cover the interior sites `1..nz-1` and store whole vectors: a shifted store can then
/// reach z = 0 or z = nz - 1 of its own target run (never another run), and those two shell
/// values are restored afterwards. The two shell sites of the row only emit into the
/// interior along ±z. Each site's arithmetic does not depend on `L`, so kernels of any width
/// with the same [`MulAdd`] write the same state bit for bit (the totals are summed in a
/// different order).
///
/// # Safety
/// `src` valid for `19 * nz` reads; `codes` of length `nz`; every target run valid for
/// writes at offsets `-c_z ..= nz - 1 - c_z` and written by no other row (the sink excepted,
/// which only its own thread writes).
#[inline(always)]
unsafe fn process_row_generic<A: MulAdd, const L: usize>(
    src: *const f32,
    nz: usize,
    codes: &[f32],
    rp: &RowParams,
    targets: &RowTargets,
) -> f32 {
    // Shell sites have code 0, so the collision passes their fixed values through and every
    // chunk can be handled alike; stores that land on z = 0 or nz - 1 are restored below,
    // those past the ends of a run fall into its padding.
    let mut total = 0.0f32;
    if nz < L {
        for k in 0..nz {
            let mut stores = TargetStores { targets, k };
            let t = collide_chunk::<A, 1>(src, nz, k, codes, rp, &mut stores);
            if k > 0 && k < nz - 1 {
                total += t[0];
            }
        }
    } else {
        // The last chunk ends at nz - 1; when nz is not a multiple of L it overlaps the
        // previous chunk, whose sites it recomputes and stores again, identically. Only
        // interior sites not yet counted add to the total.
        let last = nz - L;
        let mut lanes = [0.0f32; L];
        let mut counted = 1; // sites below this are counted (or the shell site 0)
        let mut k = 0;
        loop {
            let mut stores = TargetStores { targets, k };
            let t = collide_chunk::<A, L>(src, nz, k, codes, rp, &mut stores);
            if k > 0 && k + L < nz {
                // Wholly interior and not overlapping: every lane counts.
                for l in 0..L {
                    lanes[l] += t[l];
                }
                counted = k + L;
            } else {
                let (lo, hi) = (counted.max(k), (k + L).min(nz - 1));
                if lo < hi {
                    total += t[lo - k..hi - k].iter().sum::<f32>();
                }
                counted = counted.max(hi);
            }
            if k == last {
                break;
            }
            k = (k + L).min(last);
        }
        total += lanes.iter().sum::<f32>();
    }
    for m in 0..Q {
        let run = targets.run[m].offset(-(C[m][2] as isize));
        *run = rp.boundary[m];
        *run.add(nz - 1) = rp.boundary[m];
    }
    total
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn process_row_avx2(
    src: *const f32,
    nz: usize,
    codes: &[f32],
    rp: &RowParams,
    targets: &RowTargets,
) -> f32 {
    process_row_generic::<Fused, LANES>(src, nz, codes, rp, targets)
}

/// The same code as [`process_row_avx2`] 16 lanes wide: `[f32; 16]` arithmetic becomes one
/// zmm instruction, and the coefficients stay whole-register memory operands. Rows shorter
/// than 16 sites take 8-lane chunks.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma")]
unsafe fn process_row_avx512(
    src: *const f32,
    nz: usize,
    codes: &[f32],
    rp: &RowParams,
    targets: &RowTargets,
) -> f32 {
    if nz < LANES_AVX512 {
        process_row_generic::<Fused, LANES>(src, nz, codes, rp, targets)
    } else {
        process_row_generic::<Fused, LANES_AVX512>(src, nz, codes, rp, targets)
    }
}

/// Asks the CPU to bring `data` into cache (one hint per 64-byte line); a no-op elsewhere.
#[inline]
pub fn prefetch(data: &[f32]) {
    #[cfg(target_arch = "x86_64")]
    {
        let mut i = 0;
        while i < data.len() {
            // SAFETY: prefetching is only a hint; the address lies inside `data`.
            unsafe {
                std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(
                    data.as_ptr().add(i) as *const i8,
                );
            }
            i += 16;
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = data;
}

/// Which instruction set the kernel runs with (chosen once at start-up).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum KernelIsa {
    /// AVX-512F with FMA, 16 sites per vector; the same arithmetic as [`KernelIsa::Avx2Fma`].
    Avx512,
    Avx2Fma,
    /// Plain Rust, separate multiply and add: the reference the others are tested against.
    Portable,
}

impl KernelIsa {
    /// Every kernel, widest first.
    pub const ALL: [KernelIsa; 3] = [KernelIsa::Avx512, KernelIsa::Avx2Fma, KernelIsa::Portable];

    /// The widest kernel this CPU runs.
    pub fn detect() -> KernelIsa {
        KernelIsa::ALL
            .into_iter()
            .find(|isa| isa.is_supported())
            .unwrap_or(KernelIsa::Portable)
    }

    /// Whether this CPU has the instructions of `self`.
    pub fn is_supported(self) -> bool {
        match self {
            #[cfg(target_arch = "x86_64")]
            KernelIsa::Avx512 => {
                std::is_x86_feature_detected!("avx512f")
                    && std::is_x86_feature_detected!("avx2")
                    && std::is_x86_feature_detected!("fma")
            }
            #[cfg(target_arch = "x86_64")]
            KernelIsa::Avx2Fma => {
                std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma")
            }
            KernelIsa::Portable => true,
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// The kernels this CPU runs, widest first.
    pub fn supported() -> Vec<KernelIsa> {
        KernelIsa::ALL
            .into_iter()
            .filter(|isa| isa.is_supported())
            .collect()
    }

    pub fn name(self) -> &'static str {
        match self {
            KernelIsa::Avx512 => "avx512f",
            KernelIsa::Avx2Fma => "avx2+fma",
            KernelIsa::Portable => "portable",
        }
    }

    /// The kernel called `name` ([`KernelIsa::name`]).
    pub fn from_name(name: &str) -> Option<KernelIsa> {
        KernelIsa::ALL.into_iter().find(|isa| isa.name() == name)
    }
}

/// The targets of row y of a plane: run `m` of row `y + cy` in target plane `planes[cx + 1]`
/// (the planes at x - 1, x, x + 1 of the next state, each a `ny × 19` block of padded runs),
/// shifted by `cz` so that index k of the result row lands at `k + cz`; the sink where the
/// target plane (null) or row is on the shell.
///
/// # Safety
/// Non-null planes must hold `ny * 19` padded runs; `sink` must be valid for `nz + 2` floats.
pub unsafe fn row_targets(
    planes: [*mut f32; 3],
    sink: *mut f32,
    ny: usize,
    nz: usize,
    y: usize,
) -> RowTargets {
    let mut run = [sink; Q];
    for (m, c) in C.iter().enumerate() {
        let plane = planes[(c[0] + 1) as usize];
        let ty = (y as isize + c[1] as isize) as usize;
        // Run data starts one float into its padded run (and the sink's first float), so
        // the -1 shift stays inside the allocation.
        run[m] = if !plane.is_null() && ty >= 1 && ty <= ny - 2 {
            plane
                .add((ty * Q + m) * run_stride(nz) + 1)
                .offset(c[2] as isize)
        } else {
            sink.add(1).offset(c[2] as isize)
        };
    }
    RowTargets { run }
}

/// Collides and streams interior row (x, y) with the kernel for `isa`.
///
/// # Safety
/// As [`process_row_generic`]; `isa` must be supported by this CPU
/// ([`KernelIsa::is_supported`]).
pub unsafe fn process_row(
    isa: KernelIsa,
    src: *const f32,
    nz: usize,
    codes: &[f32],
    rp: &RowParams,
    targets: &RowTargets,
) -> f32 {
    debug_assert!(codes.len() == nz);
    // SAFETY (the two target-feature kernels): the caller guarantees that this CPU supports
    // `isa` ([`KernelIsa::is_supported`], checked where the lattice chose it), and each
    // kernel is compiled with exactly the features `is_supported` detects for its variant.
    match isa {
        #[cfg(target_arch = "x86_64")]
        KernelIsa::Avx512 => process_row_avx512(src, nz, codes, rp, targets),
        #[cfg(target_arch = "x86_64")]
        KernelIsa::Avx2Fma => process_row_avx2(src, nz, codes, rp, targets),
        _ => process_row_generic::<Plain, LANES>(src, nz, codes, rp, targets),
    }
}

/// Streams a shell row (boundary values, no collision) into its interior neighbours in the
/// target planes (as in [`row_targets`]);
/// writes that would land on the shell are dropped (002 §3: inflow into the boundary is
/// ignored).
///
/// # Safety
/// Non-null planes must hold `ny * 19` padded runs, and no other thread may write the (row,
/// direction) runs this row streams into: each one has exactly one source row.
pub unsafe fn stream_shell_row(
    block: &[f32],
    planes: [*mut f32; 3],
    ny: usize,
    nz: usize,
    y: usize,
) {
    for (m, c) in C.iter().enumerate() {
        let plane = planes[(c[0] + 1) as usize];
        let ty = y as isize + c[1] as isize;
        if plane.is_null() || ty < 1 || ty > ny as isize - 2 {
            continue;
        }
        let cz = c[2] as isize;
        // Target z' = z + cz must lie in [1, nz - 2].
        let z_lo = (1 - cz).max(0) as usize;
        let z_hi = (nz as isize - 1 - cz).min(nz as isize) as usize;
        if z_lo >= z_hi {
            continue;
        }
        let run = (ty as usize * Q + m) * run_stride(nz) + 1;
        let from = block.as_ptr().add(m * run_stride(nz) + 1 + z_lo);
        let to = plane.add(run + (z_lo as isize + cz) as usize);
        std::ptr::copy_nonoverlapping(from, to, z_hi - z_lo);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::collision::Omega;
    use crate::params::ColourParams;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn cubic_factorisation_equals_dense_omega(
            sa in 0.0f64..0.5, ss in 0.0f64..0.5, g in -1.0f64..=1.0,
            f in proptest::array::uniform19(0.0f32..1.0), rho in 0.0f32..=1.0,
        ) {
            let dense = Omega::new(&ColourParams { sigma_a: sa, sigma_s: ss, g });
            let cubic = CubicOmega::new(&ReducedOmega::new(&dense));
            let input: [[f32; 1]; Q] = std::array::from_fn(|m| [f[m]]);
            let mut out = [[0.0f32; 1]; Q];
            let total = collide_lanes::<Plain, 1>(&cubic, &[rho], &[1.0], &input, &input, &mut out);
            let got = out.map(|v| v[0]);
            for i in 0..Q {
                let want: f64 = f[i] as f64
                    + rho as f64 * (0..Q).map(|j| dense.0[i][j] * f[j] as f64).sum::<f64>();
                prop_assert!((got[i] as f64 - want).abs() < 2e-5, "row {}: {} vs {}", i, got[i], want);
            }
            let sum: f32 = f.iter().sum();
            prop_assert!((total[0] - sum).abs() < 1e-5);
        }
    }
}
