//! The core: SDA on composed Riccati maps (docs/design.md §6), Newton (Hewer) polish, the
//! one-period sweep, and small dense helpers.

#![allow(clippy::needless_range_loop)]

use faer::linalg::solvers::Solve;
use faer::{Mat, Side};

use super::*;

// ---------------------------------------------------------------------------------------------
// Core: SDA on composed Riccati maps, Newton polish, sweep.

/// Measurement model of one phase: H_p (m_p×r), R_p (m_p×m_p, SPD), G_p = H_pᵀ R_p⁻¹ H_p.
pub(super) struct PhaseModel {
    pub(super) h: Mat<f64>,
    pub(super) r: Mat<f64>,
    pub(super) g: Mat<f64>,
    pub(super) measured: Vec<usize>,
}

impl PhaseModel {
    pub(super) fn new(h: Mat<f64>, r: Mat<f64>, measured: Vec<usize>) -> Result<Self, KalmanError> {
        let n = h.ncols();
        let g = if h.nrows() == 0 {
            Mat::zeros(n, n)
        } else {
            let chol = r
                .llt(Side::Lower)
                .map_err(|e| KalmanError::LinearAlgebra(format!("Cholesky of R failed: {e:?}")))?;
            let rinv_h = chol.solve(&h);
            symmetrise(&(h.transpose() * &rinv_h))
        };
        Ok(Self { h, r, g, measured })
    }
}

/// The Riccati map X ↦ Aᵀ X (I + G X)⁻¹ A + H in SDA form (G, H symmetric PSD).
/// One filter step of phase p is (A, G, H) = (Fᵀ, H_pᵀ R_p⁻¹ H_p, Q).
pub(super) struct Triple {
    pub(super) a: Mat<f64>,
    pub(super) g: Mat<f64>,
    pub(super) h: Mat<f64>,
}

/// The map "t1 then t2" in SDA form; with W = I + G₂ H₁:
/// A = A₁ W⁻¹ A₂, G = G₁ + A₁ W⁻¹ G₂ A₁ᵀ, H = H₂ + A₂ᵀ H₁ W⁻¹ A₂.
/// compose(t, t) is one SDA step.
pub(super) fn compose(t1: &Triple, t2: &Triple) -> Triple {
    let n = t1.a.nrows();
    let mut w = Mat::<f64>::identity(n, n);
    w += &t2.g * &t1.h;
    let lu = w.partial_piv_lu();
    let w_a2 = lu.solve(&t2.a);
    let w_g2 = lu.solve(&t2.g);
    let a = &t1.a * &w_a2;
    let g = symmetrise(&(&t1.g + &t1.a * &w_g2 * t1.a.transpose()));
    let h = symmetrise(&(&t2.h + t2.a.transpose() * &t1.h * &w_a2));
    Triple { a, g, h }
}

/// Fixed point X = Aᵀ X (I + G X)⁻¹ A + H of a Riccati map by the structured doubling
/// algorithm. Returns (X, iterations).
pub(super) fn sda(mut t: Triple) -> Result<(Mat<f64>, usize), KalmanError> {
    let mut change = f64::INFINITY;
    for k in 1..=SDA_MAX_ITERATIONS {
        let next = compose(&t, &t);
        let h_norm = next.h.norm_l2();
        let diff = (&next.h - &t.h).norm_l2();
        change = if h_norm > 0.0 { diff / h_norm } else { diff };
        let a_norm = next.a.norm_l2();
        if !change.is_finite() || !a_norm.is_finite() || !next.g.norm_l2().is_finite() {
            return Err(KalmanError::NoConvergence {
                iterations: k,
                last_change: change,
            });
        }
        t = next;
        if change <= SDA_CHANGE_TOLERANCE || a_norm * a_norm <= SDA_A_TOLERANCE {
            return Ok((t.h, k));
        }
    }
    if change <= SDA_ACCEPT_AT_CAP {
        return Ok((t.h, SDA_MAX_ITERATIONS));
    }
    Err(KalmanError::NoConvergence {
        iterations: SDA_MAX_ITERATIONS,
        last_change: change,
    })
}

/// Solution of the Stein equation X − A X Aᵀ = C (ρ(A) < 1) by doubling:
/// X = Σ_k A^k C A^kᵀ, X_{j+1} = X_j + A_j X_j A_jᵀ, A_{j+1} = A_j². None if it diverges.
pub(super) fn stein(a: &Mat<f64>, c: &Mat<f64>) -> Option<Mat<f64>> {
    let mut x = c.clone();
    let mut aj = a.clone();
    for _ in 0..SDA_MAX_ITERATIONS {
        let add = symmetrise(&(&aj * &x * aj.transpose()));
        let add_norm = add.norm_l2();
        x += &add;
        aj = &aj * &aj;
        let a_norm = aj.norm_l2();
        if !a_norm.is_finite() || !add_norm.is_finite() {
            return None;
        }
        if a_norm * a_norm <= SDA_A_TOLERANCE || add_norm <= 1e-17 * x.norm_l2() {
            return Some(x);
        }
    }
    None
}

