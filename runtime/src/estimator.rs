//! The online estimator: periodic steady-state Kalman filter on the reduced model, with the
//! co-rotational maps of DESIGN.md §5 at its boundary. Everything is allocated in
//! [`Estimator::new`]; `predict`, `update`, `step` and the read-outs never allocate (except to
//! build an error value).

use crate::warp::{Vec3, Warp};
use crate::RuntimeError;
use crokf_formats::{InputKind, Matrix, Model};

/// Which covariance the read-out standard deviations come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CovarianceKind {
    /// P⁻ of the phase (after `predict`, before `update`).
    Prior,
    /// P of the phase (after `update`, and initially phase 0).
    Posterior,
}

/// sqrt(diag(C P Cᵀ)) for every read-out row C, precomputed for one phase and one covariance.
#[derive(Clone, Debug)]
struct PhaseStd {
    /// 3 per sensor.
    sensors: Vec<f64>,
    /// 3n per node set.
    nodes: Vec<Vec<f64>>,
}

/// sqrt(cᵀ P c) for every row c of `rows` (k×r), P r×r row-major.
fn row_std(rows: &Matrix, p: &Matrix, out: &mut Vec<f64>, tmp: &mut [f64]) {
    let r = p.cols as usize;
    for i in 0..rows.rows as usize {
        let c = rows.row(i);
        p.mul_vec_into(c, &mut tmp[..r]);
        let v: f64 = c.iter().zip(tmp.iter()).map(|(a, b)| a * b).sum();
        out.push(v.max(0.0).sqrt());
    }
}

/// Σ aᵢ bᵢ over the common length, with four independent partial sums (lets the compiler
/// vectorise; the summation order differs from a plain left-to-right sum by rounding only).
#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let mut acc = [0.0f64; 4];
    let (ac, bc) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ar, br) = (ac.remainder(), bc.remainder());
    for (x, y) in ac.zip(bc) {
        acc[0] += x[0] * y[0];
        acc[1] += x[1] * y[1];
        acc[2] += x[2] * y[2];
        acc[3] += x[3] * y[3];
    }
    let tail: f64 = ar.iter().zip(br).map(|(x, y)| x * y).sum();
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

/// Dense row-major y = A x (+= when `add`), A given as a flat slice with `cols` columns.
#[inline]
fn matvec(a: &[f64], cols: usize, x: &[f64], y: &mut [f64], add: bool) {
    if cols == 0 {
        if !add {
            y.iter_mut().for_each(|v| *v = 0.0);
        }
        return;
    }
    for (yi, row) in y.iter_mut().zip(a.chunks_exact(cols)) {
        let s = dot(row, x);
        if add {
            *yi += s;
        } else {
            *yi = s;
        }
    }
}

/// Three rows (3×r block starting at row `3i`) times x.
#[inline]
fn rows3(m: &Matrix, block: usize, x: &[f64]) -> Vec3 {
    let r = m.cols as usize;
    let base = 3 * block * r;
    let mut out = [0.0; 3];
    for (c, o) in out.iter_mut().enumerate() {
        let row = &m.data[base + c * r..base + (c + 1) * r];
        *o = dot(row, x);
    }
    out
}

/// A periodic steady-state Kalman filter over one [`Model`].
///
/// Step k = 1, 2, …: `predict` forms x⁻_k = F x_{k−1} + G u_lin(k) and selects phase
/// p = k mod period; `update` forms x_k = x⁻_k + K_p (y_lin − H_p x⁻_k) over the channels of
/// phase p. The state starts at rest (x₀ = 0).
#[derive(Clone, Debug)]
pub struct Estimator {
    model: Model,
    r: usize,
    /// Current state x (posterior after `update`, prior after `predict`).
    x: Vec<f64>,
    /// Scratch for F x.
    x_next: Vec<f64>,
    /// Inputs after rotating load channels into the local frame (m).
    u_lin: Vec<f64>,
    /// Per load group: the input channel of each world component.
    load_channels: Vec<[Option<usize>; 3]>,
    /// Per measurement channel: (sensor, component).
    channel: Vec<(usize, usize)>,
    /// Per phase: sensors with at least one active channel.
    phase_sensors: Vec<Vec<usize>>,
    /// Per sensor scratch: y_lin (local frame) and u_lin predicted.
    y_lin: Vec<Vec3>,
    u_pred: Vec<Vec3>,
    /// Per sensor scratch: which components were filled from measurements.
    filled: Vec<[bool; 3]>,
    /// Innovation per active channel of the current phase.
    innovation: Vec<f64>,
    std_prior: Vec<PhaseStd>,
    std_posterior: Vec<PhaseStd>,
    /// Number of predictions since construction/reset.
    k: u64,
    phase: usize,
    cov: CovarianceKind,
    awaiting_update: bool,
}

