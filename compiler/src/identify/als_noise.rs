//! Noise identification of a compiled tier's filter (docs/design.md §11.6), the algorithm of
//! [`crate::identify`]: the σ of the noise model ([`crate::noise`]) fitted to the innovations of a run of the model file's filter by
//! autocovariance least squares ([`crate::algorithms::kalman::als`]), gain schedule included.

use faer::linalg::solvers::Solve as _;
use faer::Mat;
use nalgebra::DVector;

use crokf_formats as fmt;

use crate::algorithms::kalman;
use crate::full_order::FullOrder;
use crate::model_file::tier::{linearised_of_file, reduced_model_of_file};
use crate::noise::NoiseSpec;

use crate::nonlinear::filter::scaled_system;
use crate::nonlinear::NonlinearError;

/// What [`identify_noise`] found for one random-walk load group: σ in the scene and σ
/// identified, for the force (N per step) and, with rate states, its rate (N/s per step).
#[derive(Clone, Debug)]
pub struct IdentifiedLoad {
    /// The load group (index into the scene's loads).
    pub load: usize,
    /// σ_f of the scene and identified.
    pub force_sigma: (f64, f64),
    /// σ_ḟ of the scene and identified (rate states only).
    pub rate_sigma: Option<(f64, f64)>,
}

/// The tier filter's noise identified from its innovations ([`identify_noise`]).
#[derive(Clone, Debug)]
pub struct IdentifiedNoise {
    /// Per random-walk load group.
    pub loads: Vec<IdentifiedLoad>,
    /// The factor on the σ of the white process-noise channels (None without any).
    pub white_scale: Option<f64>,
    /// The tier's model error (docs/design.md §11.9): (the filters' factor on the measured S,
    /// the factor identified, also on the measured S); None when the tier has no measured
    /// model error.
    pub model_error_scale: Option<(f64, f64)>,
    /// The factor on the markers' σ.
    pub measurement_scale: f64,
    /// The least-squares fit (θ per parameter: white, then per load force and rate, then the
    /// model error, then R).
    pub estimate: kalman::als::AlsEstimate,
}

