// Over 800 lines, one job: the packed kernel is 510 lines; the rest is its tests against the scalar kernel.
//! The reduced element force of [`crate::gather`], [`crate::polar_rotation`] and
//! [`crate::scatter`] over many sampled elements at once (docs/design.md §10): the elements
//! packed by [`LANES`] into blocks, structure of arrays (entry k of element l of a block at
//! `8k + l`), so that every product of the force runs across 8 elements in one SIMD register
//! (AVX-512: one instruction per product for 8 elements; AVX2: two) and the polar
//! decompositions of 8 elements share one latency chain (the kernel's lane-wise polar decomposition).
//!
//! Per block, with `fma(a, b, c)` = a·b + c (fused with AVX2/AVX-512):
//! ```text
//! u = V_e q, v = V_e q̇                  12 rows, summed over the r columns in order
//! x = X + u,  F = Σₐ xₐ ⊗ ∇Nₐ,  R = polar(F)        (lane-wise the scalar kernel's operations)
//! local = Rᵀ(xₐ − x₀) − (Xₐ − X₀) + β Rᵀ vₐ,  z = Kₑ local,  force = wₑ R z
//! acc[j] += Σᵢ V_e[i][j] forceᵢ          per lane; out[j] = Σ_lanes acc[j] at the end
//! ```
//! Without fused multiply–adds (the portable path) every element's force is bit-for-bit the
//! scalar kernel's; only the sum over elements into `out` runs in another order (per lane, then
//! across lanes). With them, each product of the gather, Kₑ local and the scatter rounds once
//! instead of twice. Either way the difference from the scalar kernel is round-off
//! (asserted in the tests below: ≤ 1e-13 of the largest element force term; rotations within
//! 1e-14, bit for bit on the portable path: the polar decomposition itself is never fused).

use crate::lanes::{polar_rotations, Mat3S};
use crate::simd::{Lanes8, Simd};
use crate::{Element, Mat3, PolarError};

/// Elements per block (f64 lanes of one AVX-512 register).
pub const LANES: usize = 8;

// Entry offsets within a block (one entry = LANES values).
const WEIGHT: usize = 0;
const REST: usize = 1;
const REST_DIFF: usize = REST + 12;
const GRADIENTS: usize = REST_DIFF + 12;
const STIFFNESS: usize = GRADIENTS + 12;
const COLUMNS: usize = STIFFNESS + 144;

/// An instruction set the blocked kernels run on, held only where this CPU has it: a value
/// comes from [`Isa::best`], [`Isa::available`] or [`Isa::portable`], so passing one to
/// [`Blocks::reduced_force`] or [`Blocks::add_warped_tangent`] is always safe. The
/// plain methods use [`Isa::best`]; the `_on` forms let a benchmark or a test run each path
/// on the same machine.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Isa(Path);

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Path {
    Portable,
    #[cfg(target_arch = "x86_64")]
    Avx2,
    #[cfg(target_arch = "x86_64")]
    Avx512,
}

impl Isa {
    /// The portable lanes (no CPU feature; each element's force bit for bit the scalar
    /// kernel's).
    pub fn portable() -> Self {
        Isa(Path::Portable)
    }

    /// AVX2 + FMA, where the CPU has them.
    pub fn avx2() -> Option<Self> {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            return Some(Isa(Path::Avx2));
        }
        None
    }

    /// AVX-512F, where the CPU has it (it implies AVX2 and FMA).
    pub fn avx512() -> Option<Self> {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx512f") {
            return Some(Isa(Path::Avx512));
        }
        None
    }

    /// Every path this CPU runs, portable first, the fastest last.
    pub fn available() -> Vec<Self> {
        std::iter::once(Isa::portable())
            .chain(Isa::avx2())
            .chain(Isa::avx512())
            .collect()
    }

    /// The fastest path this CPU runs (AVX-512, else AVX2 + FMA, else portable).
    pub fn best() -> Self {
        Isa::avx512()
            .or_else(Isa::avx2)
            .unwrap_or_else(Isa::portable)
    }

    /// Runs `f` inside a function compiled for this path's instructions, so that LLVM may
    /// vectorise `f`'s loops (once inlined there) for them; the arithmetic of `f` is unchanged
    /// except as vectorisation orders it. For plain loops outside the kernel (the runtime's
    /// covariance recursion); the blocked kernels choose their lanes themselves.
    #[inline(always)]
    pub fn dispatch<R>(self, f: impl FnOnce() -> R) -> R {
        match self.0 {
            Path::Portable => f(),
            // SAFETY: an `Isa` holds AVX2 only where the CPU has AVX2 and FMA.
            #[cfg(target_arch = "x86_64")]
            Path::Avx2 => unsafe { with_avx2(f) },
            // SAFETY: an `Isa` holds AVX-512 only where the CPU has AVX-512F.
            #[cfg(target_arch = "x86_64")]
            Path::Avx512 => unsafe { with_avx512(f) },
        }
    }

    /// "portable", "avx2" or "avx512".
    pub fn name(self) -> &'static str {
        match self.0 {
            Path::Portable => "portable",
            #[cfg(target_arch = "x86_64")]
            Path::Avx2 => "avx2",
            #[cfg(target_arch = "x86_64")]
            Path::Avx512 => "avx512",
        }
    }
}

