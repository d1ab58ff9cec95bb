//! The tier filter's covariance recursion while channels are missing (docs/design.md §11.11).
//!
//! The stored gains and read-out σ belong to the steady-state filter with every active channel
//! measured. When a channel of the phase has no value (a marker lost, a value gated), that
//! filter is no longer the right one: its gain columns for the channels still present were
//! designed together with the missing one, and its covariance does not grow where only the
//! missing channel looked (a load seen mainly by a lost marker). From such an update on, the
//! filter carries its own covariance P (n × n):
//! ```text
//! start:    P⁻ = the stored filter's prior of the phase
//! update:   S = H_u P⁻ H_uᵀ + R_u,  s⁺ = s⁻ + P⁻H_uᵀ S⁻¹ ν_u,  P = P⁻ − P⁻H_uᵀ S⁻¹ H_u P⁻
//! predict:  P⁻ = F P Fᵀ + Q
//! ```
//! over the channels u present, with Q the process noise of the stored filter in use (its
//! force-σ level and schedule point) and F the tier's step linearised at the Newton matrix of
//! the step just taken, J = (1 + a₂β) K_t + (a₀ + a₂α) M (the compiler's
//! `LinearisedTier::transition` with K_t for the tangent at rest):
//! ```text
//! q̂ = J⁻¹ [ (a₀M + a₂C) q + ((6/τ)M + 2C) q̇ + (2M + (τ/2)C) q̈ + VᵀB f ],  C = αM + βK_t
//! (q, q̇, q̈)⁺ = advance(q, q̇, q̈, q̂) per coordinate,  f⁺ = f (+ Δt ḟ),  ḟ⁺ = ḟ
//! ```
//! F = D + E G: D holds advance's coefficients of (q, q̇, q̈) and the force rows (≤ 3 entries
//! per row), E the coefficient of q̂, G = J⁻¹[…] (r × n); F P Fᵀ is formed as
//! D P Dᵀ + E G P Dᵀ + (E G P Dᵀ)ᵀ + E (G P Gᵀ) Eᵀ in O(r n²) rather than O(n³).
//!
//! The same recursion carries the filter across a lowering of the force-σ level
//! (docs/design.md §11.10): the stored filter of the lower level states the covariance of its
//! own steady state, but the estimate was made with the larger σ and its error is the larger
//! level's. From the posterior the last update left (the stored one of the level before, or the
//! recursion's P when running; after a lowering at a prediction, a told start, from the level
//! before's prior at the next update), P then propagates with the lower level's Q until it
//! settles as above. A raise still moves to the higher level's stored filter at once.
//!
//! The gate and the force-σ statistic see the innovation variance of this P⁻ while the
//! recursion runs, and the read-out σ come from it. The stored filter takes over again after
//! an update with every active channel used whose prior had every active channel's innovation
//! variance at most (1 + [`SETTLED`]) times the stored filter's and whose force states'
//! variances (the largest ratio to the stored filter's) were either within the same bound or
//! no longer falling by [`SETTLING_RATE`] per update (the recursion's own steady state at the
//! current linearisation can lie above the stored filter's, designed at its schedule point).
//! The read-out σ are computed from P when read. Nothing allocates per step; a step rolled back
//! restores P and whether the recursion runs.

use super::{wilson, TierModel, TierState};
use crokf_formats::{CorotationalTier, KalmanGains};
use crokf_kernel as kernel;

/// Relative excess of variance over the stored filter's at which the recursion stops: the
/// stored σ are then at most √1.1 − 1 ≈ 5 % smaller than the recursion's.
pub const SETTLED: f64 = 0.1;

/// Relative fall per update of the force states' excess variance below which the recursion
/// stops although that excess is above [`SETTLED`]: its own steady state at this
/// linearisation lies above the stored filter's, and what is left of a loss then shrinks over
/// ≥ 1/`SETTLING_RATE` steps.
pub const SETTLING_RATE: f64 = 1e-3;

