//! The hot loop: collide one row of sites and stream it into the next state.
//!
//! A row is the `nz` sites of one (x, y) pair; in the state each of its 19 directions is a
//! contiguous run of `nz` floats (layout `[x][y][m][z]`, 002 §3.1). A row is collided
//! [`LANES`] sites at a time with the reduced Ω (see [`ReducedOmega`]), and each direction's
//! result is stored straight into the neighbouring row of the next state, shifted by `c_m`.
//! Only interior sites are written: the shell keeps its boundary values. The first and last
//! chunk of a row, whose shifted stores could reach the shell, store lane by lane.

// Lane and direction loops index several arrays at once; indices read clearer than zips.
#![allow(clippy::needless_range_loop)]

use crate::collision::{ReducedOmega, PAIRS};

use crate::lattice::{C, Q};

/// Sites collided together; 8 f32 fill one AVX2 register.
pub const LANES: usize = 8;

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

/// [`ReducedOmega`] with every coefficient repeated across the lanes, so the multiply-adds
/// take their weights straight from memory instead of broadcasting them first.
#[derive(Debug, Clone)]
pub struct WideOmega {
    o00: [f32; LANES],
    o0q: [f32; LANES],
    op0: [[f32; LANES]; PAIRS],
    even: [[[f32; LANES]; PAIRS]; PAIRS],
    /// `O_pq` as a dense 9×9 (zeros where `n_p ⟂ n_q`, never read).
    odd: [[[f32; LANES]; PAIRS]; PAIRS],
}

impl WideOmega {
    pub fn new(r: &ReducedOmega) -> WideOmega {
        WideOmega {
            o00: [r.o00; LANES],
            o0q: [r.o0q; LANES],
            op0: r.op0.map(|v| [v; LANES]),
            even: r.even.map(|row| row.map(|v| [v; LANES])),
            odd: {
                let mut odd = [[[0.0; LANES]; PAIRS]; PAIRS];
                for (t, &(p, q)) in crate::collision::ODD_PATTERN.iter().enumerate() {
                    odd[p as usize][q as usize] = [r.odd[t]; LANES];
                }
                odd
            },
        }
    }
}

/// Per-colour constants of the collision.
pub struct RowParams<'a> {
    pub green: &'a WideOmega,
    pub brown: &'a WideOmega,
    /// The shell's fixed values, restored where a shifted store touched the shell.
    pub boundary: &'a [f32; Q],
    /// Multiplier of the post-collision `f_0` on green / brown sites (0 zeroes it).
    pub keep_f0_green: f32,
    pub keep_f0_brown: f32,
}

/// Where a row's 19 results go: for each direction, the start of the target run in the next
/// state (already offset by `c_m`'s z component). Results whose target row is on the shell
/// go to a scratch "sink" instead (as in 002's kernel), so the stores need no branches.
pub struct RowTargets {
    pub run: [*mut f32; Q],
}

/// Accumulates `acc += w * x` lane by lane.
#[inline(always)]
fn fma_into<A: MulAdd, const L: usize>(acc: &mut [f32; L], w: &[f32; LANES], x: &[f32; L]) {
    for l in 0..L {
        acc[l] = A::mul_add(w[l], x[l], acc[l]);
    }
}

/// Reads L consecutive floats.
#[inline(always)]
unsafe fn load<const L: usize>(p: *const f32) -> [f32; L] {
    std::ptr::read_unaligned(p as *const [f32; L])
}

/// Odd terms of one column q: `o_p += O_pq d_q` for the pairs p with `n_p · n_q ≠ 0`,
/// spelled out so they unroll with constant indices.
macro_rules! odd_column {
    ($A:ty, $L:ident, $om:expr, $fin:expr, $o:expr, $q:literal, [$($p:literal),*]) => {{
        let a = $fin(2 * $q + 1);
        let b = $fin(2 * $q + 2);
        let mut d = [0.0f32; $L];
        for l in 0..$L {
            d[l] = a[l] - b[l];
        }
        $( fma_into::<$A, $L>(&mut $o[$p], &$om.odd[$p][$q], &d); )*
    }};
}

