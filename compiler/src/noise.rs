//! The noise model of both tiers' filters (docs/design.md §6, §11.4–11.5, §11.8–11.9): what the
//! scene states of it as one value, [`NoiseSpec`] (built once, `FullOrder::noise_spec`; the
//! noise identification varies a copy, never the scene), and which stochastic states a filter
//! carries beyond the model's own and their σ, [`NoiseModel`], built from a spec, its derived σ
//! fixed by [`NoiseModel::derive`], and read by
//! the warped tier's force states (`crate::reduced::ReducedModel::with_force_states`), the
//! co-rotational tier's filter design (`crate::nonlinear::filter`), the model file's tier
//! section (refiltering a file for a scene) and the noise identification
//! (`crate::identify::als_noise`).
//!
//! - per estimated load group (`force_model = "random_walk"`): 3 force states f (world force
//!   on the co-rotational tier, the co-rotated force on the warped one, N),
//!   f_{k+1} = f_k + w, w ~ N(0, σ² I₃), entering the step through the group's input channels.
//!   σ is either stated (`force_noise_std`) or derived from the load's range and rise time
//!   ([`ForceSigma::Derived`], §11.8);
//! - with force rates (`force_rate_noise_std` σ_ḟ > 0 on every such group; co-rotational tier):
//!   3 rate states ḟ per group, f_{k+1} = f_k + Δt ḟ_k + w_f, ḟ_{k+1} = ḟ_k + w_ḟ,
//!   w_ḟ ~ N(0, σ_ḟ² I₃);
//! - white process noise: the scene's noise channels except those of the estimated groups,
//!   which the force increments replace.

use crate::algorithms::kalman::lag;
use crate::fem::operators::{InputKind, Operators};

/// Where a load group's force σ comes from (docs/design.md §11.8).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ForceSigma {
    /// Stated by the scene (`force_noise_std`), N per step.
    Stated(f64),
    /// Derived from what the scene states of the load: the smallest σ whose filter lags the
    /// fastest stated ramp, `range` (N) reached in `rise_time` (s), by at most its own σ.
    Derived {
        /// The largest total force, N.
        range: f64,
        /// The shortest time from zero to `range`, s.
        rise_time: f64,
    },
}

impl ForceSigma {
    /// The force increment per step of the fastest ramp the statement allows, δ = F Δt / T_r
    /// (N); `None` when σ is stated.
    pub fn ramp_increment(&self, dt: f64) -> Option<f64> {
        match *self {
            ForceSigma::Stated(_) => None,
            ForceSigma::Derived { range, rise_time } => Some(range * dt / rise_time),
        }
    }
}

/// What a scene states about one estimated load group's force states.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ForceStatement {
    /// The load group (index into the scene's loads).
    pub load: usize,
    /// Its force σ: stated or to be derived.
    pub sigma: ForceSigma,
    /// σ of the rate increments, N/s per step (0: no rate states).
    pub rate_sigma: f64,
    /// The shortest time in which the load goes from zero to its range, s (the scene's
    /// `rise_time`, its default when not written; also where σ is stated).
    pub rise_time: f64,
}

/// What a scene states about its filters' noise, as one value: each estimated load group's
/// force statement and the factor on the co-rotational tier's measured model error. Built once
/// from the scene (`FullOrder::noise_spec`) and passed to every filter design, refilter and
/// identification; a caller that needs other σ (the noise identification's fixed point, a
/// measurement's explicit override) changes a copy.
#[derive(Clone, Debug, PartialEq)]
pub struct NoiseSpec {
    /// Per estimated load group, in scene order.
    pub forces: Vec<ForceStatement>,
    /// Factor on the tier's measured model error S in its filter's process noise (S × this
    /// factor; 0: no such term; docs/design.md §11.9).
    pub model_error_scale: f64,
}

impl NoiseSpec {
    /// The statement of load group `load` (index into the scene's loads), if it is estimated.
    pub fn force_mut(&mut self, load: usize) -> Option<&mut ForceStatement> {
        self.forces.iter_mut().find(|f| f.load == load)
    }

    /// Every estimated load's force σ stated as `sigma`, N per step (nothing left to derive).
    pub fn with_force_sigma(mut self, sigma: f64) -> Self {
        for f in &mut self.forces {
            f.sigma = ForceSigma::Stated(sigma);
        }
        self
    }
}

/// Why the scene's noise model cannot be built.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum NoiseError {
    /// A load group lacks its input channels (a programming error of the operators).
    #[error("load group {load} has no input channel for component {component}")]
    MissingChannel {
        /// The load group.
        load: usize,
        /// x, y or z.
        component: usize,
    },
    /// Rates on some estimated groups but not on all.
    #[error("force_rate_noise_std must be set on every estimated load or on none")]
    PartialRates,
}