impl Estimator {
    /// Validates the model, copies it and allocates every buffer; precomputes the read-out
    /// standard deviations sqrt(diag(C P Cᵀ)) for every phase (prior and posterior).
    pub fn new(model: &Model) -> Result<Self, RuntimeError> {
        model.validate()?;
        let model = model.clone();
        let r = model.r();
        let mut load_channels = vec![[None; 3]; model.loads.len()];
        for (j, ch) in model.inputs.iter().enumerate() {
            if let InputKind::Load { load, component } = ch.kind {
                load_channels[load as usize][component as usize] = Some(j);
            }
        }
        let channel: Vec<(usize, usize)> = model
            .measurements
            .iter()
            .map(|c| (c.sensor as usize, c.component as usize))
            .collect();
        let phase_sensors = model
            .kalman
            .phases
            .iter()
            .map(|ph| {
                let mut s: Vec<usize> =
                    ph.measured.iter().map(|&j| channel[j as usize].0).collect();
                s.sort_unstable();
                s.dedup();
                s
            })
            .collect();
        let max_measured = model
            .kalman
            .phases
            .iter()
            .map(|p| p.measured.len())
            .max()
            .unwrap_or(0);
        let mut tmp = vec![0.0; r];
        let std_of = |p: &Matrix, tmp: &mut [f64]| {
            let mut sensors = Vec::with_capacity(3 * model.sensors.len());
            for s in &model.sensors {
                row_std(&s.displacement_rows, p, &mut sensors, tmp);
            }
            let nodes = model
                .node_sets
                .iter()
                .map(|set| {
                    let mut v = Vec::with_capacity(set.displacement_rows.rows as usize);
                    row_std(&set.displacement_rows, p, &mut v, tmp);
                    v
                })
                .collect();
            PhaseStd { sensors, nodes }
        };
        let std_prior = model
            .kalman
            .phases
            .iter()
            .map(|ph| std_of(&ph.prior_covariance, &mut tmp))
            .collect();
        let std_posterior = model
            .kalman
            .phases
            .iter()
            .map(|ph| std_of(&ph.posterior_covariance, &mut tmp))
            .collect();
        let ns = model.sensors.len();
        Ok(Estimator {
            r,
            x: vec![0.0; r],
            x_next: vec![0.0; r],
            u_lin: vec![0.0; model.inputs.len()],
            load_channels,
            channel,
            phase_sensors,
            y_lin: vec![[0.0; 3]; ns],
            u_pred: vec![[0.0; 3]; ns],
            filled: vec![[false; 3]; ns],
            innovation: vec![0.0; max_measured],
            std_prior,
            std_posterior,
            k: 0,
            phase: 0,
            cov: CovarianceKind::Posterior,
            awaiting_update: false,
            model,
        })
    }

    /// The model.
    pub fn model(&self) -> &Model {
        &self.model
    }

    /// Back to rest: x = 0, k = 0, phase 0.
    pub fn reset(&mut self) {
        self.x.iter_mut().for_each(|v| *v = 0.0);
        self.k = 0;
        self.phase = 0;
        self.cov = CovarianceKind::Posterior;
        self.awaiting_update = false;
    }

    /// The reduced state x (length r).
    pub fn state(&self) -> &[f64] {
        &self.x
    }

