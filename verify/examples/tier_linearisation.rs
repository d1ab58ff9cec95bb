//! How far the co-rotational tier's constant gain (designed on the model linearised at rest,
//! docs/design.md §11.4) is from the tier linearised along a trajectory (docs/design.md §11.5):
//! the tier is run open loop through the runtime on the scenario's loads; at states q* along
//! the run the reduced model is linearised with its consistent tangent K_N,r(q*)
//! (`LinearisedTier::at`, `transition`) and three figures are printed per state:
//! - ρ: spectral radius of the one-period error propagator Π_p F(q*)(I − K_p H_p) of the
//!   file's gains (K_p designed at rest) on the system linearised at q* (≥ 1: the constant-gain
//!   filter is unstable there);
//! - the tip marker's posterior σ (phase 0, per component, mm) that the file claims (rest
//!   DARE), that the file's gains actually have at q* (periodic Lyapunov recursion of the
//!   Joseph form with the same Q and R: X⁻ ← F[(I−KH)X⁻(I−KH)ᵀ + KRKᵀ]Fᵀ + Q, 4,000 periods
//!   at most), and that the optimal gain at q* would have (DARE at q*);
//! - actual / claimed variance ratio (the tip ANEES that the linearisation alone explains).
//!
//! ```sh
//! cargo run --release -p crokf-verify --example tier_linearisation -- SCENE SCENARIO MODEL[@SCENE2] [POINTS]
//! ```
//! SCENE: the reference scene (the model's scene or its base scene); MODEL[@SCENE2]: a tier
//! model file, its filter recomputed for SCENE2 when given (`tier::refilter`); POINTS: number
//! of states along the run (default 6).

use std::path::PathBuf;
use std::process::ExitCode;

use crokf_compile::model_file::tier::{self, file_matrix};
use crokf_compile::nonlinear::filter::filter_of;
use crokf_compile::report::StageTimer;
use crokf_compile::FullOrder;
use crokf_runtime::{load_model, Estimator};
use crokf_verify::scenario::{Horizon, Scenario};
use nalgebra::{DMatrix, DVector};

fn main() -> ExitCode {
    crokf_verify::exit(run())
}

fn faer_to(m: &faer::Mat<f64>) -> DMatrix<f64> {
    DMatrix::from_fn(m.nrows(), m.ncols(), |i, j| m[(i, j)])
}

fn spectral_radius(m: &DMatrix<f64>) -> f64 {
    m.clone()
        .complex_eigenvalues()
        .iter()
        .map(|z| z.norm())
        .fold(0.0, f64::max)
}