/// Result of a measurement update with the Joseph form.
pub(super) struct Update {
    pub(super) gain: Mat<f64>,
    pub(super) posterior: Mat<f64>,
    pub(super) innovation_covariance: Mat<f64>,
}

/// K = P Hᵀ S⁻¹, S = H P Hᵀ + R; posterior (I − K H) P (I − K H)ᵀ + K R Kᵀ.
pub(super) fn measurement_update(p: &Mat<f64>, h: &Mat<f64>, r: &Mat<f64>) -> Update {
    let n = p.nrows();
    let m = h.nrows();
    if m == 0 {
        return Update {
            gain: Mat::zeros(n, 0),
            posterior: p.clone(),
            innovation_covariance: Mat::zeros(0, 0),
        };
    }
    let hp = h * p;
    let s = symmetrise(&(&hp * h.transpose() + r));
    let kt = match s.llt(Side::Lower) {
        Ok(chol) => chol.solve(&hp),
        Err(_) => s.partial_piv_lu().solve(&hp),
    };
    let gain = kt.transpose().to_owned();
    let mut i_kh = Mat::<f64>::identity(n, n);
    i_kh -= &gain * h;
    let posterior = symmetrise(&(&i_kh * p * i_kh.transpose() + &gain * r * gain.transpose()));
    Update {
        gain,
        posterior,
        innovation_covariance: s,
    }
}

/// One sweep through the period from the prior P₀ at phase 0.
#[derive(Clone)]
pub(super) struct Sweep {
    pub(super) phases: Vec<PhaseGain>,
    /// P_L − P₀: the fixed-point residual of the one-period map.
    pub(super) residual: Mat<f64>,
    /// Φ = M_{L−1} ⋯ M₀, M_p = F (I − K_p H_p).
    pub(super) propagator: Mat<f64>,
    /// S = H₀ P₀ H₀ᵀ + R₀.
    pub(super) innovation_covariance: Mat<f64>,
}

pub(super) fn sweep(f: &Mat<f64>, q: &Mat<f64>, phases: &[PhaseModel], p0: &Mat<f64>) -> Sweep {
    let n = f.nrows();
    let mut p = p0.clone();
    let mut phi = Mat::<f64>::identity(n, n);
    let mut out = Vec::with_capacity(phases.len());
    let mut s0 = Mat::zeros(0, 0);
    for (k, ph) in phases.iter().enumerate() {
        let up = measurement_update(&p, &ph.h, &ph.r);
        let mut m = f.clone();
        m -= f * &up.gain * &ph.h;
        phi = &m * &phi;
        let next = symmetrise(&(f * &up.posterior * f.transpose() + q));
        if k == 0 {
            s0 = up.innovation_covariance;
        }
        out.push(PhaseGain {
            measured: ph.measured.clone(),
            gain: up.gain,
            prior_covariance: p,
            posterior_covariance: up.posterior,
        });
        p = next;
    }
    Sweep {
        phases: out,
        residual: symmetrise(&(&p - p0)),
        propagator: phi,
        innovation_covariance: s0,
    }
}

pub(super) struct Solved {
    pub(super) phases: Vec<PhaseGain>,
    pub(super) worst_relative_residual: f64,
    pub(super) closed_loop_spectral_radius: f64,
    pub(super) condition: f64,
    pub(super) iterations: usize,
}

pub(super) fn relative(res: &Mat<f64>, p: &Mat<f64>, q: &Mat<f64>) -> f64 {
    res.norm_l2() / p.norm_l2().max(q.norm_l2()).max(f64::MIN_POSITIVE)
}

/// A candidate P₀ with its sweep and relative residual.
#[derive(Clone)]
pub(super) struct Candidate {
    pub(super) p0: Mat<f64>,
    pub(super) sw: Sweep,
    pub(super) res: f64,
}

impl Candidate {
    pub(super) fn new(f: &Mat<f64>, q: &Mat<f64>, phases: &[PhaseModel], p0: Mat<f64>) -> Self {
        let sw = sweep(f, q, phases, &p0);
        let res = relative(&sw.residual, &p0, q);
        Self { p0, sw, res }
    }
}