/// The sampled elements of a reduced model, packed by [`LANES`] (module docs). Padding lanes
/// of the last block hold a unit tetrahedron with zero weight, stiffness and basis rows: F = I,
/// no force. There is no empty default: build it with [`Blocks::new`].
#[derive(Clone, Debug)]
pub struct Blocks {
    r: usize,
    count: usize,
    /// Entries per block: `COLUMNS + 12 r`.
    entries: usize,
    data: Vec<f64>,
}

impl Blocks {
    /// Packs `elements` (all with r = `rows.len() / 12` columns; their `cols` are not read).
    /// Kₑ must be symmetric (the force and the tangent both multiply by Kₑᵀ; the model
    /// validator checks it).
    ///
    /// Panics if the elements have different orders or a stiffness is not 12 × 12.
    pub fn new(elements: &[Element]) -> Self {
        let r = elements.first().map_or(0, |e| e.rows.len() / 12);
        let entries = COLUMNS + 12 * r;
        let blocks = elements.len().div_ceil(LANES);
        let mut data = vec![0.0; blocks * entries * LANES];
        let unit_rest = [[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let unit_gradients = [
            [-1.0, -1.0, -1.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
        ];
        for slot in 0..blocks * LANES {
            let (b, l) = (slot / LANES, slot % LANES);
            let mut put =
                |entry: usize, value: f64| data[(b * entries + entry) * LANES + l] = value;
            let (rest, gradients) = match elements.get(slot) {
                Some(e) => {
                    assert_eq!(e.rows.len(), 12 * r, "elements of different orders");
                    assert_eq!(e.stiffness.len(), 144, "Kₑ must have 12 × 12 entries");
                    put(WEIGHT, e.weight);
                    for (k, &s) in e.stiffness.iter().enumerate() {
                        put(STIFFNESS + k, s);
                    }
                    for i in 0..12 {
                        for j in 0..r {
                            put(COLUMNS + 12 * j + i, e.rows[r * i + j]);
                        }
                    }
                    (*e.rest, *e.gradients)
                }
                None => (unit_rest, unit_gradients),
            };
            for a in 0..4 {
                for c in 0..3 {
                    put(REST + 3 * a + c, rest[a][c]);
                    put(REST_DIFF + 3 * a + c, rest[a][c] - rest[0][c]);
                    put(GRADIENTS + 3 * a + c, gradients[a][c]);
                }
            }
        }
        Blocks {
            r,
            count: elements.len(),
            entries,
            data,
        }
    }

    /// Basis size r.
    pub fn order(&self) -> usize {
        self.r
    }

    /// Number of elements.
    pub fn len(&self) -> usize {
        self.count
    }

    /// True without elements.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Length of the scratch [`Blocks::reduced_force`] needs: `LANES · r`.
    pub fn scratch_len(&self) -> usize {
        LANES * self.r
    }

    /// `out` (r) = Σₑ wₑ V_eᵀ Rₑ Kₑ (yₑ + β Rₑᵀ V_e q̇) at `q`, `velocity` (r each) over all
    /// elements (the sum of [`crate::add_reduced_force`] over them, to round-off: module
    /// docs), `rotations[e]` = Rₑ; `scratch` of [`Blocks::scratch_len`], on the path `isa`
    /// (the fastest: [`Isa::best`]). On an element the polar decomposition refuses, returns the
    /// first such element (index, cause), `out` and `rotations` then unspecified.
    #[allow(clippy::too_many_arguments)]
    pub fn reduced_force(
        &self,
        isa: Isa,
        q: &[f64],
        velocity: &[f64],
        beta: f64,
        out: &mut [f64],
        rotations: &mut [Mat3],
        scratch: &mut [f64],
    ) -> Result<(), (usize, PolarError)> {
        let r = self.r;
        assert!(
            q.len() >= r
                && velocity.len() >= r
                && out.len() == r
                && rotations.len() >= self.count
                && scratch.len() >= LANES * r,
            "Blocks::reduced_force: lengths"
        );
        match isa.0 {
            // SAFETY: the portable lanes use no CPU feature.
            Path::Portable => unsafe {
                forces::<Lanes8>(self, q, velocity, beta, out, rotations, scratch)
            },
            // SAFETY: an `Isa` holds AVX2 only where the CPU has AVX2 and FMA.
            #[cfg(target_arch = "x86_64")]
            Path::Avx2 => unsafe { forces_avx2(self, q, velocity, beta, out, rotations, scratch) },
            // SAFETY: an `Isa` holds AVX-512 only where the CPU has AVX-512F.
            #[cfg(target_arch = "x86_64")]
            Path::Avx512 => unsafe {
                forces_avx512(self, q, velocity, beta, out, rotations, scratch)
            },
        }
    }

    /// Length of the scratch [`Blocks::add_warped_tangent`] needs:
    /// `LANES · (r(r + 1)/2 + 12 r)`.
    pub fn tangent_scratch_len(&self) -> usize {
        LANES * (self.r * (self.r + 1) / 2 + 12 * self.r)
    }

    /// Adds `scale` · Σₑ wₑ V_eᵀ Rₑ Kₑ Rₑᵀ V_e to `out` (r×r row-major), both triangles with
    /// the same value (the sum of the scalar kernel's warped tangent over the elements, to
    /// round-off, symmetric by construction), with `rotations[e]` = Rₑ; `scratch` of
    /// [`Blocks::tangent_scratch_len`]; on the path `isa`. Per block and lane: A = Rᵀ V_e,
    /// B = Kₑ A, C = wₑ R B (12 × r), then the upper triangle of V_eᵀ C accumulated per lane.
    pub fn add_warped_tangent(
        &self,
        isa: Isa,
        rotations: &[Mat3],
        scale: f64,
        out: &mut [f64],
        scratch: &mut [f64],
    ) {
        let r = self.r;
        assert!(
            rotations.len() >= self.count
                && out.len() == r * r
                && scratch.len() >= self.tangent_scratch_len(),
            "Blocks::add_warped_tangent: lengths"
        );
        match isa.0 {
            // SAFETY: the portable lanes use no CPU feature.
            Path::Portable => unsafe { tangent::<Lanes8>(self, rotations, scale, out, scratch) },
            // SAFETY: an `Isa` holds AVX2 only where the CPU has AVX2 and FMA.
            #[cfg(target_arch = "x86_64")]
            Path::Avx2 => unsafe { tangent_avx2(self, rotations, scale, out, scratch) },
            // SAFETY: an `Isa` holds AVX-512 only where the CPU has AVX-512F.
            #[cfg(target_arch = "x86_64")]
            Path::Avx512 => unsafe { tangent_avx512(self, rotations, scale, out, scratch) },
        }
    }
}

/// `f()` compiled with AVX2 and FMA ([`Isa::dispatch`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn with_avx2<R>(f: impl FnOnce() -> R) -> R {
    f()
}

/// `f()` compiled with AVX-512F ([`Isa::dispatch`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma")]
fn with_avx512<R>(f: impl FnOnce() -> R) -> R {
    f()
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma")]
fn tangent_avx512(
    b: &Blocks,
    rotations: &[Mat3],
    scale: f64,
    out: &mut [f64],
    scratch: &mut [f64],
) {
    // SAFETY: this function is compiled with AVX-512F, AVX2 and FMA enabled and called only
    // after they were detected.
    unsafe { tangent::<crate::simd::Avx512>(b, rotations, scale, out, scratch) }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn tangent_avx2(b: &Blocks, rotations: &[Mat3], scale: f64, out: &mut [f64], scratch: &mut [f64]) {
    // SAFETY: compiled with AVX2 and FMA, called only after they were detected.
    unsafe { tangent::<crate::simd::Avx2>(b, rotations, scale, out, scratch) }
}

/// The tangent of [`Blocks::add_warped_tangent`] on lanes `S`.
///
/// # Safety
/// The CPU must support the instructions of `S` (`Avx512`: AVX-512F; `Avx2`: AVX2 and FMA;
/// `Lanes8`: none), e.g. called from a function compiled with those features after
/// detecting them.
#[inline(always)]
unsafe fn tangent<S: Simd>(
    b: &Blocks,
    rotations: &[Mat3],
    scale: f64,
    out: &mut [f64],
    scratch: &mut [f64],
) {
    let r = b.r;
    let pairs = r * (r + 1) / 2;
    let (acc, c_buf) = scratch.split_at_mut(LANES * pairs);
    let c_buf = &mut c_buf[..12 * r * LANES];
    acc.iter_mut().for_each(|v| *v = 0.0);
    let zero = S::splat(0.0);
    for (bi, block) in b.data.chunks_exact(b.entries * LANES).enumerate() {
        // Each lane's rotation (the identity on padding lanes: their rows are zero).
        let mut lanes = [[[0.0; LANES]; 3]; 3];
        for l in 0..LANES {
            let e = bi * LANES + l;
            let rot = if e < b.count {
                &rotations[e]
            } else {
                &crate::IDENTITY
            };
            for i in 0..3 {
                for j in 0..3 {
                    lanes[i][j][l] = rot[i][j];
                }
            }
        }
        let mut rot: Mat3S<S> = [[zero; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                rot[i][j] = S::load(&lanes[i][j]);
            }
        }
        let w = S::splat(scale) * at::<S>(block, WEIGHT);
        let columns = &block[COLUMNS * LANES..(COLUMNS + 12 * r) * LANES];
        // C_j = w R Kₑ Rᵀ V_e[·, j], column by column.
        for (col, c_out) in columns
            .chunks_exact(12 * LANES)
            .zip(c_buf.chunks_exact_mut(12 * LANES))
        {
            let mut a = [zero; 12];
            for n in 0..4 {
                let v = [
                    S::load(&col[3 * n * LANES..]),
                    S::load(&col[(3 * n + 1) * LANES..]),
                    S::load(&col[(3 * n + 2) * LANES..]),
                ];
                for c in 0..3 {
                    a[3 * n + c] = rot[0][c] * v[0] + rot[1][c] * v[1] + rot[2][c] * v[2];
                }
            }
            let mut z = [zero; 12];
            for j in 0..12 {
                for i in 0..12 {
                    z[i] = at::<S>(block, STIFFNESS + 12 * j + i).mul_add(a[j], z[i]);
                }
            }
            for n in 0..4 {
                for c in 0..3 {
                    let v =
                        rot[c][0] * z[3 * n] + rot[c][1] * z[3 * n + 1] + rot[c][2] * z[3 * n + 2];
                    (w * v).store(&mut c_out[(3 * n + c) * LANES..]);
                }
            }
        }
        // acc[p, q] += Σᵢ V_e[i][p] C[i][q] for q ≥ p, per lane.
        let mut k = 0;
        for p in 0..r {
            let vp: [S; 12] = {
                let mut v = [zero; 12];
                for (i, vi) in v.iter_mut().enumerate() {
                    *vi = S::load(&columns[(12 * p + i) * LANES..]);
                }
                v
            };
            for q in p..r {
                let cq = &c_buf[12 * q * LANES..];
                let mut s = S::load(&acc[k * LANES..]);
                for i in 0..12 {
                    s = vp[i].mul_add(S::load(&cq[i * LANES..]), s);
                }
                s.store(&mut acc[k * LANES..]);
                k += 1;
            }
        }
    }
    let mut k = 0;
    for p in 0..r {
        for q in p..r {
            let v = S::load(&acc[k * LANES..]).sum();
            out[p * r + q] += v;
            if q != p {
                out[q * r + p] += v;
            }
            k += 1;
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma")]
fn forces_avx512(
    b: &Blocks,
    q: &[f64],
    velocity: &[f64],
    beta: f64,
    out: &mut [f64],
    rotations: &mut [Mat3],
    scratch: &mut [f64],
) -> Result<(), (usize, PolarError)> {
    // SAFETY: this function is compiled with AVX-512F, AVX2 and FMA enabled and called only
    // after they were detected.
    unsafe { forces::<crate::simd::Avx512>(b, q, velocity, beta, out, rotations, scratch) }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn forces_avx2(
    b: &Blocks,
    q: &[f64],
    velocity: &[f64],
    beta: f64,
    out: &mut [f64],
    rotations: &mut [Mat3],
    scratch: &mut [f64],
) -> Result<(), (usize, PolarError)> {
    // SAFETY: compiled with AVX2 and FMA, called only after they were detected.
    unsafe { forces::<crate::simd::Avx2>(b, q, velocity, beta, out, rotations, scratch) }
}

/// The force of [`Blocks::reduced_force`] on lanes `S`.
///
/// # Safety
/// As [`tangent`]: the CPU must support the instructions of `S`.
#[inline(always)]
unsafe fn forces<S: Simd>(
    b: &Blocks,
    q: &[f64],
    velocity: &[f64],
    beta: f64,
    out: &mut [f64],
    rotations: &mut [Mat3],
    scratch: &mut [f64],
) -> Result<(), (usize, PolarError)> {
    const { assert!(S::LANES == LANES) };
    let r = b.r;
    let acc = &mut scratch[..LANES * r];
    acc.iter_mut().for_each(|v| *v = 0.0);
    for (bi, block) in b.data.chunks_exact(b.entries * LANES).enumerate() {
        let (rot, status) = block_force::<S>(block, r, q, velocity, beta, acc);
        let first = bi * LANES;
        let used = b.count.saturating_sub(first).min(LANES);
        let mut lanes = [[[0.0; LANES]; 3]; 3];
        for i in 0..3 {
            for j in 0..3 {
                rot[i][j].store(&mut lanes[i][j]);
            }
        }
        for l in 0..used {
            if let Err(e) = status[l] {
                return Err((first + l, e));
            }
            rotations[first + l] = std::array::from_fn(|i| std::array::from_fn(|j| lanes[i][j][l]));
        }
    }
    for (o, a) in out.iter_mut().zip(acc.chunks_exact(LANES)) {
        *o = S::load(a).sum();
    }
    Ok(())
}

/// Entry k of a block (its LANES values).
#[inline(always)]
fn at<S: Simd>(block: &[f64], k: usize) -> S {
    S::load(&block[k * LANES..(k + 1) * LANES])
}

/// One block: each lane's force scattered into its lane of `acc` (r × LANES, column j at
/// `acc[LANES j ..]`); returns the rotations and each lane's outcome.
#[inline(always)]
fn block_force<S: Simd>(
    block: &[f64],
    r: usize,
    q: &[f64],
    velocity: &[f64],
    beta: f64,
    acc: &mut [f64],
) -> (Mat3S<S>, [Result<(), PolarError>; 8]) {
    let at = |k: usize| at::<S>(block, k);
    let zero = S::splat(0.0);
    // u = V_e q, v = V_e q̇ (12 rows per lane), GATHER_ROWS rows at a time over all columns.
    let mut u = [zero; 12];
    let mut v = [zero; 12];
    let columns = &block[COLUMNS * LANES..(COLUMNS + 12 * r) * LANES];
    const { assert!(12 % S::GATHER_ROWS == 0 && 12 % S::SCATTER_ROWS == 0) };
    let rows = S::GATHER_ROWS;
    for first in (0..12).step_by(rows) {
        let mut uc = [zero; 12];
        let mut vc = [zero; 12];
        for (j, col) in columns.chunks_exact(12 * LANES).enumerate() {
            let (qj, vj) = (S::splat(q[j]), S::splat(velocity[j]));
            for k in 0..rows {
                let c = S::load(&col[(first + k) * LANES..]);
                uc[k] = c.mul_add(qj, uc[k]);
                vc[k] = c.mul_add(vj, vc[k]);
            }
        }
        u[first..first + rows].copy_from_slice(&uc[..rows]);
        v[first..first + rows].copy_from_slice(&vc[..rows]);
    }
    // x = X + u, F = Σₐ xₐ ⊗ ∇Nₐ (the scalar gather's operations).
    let mut x = [[zero; 3]; 4];
    for a in 0..4 {
        for c in 0..3 {
            x[a][c] = at(REST + 3 * a + c) + u[3 * a + c];
        }
    }
    let mut rot: Mat3S<S> = [[zero; 3]; 3];
    for a in 0..4 {
        for i in 0..3 {
            for j in 0..3 {
                rot[i][j] = rot[i][j] + x[a][i] * at(GRADIENTS + 3 * a + j);
            }
        }
    }
    let status = polar_rotations(&mut rot);
    // local = Rᵀ(xₐ − x₀) − (Xₐ − X₀) + β Rᵀ vₐ (the scalar scatter's operations).
    let beta = S::splat(beta);
    let mut local = [zero; 12];
    for a in 0..4 {
        let d = [x[a][0] - x[0][0], x[a][1] - x[0][1], x[a][2] - x[0][2]];
        let vv = [v[3 * a], v[3 * a + 1], v[3 * a + 2]];
        for c in 0..3 {
            let p = rot[0][c] * d[0] + rot[1][c] * d[1] + rot[2][c] * d[2];
            let lv = rot[0][c] * vv[0] + rot[1][c] * vv[1] + rot[2][c] * vv[2];
            local[3 * a + c] = (p - at(REST_DIFF + 3 * a + c)) + beta * lv;
        }
    }
    // z = Kₑ local as Σ_j local_j Kₑ[j, ·] (Kₑ symmetric).
    let mut z = [zero; 12];
    const ROWS: usize = 3;
    for first in (0..12).step_by(ROWS) {
        let mut zc = [zero; ROWS];
        for j in 0..12 {
            for k in 0..ROWS {
                zc[k] = at(STIFFNESS + 12 * j + first + k).mul_add(local[j], zc[k]);
            }
        }
        z[first..first + ROWS].copy_from_slice(&zc);
    }
    // force = wₑ R z (per node).
    let w = at(WEIGHT);
    let mut force = [zero; 12];
    for a in 0..4 {
        for c in 0..3 {
            force[3 * a + c] =
                w * (rot[c][0] * z[3 * a] + rot[c][1] * z[3 * a + 1] + rot[c][2] * z[3 * a + 2]);
        }
    }
    // acc[j] += Σᵢ V_e[i][j] forceᵢ, per lane, in the order of i (SCATTER_ROWS rows per pass
    // over the columns).
    for first in (0..12).step_by(S::SCATTER_ROWS) {
        for (col, a) in columns
            .chunks_exact(12 * LANES)
            .zip(acc.chunks_exact_mut(LANES))
        {
            let mut s = S::load(a);
            for i in first..first + S::SCATTER_ROWS {
                s = S::load(&col[i * LANES..(i + 1) * LANES]).mul_add(force[i], s);
            }
            s.store(a);
        }
    }
    (rot, status)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{add_reduced_force, transpose_rows};

    /// SplitMix64 in [-0.5, 0.5).
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> f64 {
            self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        }
    }

    /// The polar iteration as it was before the lane version (session 5, verbatim but for
    /// the names; det and X⁻ᵀ are the crate's scalar test helpers, not the lane code): the lane
    /// version must reproduce it bit for bit.
    fn reference_polar(f: &Mat3) -> Result<Mat3, PolarError> {
        use crate::{det, inverse_transpose};
        fn norm(m: &Mat3) -> f64 {
            m.iter().flatten().map(|v| v * v).sum::<f64>().sqrt()
        }
        let n = norm(f);
        let d = det(f);
        if !(n.is_finite() && d.is_finite()) {
            return Err(PolarError::NoConvergence);
        }
        if d <= 1e-12 * n * n * n {
            return Err(PolarError::Inverted(d));
        }
        let mut x = *f;
        let mut scaled = true;
        for _ in 0..30 {
            let Some(inv_t) = inverse_transpose(&x) else {
                return Err(PolarError::NoConvergence);
            };
            let gamma = if scaled {
                (norm(&inv_t) / norm(&x)).sqrt()
            } else {
                1.0
            };
            let (a, b) = (0.5 * gamma, 0.5 / gamma);
            let mut change = 0.0;
            for i in 0..3 {
                for j in 0..3 {
                    let next = a * x[i][j] + b * inv_t[i][j];
                    change += (next - x[i][j]) * (next - x[i][j]);
                    x[i][j] = next;
                }
            }
            if change <= 1e-16 {
                return Ok(x);
            }
            scaled = change > 1e-4;
        }
        Err(PolarError::NoConvergence)
    }

    /// Random F: rotations of stretches from 1e-6 to 0.5, a few inverted, singular or
    /// non-finite ones.
    fn matrices(rng: &mut Rng, n: usize) -> Vec<Mat3> {
        (0..n)
            .map(|k| {
                let size = [1e-6, 1e-3, 0.05, 0.5, 3.0][k % 5];
                let mut f: Mat3 = std::array::from_fn(|i| {
                    std::array::from_fn(|j| (i == j) as u8 as f64 + size * rng.next())
                });
                match k % 23 {
                    7 => f[0] = [-f[0][0], -f[0][1], -f[0][2]],
                    11 => f[2] = f[1],
                    13 => f[1][1] = f64::NAN,
                    _ => {}
                }
                f
            })
            .collect()
    }

    /// The lane polar on one chunk of 8 matrices with lane type S: outcomes and matrices.
    #[inline(always)]
    fn lane_polar<S: Simd>(chunk: &[Mat3]) -> ([Result<(), PolarError>; 8], Vec<Mat3>) {
        let mut lanes = [[[0.0; 8]; 3]; 3];
        for (l, f) in chunk.iter().enumerate() {
            for i in 0..3 {
                for j in 0..3 {
                    lanes[i][j][l] = f[i][j];
                }
            }
        }
        let mut m: Mat3S<S> =
            std::array::from_fn(|i| std::array::from_fn(|j| S::load(&lanes[i][j])));
        let got = polar_rotations(&mut m);
        for i in 0..3 {
            for j in 0..3 {
                m[i][j].store(&mut lanes[i][j]);
            }
        }
        let mats = (0..8)
            .map(|l| std::array::from_fn(|i| std::array::from_fn(|j| lanes[i][j][l])))
            .collect();
        (got, mats)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    fn lane_polar_avx2(chunk: &[Mat3]) -> ([Result<(), PolarError>; 8], Vec<Mat3>) {
        lane_polar::<crate::simd::Avx2>(chunk)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    fn lane_polar_avx512(chunk: &[Mat3]) -> ([Result<(), PolarError>; 8], Vec<Mat3>) {
        lane_polar::<crate::simd::Avx512>(chunk)
    }

    /// The polar decomposition on 8 lanes (portable, and AVX-512 where the CPU has it) and on
    /// one (`polar_rotation`, the compiler's) against the iteration as it was: bit for bit.
    #[test]
    fn lane_polar_is_the_scalar_iteration_bit_for_bit() {
        let mut rng = Rng(3);
        let all = matrices(&mut rng, 8 * 40);
        let mut kinds = [0usize; 3];
        type Variant = fn(&[Mat3]) -> ([Result<(), PolarError>; 8], Vec<Mat3>);
        let mut variants: Vec<Variant> = vec![lane_polar::<Lanes8>];
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU has AVX2 and FMA (checked just above).
            variants.push(|c| unsafe { lane_polar_avx2(c) });
        }
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: the CPU has AVX-512F (checked just above).
            variants.push(|c| unsafe { lane_polar_avx512(c) });
        }
        for chunk in all.chunks_exact(8) {
            for variant in &variants {
                let (got, rot) = variant(chunk);
                for (l, f) in chunk.iter().enumerate() {
                    let want = reference_polar(f);
                    match (want, got[l]) {
                        (Ok(w), Ok(())) => {
                            kinds[0] += 1;
                            let bits = |m: &Mat3| m.map(|row| row.map(f64::to_bits));
                            assert_eq!(bits(&w), bits(&rot[l]));
                            assert_eq!(crate::polar_rotation(f).map(|m| bits(&m)), Ok(bits(&w)));
                        }
                        (Err(PolarError::Inverted(a)), Err(PolarError::Inverted(b))) => {
                            kinds[1] += 1;
                            assert_eq!(a.to_bits(), b.to_bits());
                            assert_eq!(crate::polar_rotation(f), Err(PolarError::Inverted(a)));
                        }
                        (Err(PolarError::NoConvergence), Err(PolarError::NoConvergence)) => {
                            kinds[2] += 1;
                            assert_eq!(crate::polar_rotation(f), Err(PolarError::NoConvergence));
                        }
                        (w, g) => panic!("lane {l}: scalar {w:?}, lanes {g:?}"),
                    }
                }
            }
        }
        // Every outcome occurred.
        assert!(kinds.iter().all(|&k| k > 0), "{kinds:?}");
    }

    struct Owned {
        weight: f64,
        rest: [[f64; 3]; 4],
        gradients: [[f64; 3]; 4],
        stiffness: Vec<f64>,
        rows: Vec<f64>,
        cols: Vec<f64>,
    }

    impl Owned {
        fn view(&self) -> Element<'_> {
            Element {
                weight: self.weight,
                rest: &self.rest,
                gradients: &self.gradients,
                stiffness: &self.stiffness,
                rows: &self.rows,
                cols: &self.cols,
            }
        }
    }

    /// `n` random tetrahedra (about 0.1 m, stiffness ~1e6 N/m, symmetric), r basis columns
    /// with some zero rows (fixed DOFs).
    fn elements(rng: &mut Rng, n: usize, r: usize) -> Vec<Owned> {
        (0..n)
            .map(|k| {
                let o = [rng.next(), rng.next(), rng.next()];
                let mut rest = [o; 4];
                for a in 1..4 {
                    rest[a][a - 1] += 0.1;
                    for c in 0..3 {
                        rest[a][c] += 0.02 * rng.next();
                    }
                }
                let d: Mat3 =
                    std::array::from_fn(|i| std::array::from_fn(|j| rest[j + 1][i] - rest[0][i]));
                let it = crate::inverse_transpose(&d).unwrap();
                let mut gradients = [[0.0; 3]; 4];
                for a in 1..4 {
                    for c in 0..3 {
                        gradients[a][c] = it[c][a - 1];
                        gradients[0][c] -= it[c][a - 1];
                    }
                }
                let half: Vec<f64> = (0..144).map(|_| 1e6 * rng.next()).collect();
                let stiffness = (0..144)
                    .map(|i| half[i] + half[(i % 12) * 12 + i / 12])
                    .collect();
                let rows: Vec<f64> = (0..12 * r)
                    .map(|i| {
                        if (i / r + k).is_multiple_of(7) {
                            0.0
                        } else {
                            rng.next()
                        }
                    })
                    .collect();
                let cols = transpose_rows(&rows);
                Owned {
                    weight: 1.0 + rng.next(),
                    rest,
                    gradients,
                    stiffness,
                    rows,
                    cols,
                }
            })
            .collect()
    }

    /// The blocked force against the scalar kernel summed element by element, to round-off.
    /// Portable path: rotations bit for bit (each element's force is the scalar one, only the
    /// order of the sum over elements differs); SIMD paths: the fused gather changes F, so
    /// the rotations too, at round-off.
    #[test]
    fn blocks_equal_the_scalar_kernel() {
        let mut rng = Rng(11);
        for (n, r) in [(1, 3), (8, 20), (21, 20), (17, 7)] {
            let owned = elements(&mut rng, n, r);
            let views: Vec<Element> = owned.iter().map(Owned::view).collect();
            let blocks = Blocks::new(&views);
            assert_eq!((blocks.len(), blocks.order()), (n, r));
            let q: Vec<f64> = (0..r).map(|_| 0.02 * rng.next()).collect();
            let velocity: Vec<f64> = (0..r).map(|_| rng.next()).collect();
            let beta = 1e-3;
            let mut want = vec![0.0; r];
            let mut want_rot = Vec::new();
            // Scale of the sum: the largest |term| of any element's contribution.
            let mut scale: f64 = 0.0;
            for e in &views {
                let mut one = vec![0.0; r];
                want_rot.push(add_reduced_force(e, &q, &velocity, beta, &mut one).unwrap());
                scale = one.iter().fold(scale, |m, v| m.max(v.abs()));
                want.iter_mut().zip(&one).for_each(|(w, o)| *w += o);
            }
            let mut scratch = vec![0.0; blocks.scratch_len()];
            // The fused paths (AVX2, AVX-512) run the same operations in the same order.
            let mut fused: Option<(Vec<f64>, Vec<Mat3>)> = None;
            for isa in Isa::available() {
                let (path, portable) = (isa.name(), isa == Isa::portable());
                let mut out = vec![0.0; r];
                let mut rot = vec![[[0.0; 3]; 3]; n];
                blocks
                    .reduced_force(isa, &q, &velocity, beta, &mut out, &mut rot, &mut scratch)
                    .unwrap();
                if portable {
                    assert_eq!(rot, want_rot, "rotations");
                } else if let Some((first_out, first_rot)) = &fused {
                    assert_eq!(
                        (first_out, first_rot),
                        (&out, &rot),
                        "{path} against the other fused path"
                    );
                } else {
                    fused = Some((out.clone(), rot.clone()));
                }
                if !portable {
                    let off = rot
                        .iter()
                        .flatten()
                        .flatten()
                        .zip(want_rot.iter().flatten().flatten());
                    let worst = off.fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
                    assert!(worst < 1e-14, "rotations differ by {worst:e}");
                }
                let worst = out
                    .iter()
                    .zip(&want)
                    .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
                eprintln!(
                    "n {n}, r {r}, {path}: {:.1e} of the largest term",
                    worst / scale
                );
                assert!(worst <= 1e-13 * scale, "{worst:e} vs {scale:e}");
            }
        }
    }

    /// The blocked warped tangent against the scalar kernel's, summed and symmetrised as the
    /// runtime did: to round-off, and exactly symmetric.
    #[test]
    fn blocked_tangent_equals_the_scalar_kernel() {
        let mut rng = Rng(17);
        for (n, r) in [(1, 3), (21, 20), (17, 7)] {
            let owned = elements(&mut rng, n, r);
            let views: Vec<Element> = owned.iter().map(Owned::view).collect();
            let blocks = Blocks::new(&views);
            let rotations: Vec<Mat3> = (0..n)
                .map(|_| {
                    let f: Mat3 = std::array::from_fn(|i| {
                        std::array::from_fn(|j| (i == j) as u8 as f64 + 0.4 * rng.next())
                    });
                    crate::polar_rotation(&f).unwrap()
                })
                .collect();
            let scale = 1.7;
            let mut want = vec![0.0; r * r];
            let mut tmp = vec![0.0; 24 * r];
            for (e, rot) in views.iter().zip(&rotations) {
                crate::add_warped_tangent(e, rot, scale, &mut tmp, &mut want);
            }
            let size = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            let mut scratch = vec![0.0; blocks.tangent_scratch_len()];
            for isa in Isa::available() {
                let path = isa.name();
                let mut got = vec![1.0; r * r];
                blocks.add_warped_tangent(isa, &rotations, scale, &mut got, &mut scratch);
                let mut worst: f64 = 0.0;
                for i in 0..r {
                    for j in 0..r {
                        assert_eq!(got[i * r + j], got[j * r + i]);
                        let sym = 0.5 * (want[i * r + j] + want[j * r + i]);
                        worst = worst.max((got[i * r + j] - 1.0 - sym).abs());
                    }
                }
                eprintln!("tangent n {n}, r {r}, {path}: {:.1e}", worst / size);
                assert!(worst <= 1e-13 * size, "{worst:e} vs {size:e}");
            }
        }
    }

    /// The first refused element is reported, as the scalar loop would.
    #[test]
    fn the_first_inverted_element_is_reported() {
        let mut rng = Rng(5);
        let mut owned = elements(&mut rng, 19, 4);
        for e in [12, 17] {
            owned[e].rest.swap(1, 2);
        }
        let views: Vec<Element> = owned.iter().map(Owned::view).collect();
        let blocks = Blocks::new(&views);
        let mut scratch = vec![0.0; blocks.scratch_len()];
        let (mut out, mut rot) = (vec![0.0; 4], vec![[[0.0; 3]; 3]; 19]);
        let got = blocks.reduced_force(
            Isa::best(),
            &[0.0; 4],
            &[0.0; 4],
            0.0,
            &mut out,
            &mut rot,
            &mut scratch,
        );
        assert!(matches!(got, Err((12, PolarError::Inverted(_)))), "{got:?}");
    }

    /// `Isa::dispatch` runs the closure once on every path this CPU has and returns its result;
    /// plain (non-reassociated, unfused) arithmetic in it gives the same bits on every path.
    #[test]
    fn dispatch_runs_the_closure_with_the_same_arithmetic_on_every_path() {
        let mut rng = Rng(3);
        let a: Vec<f64> = (0..1000).map(|_| rng.next()).collect();
        let b: Vec<f64> = (0..1000).map(|_| rng.next()).collect();
        let axpy = |out: &mut Vec<f64>| {
            for ((o, x), y) in out.iter_mut().zip(&a).zip(&b) {
                *o += x * y - 0.5 * x;
            }
            out.len()
        };
        let mut want = vec![1.0; 1000];
        axpy(&mut want);
        for isa in Isa::available() {
            let mut got = vec![1.0; 1000];
            let mut calls = 0;
            let len = isa.dispatch(|| {
                calls += 1;
                axpy(&mut got)
            });
            assert_eq!((len, calls), (1000, 1), "{}", isa.name());
            assert_eq!(got, want, "{}", isa.name());
        }
    }
}
