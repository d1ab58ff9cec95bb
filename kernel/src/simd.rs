//! A few lanes of f64 as one value, so that the polar decomposition ([`crate::lanes`]) and the
//! blocked force ([`crate::block`]) are written once and run on 1 lane (`f64`: the scalar
//! kernel), 8 lanes in arrays (portable; LLVM vectorises each operation for the target it
//! is compiled for), two AVX2 registers or one AVX-512 register. Every operation is the IEEE one lane by
//! lane (no reassociation), so a lane's result does not depend on the implementation except
//! through [`Simd::mul_add`], which is fused in `Avx2` and `Avx512`.

use std::ops::{Add, Div, Mul, Sub};

/// Lanes of f64 (at most 8; lane masks are bytes, bit l for lane l).
pub trait Simd:
    Copy + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + Div<Output = Self>
{
    /// Number of lanes.
    const LANES: usize;
    /// Rows of the blocked gather u = V_e q, v = V_e q̇ per pass over the basis columns
    /// ([`crate::block`]; divides 12): two accumulators per row plus two splats and a load
    /// stay in the registers.
    const GATHER_ROWS: usize = 3;
    /// Rows of the blocked scatter Σᵢ V_e[i][j] forceᵢ per pass over the columns (divides 12):
    /// these force rows stay in the registers across the pass.
    const SCATTER_ROWS: usize = 12;
    /// Every lane `v`.
    fn splat(v: f64) -> Self;
    /// Lanes from `s[..LANES]`.
    fn load(s: &[f64]) -> Self;
    /// Lanes into `s[..LANES]`.
    fn store(self, s: &mut [f64]);
    /// Lane l.
    fn lane(self, l: usize) -> f64;
    /// √ per lane (correctly rounded).
    fn sqrt(self) -> Self;
    /// self · b + c: rounded once on the fused lane types (AVX2 + FMA, AVX-512), twice on the
    /// portable lanes.
    fn mul_add(self, b: Self, c: Self) -> Self;
    /// Lanes of `a` where bit l of `mask` is set, of `b` elsewhere.
    fn blend(mask: u8, a: Self, b: Self) -> Self;
    /// Mask of the lanes with `self ≤ o` (false where either is NaN).
    fn le(self, o: Self) -> u8 {
        let mut m = 0;
        for l in 0..Self::LANES {
            m |= ((self.lane(l) <= o.lane(l)) as u8) << l;
        }
        m
    }
    /// Mask of the lanes with `self > o` (false where either is NaN).
    fn gt(self, o: Self) -> u8 {
        let mut m = 0;
        for l in 0..Self::LANES {
            m |= ((self.lane(l) > o.lane(l)) as u8) << l;
        }
        m
    }
    /// Mask of the finite lanes.
    fn finite(self) -> u8 {
        let mut m = 0;
        for l in 0..Self::LANES {
            m |= (self.lane(l).is_finite() as u8) << l;
        }
        m
    }
    /// Mask of the lanes that are finite and not zero.
    fn finite_nonzero(self) -> u8 {
        let mut m = 0;
        for l in 0..Self::LANES {
            let v = self.lane(l);
            m |= ((v != 0.0 && v.is_finite()) as u8) << l;
        }
        m
    }
    /// Sum of the lanes, in lane order.
    fn sum(self) -> f64 {
        let mut s = self.lane(0);
        for l in 1..Self::LANES {
            s += self.lane(l);
        }
        s
    }
}

impl Simd for f64 {
    const LANES: usize = 1;
    #[inline(always)]
    fn splat(v: f64) -> Self {
        v
    }
    #[inline(always)]
    fn load(s: &[f64]) -> Self {
        s[0]
    }
    #[inline(always)]
    fn store(self, s: &mut [f64]) {
        s[0] = self;
    }
    #[inline(always)]
    fn lane(self, _: usize) -> f64 {
        self
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        f64::sqrt(self)
    }
    #[inline(always)]
    fn mul_add(self, b: Self, c: Self) -> Self {
        self * b + c
    }
    #[inline(always)]
    fn blend(mask: u8, a: Self, b: Self) -> Self {
        if mask & 1 != 0 {
            a
        } else {
            b
        }
    }
}