/// The covariance recursion's state and scratch (allocated once, at the estimator's size).
#[derive(Clone, Debug)]
pub(crate) struct Recursion {
    n: usize,
    /// Whether P is in use (instead of the stored filter's covariances).
    active: bool,
    /// P⁻ after a prediction, P after an update (n × n, row-major).
    p: Vec<f64>,
    /// P and `active` before the last prediction (restored by [`Recursion::rollback`]).
    p_prev: Vec<f64>,
    active_prev: bool,
    /// The pending update's P and whether it settles (committed by [`Recursion::commit`]).
    p_upd: Vec<f64>,
    settles: bool,
    /// The largest ratio of a force state's prior variance to the stored filter's at the last
    /// committed update with every channel used (+∞ before one), and the pending update's.
    excess: f64,
    excess_upd: f64,
    /// The structure of F = D + E G (module docs).
    shape: Shape,
    /// G (r × n), G P (r × n), (G P Dᵀ)ᵀ (n × r), G P Gᵀ (r × r), P Dᵀ (n × n).
    g: Vec<f64>,
    gp: Vec<f64>,
    gpd_t: Vec<f64>,
    gpg: Vec<f64>,
    pd: Vec<f64>,
    /// One row of G P Dᵀ (n).
    row: Vec<f64>,
    /// C = αM + βK_t (r × r).
    damping: Vec<f64>,
    /// Per active channel of the update's phase: the prior innovation variance (H P⁻ Hᵀ)_aa
    /// + R_aa, m².
    variance: Vec<f64>,
    /// The present channels' P⁻H_uᵀ (transposed: m_u × n), S (m_u × m_u) and S⁻¹ν (m_u).
    pht: Vec<f64>,
    innovation_covariance: Vec<f64>,
    weights: Vec<f64>,
}

impl Recursion {
    /// Not running, with every buffer for `tier`.
    pub(crate) fn new(tier: &TierModel) -> Self {
        let (r, n) = (tier.r, tier.n);
        let mm = tier.max_measured();
        Recursion {
            n,
            active: false,
            p: vec![0.0; n * n],
            p_prev: vec![0.0; n * n],
            active_prev: false,
            p_upd: vec![0.0; n * n],
            settles: false,
            excess: f64::INFINITY,
            excess_upd: f64::INFINITY,
            shape: Shape::new(tier),
            g: vec![0.0; r * n],
            gp: vec![0.0; r * n],
            gpd_t: vec![0.0; n * r],
            gpg: vec![0.0; r * r],
            pd: vec![0.0; n * n],
            row: vec![0.0; n],
            damping: vec![0.0; r * r],
            variance: vec![0.0; mm],
            pht: vec![0.0; mm * n],
            innovation_covariance: vec![0.0; mm * mm],
            weights: vec![0.0; mm],
        }
    }

    /// Whether the filter runs on its own covariance.
    pub(crate) fn active(&self) -> bool {
        self.active
    }

    /// Stopped (the estimator's reset).
    pub(crate) fn reset(&mut self) {
        self.active = false;
        self.active_prev = false;
        self.excess = f64::INFINITY;
    }

    /// After the tier's step `state.step` (whose Newton matrix is factored in `state`): keeps
    /// P for a rollback and, when running, P⁻ = F P Fᵀ + Q with the Q of the stored filter in
    /// use.
    pub(crate) fn predict(
        &mut self,
        tier: &TierModel,
        section: &CorotationalTier,
        state: &TierState,
    ) {
        self.active_prev = self.active;
        if !self.active {
            return;
        }
        std::mem::swap(&mut self.p, &mut self.p_prev);
        tier.isa.dispatch(
            #[inline(always)]
            || {
                self.transition(tier, state);
                self.propagate(tier, section, state);
            },
        );
    }

    /// Runs from the posterior of stored filter `filter` at `phase` when not running: the
    /// covariance an update of that filter left, from which the lowered force-σ level's Q now
    /// propagates (module docs). Running, P already is that covariance.
    pub(crate) fn start_at_posterior(
        &mut self,
        section: &CorotationalTier,
        filter: usize,
        phase: usize,
    ) {
        if self.active {
            return;
        }
        self.p.copy_from_slice(
            &stored(section, filter).phases[phase]
                .posterior_covariance
                .data,
        );
        self.active = true;
        self.excess = f64::INFINITY;
    }