/// One estimated load group's force states (3, x, y, z).
#[derive(Clone, Debug, PartialEq)]
pub struct ForceGroup {
    /// The load group (index into the scene's loads).
    pub load: usize,
    /// The deterministic input channels of its x, y, z components (indices into
    /// `Operators::inputs`).
    pub channels: [usize; 3],
    /// Where σ comes from.
    pub statement: ForceSigma,
    /// σ of the force increments, N per step: the stated one, or the derived one once
    /// [`NoiseModel::derive`] ran (before: the stated ramp's increment δ, a first guess).
    pub sigma: f64,
    /// σ of the rate increments, N/s per step (0: no rate states).
    pub rate_sigma: f64,
    /// The load's rise time, s ([`ForceStatement::rise_time`]).
    pub rise_time: f64,
}

/// The states of a filter beyond the model's own and the white noise it keeps (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct NoiseModel {
    /// The estimated load groups with force states, in scene order.
    pub groups: Vec<ForceGroup>,
    /// Whether every group's force states carry their rates (3 more states per group).
    pub rates: bool,
    /// The white process-noise channels (indices into `Operators::noise`).
    pub white: Vec<usize>,
    /// Factor on the tier's measured model error ([`NoiseSpec::model_error_scale`]).
    pub model_error_scale: f64,
}

/// One derived σ, for the compile's notes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Derivation {
    /// The load group.
    pub load: usize,
    /// The derived σ, N per step.
    pub sigma: f64,
    /// The fastest stated ramp's increment δ, N per step.
    pub ramp_increment: f64,
    /// λ of the derived σ's filter (≤ 1 unless the search range ran out).
    pub lag: f64,
}

impl Derivation {
    /// The compile's note on this σ, for the load named `name`.
    pub fn note(&self, name: &str) -> String {
        format!(
            "load '{name}': force σ {:.3e} N per step, derived from its range and rise time (the \
             fastest stated ramp adds {:.3e} N per step; the filter's steady lag on it is {:.2} of \
             its own σ){}",
            self.sigma,
            self.ramp_increment,
            self.lag.sqrt(),
            if self.lag > 1.0 {
                " — NOT within one σ: no σ up to 1000 × the ramp's increment reached it"
            } else {
                ""
            }
        )
    }
}

impl NoiseModel {
    /// The noise model of `spec` on the operators `ops`, the time step `dt` (s) giving the
    /// first guess of a derived σ.
    pub fn new(spec: &NoiseSpec, ops: &Operators, dt: f64) -> Result<Self, NoiseError> {
        let statements = &spec.forces;
        let mut groups = Vec::with_capacity(statements.len());
        for s in statements {
            let mut channels = [0; 3];
            for (c, channel) in channels.iter_mut().enumerate() {
                *channel = load_channel(ops, s.load, c).ok_or(NoiseError::MissingChannel {
                    load: s.load,
                    component: c,
                })?;
            }
            let sigma = match s.sigma {
                ForceSigma::Stated(sigma) => sigma,
                derived => derived.ramp_increment(dt).unwrap_or(0.0),
            };
            groups.push(ForceGroup {
                load: s.load,
                channels,
                statement: s.sigma,
                sigma,
                rate_sigma: s.rate_sigma,
                rise_time: s.rise_time,
            });
        }
        let rates = if statements.iter().all(|s| s.rate_sigma == 0.0) {
            false
        } else if statements.iter().all(|s| s.rate_sigma > 0.0) {
            true
        } else {
            return Err(NoiseError::PartialRates);
        };
        let white = (0..ops.noise.len())
            .filter(|&j| match ops.noise[j].kind {
                InputKind::Noise { load: Some(g) } => !statements.iter().any(|s| s.load == g),
                _ => true,
            })
            .collect();
        Ok(NoiseModel {
            groups,
            rates,
            white,
            model_error_scale: spec.model_error_scale,
        })
    }

    /// The same noise model without rate states (the derivation's filter, §11.8).
    pub fn without_rates(&self) -> NoiseModel {
        NoiseModel {
            rates: false,
            ..self.clone()
        }
    }

    /// Fixes every derived σ (docs/design.md §11.8): for each group with a
    /// [`ForceSigma::Derived`] statement, the smallest σ for which `lag(model, k)` — λ of group
    /// k's force block in the filter designed for `model` ([`lag::ramp_lag`] with that group's
    /// ramp increment) — is at most 1, by bisection in log σ over [δ/10³, δ·10³]. With several
    /// derived groups the search runs group by group, three rounds. Returns what was derived.
    pub fn derive<E>(
        &mut self,
        dt: f64,
        mut lag: impl FnMut(&NoiseModel, usize, f64) -> Result<f64, E>,
    ) -> Result<Vec<Derivation>, E> {
        let derived: Vec<(usize, f64)> = self
            .groups
            .iter()
            .enumerate()
            .filter_map(|(k, g)| g.statement.ramp_increment(dt).map(|d| (k, d)))
            .collect();
        let rounds = if derived.len() > 1 { 3 } else { 1 };
        let mut out = Vec::with_capacity(derived.len());
        for round in 0..rounds {
            for &(k, delta) in &derived {
                let (sigma, lambda) = lag::smallest_honest_sigma(delta * 1e-3, delta * 1e3, |s| {
                    let mut trial = self.clone();
                    trial.groups[k].sigma = s;
                    lag(&trial, k, delta)
                })?;
                self.groups[k].sigma = sigma;
                if round + 1 == rounds {
                    out.push(Derivation {
                        load: self.groups[k].load,
                        sigma,
                        ramp_increment: delta,
                        lag: lambda,
                    });
                }
            }
        }
        Ok(out)
    }