/// 8 lanes in an array, unfused (the portable path: every operation the scalar one).
#[derive(Clone, Copy, Debug)]
#[repr(align(64))]
pub struct Lanes8(pub [f64; 8]);

macro_rules! lanewise {
    ($tr:ident, $f:ident, $op:tt) => {
        impl $tr for Lanes8 {
            type Output = Self;
            #[inline(always)]
            fn $f(self, o: Self) -> Self {
                let mut out = [0.0; 8];
                for l in 0..8 {
                    out[l] = self.0[l] $op o.0[l];
                }
                Lanes8(out)
            }
        }
    };
}
lanewise!(Add, add, +);
lanewise!(Sub, sub, -);
lanewise!(Mul, mul, *);
lanewise!(Div, div, /);

impl Simd for Lanes8 {
    const LANES: usize = 8;
    #[inline(always)]
    fn splat(v: f64) -> Self {
        Lanes8([v; 8])
    }
    #[inline(always)]
    fn load(s: &[f64]) -> Self {
        Lanes8(s[..8].try_into().expect("8 lanes"))
    }
    #[inline(always)]
    fn store(self, s: &mut [f64]) {
        s[..8].copy_from_slice(&self.0);
    }
    #[inline(always)]
    fn lane(self, l: usize) -> f64 {
        self.0[l]
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        Lanes8(self.0.map(f64::sqrt))
    }
    #[inline(always)]
    fn mul_add(self, b: Self, c: Self) -> Self {
        let mut out = [0.0; 8];
        for l in 0..8 {
            out[l] = self.0[l] * b.0[l] + c.0[l];
        }
        Lanes8(out)
    }
    #[inline(always)]
    fn blend(mask: u8, a: Self, b: Self) -> Self {
        let mut out = b.0;
        for l in 0..8 {
            if mask & (1 << l) != 0 {
                out[l] = a.0[l];
            }
        }
        Lanes8(out)
    }
}

#[cfg(target_arch = "x86_64")]
pub use avx512::Avx512;

#[cfg(target_arch = "x86_64")]
mod avx512 {
    //! 8 lanes in one AVX-512 register. Only to be used inside a function compiled with
    //! `#[target_feature(enable = "avx512f")]` on a CPU that has it (the methods inline
    //! there).
    use super::Simd;
    use std::arch::x86_64::*;
    use std::ops::{Add, Div, Mul, Sub};

    /// 8 f64 lanes of a `__m512d`; fused multiply–add.
    #[derive(Clone, Copy, Debug)]
    pub struct Avx512(__m512d);

    macro_rules! op {
        ($tr:ident, $f:ident, $intr:ident) => {
            impl $tr for Avx512 {
                type Output = Self;
                #[inline(always)]
                fn $f(self, o: Self) -> Self {
                    // SAFETY: Avx512 values exist only inside AVX-512F code (module docs).
                    Avx512(unsafe { $intr(self.0, o.0) })
                }
            }
        };
    }
    op!(Add, add, _mm512_add_pd);
    op!(Sub, sub, _mm512_sub_pd);
    op!(Mul, mul, _mm512_mul_pd);
    op!(Div, div, _mm512_div_pd);