    /// Restores P and whether the recursion runs to their values before the last prediction.
    pub(crate) fn rollback(&mut self) {
        if self.active_prev {
            std::mem::swap(&mut self.p, &mut self.p_prev);
        }
        self.active = self.active_prev;
    }

    /// G = J⁻¹ [a₀M + a₂C, (6/τ)M + 2C, 2M + (τ/2)C, VᵀB_f, 0] (r × n, module docs) at the
    /// state's Newton matrix: the right-hand sides formed row by row, then one forward and one
    /// back substitution with the step's Cholesky factor on all n columns at once.
    #[inline(always)]
    fn transition(&mut self, tier: &TierModel, state: &TierState) {
        let (r, n) = (tier.r, self.n);
        let w = wilson(tier);
        // K_t from J = scale·K_t + c_m M, then C = αM + βK_t.
        let c_m = w.a0 + w.a2 * tier.alpha;
        let scale = 1.0 + w.a2 * tier.beta;
        for ((c, &j), &m) in self.damping.iter_mut().zip(&state.newton).zip(&tier.mass) {
            *c = tier.alpha * m + tier.beta * (j - c_m * m) / scale;
        }
        let blocks = [(w.a0, w.a2), (w.a1, 2.0), (2.0, 0.5 * w.tau)];
        let nf = tier.force_channels.len();
        for i in 0..r {
            let row = &mut self.g[i * n..(i + 1) * n];
            let (m, c) = (
                &tier.mass[i * r..(i + 1) * r],
                &self.damping[i * r..(i + 1) * r],
            );
            for (blk, &(cm, cc)) in blocks.iter().enumerate() {
                for ((o, &mv), &cv) in row[blk * r..(blk + 1) * r].iter_mut().zip(m).zip(c) {
                    *o = cm * mv + cc * cv;
                }
            }
            for (k, &ch) in tier.force_channels.iter().enumerate() {
                row[3 * r + k] = tier.input[i * tier.m + ch];
            }
            row[3 * r + nf..].iter_mut().for_each(|v| *v = 0.0);
        }
        // L Lᵀ G = RHS with L the lower factor in `state.jac` (row-major).
        let l = &state.jac;
        for i in 0..r {
            let (done, rest) = self.g.split_at_mut(i * n);
            let row = &mut rest[..n];
            for k in 0..i {
                let f = l[i * r + k];
                for (o, v) in row.iter_mut().zip(&done[k * n..(k + 1) * n]) {
                    *o -= f * v;
                }
            }
            let d = l[i * r + i];
            row.iter_mut().for_each(|v| *v /= d);
        }
        for i in (0..r).rev() {
            let (head, tail) = self.g.split_at_mut((i + 1) * n);
            let row = &mut head[i * n..];
            for k in i + 1..r {
                let f = l[k * r + i];
                for (o, v) in row.iter_mut().zip(&tail[(k - i - 1) * n..(k - i) * n]) {
                    *o -= f * v;
                }
            }
            let d = l[i * r + i];
            row.iter_mut().for_each(|v| *v /= d);
        }
    }

