//! The runtime's two hot loops, written so that LLVM vectorises them, and compiled twice: for
//! the baseline target and with AVX2 + FMA, chosen at run time (`is_x86_feature_detected!`,
//! cached by std). No dependency: this is what `multiversion` would generate for two targets,
//! in twenty lines.
//!
//! - [`matvec_t`]: y = A x or y += A x from Aᵀ (f64; the step's F x, G u, K ν and the sensor
//!   and load rows), [`matvec`] from A row-major (the sensor read-outs);
//! - [`display`]: the displayed nodes' u = C_i x and ω = W_i x from f32 or 16-bit
//!   fixed-point rows, grouped by 8 nodes, accumulated in f32, and the warp R̃(ω) u on 8
//!   nodes at once (the read-out; the rounding it costs is measured in `tests/readout.rs`).

/// Σ aᵢ bᵢ with four partial sums (f64).
#[inline(always)]
fn dot<const FUSED: bool>(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0f64; 4];
    let (ac, bc) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ar, br) = (ac.remainder(), bc.remainder());
    for (x, y) in ac.zip(bc) {
        for l in 0..4 {
            acc[l] = if FUSED {
                x[l].mul_add(y[l], acc[l])
            } else {
                acc[l] + x[l] * y[l]
            };
        }
    }
    let tail: f64 = ar.iter().zip(br).map(|(x, y)| x * y).sum();
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

