//! The noise model of the co-rotational tier's filter (docs/design.md §11.4–11.5): which
//! stochastic states the filter carries and their σ, built once from the scene
//! ([`NoiseModel::of_scene`]) and read by the filter design ([`super::filter`]), the model
//! file's tier section (`crate::model_file::tier`: refiltering a file for a scene) and the
//! noise identification ([`super::identify`]).
//!
//! - per random-walk load group (`force_model = "random_walk"`, `force_noise_std` σ > 0):
//!   3 force states f (world force, N), f_{k+1} = f_k + w, w ~ N(0, σ² I₃), entering the step
//!   through the group's input channels;
//! - with force rates (`force_rate_noise_std` σ_ḟ > 0 on every such group): 3 rate states ḟ
//!   per group, f_{k+1} = f_k + Δt ḟ_k + w_f, ḟ_{k+1} = ḟ_k + w_ḟ, w_ḟ ~ N(0, σ_ḟ² I₃);
//! - white process noise: the scene's noise channels except those of the random-walk groups,
//!   which the force increments replace.

use crate::fem::operators::InputKind;
use crate::full_order::FullOrder;

use super::NonlinearError;

/// One random-walk load group's force states (3, world x, y, z).
#[derive(Clone, Debug, PartialEq)]
pub struct ForceGroup {
    /// The load group (index into the scene's loads).
    pub load: usize,
    /// The deterministic input channels of its x, y, z components (indices into
    /// `full.operators.inputs`).
    pub channels: [usize; 3],
    /// σ of the force increments, N per step.
    pub sigma: f64,
    /// σ of the rate increments, N/s per step (0: no rate states).
    pub rate_sigma: f64,
}

/// The states of the tier's filter beyond (q, q̇, q̈) and the white noise it keeps (module
/// docs).
#[derive(Clone, Debug, PartialEq)]
pub struct NoiseModel {
    /// The random-walk load groups with force states, in scene order.
    pub groups: Vec<ForceGroup>,
    /// Whether every group's force states carry their rates (3 more states per group).
    pub rates: bool,
    /// The white process-noise channels (indices into `full.operators.noise`).
    pub white: Vec<usize>,
}

impl NoiseModel {
    /// The scene's noise model: its random-walk loads ([`FullOrder::random_walk_loads`]) with
    /// their rates ([`FullOrder::force_rate_sigmas`], on every group or on none) and the white
    /// channels they do not replace.
    pub fn of_scene(full: &FullOrder) -> Result<Self, NonlinearError> {
        let loads = full.random_walk_loads();
        let rates = full.force_rate_sigmas();
        let mut groups = Vec::with_capacity(loads.len());
        for (&(g, sigma), &rate_sigma) in loads.iter().zip(&rates) {
            let mut channels = [0; 3];
            for (c, channel) in channels.iter_mut().enumerate() {
                *channel = load_channel(full, g, c).ok_or_else(|| {
                    NonlinearError::Invalid(format!(
                        "tier filter: load group {g} has no input channel for component {c}"
                    ))
                })?;
            }
            groups.push(ForceGroup {
                load: g,
                channels,
                sigma,
                rate_sigma,
            });
        }
        let with_rates = if rates.iter().all(|&r| r == 0.0) {
            false
        } else if rates.iter().all(|&r| r > 0.0) {
            true
        } else {
            return Err(NonlinearError::Invalid(
                "tier filter: force_rate_noise_std must be set on every random-walk load or on \
                 none"
                    .into(),
            ));
        };
        let white = (0..full.operators.noise.len())
            .filter(|&j| match full.operators.noise[j].kind {
                InputKind::Noise { load: Some(g) } => !loads.iter().any(|&(l, _)| l == g),
                _ => true,
            })
            .collect();
        Ok(NoiseModel {
            groups,
            rates: with_rates,
            white,
        })
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
pub(crate) fn load_channel(full: &FullOrder, load: usize, c: usize) -> Option<usize> {
    full.operators
        .inputs
        .iter()
        .position(|ch| ch.kind == InputKind::Load { load, component: c })
}