    /// P ← F P_prev Fᵀ + Q (module docs), symmetrised; every product as contiguous row
    /// operations.
    #[inline(always)]
    fn propagate(&mut self, tier: &TierModel, section: &CorotationalTier, state: &TierState) {
        let (r, n) = (tier.r, self.n);
        let p = &self.p_prev;
        let shape = &self.shape;
        // G P (r × n) and G P Gᵀ (r × r).
        for d in 0..r {
            let out = &mut self.gp[d * n..(d + 1) * n];
            out.iter_mut().for_each(|v| *v = 0.0);
            for (c, &g) in self.g[d * n..(d + 1) * n].iter().enumerate() {
                if g != 0.0 {
                    for (o, pv) in out.iter_mut().zip(&p[c * n..(c + 1) * n]) {
                        *o += g * pv;
                    }
                }
            }
            for e in 0..r {
                self.gpg[d * r + e] =
                    dot(&self.gp[d * n..(d + 1) * n], &self.g[e * n..(e + 1) * n]);
            }
            // (G P Dᵀ)[d, ·], stored transposed.
            shape.times_dt(&self.gp[d * n..(d + 1) * n], &mut self.row);
            for (j, &v) in self.row.iter().enumerate() {
                self.gpd_t[j * r + d] = v;
            }
        }
        // P Dᵀ (n × n), row by row.
        for i in 0..n {
            shape.times_dt(&p[i * n..(i + 1) * n], &mut self.pd[i * n..(i + 1) * n]);
        }
        let q = &stored(section, tier.filter_index(state.level, state.filter))
            .process_noise
            .data;
        for i in 0..n {
            let out = &mut self.p[i * n..(i + 1) * n];
            // (D P Dᵀ)[i, ·] = Σ_c D[i, c] (P Dᵀ)[c, ·], plus Q.
            out.copy_from_slice(&q[i * n..(i + 1) * n]);
            shape.for_row(i, |c, v| {
                for (o, x) in out.iter_mut().zip(&self.pd[c * n..(c + 1) * n]) {
                    *o += v * x;
                }
            });
            // (D P Gᵀ Eᵀ)[i, j] = e_j (G P Dᵀ)[d(j), i]: per block of j, contiguous in d.
            let gpd_i = &self.gpd_t[i * r..(i + 1) * r];
            for blk in 0..3 {
                let e = shape.lift[blk];
                for (o, x) in out[blk * r..(blk + 1) * r].iter_mut().zip(gpd_i) {
                    *o += e * x;
                }
            }
            if i < 3 * r {
                let (ei, di) = (shape.lift[i / r], i % r);
                // (E G P Dᵀ)[i, ·] = e_i (G P Dᵀ)[d(i), ·].
                for (j, o) in out.iter_mut().enumerate() {
                    *o += ei * self.gpd_t[j * r + di];
                }
                // (E G P Gᵀ Eᵀ)[i, j] = e_i e_j (G P Gᵀ)[d(i), d(j)].
                let gpg = &self.gpg[di * r..(di + 1) * r];
                for blk in 0..3 {
                    let e = ei * shape.lift[blk];
                    for (o, x) in out[blk * r..(blk + 1) * r].iter_mut().zip(gpg) {
                        *o += e * x;
                    }
                }
            }
        }
        symmetrise(&mut self.p, n);
    }

    /// The prior innovation variance of `phase`'s active channels for the gate and the
    /// force-σ statistic: the recursion's (H P⁻ Hᵀ)_aa + R_aa while it runs, else `None` (the
    /// stored filter's).
    pub(crate) fn prior_variance(&mut self, tier: &TierModel, phase: usize) -> Option<&[f64]> {
        if !self.active {
            return None;
        }
        self.fill_variance(tier, phase);
        Some(&self.variance[..tier.measured[phase].len()])
    }

    #[inline(always)]
    fn fill_variance(&mut self, tier: &TierModel, phase: usize) {
        let (r, n) = (tier.r, self.n);
        for (a, &j) in tier.measured[phase].iter().enumerate() {
            let j = j as usize;
            let h = channel_row(tier, j);
            self.variance[a] = quadratic(h, &self.p, n, r) + tier.measurement_variance[j];
        }
    }

    /// The update of `phase` from P⁻ over the channels `state.present` marks, with the
    /// innovations in `state.innovation` (module docs): `state.s_upd` and the pending P.
    /// Starts the recursion from the prior of the stored filter in use when it is not running,
    /// or of stored filter `prior_from` (the level before a lowering at this step's
    /// prediction). Nothing is committed. Err when S is not positive definite (its failing
    /// pivot).
    pub(crate) fn update(
        &mut self,
        tier: &TierModel,
        section: &CorotationalTier,
        state: &mut TierState,
        phase: usize,
        prior_from: Option<usize>,
    ) -> Result<(), usize> {
        tier.isa.dispatch(
            #[inline(always)]
            || self.update_on_this_path(tier, section, state, phase, prior_from),
        )
    }