#[inline(always)]
fn matvec_body<const FUSED: bool>(a: &[f64], cols: usize, x: &[f64], y: &mut [f64], add: bool) {
    if cols == 0 {
        if !add {
            y.iter_mut().for_each(|v| *v = 0.0);
        }
        return;
    }
    for (yi, row) in y.iter_mut().zip(a.chunks_exact(cols)) {
        let s = dot::<FUSED>(row, x);
        *yi = if add { *yi + s } else { s };
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn matvec_avx2(a: &[f64], cols: usize, x: &[f64], y: &mut [f64], add: bool) {
    matvec_body::<true>(a, cols, x, y, add)
}

#[cfg(target_arch = "x86_64")]
#[inline]
fn has_avx2_fma() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}

/// Rows per SIMD vector of [`matvec_t`] (f64 lanes of one AVX2 register); every column of a
/// [`Columns`] matrix is padded with zeros to a multiple of it.
const LANES: usize = 4;
/// Vectors per register block of [`matvec_t`] (16 rows).
const BLOCK: usize = 4;

/// A `rows × cols` matrix A stored column by column (Aᵀ row-major), each column padded with
/// zeros to `stride` = rows rounded up to a multiple of 4, for [`matvec_t`].
#[derive(Clone, Debug, Default)]
pub(crate) struct Columns {
    data: Vec<f64>,
    rows: usize,
    cols: usize,
    stride: usize,
}

impl Columns {
    /// From A row-major (`a.len()` = rows·cols).
    pub(crate) fn from_row_major(a: &[f64], rows: usize, cols: usize) -> Self {
        assert_eq!(a.len(), rows * cols, "matrix data and shape disagree");
        let stride = rows.div_ceil(LANES) * LANES;
        let mut data = vec![0.0; stride * cols];
        for i in 0..rows {
            for j in 0..cols {
                data[j * stride + i] = a[i * cols + j];
            }
        }
        Columns {
            data,
            rows,
            cols,
            stride,
        }
    }
}

/// One block of `NV` vectors (4·NV rows from `first`) of y = A x or y += A x: two sets of
/// accumulators (even and odd columns) so that two fused multiply–add chains per vector run in
/// parallel; rows at or beyond `y.len()` (the zero padding) are computed but not stored.
#[inline(always)]
fn block_portable<const NV: usize>(a: &Columns, x: &[f64], y: &mut [f64], first: usize, add: bool) {
    let mut even = [[0.0f64; LANES]; NV];
    let mut odd = [[0.0f64; LANES]; NV];
    let fma = |acc: &mut [f64; LANES], col: &[f64], xj: f64| {
        for l in 0..LANES {
            acc[l] += col[l] * xj;
        }
    };
    let cols = a.cols.min(x.len());
    let column = |j: usize, v: usize| {
        let at = j * a.stride + first + LANES * v;
        &a.data[at..at + LANES]
    };
    let mut j = 0;
    while j + 2 <= cols {
        for v in 0..NV {
            fma(&mut even[v], column(j, v), x[j]);
            fma(&mut odd[v], column(j + 1, v), x[j + 1]);
        }
        j += 2;
    }
    if j < cols {
        for v in 0..NV {
            fma(&mut even[v], column(j, v), x[j]);
        }
    }
    for v in 0..NV {
        for l in 0..LANES {
            let i = first + LANES * v + l;
            if i < y.len() {
                let s = even[v][l] + odd[v][l];
                y[i] = if add { y[i] + s } else { s };
            }
        }
    }
}

/// y = A x or y += A x by blocks of 16 rows, then one block of the 4, 8 or 12 left.
#[inline(always)]
fn matvec_t_portable(a: &Columns, x: &[f64], y: &mut [f64], add: bool) {
    let vectors = a.stride / LANES;
    let mut v = 0;
    while v + BLOCK <= vectors {
        block_portable::<BLOCK>(a, x, y, LANES * v, add);
        v += BLOCK;
    }
    match vectors - v {
        1 => block_portable::<1>(a, x, y, LANES * v, add),
        2 => block_portable::<2>(a, x, y, LANES * v, add),
        3 => block_portable::<3>(a, x, y, LANES * v, add),
        _ => {}
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    //! [`super::matvec_t`] with AVX2 + FMA intrinsics (same blocks as the portable version).
    use super::{Columns, BLOCK, LANES};
    use std::arch::x86_64::*;

    /// See [`super::block_portable`]. Caller: `first + 4·NV ≤ a.stride`, `x.len() ≥ a.cols`.
    #[inline(always)]
    unsafe fn block<const NV: usize>(
        a: &Columns,
        x: &[f64],
        y: &mut [f64],
        first: usize,
        add: bool,
    ) {
        let base = a.data.as_ptr().add(first);
        let xp = x.as_ptr();
        let mut even = [_mm256_setzero_pd(); NV];
        let mut odd = [_mm256_setzero_pd(); NV];
        let mut j = 0;
        // Four columns per iteration (the loop's bookkeeping shared by 4·NV products), then
        // the pair and the single column left.
        while j + 4 <= a.cols {
            let c0 = base.add(j * a.stride);
            let (c1, c2, c3) = (c0.add(a.stride), c0.add(2 * a.stride), c0.add(3 * a.stride));
            let (x0, x1) = (_mm256_set1_pd(*xp.add(j)), _mm256_set1_pd(*xp.add(j + 1)));
            let (x2, x3) = (
                _mm256_set1_pd(*xp.add(j + 2)),
                _mm256_set1_pd(*xp.add(j + 3)),
            );
            for v in 0..NV {
                even[v] = _mm256_fmadd_pd(_mm256_loadu_pd(c0.add(LANES * v)), x0, even[v]);
                odd[v] = _mm256_fmadd_pd(_mm256_loadu_pd(c1.add(LANES * v)), x1, odd[v]);
            }
            for v in 0..NV {
                even[v] = _mm256_fmadd_pd(_mm256_loadu_pd(c2.add(LANES * v)), x2, even[v]);
                odd[v] = _mm256_fmadd_pd(_mm256_loadu_pd(c3.add(LANES * v)), x3, odd[v]);
            }
            j += 4;
        }
        if j + 2 <= a.cols {
            let (x0, x1) = (_mm256_set1_pd(*xp.add(j)), _mm256_set1_pd(*xp.add(j + 1)));
            let (c0, c1) = (base.add(j * a.stride), base.add((j + 1) * a.stride));
            for v in 0..NV {
                even[v] = _mm256_fmadd_pd(_mm256_loadu_pd(c0.add(LANES * v)), x0, even[v]);
                odd[v] = _mm256_fmadd_pd(_mm256_loadu_pd(c1.add(LANES * v)), x1, odd[v]);
            }
            j += 2;
        }
        if j < a.cols {
            let x0 = _mm256_set1_pd(*xp.add(j));
            let c0 = base.add(j * a.stride);
            for v in 0..NV {
                even[v] = _mm256_fmadd_pd(_mm256_loadu_pd(c0.add(LANES * v)), x0, even[v]);
            }
        }
        for v in 0..NV {
            let s = _mm256_add_pd(even[v], odd[v]);
            let i = first + LANES * v;
            if i + LANES <= y.len() {
                let out = y.as_mut_ptr().add(i);
                let s = if add {
                    _mm256_add_pd(_mm256_loadu_pd(out), s)
                } else {
                    s
                };
                _mm256_storeu_pd(out, s);
            } else if i < y.len() {
                let mut lanes = [0.0f64; LANES];
                _mm256_storeu_pd(lanes.as_mut_ptr(), s);
                for (o, l) in y[i..].iter_mut().zip(lanes) {
                    *o = if add { *o + l } else { l };
                }
            }
        }
    }

    /// See [`super::matvec_t`]. Caller: the CPU has AVX2 and FMA, `x.len() ≥ a.cols`.
    #[target_feature(enable = "avx2,fma")]
    pub(super) unsafe fn matvec_t(a: &Columns, x: &[f64], y: &mut [f64], add: bool) {
        let vectors = a.stride / LANES;
        let mut v = 0;
        while v + BLOCK <= vectors {
            block::<BLOCK>(a, x, y, LANES * v, add);
            v += BLOCK;
        }
        match vectors - v {
            1 => block::<1>(a, x, y, LANES * v, add),
            2 => block::<2>(a, x, y, LANES * v, add),
            3 => block::<3>(a, x, y, LANES * v, add),
            _ => {}
        }
    }
}

/// y = A x (`add` false) or y += A x, A a [`Columns`] matrix (rows = `y.len()`, at most
/// `a.rows()`; columns = `x.len()`, at least the matrix's). Column by column
/// (y += x_j A_:j) with 16 rows of y held in registers as two accumulator sets (even and odd
/// j, added at the end): no horizontal sums, one fused multiply–add per 4 products, no scalar
/// tail (the padding).
#[inline]
pub(crate) fn matvec_t(a: &Columns, x: &[f64], y: &mut [f64], add: bool) {
    assert!(x.len() >= a.cols && y.len() <= a.rows, "matvec_t: shapes");
    #[cfg(target_arch = "x86_64")]
    if has_avx2_fma() {
        // SAFETY: the CPU has AVX2 and FMA (checked just above); x holds every column's
        // coefficient and y no more rows than the matrix (asserted above), and the kernel reads
        // columns only within `a.stride` (whole vectors of the padded storage).
        return unsafe { avx2::matvec_t(a, x, y, add) };
    }
    matvec_t_portable(a, x, y, add)
}

/// A x for A of three rows (row-major, 3 × `cols`, `x.len()` ≥ cols), portable: four partial
/// sums per row, the three rows interleaved.
fn rows3_portable(a: &[f64], cols: usize, x: &[f64]) -> [f64; 3] {
    let x = &x[..cols];
    let (r0, rest) = a[..3 * cols].split_at(cols);
    let (r1, r2) = rest.split_at(cols);
    let mut acc = [[0.0f64; 4]; 3];
    let xc = x.chunks_exact(4);
    let tail_x = xc.remainder();
    for (((xs, a0), a1), a2) in xc
        .zip(r0.chunks_exact(4))
        .zip(r1.chunks_exact(4))
        .zip(r2.chunks_exact(4))
    {
        for l in 0..4 {
            acc[0][l] += a0[l] * xs[l];
            acc[1][l] += a1[l] * xs[l];
            acc[2][l] += a2[l] * xs[l];
        }
    }
    let head = cols - tail_x.len();
    let mut out = [0.0; 3];
    for (k, (row, a)) in [r0, r1, r2].into_iter().zip(acc).enumerate() {
        let tail: f64 = row[head..].iter().zip(tail_x).map(|(p, q)| p * q).sum();
        out[k] = ((a[0] + a[1]) + (a[2] + a[3])) + tail;
    }
    out
}

#[cfg(target_arch = "x86_64")]
mod avx2_rows3 {
    use std::arch::x86_64::*;

    /// Sum of the four lanes of `v`.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn lanes(v: __m256d) -> f64 {
        let pair = _mm_add_pd(_mm256_castpd256_pd128(v), _mm256_extractf128_pd(v, 1));
        _mm_cvtsd_f64(_mm_add_sd(pair, _mm_unpackhi_pd(pair, pair)))
    }

    /// See [`super::rows3`]: two accumulator registers per row (six independent fused
    /// multiply–add chains), eight columns an iteration, the last columns scalar.
    #[target_feature(enable = "avx2,fma")]
    pub(super) fn rows3(a: &[f64], cols: usize, x: &[f64]) -> [f64; 3] {
        let x = &x[..cols];
        let (r0, rest) = a[..3 * cols].split_at(cols);
        let (r1, r2) = rest.split_at(cols);
        let mut acc = [_mm256_setzero_pd(); 6];
        let chunks = cols / 8;
        for k in 0..chunks {
            let at = 8 * k;
            // SAFETY (every load below): at + 8 ≤ cols, the length of x and of each row.
            unsafe {
                let x0 = _mm256_loadu_pd(x.as_ptr().add(at));
                let x1 = _mm256_loadu_pd(x.as_ptr().add(at + 4));
                acc[0] = _mm256_fmadd_pd(_mm256_loadu_pd(r0.as_ptr().add(at)), x0, acc[0]);
                acc[1] = _mm256_fmadd_pd(_mm256_loadu_pd(r0.as_ptr().add(at + 4)), x1, acc[1]);
                acc[2] = _mm256_fmadd_pd(_mm256_loadu_pd(r1.as_ptr().add(at)), x0, acc[2]);
                acc[3] = _mm256_fmadd_pd(_mm256_loadu_pd(r1.as_ptr().add(at + 4)), x1, acc[3]);
                acc[4] = _mm256_fmadd_pd(_mm256_loadu_pd(r2.as_ptr().add(at)), x0, acc[4]);
                acc[5] = _mm256_fmadd_pd(_mm256_loadu_pd(r2.as_ptr().add(at + 4)), x1, acc[5]);
            }
        }
        let head = 8 * chunks;
        let mut out = [0.0; 3];
        for (k, row) in [r0, r1, r2].into_iter().enumerate() {
            let tail: f64 = row[head..].iter().zip(&x[head..]).map(|(p, q)| p * q).sum();
            out[k] = lanes(_mm256_add_pd(acc[2 * k], acc[2 * k + 1])) + tail;
        }
        out
    }
}

/// A x for A of three rows, row-major with `cols` columns (`a.len()` ≥ 3 cols, `x.len()` ≥
/// cols).
#[inline]
pub(crate) fn rows3(a: &[f64], cols: usize, x: &[f64]) -> [f64; 3] {
    #[cfg(target_arch = "x86_64")]
    if has_avx2_fma() {
        // SAFETY: the CPU has AVX2 and FMA (checked just above).
        return unsafe { avx2_rows3::rows3(a, cols, x) };
    }
    rows3_portable(a, cols, x)
}

/// y = A x (`add` false) or y += A x, A row-major with `cols` columns and `y.len()` rows.
#[inline]
pub(crate) fn matvec(a: &[f64], cols: usize, x: &[f64], y: &mut [f64], add: bool) {
    #[cfg(target_arch = "x86_64")]
    if has_avx2_fma() {
        // SAFETY: the CPU has AVX2 and FMA (checked just above).
        return unsafe { matvec_avx2(a, cols, x, y, add) };
    }
    matvec_body::<false>(a, cols, x, y, add)
}

/// Nodes per group of the display layout (f32 lanes of one AVX2 register).
pub(crate) const GROUP: usize = 8;

/// Taylor coefficients of A₁ = (1 − cos θ)/θ² and B₁ = (θ − sin θ)/θ³ in t = θ², four terms
/// each: for t < 1/4 the first omitted terms, t⁴/10! and t⁴/11!, are below 1.1e-9, far under
/// f32 rounding.
const A1: [f32; 4] = [0.5, -1.0 / 24.0, 1.0 / 720.0, -1.0 / 40320.0];
const B1: [f32; 4] = [1.0 / 6.0, -1.0 / 120.0, 1.0 / 5040.0, -1.0 / 362880.0];

#[inline(always)]
fn lanes<const FUSED: bool>(a: [f32; GROUP], b: [f32; GROUP], c: [f32; GROUP]) -> [f32; GROUP] {
    let mut o = [0.0f32; GROUP];
    for l in 0..GROUP {
        o[l] = if FUSED {
            a[l].mul_add(b[l], c[l])
        } else {
            a[l] * b[l] + c[l]
        };
    }
    o
}

/// A row-entry type of [`DisplayRows`]: f32, or 16-bit fixed point (exact in f32).
pub(crate) trait RowEntry: Copy {
    /// The entry in f32 (before the column's scale).
    fn value(self) -> f32;
}

impl RowEntry for f32 {
    #[inline(always)]
    fn value(self) -> f32 {
        self
    }
}

impl RowEntry for i16 {
    #[inline(always)]
    fn value(self) -> f32 {
        f32::from(self)
    }
}

/// Σ_k rows[k][c][l] · x_k for one group: C rows of 8 lanes per state index k.
#[inline(always)]
fn accumulate<const C: usize, const FUSED: bool, T: RowEntry>(
    rows: &[T],
    x: &[f32],
) -> [[f32; GROUP]; C] {
    let mut acc = [[0.0f32; GROUP]; C];
    for (kb, &xk) in rows.chunks_exact(C * GROUP).zip(x) {
        for (c, a) in acc.iter_mut().enumerate() {
            let row = &kb[c * GROUP..(c + 1) * GROUP];
            for l in 0..GROUP {
                let v = row[l].value();
                a[l] = if FUSED {
                    v.mul_add(xk, a[l])
                } else {
                    a[l] + v * xk
                };
            }
        }
    }
    acc
}

/// One group's world displacements (see [`display`]) into `out` (3 per node, `count` nodes).
#[inline(always)]
fn warp_group<const FUSED: bool>(u: [[f32; GROUP]; 3], w: [[f32; GROUP]; 3], out: &mut [f64]) {
    let [ux, uy, uz] = u;
    let [wx, wy, wz] = w;
    // u + A₁ ω×u + B₁ ω×(ω×u), lane-wise in f32 (series for θ < 1/2).
    let mut t = [0.0f32; GROUP];
    for l in 0..GROUP {
        t[l] = wx[l] * wx[l] + wy[l] * wy[l] + wz[l] * wz[l];
    }
    let horner = |c: &[f32; 4]| {
        let mut v = [c[3]; GROUP];
        for &ck in c[..3].iter().rev() {
            v = lanes::<FUSED>(v, t, [ck; GROUP]);
        }
        v
    };
    let (a1, b1) = (horner(&A1), horner(&B1));
    let mut v = [[0.0f32; GROUP]; 6];
    for l in 0..GROUP {
        // ω × u, then ω × (ω × u).
        let (p, q, s) = (
            wy[l] * uz[l] - wz[l] * uy[l],
            wz[l] * ux[l] - wx[l] * uz[l],
            wx[l] * uy[l] - wy[l] * ux[l],
        );
        v[0][l] = p;
        v[1][l] = q;
        v[2][l] = s;
        v[3][l] = wy[l] * s - wz[l] * q;
        v[4][l] = wz[l] * p - wx[l] * s;
        v[5][l] = wx[l] * q - wy[l] * p;
    }
    for (l, o) in out.chunks_exact_mut(3).enumerate() {
        if t[l] < 0.25 {
            o[0] = (ux[l] + a1[l] * v[0][l] + b1[l] * v[3][l]) as f64;
            o[1] = (uy[l] + a1[l] * v[1][l] + b1[l] * v[4][l]) as f64;
            o[2] = (uz[l] + a1[l] * v[2][l] + b1[l] * v[5][l]) as f64;
        } else {
            // Large rotation: the closed form in f64.
            let omega = [wx[l] as f64, wy[l] as f64, wz[l] as f64];
            let u = [ux[l] as f64, uy[l] as f64, uz[l] as f64];
            o.copy_from_slice(&crate::warp::Warp::new(&omega).warp(&u));
        }
    }
}

#[inline(always)]
fn display_body<const FUSED: bool, D: RowEntry, T: RowEntry>(
    displacement: &[D],
    rotation: Option<&[T]>,
    r: usize,
    (xd, xr): (&[f32], &[f32]),
    out: &mut [f64],
) {
    if r == 0 {
        out.iter_mut().for_each(|v| *v = 0.0);
        return;
    }
    let block = 3 * GROUP * r;
    for (g, o) in out.chunks_mut(3 * GROUP).enumerate() {
        let u = accumulate::<3, FUSED, D>(&displacement[g * block..(g + 1) * block], xd);
        match rotation {
            Some(rot) => {
                let w = accumulate::<3, FUSED, T>(&rot[g * block..(g + 1) * block], xr);
                warp_group::<FUSED>(u, w, o);
            }
            None => {
                let [ux, uy, uz] = u;
                for (l, o) in o.chunks_exact_mut(3).enumerate() {
                    o.copy_from_slice(&[ux[l] as f64, uy[l] as f64, uz[l] as f64]);
                }
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn display_avx2<D: RowEntry, T: RowEntry>(
    displacement: &[D],
    rotation: Option<&[T]>,
    r: usize,
    x: (&[f32], &[f32]),
    out: &mut [f64],
) {
    display_body::<true, D, T>(displacement, rotation, r, x, out)
}

/// [`display_body`] with AVX2 + FMA when the CPU has them (one call per row-type pair).
#[inline(always)]
fn display_dispatch<D: RowEntry, T: RowEntry>(
    displacement: &[D],
    rotation: Option<&[T]>,
    r: usize,
    x: (&[f32], &[f32]),
    out: &mut [f64],
) {
    #[cfg(target_arch = "x86_64")]
    if has_avx2_fma() {
        // SAFETY: the CPU has AVX2 and FMA (checked just above).
        return unsafe { display_avx2(displacement, rotation, r, x, out) };
    }
    display_body::<false, D, T>(displacement, rotation, r, x, out)
}

/// How a displayed node set's rows of one kind are stored.
#[derive(Clone, Debug)]
pub(crate) enum Rows {
    /// All zero (rotation rows only): the warp is the identity and skipped.
    Zero,
    /// Single precision (x_k unscaled).
    Single(Vec<f32>),
    /// 16-bit fixed point: entry v stands for v · 2^(−e_k), e_k from [`fixed16_exponents`] of
    /// the row kind (the scale folded into the state operand).
    Fixed16(Vec<i16>),
}

/// One displayed node set's rows grouped by 8 nodes, so that one state entry multiplies 3 × 8
/// contiguous values per row kind (no horizontal sums; the warp runs on 8 nodes at once):
/// ⌈n/8⌉ groups of r × 3 × 8; entry ((g·r + k)·3 + c)·8 + l is column k of row c (x, y, z) of
/// node 8g + l (zero for padding nodes).
#[derive(Clone, Debug)]
pub(crate) struct DisplayRows {
    /// The state dimension r.
    pub(crate) r: usize,
    /// Displacement rows C_i (single precision or 16-bit, never [`Rows::Zero`]).
    pub(crate) displacement: Rows,
    /// Rotation rows W_i.
    pub(crate) rotation: Rows,
}

/// Largest magnitude of a 16-bit entry.
const FIXED16_MAX: f64 = 32767.0;

/// Per column k: the exponent e_k of 16-bit rows, the largest integer with
/// max_i |W_ik| · 2^e_k ≤ 32767 (`columns_max[k]` = that maximum; 0 for a zero column). The
/// rounding error of an entry is then at most 2^(−e_k−1) ≤ max_i |W_ik| / 32767.
pub(crate) fn fixed16_exponents(columns_max: &[f64]) -> Vec<i32> {
    columns_max
        .iter()
        .map(|&m| {
            if m > 0.0 && m.is_finite() {
                let mut e = (FIXED16_MAX / m).log2().floor().clamp(-100.0, 100.0) as i32;
                while e > -100 && m * 2f64.powi(e) > FIXED16_MAX {
                    e -= 1;
                }
                e
            } else {
                0
            }
        })
        .collect()
}

/// The 16-bit exponents of a [`DisplayRows`] set: per state index, for the displacement rows
/// and for the rotation rows ([`fixed16_exponents`]); `None` stores that kind in single
/// precision.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Fixed16<'a> {
    pub(crate) displacement: Option<&'a [i32]>,
    pub(crate) rotation: Option<&'a [i32]>,
}

impl DisplayRows {
    /// The grouped rows of n nodes: `displacement(i)` and `rotation(i)` give the r-vectors of
    /// row i (3 per node, components x, y, z); rotation rows all zero (`warped` false) are not
    /// stored; each kind in 16 bits where `fixed16` gives its exponents.
    pub(crate) fn new<'a>(
        n: usize,
        r: usize,
        displacement: impl Fn(usize) -> &'a [f64],
        rotation: impl Fn(usize) -> &'a [f64],
        warped: bool,
        fixed16: Fixed16<'_>,
    ) -> Self {
        let len = n.div_ceil(GROUP) * r * 3 * GROUP;
        let at = |i: usize, c: usize, k: usize| {
            let (g, lane) = (i / GROUP, i % GROUP);
            ((g * r + k) * 3 + c) * GROUP + lane
        };
        let store = |row: &dyn Fn(usize) -> &'a [f64], exponents: Option<&[i32]>| match exponents {
            None => {
                let mut v = vec![0.0f32; len];
                for i in 0..n {
                    for c in 0..3 {
                        for (k, &value) in row(3 * i + c)[..r].iter().enumerate() {
                            v[at(i, c, k)] = value as f32;
                        }
                    }
                }
                Rows::Single(v)
            }
            Some(e) => {
                let mut v = vec![0i16; len];
                for i in 0..n {
                    for c in 0..3 {
                        for (k, &value) in row(3 * i + c)[..r].iter().enumerate() {
                            let q = (value * 2f64.powi(e[k])).round();
                            v[at(i, c, k)] = q.clamp(-FIXED16_MAX, FIXED16_MAX) as i16;
                        }
                    }
                }
                Rows::Fixed16(v)
            }
        };
        DisplayRows {
            r,
            displacement: store(&displacement, fixed16.displacement),
            rotation: if warped {
                store(&rotation, fixed16.rotation)
            } else {
                Rows::Zero
            },
        }
    }
}

/// World displacements of the nodes of `rows` (`out`: 3 f64 per node, at most 8 per group):
/// per node u = C_i x and ω = W_i x accumulated in f32, then R̃(ω) u (`docs/design.md` §5) in
/// f32 for θ < 1/2 (four-term series) and in f64 otherwise. `x` holds 3r values: x in f32,
/// then x_k · 2^(−e_k) with the exponents of 16-bit displacement rows, then with those of
/// 16-bit rotation rows (the rows' scales folded into the state operand; single-precision rows
/// use x itself).
#[inline]
pub(crate) fn display(rows: &DisplayRows, x: &[f32], out: &mut [f64]) {
    let r = rows.r;
    let (plain, x_displacement, x_rotation) = (&x[..r], &x[r..2 * r], &x[2 * r..3 * r]);
    macro_rules! rotation {
        ($d:expr, $xd:expr) => {
            match &rows.rotation {
                Rows::Zero => display_dispatch::<_, f32>($d, None, r, ($xd, plain), out),
                Rows::Single(w) => display_dispatch($d, Some(&w[..]), r, ($xd, plain), out),
                Rows::Fixed16(w) => display_dispatch($d, Some(&w[..]), r, ($xd, x_rotation), out),
            }
        };
    }
    match &rows.displacement {
        Rows::Single(d) => rotation!(&d[..], plain),
        Rows::Fixed16(d) => rotation!(&d[..], x_displacement),
        // Not built by `DisplayRows::new`: every displayed node has displacement rows.
        Rows::Zero => out.iter_mut().for_each(|v| *v = 0.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// y = A x by the textbook double loop (A row-major).
    fn reference(a: &[f64], rows: usize, cols: usize, x: &[f64]) -> Vec<f64> {
        (0..rows)
            .map(|i| (0..cols).map(|j| a[i * cols + j] * x[j]).sum())
            .collect()
    }

    #[test]
    fn rows3_matches_the_double_loop_on_every_path() {
        // Column counts below, at and past the 8-wide chunks, with and without a tail.
        let mut seed = 7u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for cols in [0, 1, 7, 8, 9, 16, 45, 96, 97] {
            let a: Vec<f64> = (0..3 * cols).map(|_| next()).collect();
            let x: Vec<f64> = (0..cols + 2).map(|_| next()).collect();
            let want = reference(&a, 3, cols, &x[..cols]);
            let portable = rows3_portable(&a, cols, &x);
            let dispatched = rows3(&a, cols, &x);
            for k in 0..3 {
                assert!(
                    (portable[k] - want[k]).abs() < 1e-14,
                    "portable {cols} row {k}"
                );
                assert!(
                    (dispatched[k] - want[k]).abs() < 1e-14,
                    "dispatched {cols} row {k}"
                );
            }
            #[cfg(target_arch = "x86_64")]
            if has_avx2_fma() {
                // SAFETY: checked just above.
                let avx2 = unsafe { avx2_rows3::rows3(&a, cols, &x) };
                for k in 0..3 {
                    assert!((avx2[k] - want[k]).abs() < 1e-14, "avx2 {cols} row {k}");
                }
            }
        }
    }

    #[test]
    fn matvec_t_matches_the_double_loop_for_every_block_shape() {
        // Rows 0..=37 cover full 16-row blocks, the 1-, 2- and 3-vector tails and partly
        // filled last vectors; odd and even column counts cover the unpaired last column.
        let mut seed = 1u64;
        let mut next = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for rows in 0..=37 {
            for cols in [0, 1, 2, 5, 8] {
                let a: Vec<f64> = (0..rows * cols).map(|_| next()).collect();
                let x: Vec<f64> = (0..cols).map(|_| next()).collect();
                let y0: Vec<f64> = (0..rows).map(|_| next()).collect();
                let m = Columns::from_row_major(&a, rows, cols);
                let want = reference(&a, rows, cols, &x);
                let mut y = y0.clone();
                matvec_t(&m, &x, &mut y, false);
                let mut y_add = y0.clone();
                matvec_t(&m, &x, &mut y_add, true);
                let mut y_portable = y0.clone();
                matvec_t_portable(&m, &x, &mut y_portable, true);
                for i in 0..rows {
                    assert!((y[i] - want[i]).abs() < 1e-14, "{rows}×{cols} row {i}");
                    assert!(
                        (y_add[i] - y0[i] - want[i]).abs() < 1e-14,
                        "{rows}×{cols} add"
                    );
                    assert!((y_portable[i] - y0[i] - want[i]).abs() < 1e-14, "portable");
                }
            }
        }
    }
}
