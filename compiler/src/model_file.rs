//! Model-file assembly (docs/model-format.md): the reduced system, the Kalman schedule and the
//! output rows of one order, laid out as the runtime reads them; the co-rotational tier's
//! section in [`tier`].

pub mod tier;

use faer::Mat;

use crokf_formats as fmt;

use crate::algorithms::kalman;
use crate::contact::{ContactRegion, ReducedRegion, RegionCompliance};
use crate::fem::operators::InputKind;
use crate::full_order::FullOrder;
use crate::outputs::{Measurements, OutputRows};
use crate::reduced::ReducedModel;

/// Converts a faer matrix to the model file's row-major matrix.
pub fn to_matrix(m: faer::MatRef<f64>) -> fmt::Matrix {
    fmt::Matrix::from_fn(m.nrows() as u32, m.ncols() as u32, |i, j| m[(i, j)])
}

/// The model file's Kalman gains (a model's `kalman` or its tier's) of a periodic schedule
/// with process noise `process_noise` per step.
pub fn kalman_gains(
    schedule: &kalman::PeriodicSchedule,
    process_noise: &Mat<f64>,
    measurements: &Measurements,
) -> fmt::KalmanGains {
    fmt::KalmanGains {
        period: schedule.period as u32,
        phases: schedule
            .phases
            .iter()
            .map(|p| fmt::KalmanPhase {
                measured: p.measured.iter().map(|&i| i as u32).collect(),
                gain: to_matrix(p.gain.as_ref()),
                prior_covariance: to_matrix(p.prior_covariance.as_ref()),
                posterior_covariance: to_matrix(p.posterior_covariance.as_ref()),
            })
            .collect(),
        process_noise: to_matrix(process_noise.as_ref()),
        measurement_variance: measurements.variance.clone(),
    }
}

/// Builds the model file's contents from the reduced system and the Kalman schedule.
pub fn assemble_model(
    full: &FullOrder,
    rows: &OutputRows,
    reduced: &ReducedModel,
    schedule: &kalman::PeriodicSchedule,
    measurements: &Measurements,
    contact: Option<&(ContactRegion, RegionCompliance)>,
    mut report: fmt::CompileReport,
) -> fmt::Model {
    let r = reduced.transition.nrows();
    let ops = &full.operators;
    let fem = &full.fem;
    let out = reduced.outputs.as_ref();
    let block = |start: usize, len: usize| to_matrix(out.subrows(start, len));
    let mut sensors = Vec::new();
    for (si, s) in ops.sensors.iter().enumerate() {
        let at = rows.sensor_row(si);
        sensors.push(fmt::SensorInfo {
            name: s.name.clone(),
            position: s.position,
            displacement_rows: block(at, 3),
            rotation_rows: block(at + 3, 3),
            components: s.components.iter().map(|c| c.index() as u8).collect(),
            every: s.every,
        });
    }
    let loads = ops
        .loads
        .iter()
        .enumerate()
        .map(|(g, l)| fmt::LoadGroup {
            name: l.name.clone(),
            rotation_rows: block(rows.load_row(g), 3),
        })
        .collect();
    let mut node_sets = Vec::new();
    for (k, set) in ops.node_sets.iter().enumerate() {
        let n = set.nodes.len();
        let mut disp = Mat::<f64>::zeros(3 * n, r);
        let mut rot = Mat::<f64>::zeros(3 * n, r);
        for i in 0..n {
            let at = rows.node_row(k, i);
            for c in 0..3 {
                for j in 0..r {
                    disp[(3 * i + c, j)] = out[(at + c, j)];
                    rot[(3 * i + c, j)] = out[(at + 3 + c, j)];
                }
            }
        }
        node_sets.push(fmt::NodeSet {
            name: set.name.clone(),
            node_tags: set.nodes.iter().map(|&i| fem.node_tags[i]).collect(),
            rest_positions: fmt::Matrix::from_fn(n as u32, 3, |i, c| {
                fem.positions[set.nodes[i]][c]
            }),
            triangles: set.triangles.clone(),
            displacement_rows: to_matrix(disp.as_ref()),
            rotation_rows: to_matrix(rot.as_ref()),
        });
    }
    let inputs = ops
        .inputs
        .iter()
        .map(|c| fmt::InputChannel {
            label: c.label.clone(),
            kind: match c.kind {
                InputKind::Load { load, component } => fmt::InputKind::Load {
                    load: load as u32,
                    component: component as u8,
                },
                _ => fmt::InputKind::Gravity {
                    acceleration: full.scene.scene.gravity.unwrap_or([0.0; 3]),
                },
            },
        })
        .collect();
    let contact = contact.map(|(region, compliance)| {
        let rows3 = 3 * region.len();
        let p = out.nrows() - rows3;
        let (section, note) = region.section(
            fem,
            compliance,
            ReducedRegion {
                transition: reduced.transition.as_ref(),
                balanced_order: reduced.balanced_order,
                rows: out.subrows(p, rows3),
                input_rows: reduced.contact_input.as_ref(),
                theta_rows: reduced.contact_theta.as_ref(),
                theta: full.wilson.theta,
                input: reduced.input.as_ref(),
            },
        );
        report.notes.push(note);
        section
    });
    fmt::Model {
        dt: full.wilson.dt,
        theta: full.wilson.theta,
        state_dim: r as u32,
        transition: to_matrix(reduced.transition.as_ref()),
        input: to_matrix(reduced.input.as_ref()),
        inputs,
        loads,
        sensors,
        measurements: measurements
            .channels
            .iter()
            .map(|&(sensor, component)| fmt::MeasurementChannel {
                sensor: sensor as u32,
                component: component as u8,
            })
            .collect(),
        kalman: kalman_gains(schedule, &reduced.process_noise(), measurements),
        node_sets,
        report,
        inputs_digest: full.digest(),
        tier: None,
        contact,
    }
}