    /// [`Recursion::update`]'s body, inlined into the kernel path's function.
    #[inline(always)]
    fn update_on_this_path(
        &mut self,
        tier: &TierModel,
        section: &CorotationalTier,
        state: &mut TierState,
        phase: usize,
        prior_from: Option<usize>,
    ) -> Result<(), usize> {
        let (r, n) = (tier.r, self.n);
        let filter = tier.filter_index(state.level, state.filter);
        if !self.active {
            let from = prior_from.unwrap_or(filter);
            self.p
                .copy_from_slice(&stored(section, from).phases[phase].prior_covariance.data);
            self.fill_variance(tier, phase);
        }
        let measured = &tier.measured[phase];
        let nm = measured.len();
        // P⁻H_uᵀ (rows of `pht`, one per present channel) and S.
        let mut mu = 0;
        for (a, &j) in measured.iter().enumerate() {
            if !state.present[a] {
                continue;
            }
            let h = channel_row(tier, j as usize);
            // (P⁻ hᵀ)ᵀ = Σ_c h_c P⁻[c, ·] (P⁻ symmetric): row operations.
            let out = &mut self.pht[mu * n..(mu + 1) * n];
            out.iter_mut().for_each(|v| *v = 0.0);
            for (&hc, row) in h.iter().zip(self.p.chunks_exact(n)) {
                for (o, pv) in out.iter_mut().zip(row) {
                    *o += hc * pv;
                }
            }
            self.weights[mu] = state.innovation[a];
            mu += 1;
        }
        let s = &mut self.innovation_covariance[..mu * mu];
        let mut k = 0;
        for (a, &j) in measured.iter().enumerate() {
            if !state.present[a] {
                continue;
            }
            let h = channel_row(tier, j as usize);
            for l in 0..mu {
                s[k * mu + l] = dot(h, &self.pht[l * n..l * n + r]);
            }
            s[k * mu + k] += tier.measurement_variance[j as usize];
            k += 1;
        }
        kernel::cholesky(s, mu)?;
        kernel::cholesky_solve(s, mu, &mut self.weights[..mu]);
        // s⁺ = s⁻ + Σ_k w_k (P⁻H_uᵀ)[·, k].
        state.s_upd.copy_from_slice(&state.s);
        for (column, &w) in self.pht.chunks_exact(n).zip(&self.weights[..mu]) {
            for (o, g) in state.s_upd.iter_mut().zip(column) {
                *o += g * w;
            }
        }
        state.filter_upd = tier.nearest_filter(&state.s_upd[..r]);
        // P = P⁻ − Vᵀ V with V = L⁻¹ (P⁻H_uᵀ)ᵀ (forward substitution, in place).
        for k in 0..mu {
            for l in 0..k {
                let f = s[k * mu + l];
                let (done, rest) = self.pht.split_at_mut(k * n);
                for (o, v) in rest[..n].iter_mut().zip(&done[l * n..(l + 1) * n]) {
                    *o -= f * v;
                }
            }
            let d = s[k * mu + k];
            self.pht[k * n..(k + 1) * n]
                .iter_mut()
                .for_each(|v| *v /= d);
        }
        self.p_upd.copy_from_slice(&self.p);
        for v in self.pht[..mu * n].chunks_exact(n) {
            for i in 0..n {
                let vi = v[i];
                for (o, vj) in self.p_upd[i * n..(i + 1) * n].iter_mut().zip(v) {
                    *o -= vi * vj;
                }
            }
        }
        symmetrise(&mut self.p_upd, n);
        // Back to the stored filter when every channel was used and the prior is near the
        // stored one or no longer approaching it (module docs).
        let stored_variance = tier.innovation_variance(filter, phase);
        let stored_prior = &stored(section, filter).phases[phase].prior_covariance.data;
        self.excess_upd = if mu == nm {
            (3 * r..n)
                .map(|i| self.p[i * n + i] / stored_prior[i * n + i])
                .fold(0.0, f64::max)
        } else {
            f64::INFINITY
        };
        let channels_near = self.variance[..nm]
            .iter()
            .zip(stored_variance)
            .all(|(&v, &s)| v <= (1.0 + SETTLED) * s);
        self.settles = settles(mu == nm, channels_near, self.excess_upd, self.excess);
        Ok(())
    }

