//! The runtime's two hot loops, written so that LLVM vectorises them, and compiled twice: for
//! the baseline target and with AVX2 + FMA, chosen at run time (`is_x86_feature_detected!`,
//! cached by std). No dependency: this is what `multiversion` would generate for two targets,
//! in twenty lines.
//!
//! - [`matvec_t`]: y = A x or y += A x from Aᵀ (f64; the step's F x, G u, K ν and the sensor
//!   and load rows), [`matvec`] from A row-major (the sensor read-outs);
//! - [`display`]: the displayed nodes' u = C_i x and ω = W_i x from f32 rows grouped by 8
//!   nodes, accumulated in f32, and the warp R̃(ω) u on 8 nodes at once (the read-out; the
//!   rounding it costs is measured in `tests/readout.rs`).

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

/// Rows per register block of [`matvec_t`] (four AVX2 registers of f64).
const BLOCK: usize = 16;

#[inline(always)]
fn matvec_t_body<const FUSED: bool>(at: &[f64], x: &[f64], y: &mut [f64], add: bool) {
    let rows = y.len();
    if rows == 0 {
        return;
    }
    let cols = x.len().min(at.len() / rows);
    let mut b = 0;
    while b + BLOCK <= rows {
        let mut acc = [0.0f64; BLOCK];
        if add {
            acc.copy_from_slice(&y[b..b + BLOCK]);
        }
        for (j, &xj) in x[..cols].iter().enumerate() {
            let col = &at[j * rows + b..j * rows + b + BLOCK];
            for l in 0..BLOCK {
                acc[l] = if FUSED {
                    col[l].mul_add(xj, acc[l])
                } else {
                    acc[l] + col[l] * xj
                };
            }
        }
        y[b..b + BLOCK].copy_from_slice(&acc);
        b += BLOCK;
    }
    if b < rows {
        let tail = &mut y[b..];
        if !add {
            tail.iter_mut().for_each(|v| *v = 0.0);
        }
        for (j, &xj) in x[..cols].iter().enumerate() {
            let col = &at[j * rows + b..(j + 1) * rows];
            for (t, &c) in tail.iter_mut().zip(col) {
                *t = if FUSED {
                    c.mul_add(xj, *t)
                } else {
                    *t + c * xj
                };
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn matvec_t_avx2(at: &[f64], x: &[f64], y: &mut [f64], add: bool) {
    matvec_t_body::<true>(at, x, y, add)
}

/// y = A x (`add` false) or y += A x with A given transposed: `at[j·rows + i]` = A_ij,
/// rows = `y.len()`, columns = `x.len()`. Column by column (y += x_j A_:j) with 16 rows of y
/// held in registers: no horizontal sums, one fused multiply–add per 4 products.
#[inline]
pub(crate) fn matvec_t(at: &[f64], x: &[f64], y: &mut [f64], add: bool) {
    #[cfg(target_arch = "x86_64")]
    if has_avx2_fma() {
        // SAFETY: the CPU has AVX2 and FMA (checked just above).
        return unsafe { matvec_t_avx2(at, x, y, add) };
    }
    matvec_t_body::<false>(at, x, y, add)
}

/// The transpose of a row-major `rows × cols` matrix, row-major (`cols × rows`).
pub(crate) fn transpose(a: &[f64], rows: usize, cols: usize) -> Vec<f64> {
    let mut t = vec![0.0; rows * cols];
    for i in 0..rows {
        for j in 0..cols {
            t[j * rows + i] = a[i * cols + j];
        }
    }
    t
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

#[inline(always)]
fn display_body<const FUSED: bool>(
    rows: &[f32],
    x: &[f32],
    r: usize,
    nodes: usize,
    warped: bool,
    out: &mut [f64],
) {
    if r == 0 {
        out.iter_mut().for_each(|v| *v = 0.0);
        return;
    }
    let x = &x[..r];
    for (g, block) in rows.chunks_exact(6 * GROUP * r).enumerate() {
        // acc[c][l]: component c (u_x, u_y, u_z, ω_x, ω_y, ω_z) of node 8g + l.
        let mut acc = [[0.0f32; GROUP]; 6];
        for (kb, &xk) in block.chunks_exact(6 * GROUP).zip(x) {
            for (c, a) in acc.iter_mut().enumerate() {
                let row = &kb[c * GROUP..(c + 1) * GROUP];
                for l in 0..GROUP {
                    a[l] = if FUSED {
                        row[l].mul_add(xk, a[l])
                    } else {
                        a[l] + row[l] * xk
                    };
                }
            }
        }
        let [ux, uy, uz, wx, wy, wz] = acc;
        let first = g * GROUP;
        let count = GROUP.min(nodes.saturating_sub(first));
        if !warped {
            for l in 0..count {
                let o = &mut out[3 * (first + l)..3 * (first + l) + 3];
                o.copy_from_slice(&[ux[l] as f64, uy[l] as f64, uz[l] as f64]);
            }
            continue;
        }
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
        let mut w = [[0.0f32; GROUP]; 6];
        for l in 0..GROUP {
            // ω × u, then ω × (ω × u).
            let (p, q, s) = (
                wy[l] * uz[l] - wz[l] * uy[l],
                wz[l] * ux[l] - wx[l] * uz[l],
                wx[l] * uy[l] - wy[l] * ux[l],
            );
            w[0][l] = p;
            w[1][l] = q;
            w[2][l] = s;
            w[3][l] = wy[l] * s - wz[l] * q;
            w[4][l] = wz[l] * p - wx[l] * s;
            w[5][l] = wx[l] * q - wy[l] * p;
        }
        for l in 0..count {
            let i = first + l;
            let o = &mut out[3 * i..3 * i + 3];
            if t[l] < 0.25 {
                o[0] = (ux[l] + a1[l] * w[0][l] + b1[l] * w[3][l]) as f64;
                o[1] = (uy[l] + a1[l] * w[1][l] + b1[l] * w[4][l]) as f64;
                o[2] = (uz[l] + a1[l] * w[2][l] + b1[l] * w[5][l]) as f64;
            } else {
                // Large rotation: the closed form in f64.
                let omega = [wx[l] as f64, wy[l] as f64, wz[l] as f64];
                let u = [ux[l] as f64, uy[l] as f64, uz[l] as f64];
                o.copy_from_slice(&crate::warp::Warp::new(&omega).warp(&u));
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn display_avx2(rows: &[f32], x: &[f32], r: usize, nodes: usize, warped: bool, out: &mut [f64]) {
    display_body::<true>(rows, x, r, nodes, warped, out)
}

/// World displacements of `nodes` nodes from the grouped f32 display rows (layout
/// `[group][k][component][lane]`, 6 × 8 values per state index and group): per node
/// u = C_i x, ω = W_i x accumulated in f32, then R̃(ω) u (`docs/design.md` §5) in f32 for
/// θ < 1/2 (four-term series) and in f64 otherwise; `out` gets 3 f64 per node.
#[inline]
pub(crate) fn display(
    rows: &[f32],
    x: &[f32],
    r: usize,
    nodes: usize,
    warped: bool,
    out: &mut [f64],
) {
    #[cfg(target_arch = "x86_64")]
    if has_avx2_fma() {
        // SAFETY: the CPU has AVX2 and FMA (checked just above).
        return unsafe { display_avx2(rows, x, r, nodes, warped, out) };
    }
    display_body::<false>(rows, x, r, nodes, warped, out)
}