    /// Overwrites the reduced state (length r, finite).
    pub fn set_state(&mut self, x: &[f64]) -> Result<(), RuntimeError> {
        check_len("state", self.r, x.len())?;
        if let Some(i) = x.iter().position(|v| !v.is_finite()) {
            return Err(RuntimeError::NonFinite {
                what: "state",
                index: i,
                value: x[i],
            });
        }
        self.x.copy_from_slice(x);
        Ok(())
    }

    /// Number of predictions since construction or `reset` (the step index k).
    pub fn step_index(&self) -> u64 {
        self.k
    }

    /// Time of the current estimate, k·Δt (s).
    pub fn time(&self) -> f64 {
        self.k as f64 * self.model.dt
    }

    /// Phase of the current step, k mod period.
    pub fn phase(&self) -> usize {
        self.phase
    }

    /// Whether the read-out standard deviations currently come from P⁻ or P.
    pub fn covariance_kind(&self) -> CovarianceKind {
        self.cov
    }

    /// Measurement channels active in the current phase (indices into `model().measurements`).
    pub fn active_measurements(&self) -> &[u32] {
        &self.model.kalman.phases[self.phase].measured
    }

    /// x⁻ = F x + G u_lin, then k += 1 and the phase becomes k mod period.
    ///
    /// `inputs`: one world-frame value per input channel (`model().inputs`), N for load
    /// channels, a dimensionless scale for gravity. Load channels of group g are rotated into
    /// the local frame, f_lin = R(ω_g)ᵀ f_world with ω_g = W_g x (the current state; a world
    /// component without its own channel counts as 0 and its local image is dropped).
    /// Non-finite inputs are rejected before anything changes.
    pub fn predict(&mut self, inputs: &[f64]) -> Result<(), RuntimeError> {
        check_len("inputs", self.u_lin.len(), inputs.len())?;
        if let Some(i) = inputs.iter().position(|v| !v.is_finite()) {
            return Err(RuntimeError::NonFiniteInput {
                channel: self.model.inputs[i].label.clone(),
                value: inputs[i],
            });
        }
        self.u_lin.copy_from_slice(inputs);
        for (g, chans) in self.load_channels.iter().enumerate() {
            if chans.iter().all(Option::is_none) {
                continue;
            }
            let f_world: Vec3 = [0, 1, 2].map(|c| chans[c].map_or(0.0, |j| inputs[j]));
            let omega = rows3(&self.model.loads[g].rotation_rows, 0, &self.x);
            let f_lin = Warp::new(&omega).rotate_transpose(&f_world);
            for c in 0..3 {
                if let Some(j) = chans[c] {
                    self.u_lin[j] = f_lin[c];
                }
            }
        }
        let r = self.r;
        matvec(
            &self.model.transition.data,
            r,
            &self.x,
            &mut self.x_next,
            false,
        );
        let m = self.u_lin.len();
        matvec(
            &self.model.input.data,
            m,
            &self.u_lin,
            &mut self.x_next,
            true,
        );
        std::mem::swap(&mut self.x, &mut self.x_next);
        self.k += 1;
        self.phase = (self.k % self.model.kalman.period as u64) as usize;
        self.cov = CovarianceKind::Prior;
        self.awaiting_update = true;
        Ok(())
    }

    /// Measurement update of the current phase; `measurements[i]` is the world-frame value of
    /// channel i (`model().measurements`, m), `None` when missing. Returns the number of values
    /// used.
    ///
    /// Only channels active in the phase are used (others are ignored). For each sensor with
    /// an active channel: ω̄ = W_s x⁻; the world displacement y_world is the measured
    /// components, with every other component (unmeasured, inactive or missing) filled from the
    /// prediction R̃(ω̄) C_s x⁻; then y_lin = R̃(ω̄)⁻¹ y_world and the innovation of an active
    /// channel is `y_lin[c] − (C_s x⁻)[c]`. x = x⁻ + K_p · innovation. A phase without active
    /// channels (or with all of them missing) leaves the state unchanged. Errors — wrong
    /// length, a non-finite value, `update` without a preceding `predict`, a non-invertible
    /// R̃ — leave the state untouched.
    pub fn update(&mut self, measurements: &[Option<f64>]) -> Result<usize, RuntimeError> {
        check_len("measurements", self.channel.len(), measurements.len())?;
        self.update_with(|i| measurements[i])
    }