    /// The pending update's P (finite: checked by the caller with the state).
    pub(crate) fn pending(&self) -> &[f64] {
        &self.p_upd
    }

    /// Commits the last [`Recursion::update`]: P ← the pending P; the recursion stops when it
    /// settled.
    pub(crate) fn commit(&mut self) {
        std::mem::swap(&mut self.p, &mut self.p_upd);
        self.active = !self.settles;
        self.excess = if self.active {
            self.excess_upd
        } else {
            f64::INFINITY
        };
    }

    /// The prior innovation variances of the last update's active channels (valid after
    /// [`Recursion::update`]).
    pub(crate) fn variance(&self, count: usize) -> &[f64] {
        &self.variance[..count]
    }

    /// P (n × n, row-major) while running: P⁻ after a prediction, P after an update.
    pub(crate) fn covariance(&self) -> Option<&[f64]> {
        self.active.then_some(&self.p[..])
    }

    /// Read-out σ sqrt(diag(C P_qq Cᵀ)) from P into `out`, one per row C of `rows` (r each:
    /// a sensor's or a node set's rows; valid while running). Computed when read, not per step.
    pub(crate) fn std_of_rows(&self, tier: &TierModel, rows: &[f64], out: &mut [f64]) {
        let r = tier.r;
        for (o, row) in out.iter_mut().zip(rows.chunks_exact(r)) {
            *o = quadratic(row, &self.p, self.n, r).max(0.0).sqrt();
        }
    }
}

/// F (n × n, row-major) of the tier's step linearised at `state`'s Newton matrix, as the
/// recursion forms it (module docs: F = D + E G); for checks against an independent
/// linearisation. `None` before the first step (no Newton matrix yet). Allocates.
pub fn linearised_step(tier: &TierModel, state: &TierState) -> Option<Vec<f64>> {
    if !state.has_factor {
        return None;
    }
    let (r, n) = (tier.r, tier.n);
    let mut rec = Recursion::new(tier);
    rec.transition(tier, state);
    let mut f = vec![0.0; n * n];
    for i in 0..n {
        rec.shape.for_row(i, |c, v| f[i * n + c] += v);
        if i < 3 * r {
            let (e, d) = (rec.shape.lift[i / r], i % r);
            for c in 0..n {
                f[i * n + c] += e * rec.g[d * n + c];
            }
        }
    }
    Some(f)
}

/// The sparse part of F = D + E G (module docs): D's rows and E's coefficients.
#[derive(Clone, Debug)]
struct Shape {
    r: usize,
    /// Force states and whether their rates follow them.
    nf: usize,
    rates: bool,
    dt: f64,
    /// advance(u, v, a, û)'s coefficient of source `src` (u, v, a) in output `blk`
    /// (u', v', a'): `coeff[src][blk]`.
    coeff: [[f64; 3]; 3],
    /// advance's coefficient of û in output `blk`: E's entries.
    lift: [f64; 3],
}

impl Shape {
    fn new(tier: &TierModel) -> Self {
        // advance(u, v, a, û) is linear: its coefficients from unit arguments.
        let w = wilson(tier).scheme;
        let unit = |k: usize| {
            let mut x = [0.0; 4];
            x[k] = 1.0;
            let (u, v, a) = w.advance(x[0], x[1], x[2], x[3]);
            [u, v, a]
        };
        Shape {
            r: tier.r,
            nf: tier.force_channels.len(),
            rates: tier.force_rates,
            dt: tier.dt,
            coeff: std::array::from_fn(unit),
            lift: unit(3),
        }
    }

    /// Calls `each(c, D[i, c])` for the nonzero entries of row i of D.
    #[inline(always)]
    fn for_row(&self, i: usize, mut each: impl FnMut(usize, f64)) {
        let (r, nf) = (self.r, self.nf);
        if i < 3 * r {
            let (blk, d) = (i / r, i % r);
            for src in 0..3 {
                each(src * r + d, self.coeff[src][blk]);
            }
        } else if i < 3 * r + nf {
            each(i, 1.0);
            if self.rates {
                each(i + nf, self.dt);
            }
        } else {
            each(i, 1.0);
        }
    }