/// The noise of a model file's tier filter identified by autocovariance least squares
/// (docs/design.md §11.6, [`kalman::als`]) from the innovations of a run of that filter, gain
/// schedule included, from rest: `innovations[k]` = y_k − H V q⁻_k at every step k (in the
/// model's measurement order, NaN for a channel the step's phase does not measure), `filters[k]`
/// = (the schedule's filter that updated step k, the step's phase) (`Estimator::tier_filter`
/// after the update: 0 rest, i ≥ 1 `scheduled[i − 1]`; `Estimator::phase`), the innovation gate
/// off; the first `skip` steps are left out of the statistics. The gains are
/// the model file's (those the run used); the transitions are the tier linearised at rest and
/// at each scheduled point, all mapped into the rest filter's scaled coordinates. Parameters:
/// a factor on the variance of the white channels, of each random-walk load group's force
/// increments and rate increments, of the tier's model error (when the filter has that term,
/// docs/design.md §11.9) and of the markers' variance; each is σ² × θ, θ ≥ 0, σ those of
/// the noise `spec` (the run's filters' σ, on the scene `full`'s loads and markers: the same as
/// the model's).
/// Approximation: a white channel's process noise enters through the modal load of the rest
/// linearisation at every point (the force, rate and marker parameters are exact; the example
/// scenes have no white channel on the tier). Lags 0 … `lags`−1.
pub fn identify_noise(
    full: &FullOrder,
    spec: &NoiseSpec,
    model: &fmt::Model,
    innovations: &[Vec<f64>],
    filters: &[(usize, usize)],
    skip: usize,
    lags: usize,
) -> Result<IdentifiedNoise, NonlinearError> {
    let (lin, measurements, noise) = linearised_of_file(full, model, spec)?;
    let Some(t) = model.tier.as_ref() else {
        return Err(NonlinearError::Invalid("the model has no tier".into()));
    };
    let sys = scaled_system(&lin, &measurements)?;
    let (n, m) = (sys.f.nrows(), measurements.channels.len());
    let t0 = sys.t.partial_piv_lu();
    let period = t.kalman.period as usize;
    // The file's gains of a filter per phase (s coordinates, the phase's channels) as
    // K̂ = T₀⁻¹ K_s with a zero column for each channel the phase does not measure.
    let gains_of = |k: &fmt::KalmanGains, which: usize| -> Result<Vec<Mat<f64>>, NonlinearError> {
        if k.phases.len() != period {
            return Err(NonlinearError::Invalid(format!(
                "noise identification: filter {which} has {} phases, the tier {period}",
                k.phases.len()
            )));
        }
        k.phases
            .iter()
            .map(|phase| {
                let cols = phase.measured.len();
                if phase.gain.rows as usize != n
                    || phase.gain.cols as usize != cols
                    || phase.measured.iter().any(|&j| j as usize >= m)
                {
                    return Err(NonlinearError::Invalid(format!(
                        "noise identification: filter {which}'s gain does not fit its channels"
                    )));
                }
                let mut gain = Mat::<f64>::zeros(n, m);
                for (a, &j) in phase.measured.iter().enumerate() {
                    for i in 0..n {
                        gain[(i, j as usize)] = phase.gain.data[i * cols + a];
                    }
                }
                Ok(t0.solve(&gain))
            })
            .collect()
    };
    let mut transitions = vec![sys.f.clone()];
    let mut gains = vec![gains_of(&t.kalman, 0)?];
    if !t.scheduled.is_empty() {
        let reduced = reduced_model_of_file(full, t)?;
        for (i, point) in t.scheduled.iter().enumerate() {
            let at = lin.at(&reduced, &DVector::from_column_slice(&point.point));
            let sys_i = scaled_system(&at, &measurements)?;
            // x̂ = T₀⁻¹ s = X x̃_i, X = T₀⁻¹ T_i: F̂ = X F̃_i X⁻¹.
            let x = t0.solve(&sys_i.t);
            let xf = &x * &sys_i.f;
            let f_hat = x
                .transpose()
                .partial_piv_lu()
                .solve(xf.transpose())
                .transpose()
                .to_owned();
            transitions.push(f_hat);
            gains.push(gains_of(&point.kalman, i + 1)?);
        }
    }
    // One (F̂, K̂) per filter and phase, indexed filter · period + phase.
    let (transitions, gains): (Vec<Mat<f64>>, Vec<Mat<f64>>) = transitions
        .iter()
        .zip(&gains)
        .flat_map(|(f, per_phase)| per_phase.iter().map(move |k| (f.clone(), k.clone())))
        .unzip();
    if let Some(k) = filters.iter().position(|&(i, p)| {
        p >= period
            || i.checked_mul(period)
                .and_then(|x| x.checked_add(p))
                .is_none_or(|x| x >= gains.len())
    }) {
        return Err(NonlinearError::Invalid(format!(
            "noise identification: step {k} names filter {} phase {}, the model has {} filters \
             of {period} phases",
            filters[k].0,
            filters[k].1,
            gains.len() / period.max(1)
        )));
    }
    let sequence: Vec<usize> = filters.iter().map(|&(i, p)| i * period + p).collect();
    let (nw, nf, nr) = (
        lin.noise_columns.len(),
        lin.force_columns.len(),
        lin.rate_sigma.len(),
    );
    let part = |name: String, columns: std::ops::Range<usize>| {
        let g = sys.noise.subcols(columns.start, columns.len());
        kalman::als::NoiseParameter {
            name,
            process: g * g.transpose(),
            measurement: vec![0.0; m],
        }
    };
    let mut parameters = Vec::new();
    if nw > 0 {
        parameters.push(part("white process noise".into(), 0..nw));
    }
    for (i, group) in noise.groups.iter().enumerate() {
        let name = &full.scene.scene.loads[group.load].name;
        parameters.push(part(
            format!("force of load '{name}'"),
            nw + 3 * i..nw + 3 * i + 3,
        ));
        if nr > 0 {
            parameters.push(part(
                format!("force rate of load '{name}'"),
                nw + nf + 3 * i..nw + nf + 3 * i + 3,
            ));
        }
    }
    // The model error at factor 1 on the measured S: θ is the factor itself (also where the
    // filters ran with another factor, or without the term).
    let nm = sys.model_error_unit.ncols();
    if nm > 0 {
        let g = &sys.model_error_unit;
        parameters.push(kalman::als::NoiseParameter {
            name: "the tier's model error".into(),
            process: g * g.transpose(),
            measurement: vec![0.0; m],
        });
    }
    parameters.push(kalman::als::NoiseParameter {
        name: "markers".into(),
        process: Mat::zeros(n, n),
        measurement: measurements.variance.clone(),
    });
    let estimate = kalman::als::scheduled_autocovariance_least_squares(
        sys.h.as_ref(),
        kalman::als::GainSchedule {
            transitions: &transitions,
            gains: &gains,
            sequence: &sequence,
        },
        &parameters,
        innovations,
        skip,
        lags,
    )
    .map_err(|e| NonlinearError::Invalid(e.to_string()))?;
    let theta = &estimate.theta;
    let mut at = usize::from(nw > 0);
    let mut identified = Vec::with_capacity(noise.groups.len());
    for (i, group) in noise.groups.iter().enumerate() {
        let (g, sigma) = (group.load, group.sigma);
        let force_sigma = (sigma, sigma * theta[at].sqrt());
        at += 1;
        let rate_sigma = (nr > 0).then(|| {
            let scene = lin.rate_sigma[3 * i];
            at += 1;
            (scene, scene * theta[at - 1].sqrt())
        });
        identified.push(IdentifiedLoad {
            load: g,
            force_sigma,
            rate_sigma,
        });
    }
    let model_error_scale = (nm > 0).then(|| {
        at += 1;
        (lin.model_error_scale, theta[at - 1])
    });
    Ok(IdentifiedNoise {
        loads: identified,
        model_error_scale,
        white_scale: (nw > 0).then(|| theta[0].sqrt()),
        measurement_scale: theta[at].sqrt(),
        estimate,
    })
}