/// The odd-term columns `odd_column!` spells out (the pattern is symmetric, so columns equal
/// rows; checked against `ODD_PATTERN` in tests).
pub const ODD_ROWS: [&[u8]; PAIRS] = [
    &[0, 3, 4, 5, 6],
    &[1, 3, 4, 7, 8],
    &[2, 5, 6, 7, 8],
    &[0, 1, 3, 5, 6, 7, 8],
    &[0, 1, 4, 5, 6, 7, 8],
    &[0, 2, 3, 4, 5, 7, 8],
    &[0, 2, 3, 4, 6, 7, 8],
    &[1, 2, 3, 4, 5, 6, 7],
    &[1, 2, 3, 4, 5, 6, 8],
];

/// Emits `base(m) + rho · (Ω f)_m` for all 19 directions through `out` (direction 0 also
/// multiplied by `keep0`) and returns the lane-wise total density `Σ_m f_m`.
///
/// Two passes over the nine direction pairs keep at most nine accumulators live, so the
/// weights come straight from memory: the even part (pair sums) first, then the odd part
/// (pair differences); `f` is re-read from L1 rather than held in registers.
#[inline(always)]
unsafe fn collide_lanes<A: MulAdd, const L: usize>(
    om: &WideOmega,
    rho: &[f32; L],
    keep0: &[f32; L],
    fin: impl Fn(usize) -> [f32; L],
    base: impl Fn(usize) -> [f32; L],
    mut out: impl FnMut(usize, [f32; L]),
) -> [f32; L] {
    let f0 = fin(0);
    let mut e = [[0.0f32; L]; PAIRS];
    for p in 0..PAIRS {
        for l in 0..L {
            e[p][l] = om.op0[p][l] * f0[l];
        }
    }
    let mut ssum = [0.0f32; L];
    for q in 0..PAIRS {
        let (a, b) = (fin(2 * q + 1), fin(2 * q + 2));
        let mut sq = [0.0f32; L];
        for l in 0..L {
            sq[l] = a[l] + b[l];
            ssum[l] += sq[l];
        }
        for p in 0..PAIRS {
            fma_into::<A, L>(&mut e[p], &om.even[p][q], &sq);
        }
    }
    let mut o = [[0.0f32; L]; PAIRS];
    odd_column!(A, L, om, fin, o, 0, [0, 3, 4, 5, 6]);
    odd_column!(A, L, om, fin, o, 1, [1, 3, 4, 7, 8]);
    odd_column!(A, L, om, fin, o, 2, [2, 5, 6, 7, 8]);
    odd_column!(A, L, om, fin, o, 3, [0, 1, 3, 5, 6, 7, 8]);
    odd_column!(A, L, om, fin, o, 4, [0, 1, 4, 5, 6, 7, 8]);
    odd_column!(A, L, om, fin, o, 5, [0, 2, 3, 4, 5, 7, 8]);
    odd_column!(A, L, om, fin, o, 6, [0, 2, 3, 4, 6, 7, 8]);
    odd_column!(A, L, om, fin, o, 7, [1, 2, 3, 4, 5, 6, 7]);
    odd_column!(A, L, om, fin, o, 8, [1, 2, 3, 4, 5, 6, 8]);
    let b0 = base(0);
    let mut r0 = [0.0f32; L];
    let mut total = [0.0f32; L];
    for l in 0..L {
        let c0 = A::mul_add(om.o00[l], f0[l], om.o0q[l] * ssum[l]);
        r0[l] = A::mul_add(rho[l], c0, b0[l]) * keep0[l];
        total[l] = f0[l] + ssum[l];
    }
    out(0, r0);
    for p in 0..PAIRS {
        let (bp, bm) = (base(2 * p + 1), base(2 * p + 2));
        let mut plus = [0.0f32; L];
        let mut minus = [0.0f32; L];
        for l in 0..L {
            plus[l] = A::mul_add(rho[l], e[p][l] + o[p][l], bp[l]);
            minus[l] = A::mul_add(rho[l], e[p][l] - o[p][l], bm[l]);
        }
        out(2 * p + 1, plus);
        out(2 * p + 2, minus);
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
    mut out: impl FnMut(usize, [f32; L]),
) -> [f32; L] {
    let fin = |m: usize| load::<L>(src.add(m * nz + k0));
    let code: &[f32; L] = codes[k0..k0 + L].try_into().expect("chunk");
    // Folds without early exit so they vectorise.
    let any_medium = code.iter().fold(false, |a, &c| a | (c != 0.0));
    let any_brown = code.iter().fold(false, |a, &c| a | (c < 0.0));
    if !any_medium {
        // Empty space, most of a forest grid, only streams.
        let mut total = [0.0f32; L];
        for m in 0..Q {
            let f = fin(m);
            for l in 0..L {
                total[l] += f[l];
            }
            out(m, f);
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
        return collide_lanes::<A, L>(rp.green, &rho, &keep0, fin, fin, out);
    }
    // Mixed chunk: green collision into `res`, then the brown one added on top.
    let mut res = [[0.0f32; L]; Q];
    let ones = [1.0f32; L];
    let total = collide_lanes::<A, L>(rp.green, &rho, &ones, fin, fin, |m, v| res[m] = v);
    for l in 0..L {
        rho[l] = (-code[l]).max(0.0);
    }
    let snapshot = res;
    collide_lanes::<A, L>(rp.brown, &rho, &keep0, fin, |m| snapshot[m], out);
    total
}

/// Collides and streams a whole interior row; returns the total density of its interior
/// sites before the step.
///
/// Chunks cover the interior sites `1..nz-1` and store whole vectors: a shifted store can then
/// reach z = 0 or z = nz - 1 of its own target run (never another run), and those two shell
/// values are restored afterwards. The two shell sites of the row only emit into the
/// interior along ±z.
///
/// # Safety
/// `src` valid for `19 * nz` reads; `codes` of length `nz`; every target run valid for
/// writes at offsets `-c_z ..= nz - 1 - c_z` and written by no other row (the sink excepted,
/// which only its own thread writes).
#[inline(always)]
unsafe fn process_row_generic<A: MulAdd>(
    src: *const f32,
    nz: usize,
    codes: &[f32],
    rp: &RowParams,
    targets: &RowTargets,
) -> f32 {
    // Shell sites have code 0, so the collision passes their fixed values through: chunks can
    // start at z = 0 and stay aligned with the runs. A store may then reach z = 0 or nz - 1
    // of its own run (restored below) but must not cross into the next run, which only the
    // first and last chunk could do.
    let mut total = 0.0f32;
    if nz < LANES + 2 {
        for k in 0..nz {
            let t = collide_chunk::<A, 1>(src, nz, k, codes, rp, |m, v: [f32; 1]| {
                store_in_run(targets.run[m], m, k, &v, nz)
            });
            if k > 0 && k < nz - 1 {
                total += t[0];
            }
        }
    } else {
        let t = collide_chunk::<A, LANES>(src, nz, 0, codes, rp, |m, v| {
            store_in_run(targets.run[m], m, 0, &v, nz)
        });
        total += t[1..].iter().sum::<f32>();
        let mut lanes = [0.0f32; LANES];
        let mut k = LANES;
        // Chunks of interior sites only: their stores stay inside [k - 1, k + LANES].
        while k + LANES < nz {
            let t = collide_chunk::<A, LANES>(src, nz, k, codes, rp, |m, v| {
                std::ptr::write_unaligned(targets.run[m].add(k) as *mut [f32; LANES], v)
            });
            for l in 0..LANES {
                lanes[l] += t[l];
            }
            k += LANES;
        }
        total += lanes.iter().sum::<f32>();
        // The last chunk ends at the shell site nz - 1. When nz is not a multiple of LANES
        // it overlaps the previous chunk, whose sites it recomputes and stores again,
        // identically; only the new interior sites count.
        let last = nz - LANES;
        let t = collide_chunk::<A, LANES>(src, nz, last, codes, rp, |m, v| {
            store_in_run(targets.run[m], m, last, &v, nz)
        });
        total += t[k - last..LANES - 1].iter().sum::<f32>();
    }
    for m in 0..Q {
        let run = targets.run[m].offset(-(C[m][2] as isize));
        *run = rp.boundary[m];
        *run.add(nz - 1) = rp.boundary[m];
    }
    total
}

/// Stores sites `k0..k0 + L` of direction m shifted by `c_z`, dropping lanes that would
/// leave the target run (z < 0 or z ≥ nz).
#[inline(always)]
unsafe fn store_in_run<const L: usize>(
    target: *mut f32,
    m: usize,
    k0: usize,
    v: &[f32; L],
    nz: usize,
) {
    let cz = C[m][2] as isize;
    let first = k0 as isize + cz;
    if first >= 0 && first + L as isize <= nz as isize {
        std::ptr::write_unaligned(target.add(k0) as *mut [f32; L], *v);
    } else {
        for (l, &x) in v.iter().enumerate() {
            let z = first + l as isize;
            if z >= 0 && z < nz as isize {
                *target.add(k0 + l) = x;
            }
        }
    }
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
    process_row_generic::<Fused>(src, nz, codes, rp, targets)
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
    Avx2Fma,
    Portable,
}

impl KernelIsa {
    pub fn detect() -> KernelIsa {
        #[cfg(target_arch = "x86_64")]
        {
            if std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma") {
                return KernelIsa::Avx2Fma;
            }
        }
        KernelIsa::Portable
    }

    pub fn name(self) -> &'static str {
        match self {
            KernelIsa::Avx2Fma => "avx2+fma",
            KernelIsa::Portable => "portable",
        }
    }
}

