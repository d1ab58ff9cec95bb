//! The polar rotation of several deformation gradients at once, one per SIMD lane: the
//! iteration of [`crate::polar_rotation`] (which is this function on one lane, `f64`, so
//! there is one copy of it). Every lane runs exactly the scalar sequence of IEEE operations
//! (no fused multiply–adds, correctly rounded division and square root), so each lane's
//! result is bit-for-bit the scalar one whatever the lane type. A lane stops where the scalar
//! iteration would (its own test, its own error); the others go on.

use crate::simd::Simd;
use crate::PolarError;

/// A 3×3 matrix per lane: `m[i][j]` holds entry (i, j) of every lane's matrix.
pub(crate) type Mat3S<S> = [[S; 3]; 3];

#[inline(always)]
fn det<S: Simd>(m: &Mat3S<S>) -> S {
    m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
}

/// ‖m‖_F: the nine squares summed in row-major order.
#[inline(always)]
fn norm<S: Simd>(m: &Mat3S<S>) -> S {
    let mut s = m[0][0] * m[0][0];
    for k in 1..9 {
        let v = m[k / 3][k % 3];
        s = s + v * v;
    }
    s.sqrt()
}

/// The cofactor matrix times `inv` (X⁻ᵀ when inv = 1/det X).
#[inline(always)]
fn cofactors<S: Simd>(m: &Mat3S<S>, inv: S) -> Mat3S<S> {
    [
        [
            (m[1][1] * m[2][2] - m[1][2] * m[2][1]) * inv,
            (m[1][2] * m[2][0] - m[1][0] * m[2][2]) * inv,
            (m[1][0] * m[2][1] - m[1][1] * m[2][0]) * inv,
        ],
        [
            (m[0][2] * m[2][1] - m[0][1] * m[2][2]) * inv,
            (m[0][0] * m[2][2] - m[0][2] * m[2][0]) * inv,
            (m[0][1] * m[2][0] - m[0][0] * m[2][1]) * inv,
        ],
        [
            (m[0][1] * m[1][2] - m[0][2] * m[1][1]) * inv,
            (m[0][2] * m[1][0] - m[0][0] * m[1][2]) * inv,
            (m[0][0] * m[1][1] - m[0][1] * m[1][0]) * inv,
        ],
    ]
}

/// The rotation R of F = R S for each lane's F, in place of `f` (see
/// [`crate::polar_rotation`] for the iteration, its stopping rule and its refusals); lane l's
/// outcome is `out[l]` (l < `S::LANES`), a refused lane's matrix is unspecified. The lanes'
/// bookkeeping is bit masks (bit l: lane l); an iteration in which no live lane is scaled
/// skips γ (it is 1, so a = b = ½ exactly as the scalar iteration has them).
#[inline(always)]
pub(crate) fn polar_rotations<S: Simd>(f: &mut Mat3S<S>) -> [Result<(), PolarError>; 8] {
    const { assert!(S::LANES <= 8) };
    let all = (((1u16 << S::LANES) - 1) & 0xff) as u8;
    let n = norm(f);
    let d0 = det(f);
    // Refused before iterating: not finite (no convergence) or inverted / degenerate.
    let zero = S::splat(0.0);
    let finite = n.finite() & d0.finite();
    let inverted = finite & d0.le(S::splat(1e-12) * n * n * n);
    // live: still iterating; scaled: Higham's γ in the lane's next iteration; ok: converged.
    let mut live = finite & !inverted & all;
    let mut scaled = all;
    let mut ok = 0u8;
    let x = f;
    let (half, one) = (S::splat(0.5), S::splat(1.0));
    for _ in 0..30 {
        if live == 0 {
            break;
        }
        let d = det(x);
        let regular = d.finite_nonzero();
        let inv_t = cofactors(x, one / d);
        let (a, b) = if live & scaled != 0 {
            let gamma = S::blend(scaled, (norm(&inv_t) / norm(x)).sqrt(), one);
            (half * gamma, half / gamma)
        } else {
            (half, half)
        };
        let update = live & regular;
        let mut change = zero;
        for i in 0..3 {
            for j in 0..3 {
                let next = a * x[i][j] + b * inv_t[i][j];
                change = change + (next - x[i][j]) * (next - x[i][j]);
                x[i][j] = S::blend(update, next, x[i][j]);
            }
        }
        // A singular iterate ends its lane (no convergence); a change ≤ 1e-16 converges it.
        let done = update & change.le(S::splat(1e-16));
        ok |= done;
        live &= regular & !done;
        scaled = change.gt(S::splat(1e-4));
    }
    let mut out = [Err(PolarError::NoConvergence); 8];
    for (l, o) in out.iter_mut().enumerate().take(S::LANES) {
        if ok & (1 << l) != 0 {
            *o = Ok(());
        } else if inverted & (1 << l) != 0 {
            *o = Err(PolarError::Inverted(d0.lane(l)));
        }
    }
    out
}