/// Tip σ per component (mm) of the q-block of P.
fn tip_sigma(rows: &DMatrix<f64>, p: &DMatrix<f64>) -> [f64; 3] {
    let r = rows.ncols();
    let pq = p.view((0, 0), (r, r));
    let s = rows * pq * rows.transpose();
    [0, 1, 2].map(|c| 1e3 * s[(c, c)].max(0.0).sqrt())
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 3 {
        return Err("usage: tier_linearisation SCENE SCENARIO MODEL[@SCENE2] [POINTS]".into());
    }
    let base = FullOrder::build(&PathBuf::from(&args[0]), &mut StageTimer::default())?;
    let scenario = Scenario::read(&PathBuf::from(&args[1]))?;
    let points: usize = args.get(3).map_or(Ok(6), |s| s.parse())?;
    let (file, variant) = match args[2].split_once('@') {
        Some((f, s)) => (f.to_string(), Some(s.to_string())),
        None => (args[2].clone(), None),
    };
    let mut model = load_model(&file)?;
    let full = match &variant {
        Some(scene) => {
            let full = FullOrder::build(&PathBuf::from(scene), &mut StageTimer::default())?;
            tier::refilter(&full, &mut model, &full.noise)?;
            full
        }
        None => base,
    };
    let t = model
        .tier
        .as_ref()
        .ok_or("the model has no co-rotational tier")?;
    let (lin0, measurements, _) = tier::linearised_of_file(&full, &model, &full.noise)?;
    let reduced = tier::reduced_model_of_file(&full, t)?;
    let r = t.order as usize;
    let ops = &full.operators;
    let steps = match scenario.horizon(full.wilson.dt) {
        Horizon::Steps(k) => k,
        Horizon::Steady(_) => return Err("the scenario needs a fixed horizon".into()),
    };
    let tip = ops
        .sensors
        .iter()
        .position(|s| s.name == "tip")
        .unwrap_or_else(|| {
            ops.sensors
                .iter()
                .position(|s| s.name == "near_probe")
                .unwrap_or(0)
        });
    let tip_rows = file_matrix(&t.sensor_rows[tip]);
    // Open-loop run: q at `points` states spread over the run (the last one included).
    let mut est = Estimator::new(&model)?;
    if points == 0 || points > steps {
        return Err(format!("{points} states asked of a {steps}-step run (1 … {steps})").into());
    }
    let picks: Vec<usize> = (0..points)
        .map(|i| ((i + 1) * steps) / points - 1)
        .collect();
    let mut states = Vec::new();
    for k in 0..steps {
        est.predict(&scenario.inputs_at(ops, k as f64 * full.wilson.dt))?;
        if picks.contains(&k) {
            states.push((k, DVector::from_column_slice(&est.state()[..r])));
        }
    }
    let kal = &t.kalman;
    let gains: Vec<DMatrix<f64>> = kal.phases.iter().map(|p| file_matrix(&p.gain)).collect();
    let q_noise = file_matrix(&kal.process_noise);
    let claimed = tip_sigma(&tip_rows, &file_matrix(&kal.phases[0].posterior_covariance));
    println!(
        "tip sensor: {}; force σ = {:?} N/step; claimed (rest DARE) tip posterior σ = {:.3?} mm\n",
        ops.sensors[tip].name, lin0.force_sigma, claimed
    );
    println!("| step | ‖q*‖ | ρ(rest gain at q*) | actual tip σ (mm), rest gain at q* | optimal tip σ at q* (mm) | actual/claimed variance |");
    println!("|---:|---:|---:|---|---|---:|");
    for q0 in std::iter::once((0usize, DVector::zeros(r))).chain(states) {
        let (k, q) = q0;
        let lin = lin0.at(&reduced, &q);
        let (f, h) = lin.transition()?;
        let n = f.nrows();
        // One-period propagator of the error with the file's gains.
        let mut phi = DMatrix::<f64>::identity(n, n);
        let update = |p: usize| {
            let meas = &kal.phases[p].measured;
            let hp = DMatrix::from_fn(meas.len(), n, |i, j| h[(meas[i] as usize, j)]);
            let rp = DMatrix::from_fn(meas.len(), meas.len(), |i, j| {
                if i == j {
                    kal.measurement_variance[meas[i] as usize]
                } else {
                    0.0
                }
            });
            let a = DMatrix::<f64>::identity(n, n) - &gains[p] * &hp;
            (a, rp)
        };
        let period = kal.period as usize;
        for p in 0..period {
            let (a, _) = update(p);
            phi = &f * a * phi;
        }
        let rho = spectral_radius(&phi);
        // Actual covariance: start from the claimed prior of phase 0, iterate periods.
        let mut x = file_matrix(&kal.phases[0].prior_covariance);
        let mut posterior0 = x.clone();
        let mut converged = false;
        for _ in 0..4000 {
            let before = x.clone();
            for p in 0..period {
                let (a, rp) = update(p);
                let kp = &gains[p];
                let post = &a * &x * a.transpose() + kp * rp * kp.transpose();
                if p == 0 {
                    posterior0 = post.clone();
                }
                x = &f * post * f.transpose() + &q_noise;
            }
            if !x.iter().all(|v| v.is_finite()) || x.norm() > 1e12 * (1.0 + before.norm()) {
                break;
            }
            if (&x - &before).norm() <= 1e-12 * x.norm() {
                converged = true;
                break;
            }
        }
        let actual = if converged {
            tip_sigma(&tip_rows, &posterior0)
        } else {
            [f64::INFINITY; 3]
        };
        let optimal = match filter_of(&lin, &measurements) {
            Ok(filter) => tip_sigma(
                &tip_rows,
                &faer_to(&filter.schedule.phases[0].posterior_covariance),
            ),
            Err(_) => [f64::NAN; 3],
        };
        let ratio =
            actual.iter().map(|a| a * a).sum::<f64>() / claimed.iter().map(|c| c * c).sum::<f64>();
        println!(
            "| {k} | {:.3e} | {rho:.4} | {:.3?} | {:.3?} | {ratio:.2} |",
            q.norm(),
            actual,
            optimal
        );
    }
    Ok(())
}
