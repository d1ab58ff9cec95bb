//! The runtime's two hot loops, written so that LLVM vectorises them, and compiled twice: for
//! the baseline target and with AVX2 + FMA, chosen at run time (`is_x86_feature_detected!`,
//! cached by std). No dependency: this is what `multiversion` would generate for two targets,
//! in twenty lines.
//!
//! - [`matvec`]: y = A x or y += A x, A dense row-major (f64; the step's F x, G u, K ν and the
//!   sensor rows);
//! - [`display_blocks`]: for every node, the 6 dot products of its f32 row block
//!   [C_i; W_i] (6 × r̂) with the f32 state, accumulated in f32 (the read-out; the rounding it
//!   costs is measured in `tests/readout.rs`).

/// f32 lanes the display rows are padded to.
pub(crate) const LANES: usize = 8;

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

#[inline(always)]
fn blocks_body<const FUSED: bool, F: FnMut(usize, [f32; 6])>(
    rows: &[f32],
    x: &[f32],
    padded: usize,
    f: &mut F,
) {
    if padded == 0 {
        return;
    }
    let x = &x[..padded];
    for (i, block) in rows.chunks_exact(6 * padded).enumerate() {
        let mut acc = [[0.0f32; LANES]; 6];
        for (c, xc) in x.chunks_exact(LANES).enumerate() {
            for (k, a) in acc.iter_mut().enumerate() {
                let row = &block[k * padded + c * LANES..k * padded + (c + 1) * LANES];
                for l in 0..LANES {
                    a[l] = if FUSED {
                        row[l].mul_add(xc[l], a[l])
                    } else {
                        a[l] + row[l] * xc[l]
                    };
                }
            }
        }
        let sums = acc.map(|a| ((a[0] + a[4]) + (a[1] + a[5])) + ((a[2] + a[6]) + (a[3] + a[7])));
        f(i, sums);
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn blocks_avx2<F: FnMut(usize, [f32; 6])>(rows: &[f32], x: &[f32], padded: usize, f: &mut F) {
    blocks_body::<true, F>(rows, x, padded, f)
}

/// For node block i of `rows` (6 × `padded` f32 each), calls `f(i, [C_i x; W_i x])` with the
/// dot products accumulated in f32. `x.len() ≥ padded`, `padded` a multiple of [`LANES`].
#[inline]
pub(crate) fn display_blocks<F: FnMut(usize, [f32; 6])>(
    rows: &[f32],
    x: &[f32],
    padded: usize,
    mut f: F,
) {
    #[cfg(target_arch = "x86_64")]
    if has_avx2_fma() {
        // SAFETY: the CPU has AVX2 and FMA (checked just above).
        return unsafe { blocks_avx2(rows, x, padded, &mut f) };
    }
    blocks_body::<false, F>(rows, x, padded, &mut f)
}