    // SAFETY (every method): Avx512 values exist only inside AVX-512F code (module docs);
    // loads and stores check their slice length first.
    impl Simd for Avx512 {
        const LANES: usize = 8;
        // 32 registers of 8 lanes: all 12 rows of the gather at once (24 accumulators), the
        // whole force across the scatter. Against 3 gather rows: the meniscus tier's force
        // evaluation 8.7 → 7.6 µs on a Zen 5 (`tier_step`, docs/results/benchmarks.md).
        const GATHER_ROWS: usize = 12;
        const SCATTER_ROWS: usize = 12;
        #[inline(always)]
        fn splat(v: f64) -> Self {
            Avx512(unsafe { _mm512_set1_pd(v) })
        }
        #[inline(always)]
        fn load(s: &[f64]) -> Self {
            assert!(s.len() >= 8);
            Avx512(unsafe { _mm512_loadu_pd(s.as_ptr()) })
        }
        #[inline(always)]
        fn store(self, s: &mut [f64]) {
            assert!(s.len() >= 8);
            unsafe { _mm512_storeu_pd(s.as_mut_ptr(), self.0) }
        }
        #[inline(always)]
        fn lane(self, l: usize) -> f64 {
            let mut a = [0.0; 8];
            self.store(&mut a);
            a[l]
        }
        #[inline(always)]
        fn sqrt(self) -> Self {
            Avx512(unsafe { _mm512_sqrt_pd(self.0) })
        }
        #[inline(always)]
        fn mul_add(self, b: Self, c: Self) -> Self {
            Avx512(unsafe { _mm512_fmadd_pd(self.0, b.0, c.0) })
        }
        #[inline(always)]
        fn blend(mask: u8, a: Self, b: Self) -> Self {
            Avx512(unsafe { _mm512_mask_blend_pd(mask, b.0, a.0) })
        }
        #[inline(always)]
        fn le(self, o: Self) -> u8 {
            unsafe { _mm512_cmp_pd_mask::<_CMP_LE_OQ>(self.0, o.0) }
        }
        #[inline(always)]
        fn gt(self, o: Self) -> u8 {
            unsafe { _mm512_cmp_pd_mask::<_CMP_GT_OQ>(self.0, o.0) }
        }
        #[inline(always)]
        fn finite(self) -> u8 {
            // v − v is 0 exactly when v is finite (NaN for ±∞ and NaN).
            unsafe {
                let v = self.0;
                _mm512_cmp_pd_mask::<_CMP_EQ_OQ>(_mm512_sub_pd(v, v), _mm512_setzero_pd())
            }
        }
        #[inline(always)]
        fn finite_nonzero(self) -> u8 {
            self.finite()
                & unsafe { _mm512_cmp_pd_mask::<_CMP_NEQ_OQ>(self.0, _mm512_setzero_pd()) }
        }
        #[inline(always)]
        fn sum(self) -> f64 {
            let mut a = [0.0; 8];
            self.store(&mut a);
            let mut s = a[0];
            for v in &a[1..] {
                s += v;
            }
            s
        }
    }
}

#[cfg(target_arch = "x86_64")]
pub use avx2::Avx2;

#[cfg(target_arch = "x86_64")]
mod avx2 {
    //! 8 lanes in two AVX2 registers. Only to be used inside a function compiled with
    //! `#[target_feature(enable = "avx2,fma")]` on a CPU that has them (the methods inline
    //! there).
    use super::Simd;
    use std::arch::x86_64::*;
    use std::ops::{Add, Div, Mul, Sub};

    /// 8 f64 lanes as two `__m256d` (lanes 0–3, 4–7); fused multiply–add.
    #[derive(Clone, Copy, Debug)]
    pub struct Avx2(__m256d, __m256d);

    macro_rules! op {
        ($tr:ident, $f:ident, $intr:ident) => {
            impl $tr for Avx2 {
                type Output = Self;
                #[inline(always)]
                fn $f(self, o: Self) -> Self {
                    // SAFETY: Avx2 values exist only inside AVX2 + FMA code (module docs).
                    unsafe { Avx2($intr(self.0, o.0), $intr(self.1, o.1)) }
                }
            }
        };
    }
    op!(Add, add, _mm256_add_pd);
    op!(Sub, sub, _mm256_sub_pd);
    op!(Mul, mul, _mm256_mul_pd);
    op!(Div, div, _mm256_div_pd);

    /// The 4-bit mask of a comparison result (all-ones lanes).
    #[inline(always)]
    unsafe fn bits(lo: __m256d, hi: __m256d) -> u8 {
        (_mm256_movemask_pd(lo) | (_mm256_movemask_pd(hi) << 4)) as u8
    }

    /// The 8-bit mask of comparison `P` (`_CMP_*`) of two 8-lane values.
    #[inline(always)]
    unsafe fn compare<const P: i32>(a: (__m256d, __m256d), b: (__m256d, __m256d)) -> u8 {
        bits(_mm256_cmp_pd::<P>(a.0, b.0), _mm256_cmp_pd::<P>(a.1, b.1))
    }