    /// out = x Dᵀ (x, out of length n): out[j] = Σ_c D[j, c] x[c], block by block.
    #[inline(always)]
    fn times_dt(&self, x: &[f64], out: &mut [f64]) {
        let (r, nf) = (self.r, self.nf);
        for blk in 0..3 {
            let o = &mut out[blk * r..(blk + 1) * r];
            o.iter_mut().for_each(|v| *v = 0.0);
            for src in 0..3 {
                let c = self.coeff[src][blk];
                for (ov, xv) in o.iter_mut().zip(&x[src * r..(src + 1) * r]) {
                    *ov += c * xv;
                }
            }
        }
        for k in 0..nf {
            let i = 3 * r + k;
            out[i] = x[i] + if self.rates { self.dt * x[i + nf] } else { 0.0 };
        }
        out[3 * r + nf..].copy_from_slice(&x[3 * r + nf..]);
    }
}

/// Stored filter `filter` ([`TierModel::filter_index`]) of the model file's tier section, whose
/// covariances the recursion reads in place (not copied into the prepared tier: a multi-rate
/// tier stores a prior per phase and filter).
fn stored(section: &CorotationalTier, filter: usize) -> &KalmanGains {
    section
        .filters()
        .nth(filter)
        .expect("the prepared tier's filters are the section's")
}

/// Whether the recursion hands back to the stored filter after an update (module docs): every
/// channel used, every channel's innovation variance near the stored one (`channels_near`), and
/// the force states' largest variance ratio to the stored filter's, `excess`, within
/// [`SETTLED`] or no longer falling by [`SETTLING_RATE`] from the last such update's
/// (`previous`, +∞ for none).
fn settles(all_used: bool, channels_near: bool, excess: f64, previous: f64) -> bool {
    all_used
        && channels_near
        && (excess <= 1.0 + SETTLED || excess >= (1.0 - SETTLING_RATE) * previous)
}

/// H's row of measurement channel j (r, over q).
#[inline(always)]
fn channel_row(tier: &TierModel, j: usize) -> &[f64] {
    let (s, c) = tier.channel[j];
    &tier.sensor_rows[s][c * tier.r..(c + 1) * tier.r]
}

/// h P_qq hᵀ for a row h of length r and the leading r × r block of the n × n P.
#[inline(always)]
fn quadratic(h: &[f64], p: &[f64], n: usize, r: usize) -> f64 {
    h.iter()
        .zip(p.chunks_exact(n))
        .map(|(hi, row)| hi * dot(&row[..r], h))
        .sum()
}

/// a · b with eight independent partial sums (a vector register's worth: the sum is not
/// latency-bound on one accumulator as the sequential one is).
#[inline(always)]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f64 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in ca.zip(cb) {
        for l in 0..8 {
            acc[l] += x[l] * y[l];
        }
    }
    ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7])) + tail
}

/// A ← (A + Aᵀ)/2 (n × n, row-major).
#[inline(always)]
fn symmetrise(a: &mut [f64], n: usize) {
    for i in 0..n {
        for j in i + 1..n {
            let v = 0.5 * (a[i * n + j] + a[j * n + i]);
            a[i * n + j] = v;
            a[j * n + i] = v;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settles_near_the_stored_filter_or_when_the_excess_stops_falling() {
        // Near the stored filter.
        assert!(settles(true, true, 1.05, f64::INFINITY));
        // Above it and still falling by more than SETTLING_RATE: not yet.
        assert!(!settles(true, true, 1.5, f64::INFINITY));
        assert!(!settles(true, true, 1.5, 1.6));
        // Above it and no longer falling (its own steady state): hand back.
        assert!(settles(true, true, 1.5, 1.5 * (1.0 + 0.5 * SETTLING_RATE)));
        assert!(settles(true, true, 1.5, 1.4));
        // A channel missing, or a channel's variance above the stored one: never.
        assert!(!settles(false, true, 1.0, 1.0));
        assert!(!settles(true, false, 1.0, 1.0));
    }
}