    /// [`Estimator::update`] with measurement i given by `get(i)` (i < number of channels).
    pub fn update_with(
        &mut self,
        get: impl Fn(usize) -> Option<f64>,
    ) -> Result<usize, RuntimeError> {
        if !self.awaiting_update {
            return Err(RuntimeError::UpdateWithoutPredict);
        }
        for i in 0..self.channel.len() {
            if let Some(v) = get(i) {
                if !v.is_finite() {
                    return Err(RuntimeError::NonFiniteMeasurement {
                        channel: self.channel_label(i),
                        value: v,
                    });
                }
            }
        }
        let phase = &self.model.kalman.phases[self.phase];
        // Predicted local displacement and world measurement per active sensor.
        for &s in &self.phase_sensors[self.phase] {
            self.u_pred[s] = rows3(&self.model.sensors[s].displacement_rows, 0, &self.x);
            self.filled[s] = [false; 3];
        }
        let mut used = 0;
        for &j in &phase.measured {
            let (s, c) = self.channel[j as usize];
            if let Some(v) = get(j as usize) {
                self.y_lin[s][c] = v; // world value for now
                self.filled[s][c] = true;
                used += 1;
            }
        }
        for &s in &self.phase_sensors[self.phase] {
            let maps = Warp::new(&rows3(&self.model.sensors[s].rotation_rows, 0, &self.x));
            let pred_world = maps.warp(&self.u_pred[s]);
            let y_world: Vec3 = [0, 1, 2].map(|c| {
                if self.filled[s][c] {
                    self.y_lin[s][c]
                } else {
                    pred_world[c]
                }
            });
            match maps.unwarp(&y_world) {
                Some(y) => self.y_lin[s] = y,
                None => {
                    return Err(RuntimeError::SingularWarp {
                        sensor: self.model.sensors[s].name.clone(),
                        angle: maps.angle(),
                    })
                }
            }
        }
        // Nothing above touched x; apply the update.
        let nm = phase.measured.len();
        for (a, &j) in phase.measured.iter().enumerate() {
            let (s, c) = self.channel[j as usize];
            self.innovation[a] = self.y_lin[s][c] - self.u_pred[s][c];
        }
        matvec(
            &phase.gain.data,
            nm,
            &self.innovation[..nm],
            &mut self.x,
            true,
        );
        self.cov = CovarianceKind::Posterior;
        self.awaiting_update = false;
        Ok(used)
    }

    /// `predict(inputs)` then `update(measurements)`. Wrong lengths and non-finite values are
    /// rejected before the prediction; only a non-invertible R̃ (|ω̄| near 2π) can fail after it.
    pub fn step(
        &mut self,
        inputs: &[f64],
        measurements: &[Option<f64>],
    ) -> Result<usize, RuntimeError> {
        check_len("measurements", self.channel.len(), measurements.len())?;
        // Reject bad measurements before the prediction changes the state.
        if let Some(i) = measurements
            .iter()
            .position(|v| v.is_some_and(|v| !v.is_finite()))
        {
            return Err(RuntimeError::NonFiniteMeasurement {
                channel: self.channel_label(i),
                value: measurements[i].unwrap_or(f64::NAN),
            });
        }
        self.predict(inputs)?;
        self.update(measurements)
    }

    fn channel_label(&self, i: usize) -> String {
        let (s, c) = self.channel[i];
        format!(
            "{}.{}",
            self.model.sensors[s].name,
            crokf_formats::component_label(c as u8)
        )
    }

    fn current_std(&self) -> &PhaseStd {
        match self.cov {
            CovarianceKind::Prior => &self.std_prior[self.phase],
            CovarianceKind::Posterior => &self.std_posterior[self.phase],
        }
    }