/// Newton (Hewer) steps on the one-period map in correction form:
/// P₀ ← P₀ + Δ with Δ − Φ Δ Φᵀ = P_L − P₀, Φ the closed-loop propagator of the current gains
/// (equivalently P₀ ← the periodic Lyapunov solution of the current gains: Hewer's
/// iteration, which stays stabilizing and converges monotonically from a stabilizing start).
///
/// `polish`: keep a step only while it reduces the residual, stop when it no longer halves
/// it. Otherwise (Hewer from a stabilizing start): take every step, stop when the step is at
/// rounding level or the residual has not improved for three steps, return the best iterate.
/// Returns the result and the number of steps taken.
pub(super) fn newton(
    f: &Mat<f64>,
    q: &Mat<f64>,
    phases: &[PhaseModel],
    start: Candidate,
    max_steps: usize,
    polish: bool,
) -> (Candidate, usize) {
    let mut cur = start;
    let mut best: Option<Candidate> = None;
    let mut since_best = 0;
    let mut steps = 0;
    while steps < max_steps && cur.res > NEWTON_DONE {
        let Some(delta) = stein(&cur.sw.propagator, &cur.sw.residual) else {
            break;
        };
        let cand = Candidate::new(f, q, phases, symmetrise(&(&cur.p0 + &delta)));
        if !cand.res.is_finite() {
            break;
        }
        if polish {
            if cand.res >= cur.res {
                break;
            }
            let halved = cand.res <= 0.5 * cur.res;
            cur = cand;
            steps += 1;
            if !halved {
                break;
            }
        } else {
            let small = delta.norm_l2() <= 1e-14 * cand.p0.norm_l2();
            let prev = std::mem::replace(&mut cur, cand);
            steps += 1;
            match &best {
                Some(b) if b.res <= prev.res => since_best += 1,
                _ => {
                    best = Some(prev);
                    since_best = 0;
                }
            }
            if small || since_best >= 3 {
                break;
            }
        }
    }
    match best {
        Some(b) if b.res < cur.res => (b, steps),
        _ => (cur, steps),
    }
}

/// Route: SDA on the composed one-period map, Newton polish; if that fails (no convergence,
/// residual too large or a closed loop that is not stable — seen with near-perfect sensors,
/// R ≲ 1e-16 relative to H Q Hᵀ, where I + G H has condition ~ 1/R and rounding makes the
/// doubling collapse onto a non-stabilizing solution) and F is Schur-stable, Hewer's
/// iteration from the stabilizing gain K = 0 (P₀ = 0), then the same checks.
pub(super) fn solve_periodic(
    f: &Mat<f64>,
    q: &Mat<f64>,
    phases: &[PhaseModel],
) -> Result<Solved, KalmanError> {
    let ft = f.transpose().to_owned();
    let triple = |ph: &PhaseModel| Triple {
        a: ft.clone(),
        g: ph.g.clone(),
        h: q.clone(),
    };
    let mut map = triple(&phases[0]);
    for ph in &phases[1..] {
        map = compose(&map, &triple(ph));
    }
    let accept_ref = |c: &Candidate| -> Result<f64, KalmanError> {
        if c.res.is_nan() || c.res > RESIDUAL_THRESHOLD {
            return Err(KalmanError::ResidualTooLarge {
                residual: c.res,
                threshold: RESIDUAL_THRESHOLD,
            });
        }
        let radius = spectral_radius(&c.sw.propagator)?;
        if radius.is_nan() || radius >= 1.0 {
            return Err(KalmanError::UnstableClosedLoop {
                radius,
                innovation_condition: condition_spd(&c.sw.innovation_covariance)?,
            });
        }
        Ok(radius)
    };
    let finish = |c: Candidate, radius: f64, iterations: usize| -> Result<Solved, KalmanError> {
        let condition = condition_spd(&c.sw.innovation_covariance)?;
        Ok(Solved {
            phases: c.sw.phases,
            worst_relative_residual: c.res,
            closed_loop_spectral_radius: radius,
            condition,
            iterations,
        })
    };
    let n = f.nrows();
    let mut failed: Vec<(Candidate, usize)> = Vec::new();
    // Route 1: SDA on the one-period map, Newton polish.
    let first_err = match sda(map) {
        Ok((p0, iterations)) => {
            let start = Candidate::new(f, q, phases, p0);
            let (c, steps) = newton(f, q, phases, start, NEWTON_STEPS, true);
            match accept_ref(&c) {
                Ok(radius) => return finish(c, radius, iterations + steps),
                Err(e) => {
                    failed.push((c, iterations + steps));
                    e
                }
            }
        }
        Err(e) => e,
    };
    // Route 2 (F Schur-stable): Hewer's iteration from the stabilizing gain K = 0.
    if spectral_radius(f)? < 1.0 {
        let start = Candidate::new(f, q, phases, Mat::zeros(n, n));
        let (c, steps) = newton(f, q, phases, start, HEWER_MAX_STEPS, false);
        let (c, more) = newton(f, q, phases, c, NEWTON_STEPS, true);
        match accept_ref(&c) {
            Ok(radius) => return finish(c, radius, steps + more),
            Err(_) => failed.push((c, steps + more)),
        }
    }
    // Route 3: a Newton/SDA iterate carries absolute rounding ~ eps‖P‖ in every direction;
    // when H P Hᵀ + R is ill-conditioned (small R, more sensors than noise channels) that
    // noise is amplified into K and the closed loop can fail the check although a
    // stabilizing filter exists. The plain Riccati recursion P₀ ← P_L (Joseph form) is
    // attracted to the stabilizing solution and keeps the structure that makes K well
    // defined: run it from the best candidate within a flop budget.
    let max_sweeps = (RECURSION_FLOP_BUDGET / (8.0 * (n * n * n * phases.len()) as f64))
        .clamp(1.0, RECURSION_MAX_SWEEPS as f64) as usize;
    let best = failed
        .into_iter()
        .filter(|(c, _)| c.res.is_finite())
        .min_by(|a, b| a.0.res.total_cmp(&b.0.res));
    if let Some((c, iterations)) = best {
        if let Some((c, radius, sweeps)) = settle(f, q, phases, c, max_sweeps, &accept_ref) {
            return finish(c, radius, iterations + sweeps);
        }
    }
    Err(first_err)
}