    /// The shortest rise time of the estimated loads, s (`None` without force states): the
    /// time over which the force-σ levels' statistic averages (docs/design.md §11.10).
    pub fn shortest_rise_time(&self) -> Option<f64> {
        self.groups
            .iter()
            .map(|g| g.rise_time)
            .min_by(f64::total_cmp)
    }

    /// The load groups with force states (indices into the scene's loads): the model file's
    /// `force_loads`.
    pub fn force_loads(&self) -> Vec<usize> {
        self.groups.iter().map(|g| g.load).collect()
    }

    /// Per force state (3 per group, x, y, z): its input channel.
    pub fn force_channels(&self) -> Vec<usize> {
        self.groups.iter().flat_map(|g| g.channels).collect()
    }

    /// Per force state: σ of its increments, N per step.
    pub fn force_sigma(&self) -> Vec<f64> {
        self.groups.iter().flat_map(|g| [g.sigma; 3]).collect()
    }

    /// Per rate state (3 per group): σ of its increments, N/s per step; empty without rates.
    pub fn rate_sigma(&self) -> Vec<f64> {
        if !self.rates {
            return Vec::new();
        }
        self.groups.iter().flat_map(|g| [g.rate_sigma; 3]).collect()
    }
}

/// The deterministic input channel of component `c` of load group `load`, if any.
pub fn load_channel(ops: &Operators, load: usize, c: usize) -> Option<usize> {
    ops.inputs
        .iter()
        .position(|ch| ch.kind == InputKind::Load { load, component: c })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn group(load: usize, statement: ForceSigma, dt: f64) -> ForceGroup {
        ForceGroup {
            load,
            channels: [3 * load, 3 * load + 1, 3 * load + 2],
            statement,
            sigma: match statement {
                ForceSigma::Stated(s) => s,
                d => d.ramp_increment(dt).unwrap(),
            },
            rate_sigma: 0.0,
            rise_time: 0.2,
        }
    }

    /// λ = (c_k / σ_k)³ (the scalar law of kalman::lag) with c_k growing with the other group's
    /// σ: the derived σ are the fixed point, stated σ are left alone.
    #[test]
    fn derived_sigmas_meet_the_lag_criterion_and_stated_ones_stay() {
        let dt = 1e-3;
        let mut noise = NoiseModel {
            groups: vec![
                group(
                    0,
                    ForceSigma::Derived {
                        range: 1.0,
                        rise_time: 0.2,
                    },
                    dt,
                ),
                group(1, ForceSigma::Stated(0.25), dt),
                group(
                    2,
                    ForceSigma::Derived {
                        range: 2.0,
                        rise_time: 0.1,
                    },
                    dt,
                ),
            ],
            rates: false,
            white: Vec::new(),
            model_error_scale: 1.0,
        };
        let lag = |m: &NoiseModel, k: usize, delta: f64| {
            let other = m.groups[2 - k].sigma;
            let c = 3.0 * delta * (1.0 + 0.1 * other);
            Ok::<_, ()>((c / m.groups[k].sigma).powi(3))
        };
        let derived = noise.derive(dt, lag).unwrap();
        assert_eq!(derived.len(), 2);
        assert_eq!(noise.groups[1].sigma, 0.25);
        for d in &derived {
            assert!(d.lag <= 1.0 && d.lag > 0.95, "λ {}", d.lag);
        }
        // δ = F Δt / T_r: 5e-3 and 2e-2 N per step.
        assert!((derived[0].ramp_increment - 5e-3).abs() < 1e-15);
        assert!((derived[1].ramp_increment - 2e-2).abs() < 1e-15);
        let (s0, s2) = (noise.groups[0].sigma, noise.groups[2].sigma);
        assert!(
            (s0 / (3.0 * 5e-3 * (1.0 + 0.1 * s2)) - 1.0).abs() < 0.02,
            "σ0 {s0}"
        );
        assert!(
            (s2 / (3.0 * 2e-2 * (1.0 + 0.1 * s0)) - 1.0).abs() < 0.02,
            "σ2 {s2}"
        );
    }
}
