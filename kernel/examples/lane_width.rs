//! What the wider registers can give at most (not a test; numbers for docs/results/benchmarks.md): the
//! time of the same count of f64 lane operations on AVX2 (4 lanes per instruction) and AVX-512
//! (8 lanes), for the operations the blocked force is made of: fused multiply–add (the gather,
//! Kₑ local and the scatter), division and square root (the polar decomposition). Each loop
//! keeps 8 independent chains per path so that throughput, not latency, bounds it.
//!
//! `cargo run --release -p crokf-kernel --example lane_width`
//!
//! Prints per operation the time per lane operation on each path (median of 15 rounds, the
//! paths alternating) and their ratio AVX2 / AVX-512: the ratio the blocked force's AVX2 path
//! would show against its AVX-512 path if that operation alone bounded both (the runtime's
//! `tier_step` example prints the kernel's own ratio).

#[cfg(target_arch = "x86_64")]
mod paths {
    use std::arch::x86_64::*;

    /// Instructions per call of the multiply–add loops: `ROUNDS` × 8 chains (division and square
    /// root: `ROUNDS`).
    pub const ROUNDS: usize = 1 << 20;

    /// `fn $name(seed) -> f64`: 8 chains of `$set(seed)`, each replaced by `$op(x)` `$rounds`
    /// times, summed by `$reduce` (so that the loop is not removed).
    macro_rules! chains {
        ($name:ident, $feature:literal, $set:ident, $reduce:ident, $rounds:expr, |$x:ident| $op:expr) => {
            #[target_feature(enable = $feature)]
            pub unsafe fn $name(seed: f64) -> f64 {
                let mut acc = [$set(seed); 8];
                for _ in 0..$rounds {
                    for $x in &mut acc {
                        *$x = $op;
                    }
                }
                $reduce(acc)
            }
        };
    }

    chains!(fma_avx2, "avx2,fma", _mm256_set1_pd, reduce4, ROUNDS, |x| {
        _mm256_fmadd_pd(*x, _mm256_set1_pd(0.999_999_9), _mm256_set1_pd(1e-9))
    });
    chains!(
        fma_avx512,
        "avx512f",
        _mm512_set1_pd,
        reduce8,
        ROUNDS,
        |x| _mm512_fmadd_pd(*x, _mm512_set1_pd(0.999_999_9), _mm512_set1_pd(1e-9))
    );
    chains!(
        div_avx2,
        "avx2,fma",
        _mm256_set1_pd,
        reduce4,
        ROUNDS / 8,
        |x| _mm256_div_pd(*x, _mm256_set1_pd(1.000_000_1))
    );
    chains!(
        div_avx512,
        "avx512f",
        _mm512_set1_pd,
        reduce8,
        ROUNDS / 8,
        |x| _mm512_div_pd(*x, _mm512_set1_pd(1.000_000_1))
    );
    chains!(
        sqrt_avx2,
        "avx2,fma",
        _mm256_set1_pd,
        reduce4,
        ROUNDS / 8,
        |x| _mm256_sqrt_pd(*x)
    );
    chains!(
        sqrt_avx512,
        "avx512f",
        _mm512_set1_pd,
        reduce8,
        ROUNDS / 8,
        |x| _mm512_sqrt_pd(*x)
    );

    #[target_feature(enable = "avx2")]
    unsafe fn reduce4(acc: [__m256d; 8]) -> f64 {
        let mut out = [0.0; 4];
        let mut s = 0.0;
        for x in acc {
            _mm256_storeu_pd(out.as_mut_ptr(), x);
            s += out.iter().sum::<f64>();
        }
        s
    }

    #[target_feature(enable = "avx512f")]
    unsafe fn reduce8(acc: [__m512d; 8]) -> f64 {
        let mut out = [0.0; 8];
        let mut s = 0.0;
        for x in acc {
            _mm512_storeu_pd(out.as_mut_ptr(), x);
            s += out.iter().sum::<f64>();
        }
        s
    }
}

#[cfg(target_arch = "x86_64")]
fn main() {
    use paths::*;
    use std::time::Instant;
    if !(is_x86_feature_detected!("avx2")
        && is_x86_feature_detected!("fma")
        && is_x86_feature_detected!("avx512f"))
    {
        println!("this CPU lacks AVX2 + FMA or AVX-512F: nothing to compare");
        return;
    }
    type Run = unsafe fn(f64) -> f64;
    // (name, AVX2 run, AVX-512 run, instructions per call)
    let ops: [(&str, Run, Run, usize); 3] = [
        ("fused multiply-add", fma_avx2, fma_avx512, ROUNDS * 8),
        ("division", div_avx2, div_avx512, ROUNDS),
        ("square root", sqrt_avx2, sqrt_avx512, ROUNDS),
    ];
    let mut sink = 0.0;
    for (name, avx2, avx512, count) in ops {
        let (mut t2, mut t5) = (Vec::new(), Vec::new());
        for round in 0..15 {
            let seed = 1.0 + round as f64 * 1e-3;
            let start = Instant::now();
            // SAFETY: both feature sets were detected above.
            sink += unsafe { avx2(seed) };
            t2.push(start.elapsed().as_secs_f64() / (count * 4) as f64);
            let start = Instant::now();
            // SAFETY: as above.
            sink += unsafe { avx512(seed) };
            t5.push(start.elapsed().as_secs_f64() / (count * 8) as f64);
        }
        let median = |mut v: Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let (a, b) = (median(t2), median(t5));
        println!(
            "{name:>18}: avx2 {:.4} ns, avx512 {:.4} ns per lane operation: ratio {:.2}",
            a * 1e9,
            b * 1e9,
            a / b
        );
    }
    // Keeps the loops' results alive.
    if sink == 0.0 {
        println!("{sink}");
    }
}

#[cfg(not(target_arch = "x86_64"))]
fn main() {
    println!("x86-64 only");
}