/// The targets of interior row (x, y): run `m` of row `(x + cx, y + cy)` in `dst`, shifted
/// by `cz` so that index k of the result row lands at `k + cz`; the sink where that row is on
/// the shell.
///
/// # Safety
/// `dst` must point at a state of `nx * ny * 19 * nz` floats, (x, y) be interior, and `sink`
/// be valid for `nz + 2` floats.
pub unsafe fn row_targets(
    dst: *mut f32,
    sink: *mut f32,
    dims: (usize, usize, usize),
    x: usize,
    y: usize,
) -> RowTargets {
    let (nx, ny, nz) = dims;
    let mut run = [sink; Q];
    for (m, c) in C.iter().enumerate() {
        let tx = (x as isize + c[0] as isize) as usize;
        let ty = (y as isize + c[1] as isize) as usize;
        // The run starts at least one float into its buffer (tx ≥ 1, or the sink's first
        // float), so the -1 shift stays inside the allocation.
        run[m] = if tx >= 1 && ty >= 1 && tx <= nx - 2 && ty <= ny - 2 {
            dst.add(((tx * ny + ty) * Q + m) * nz).offset(c[2] as isize)
        } else {
            sink.add(1).offset(c[2] as isize)
        };
    }
    RowTargets { run }
}

/// Collides and streams interior row (x, y) with the kernel for `isa`.
///
/// # Safety
/// As [`process_row_generic`]; `isa` must be supported by this CPU ([`KernelIsa::detect`]).
pub unsafe fn process_row(
    isa: KernelIsa,
    src: *const f32,
    nz: usize,
    codes: &[f32],
    rp: &RowParams,
    targets: &RowTargets,
) -> f32 {
    debug_assert!(codes.len() == nz);
    match isa {
        #[cfg(target_arch = "x86_64")]
        KernelIsa::Avx2Fma => process_row_avx2(src, nz, codes, rp, targets),
        _ => process_row_generic::<Plain>(src, nz, codes, rp, targets),
    }
}