/// Plain Riccati sweeps P₀ ← P_L from `c` (at most `max_sweeps`): at the first iterate that
/// passes `accept` (checked every [`RECURSION_CHECK_EVERY`] sweeps once the residual is
/// below the threshold), continue while the residual decreases (at most as many sweeps
/// again) and return the last iterate if it still passes, else the first.
pub(super) fn settle(
    f: &Mat<f64>,
    q: &Mat<f64>,
    phases: &[PhaseModel],
    mut c: Candidate,
    max_sweeps: usize,
    accept: &dyn Fn(&Candidate) -> Result<f64, KalmanError>,
) -> Option<(Candidate, f64, usize)> {
    let next = |c: &Candidate| Candidate::new(f, q, phases, symmetrise(&(&c.p0 + &c.sw.residual)));
    for sweeps in 1..=max_sweeps {
        c = next(&c);
        if !c.res.is_finite() {
            return None;
        }
        if c.res > RESIDUAL_THRESHOLD || sweeps % RECURSION_CHECK_EVERY != 0 {
            continue;
        }
        let Ok(radius) = accept(&c) else {
            continue;
        };
        let first = (c.clone(), radius, sweeps);
        let mut done = sweeps;
        while done < (2 * sweeps).min(max_sweeps) {
            let cand = next(&c);
            if cand.res.is_nan() || cand.res >= c.res {
                break;
            }
            c = cand;
            done += 1;
        }
        if done > sweeps {
            if let Ok(radius) = accept(&c) {
                return Some((c, radius, done));
            }
        }
        return Some(first);
    }
    None
}

// ---------------------------------------------------------------------------------------------
// Small helpers.

/// (M + Mᵀ)/2.
pub(super) fn symmetrise(m: &Mat<f64>) -> Mat<f64> {
    Mat::from_fn(m.nrows(), m.ncols(), |i, j| 0.5 * (m[(i, j)] + m[(j, i)]))
}

/// 2-norm condition λ_max/λ_min of a symmetric positive (semi)definite matrix; 1 if empty,
/// ∞ if singular.
pub(super) fn condition_spd(s: &Mat<f64>) -> Result<f64, KalmanError> {
    if s.nrows() == 0 {
        return Ok(1.0);
    }
    let ev = s
        .self_adjoint_eigenvalues(Side::Lower)
        .map_err(|e| KalmanError::LinearAlgebra(format!("eigenvalues of H P Hᵀ + R: {e:?}")))?;
    let lo = ev.first().copied().unwrap_or(1.0);
    let hi = ev.last().copied().unwrap_or(1.0);
    Ok(if lo > 0.0 { hi / lo } else { f64::INFINITY })
}

/// max |λ(M)|.
pub(super) fn spectral_radius(m: &Mat<f64>) -> Result<f64, KalmanError> {
    let ev = m.eigenvalues().map_err(|e| {
        KalmanError::LinearAlgebra(format!("eigenvalues of the closed loop: {e:?}"))
    })?;
    Ok(ev.iter().map(|l| l.re.hypot(l.im)).fold(0.0, f64::max))
}

pub(super) fn gcd(mut a: u64, mut b: u64) -> u64 {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a
}