    /// All-ones lanes where bit l of `mask` (of 4) is set.
    #[inline(always)]
    unsafe fn lanes(mask: u8) -> __m256d {
        let bit = _mm256_set_epi64x(8, 4, 2, 1);
        let m = _mm256_and_si256(_mm256_set1_epi64x(mask as i64), bit);
        _mm256_castsi256_pd(_mm256_cmpeq_epi64(m, bit))
    }

    // SAFETY (every method): Avx2 values exist only inside AVX2 + FMA code (module docs);
    // loads and stores check their slice length first.
    impl Simd for Avx2 {
        const LANES: usize = 8;
        // 16 registers of 4 lanes, 8 values of 8 lanes: 2 gather rows (4 accumulators, 2
        // splats, a load), 4 force rows per scatter pass (the whole force, 12 values, spilled
        // and was re-read from the stack for every column). Against 3 and 12: the meniscus
        // tier's force evaluation 13.8 → 12.5 µs on a Zen 5 (`tier_step`).
        const GATHER_ROWS: usize = 2;
        const SCATTER_ROWS: usize = 4;
        #[inline(always)]
        fn splat(v: f64) -> Self {
            unsafe { Avx2(_mm256_set1_pd(v), _mm256_set1_pd(v)) }
        }
        #[inline(always)]
        fn load(s: &[f64]) -> Self {
            assert!(s.len() >= 8);
            unsafe {
                Avx2(
                    _mm256_loadu_pd(s.as_ptr()),
                    _mm256_loadu_pd(s.as_ptr().add(4)),
                )
            }
        }
        #[inline(always)]
        fn store(self, s: &mut [f64]) {
            assert!(s.len() >= 8);
            // Plain unaligned writes rather than `_mm256_storeu_pd`: the intrinsic carries
            // `#[target_feature(enable = "avx")]`, which LLVM would not inline through this
            // feature-less method, leaving a call per store in the AVX2 kernels (seen in
            // `perf`); the writes compile to the same `vmovupd` inside AVX2 code.
            unsafe {
                let p = s.as_mut_ptr().cast::<__m256d>();
                p.write_unaligned(self.0);
                p.add(1).write_unaligned(self.1);
            }
        }
        #[inline(always)]
        fn lane(self, l: usize) -> f64 {
            let mut a = [0.0; 8];
            self.store(&mut a);
            a[l]
        }
        #[inline(always)]
        fn sqrt(self) -> Self {
            unsafe { Avx2(_mm256_sqrt_pd(self.0), _mm256_sqrt_pd(self.1)) }
        }
        #[inline(always)]
        fn mul_add(self, b: Self, c: Self) -> Self {
            unsafe {
                Avx2(
                    _mm256_fmadd_pd(self.0, b.0, c.0),
                    _mm256_fmadd_pd(self.1, b.1, c.1),
                )
            }
        }
        #[inline(always)]
        fn blend(mask: u8, a: Self, b: Self) -> Self {
            unsafe {
                Avx2(
                    _mm256_blendv_pd(b.0, a.0, lanes(mask & 15)),
                    _mm256_blendv_pd(b.1, a.1, lanes(mask >> 4)),
                )
            }
        }
        #[inline(always)]
        fn le(self, o: Self) -> u8 {
            unsafe { compare::<_CMP_LE_OQ>((self.0, self.1), (o.0, o.1)) }
        }
        #[inline(always)]
        fn gt(self, o: Self) -> u8 {
            unsafe { compare::<_CMP_GT_OQ>((self.0, self.1), (o.0, o.1)) }
        }
        #[inline(always)]
        fn finite(self) -> u8 {
            // v − v is 0 exactly when v is finite (NaN for ±∞ and NaN).
            unsafe {
                let z = _mm256_setzero_pd();
                let d = (_mm256_sub_pd(self.0, self.0), _mm256_sub_pd(self.1, self.1));
                compare::<_CMP_EQ_OQ>(d, (z, z))
            }
        }
        #[inline(always)]
        fn finite_nonzero(self) -> u8 {
            unsafe {
                let z = _mm256_setzero_pd();
                self.finite() & compare::<_CMP_NEQ_OQ>((self.0, self.1), (z, z))
            }
        }
    }
}