/// Streams a shell row (boundary values, no collision) into its interior neighbours;
/// writes that would land on the shell are dropped (002 §3: inflow into the boundary is
/// ignored).
///
/// # Safety
/// `dst` must point at a state of `nx * ny * 19 * nz` floats, and no other thread may write
/// the (row, direction) runs this row streams into: each one has exactly one source row.
pub unsafe fn stream_shell_row(
    block: &[f32],
    dst: *mut f32,
    dims: (usize, usize, usize),
    x: usize,
    y: usize,
) {
    let (nx, ny, nz) = dims;
    for (m, c) in C.iter().enumerate() {
        let tx = x as isize + c[0] as isize;
        let ty = y as isize + c[1] as isize;
        if tx < 1 || ty < 1 || tx > nx as isize - 2 || ty > ny as isize - 2 {
            continue;
        }
        let cz = c[2] as isize;
        // Target z' = z + cz must lie in [1, nz - 2].
        let z_lo = (1 - cz).max(0) as usize;
        let z_hi = (nz as isize - 1 - cz).min(nz as isize) as usize;
        if z_lo >= z_hi {
            continue;
        }
        let row = ((tx as usize * ny + ty as usize) * Q + m) * nz;
        let from = block.as_ptr().add(m * nz + z_lo);
        let to = dst.add(row + (z_lo as isize + cz) as usize);
        std::ptr::copy_nonoverlapping(from, to, z_hi - z_lo);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::collision::ODD_PATTERN;

    #[test]
    fn spelled_out_odd_rows_match_the_pattern() {
        let mut t = 0;
        for (p, row) in ODD_ROWS.iter().enumerate() {
            for &q in row.iter() {
                assert_eq!(ODD_PATTERN[t], (p as u8, q), "term {t}");
                t += 1;
            }
        }
        assert_eq!(t, ODD_PATTERN.len());
    }
}