    /// World-frame displacement of every sensor, u = R̃(W_s x) C_s x, 3 per sensor (m).
    pub fn sensor_displacements(&self, out: &mut [f64]) -> Result<(), RuntimeError> {
        check_len(
            "sensor read-out buffer",
            3 * self.model.sensors.len(),
            out.len(),
        )?;
        for (s, o) in out.chunks_exact_mut(3).enumerate() {
            o.copy_from_slice(&self.sensor_world(s));
        }
        Ok(())
    }

    /// World-frame displacement of sensor `s`, R̃(W_s x) C_s x (m).
    fn sensor_world(&self, s: usize) -> Vec3 {
        let sensor = &self.model.sensors[s];
        let u = rows3(&sensor.displacement_rows, 0, &self.x);
        Warp::new(&rows3(&sensor.rotation_rows, 0, &self.x)).warp(&u)
    }

    /// Standard deviation of every sensor's displacement, sqrt(diag(C_s P C_sᵀ)), 3 per sensor
    /// (m), from the stored covariance of the current phase (local frame; P⁻ after `predict`,
    /// P after `update`).
    pub fn sensor_std(&self, out: &mut [f64]) -> Result<(), RuntimeError> {
        let std = &self.current_std().sensors;
        check_len("sensor std buffer", std.len(), out.len())?;
        out.copy_from_slice(std);
        Ok(())
    }

    /// Estimated world value of every measurement channel (length q, m).
    pub fn measurement_estimates(&self, out: &mut [f64]) -> Result<(), RuntimeError> {
        check_len("measurement read-out buffer", self.channel.len(), out.len())?;
        // Channels of one sensor are adjacent: evaluate each sensor once.
        let mut current: Option<(usize, Vec3)> = None;
        for (o, &(s, c)) in out.iter_mut().zip(&self.channel) {
            let world = match current {
                Some((cs, w)) if cs == s => w,
                _ => {
                    let w = self.sensor_world(s);
                    current = Some((s, w));
                    w
                }
            };
            *o = world[c];
        }
        Ok(())
    }

    fn node_set(&self, set: usize) -> Result<&crokf_formats::NodeSet, RuntimeError> {
        self.model
            .node_sets
            .get(set)
            .ok_or(RuntimeError::NoSuchNodeSet {
                index: set,
                count: self.model.node_sets.len(),
            })
    }

    /// World displacement of every node of node set `set`, u_i = R̃(ω_i) u_lin,i, 3 per node
    /// (m), with u_lin,i and ω_i from the set's displacement and rotation rows.
    pub fn node_displacements(&self, set: usize, out: &mut [f64]) -> Result<(), RuntimeError> {
        let ns = self.node_set(set)?;
        check_len("node read-out buffer", 3 * ns.node_tags.len(), out.len())?;
        for (i, o) in out.chunks_exact_mut(3).enumerate() {
            let u = rows3(&ns.displacement_rows, i, &self.x);
            let omega = rows3(&ns.rotation_rows, i, &self.x);
            o.copy_from_slice(&Warp::new(&omega).warp(&u));
        }
        Ok(())
    }

    /// World position X + u of every node of node set `set`, 3 per node (m).
    pub fn node_positions(&self, set: usize, out: &mut [f64]) -> Result<(), RuntimeError> {
        self.node_displacements(set, out)?;
        let ns = &self.model.node_sets[set];
        for (o, x) in out.iter_mut().zip(&ns.rest_positions.data) {
            *o += x;
        }
        Ok(())
    }

    /// Standard deviation of every node displacement of set `set` (local frame, like
    /// [`Estimator::sensor_std`]), 3 per node (m).
    pub fn node_std(&self, set: usize, out: &mut [f64]) -> Result<(), RuntimeError> {
        self.node_set(set)?;
        let std = &self.current_std().nodes[set];
        check_len("node std buffer", std.len(), out.len())?;
        out.copy_from_slice(std);
        Ok(())
    }
}

fn check_len(what: &'static str, expected: usize, found: usize) -> Result<(), RuntimeError> {
    if expected == found {
        Ok(())
    } else {
        Err(RuntimeError::Length {
            what,
            expected,
            found,
        })
    }
}
