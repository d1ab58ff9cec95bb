//! Candidate bases of the co-rotational tier measured on reference trajectories before and
//! after hyper-reduction (docs/results/tier.md §8, docs/design.md §10 item 1): for a
//! scene with a `[reduction.corotational]` table, the scene's own training plan is run once
//! (cached in `--cache FILE`), then for every candidate basis
//!
//! - the per-run relative projection error of the training runs (worst run, and its label),
//! - the projection floor min_q ‖Vq − u_ref‖_M (relative over the trajectory) and the same
//!   projection as relative L2 over the displayed nodes, per scenario,
//! - with `--end-to-end`: ECSW at the scene's tolerance, the reduced stepper (the runtime's
//!   settings: Taylor predictor, warped Newton matrix refreshed when slow, the scene's Newton
//!   tolerance) open loop against the full-order co-rotational reference: relative L2 over the
//!   displayed nodes and at sensor 0, whole trajectory.
//!
//! ```sh
//! cargo run --release -p crokf-verify --example nonlinear_basis -- SCENE SCENARIO[,SCENARIO…] \
//!     [--cache FILE] [--pooled R] [--tolerances 1e-1,1e-2|none] [--max-order N] [--end-to-end] [--exact] [--ecsw-max N] [--ecsw-snapshots N] \
//!     [--energy | --energy-enrich] [--quadratic 1e-6,1e-3] [--runs 'TEXT|TEXT'] \
//!     [--compare-references] [--dump-end] [--consistent] [--no-predictor] [--static] [--trace]
//! ```
//!
//! `--runs`: the basis from the snapshots of the training runs whose label contains one of the
//! `|`-separated texts only (the per-run errors then count those runs alone).
//!
//! `--exact`: exact integration over every element instead of ECSW (implies `--end-to-end`).
//! `--energy`: POD and per-run errors in the energy (K) inner product instead of M;
//! `--energy-enrich`: the pooled POD in M, the enrichment measured in K (docs/results/tier.md
//! §8). Measuring aids (flags; an unknown flag is an error): `--compare-references` prints each
//! scenario's reference against the first one's (the reference's own sensitivity); `--dump-end`
//! prints the end-face nodes of the first reference at steps 50, 80, 100, 150, 200;
//! `--consistent` the consistent tangent in the reduced Newton matrix; `--no-predictor` no
//! Taylor predictor; `--static` a static check at each reference's last load (linear and
//! co-rotational, full order against Galerkin on V); `--trace` the sensor's reduced and
//! full-order values every 10 steps.
//!
//! `--quadratic γ[,γ…]`: for each candidate basis also the quadratic manifold fitted to the
//! training snapshots with regulariser γ ([`crokf_compile::nonlinear::manifold`]): its floors
//! (the same three, u(VᵀMu) against u) and its open-loop Galerkin run on every element
//! ([`crokf_verify::nonlinear::manifold::galerkin_run`]); first the same driver with W = 0 (the
//! linear basis: equals `--exact` to the Newton tolerance, the driver's check).
//!
//! Candidates: `pod r` (the first r POD vectors of the pooled snapshots, today's basis,
//! r = `--pooled`, default the scene's `order`), and for each ε of `--tolerances` the
//! per-run tolerance basis ([`basis::per_run_pod`]: the pooled r, then enrichment until every
//! run is within ε, at most `--max-order` columns, default 60), and `pod r'` of the same size
//! r' as that basis (does the pool alone do as well with as many vectors?).

use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::OnceLock;

use nalgebra::DVector;

use crokf_compile::algorithms::pod::pod;
use crokf_compile::nonlinear::basis::{self, Basis};
use crokf_compile::nonlinear::ecsw::{self, EcswOptions};
use crokf_compile::nonlinear::manifold::QuadraticManifold;
use crokf_compile::nonlinear::reduced::{
    HyperReducedModel, ReducedNewton, ReducedStepper, Refresh,
};
use crokf_compile::nonlinear::training::{train, Training, TrainingPlan};
use crokf_compile::report::StageTimer;
use crokf_compile::stepping::{CorotationalSimulator, NewtonOptions, Simulator};
use crokf_compile::FullOrder;
use crokf_verify::nonlinear::floors::displayed_dofs;
use crokf_verify::nonlinear::manifold::{galerkin_run, galerkin_static, History};
use crokf_verify::scenario::{Horizon, Scenario};

type Failure = Box<dyn std::error::Error>;

fn main() -> ExitCode {
    crokf_verify::exit(run())
}

fn flag(args: &[String], name: &str) -> Option<String> {
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}

/// The flags that take a value.
const VALUE_FLAGS: [&str; 8] = [
    "--cache",
    "--pooled",
    "--tolerances",
    "--max-order",
    "--ecsw-max",
    "--ecsw-snapshots",
    "--quadratic",
    "--runs",
];

/// The flags without a value.
const SWITCHES: [&str; 10] = [
    "--end-to-end",
    "--exact",
    "--energy",
    "--energy-enrich",
    "--compare-references",
    "--dump-end",
    "--consistent",
    "--no-predictor",
    "--static",
    "--trace",
];

/// An error naming the first flag of `args` (after the two positional arguments) that is not
/// one of [`VALUE_FLAGS`] or [`SWITCHES`], or that lacks its value.
fn check_flags(args: &[String]) -> Result<(), String> {
    let mut rest = args.iter().skip(2);
    while let Some(arg) = rest.next() {
        if VALUE_FLAGS.contains(&arg.as_str()) {
            if rest.next().is_none() {
                return Err(format!("{arg} needs a value"));
            }
        } else if arg.starts_with("--") && !SWITCHES.contains(&arg.as_str()) {
            return Err(format!("unknown flag {arg}"));
        }
    }
    Ok(())
}

/// The measuring aids of the command line, set once in `run`.
static AIDS: OnceLock<Aids> = OnceLock::new();

/// The measuring aids; none before `run` has read the command line.
fn aids() -> Aids {
    *AIDS.get_or_init(|| Aids::of(&[]))
}

/// The measuring aids (module doc), switches of the command line.
#[derive(Clone, Copy)]
struct Aids {
    /// `--compare-references`.
    compare_references: bool,
    /// `--dump-end`.
    dump_end: bool,
    /// `--consistent`.
    consistent: bool,
    /// `--no-predictor`.
    no_predictor: bool,
    /// `--static`.
    static_check: bool,
    /// `--trace`.
    trace: bool,
}

impl Aids {
    fn of(args: &[String]) -> Aids {
        let on = |name: &str| args.iter().any(|a| a == name);
        Aids {
            compare_references: on("--compare-references"),
            dump_end: on("--dump-end"),
            consistent: on("--consistent"),
            no_predictor: on("--no-predictor"),
            static_check: on("--static"),
            trace: on("--trace"),
        }
    }
}

/// A reference trajectory: the full-order co-rotational states u_k (k = 1..N) and the loads
/// f_k held over step k → k+1 (k = 0..N−1), n each.
struct Reference {
    name: String,
    states: Vec<Vec<f64>>,
    loads: Vec<Vec<f64>>,
}

fn write_vectors(out: &mut impl Write, vectors: &[Vec<f64>]) -> std::io::Result<()> {
    out.write_all(&(vectors.len() as u64).to_le_bytes())?;
    let n = vectors.first().map_or(0, Vec::len);
    out.write_all(&(n as u64).to_le_bytes())?;
    for v in vectors {
        for x in v {
            out.write_all(&x.to_le_bytes())?;
        }
    }
    Ok(())
}

fn read_u64(input: &mut impl Read) -> std::io::Result<u64> {
    let mut b = [0u8; 8];
    input.read_exact(&mut b)?;
    Ok(u64::from_le_bytes(b))
}

fn read_vectors(input: &mut impl Read) -> std::io::Result<Vec<Vec<f64>>> {
    let (count, n) = (read_u64(input)? as usize, read_u64(input)? as usize);
    let mut out = Vec::with_capacity(count);
    let mut b = [0u8; 8];
    for _ in 0..count {
        let mut v = Vec::with_capacity(n);
        for _ in 0..n {
            input.read_exact(&mut b)?;
            v.push(f64::from_le_bytes(b));
        }
        out.push(v);
    }
    Ok(out)
}

/// Training snapshots and run indices, cached (a plain little-endian dump; only this example
/// reads it, and only for the same scene).
fn training(
    full: &FullOrder,
    plan: &TrainingPlan,
    cache: Option<&Path>,
) -> Result<Training, Failure> {
    if let Some(path) = cache.filter(|p| p.exists()) {
        let mut input = std::io::BufReader::new(std::fs::File::open(path)?);
        let snapshots = read_vectors(&mut input)?;
        let runs = read_u64(&mut input)? as usize;
        let mut run_of = Vec::with_capacity(snapshots.len());
        for _ in 0..snapshots.len() {
            run_of.push(read_u64(&mut input)? as usize);
        }
        let labels: Vec<String> = plan.runs().into_iter().map(|r| r.label).collect();
        if labels.len() != runs || snapshots.first().map(Vec::len) != Some(full.fem.dof_count()) {
            return Err(format!("{}: cache does not match the scene", path.display()).into());
        }
        eprintln!(
            "training: {} snapshots from {}",
            snapshots.len(),
            path.display()
        );
        return Ok(Training {
            snapshots,
            run_of,
            runs: labels.into_iter().map(|l| (l, None)).collect(),
            ..Training::default()
        });
    }
    let started = std::time::Instant::now();
    let t = train(full, plan, &mut |k, of, label| {
        eprintln!(
            "[{:7.1} s] training run {}/{of}: {label}",
            started.elapsed().as_secs_f64(),
            k + 1
        )
    })?;
    if let Some(path) = cache {
        let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
        write_vectors(&mut out, &t.snapshots)?;
        out.write_all(&(t.runs.len() as u64).to_le_bytes())?;
        for &k in &t.run_of {
            out.write_all(&(k as u64).to_le_bytes())?;
        }
    }
    Ok(t)
}

fn reference(full: &FullOrder, path: &Path, cache: Option<&Path>) -> Result<Reference, Failure> {
    let scenario = Scenario::read(path)?;
    scenario.check_scene(&full.scene.scene, path)?;
    let dt = full.wilson.dt;
    let Horizon::Steps(steps) = scenario.horizon(dt) else {
        return Err(format!("{}: needs a fixed horizon", path.display()).into());
    };
    let n = full.fem.dof_count();
    let loads: Vec<Vec<f64>> = (0..steps)
        .map(|k| scenario.load_vector(&full.operators, n, k as f64 * dt))
        .collect();
    let name = path.display().to_string();
    let cached = cache.map(|c| {
        let stem = path
            .file_stem()
            .map_or("scenario".into(), |s| s.to_string_lossy());
        c.with_extension(format!("{stem}.reference"))
    });
    if let Some(file) = cached.as_ref().filter(|p| p.exists()) {
        let mut input = std::io::BufReader::new(std::fs::File::open(file)?);
        let states = read_vectors(&mut input)?;
        if states.len() == steps {
            return Ok(Reference {
                name,
                states,
                loads,
            });
        }
    }
    let started = std::time::Instant::now();
    let mut sim = CorotationalSimulator::new(&full.fem, full.wilson, NewtonOptions::default())?;
    let mut states = Vec::with_capacity(steps);
    for f in &loads {
        sim.step(f)?;
        states.push(sim.displacement().to_vec());
    }
    eprintln!(
        "reference {name}: {steps} steps in {:.1} s",
        started.elapsed().as_secs_f64()
    );
    if let Some(file) = cached {
        let mut out = std::io::BufWriter::new(std::fs::File::create(file)?);
        write_vectors(&mut out, &states)?;
    }
    Ok(Reference {
        name,
        states,
        loads,
    })
}

/// A read-out row: (free DOF, weight) pairs.
type Row = [(usize, f64)];

/// A named set of read-out rows (the displayed DOFs, a sensor's three components).
type ReadOut<'a> = (&'a str, &'a [Vec<(usize, f64)>]);

/// Relative L2 over the given DOF rows of `fit(k)` against the reference, whole trajectory.
fn relative_l2(
    states: &[Vec<f64>],
    rows: &[Vec<(usize, f64)>],
    fit: &dyn Fn(usize, &Row) -> f64,
) -> f64 {
    let (mut e2, mut r2) = (0.0, 0.0);
    for (k, u) in states.iter().enumerate() {
        for row in rows {
            let exact: f64 = row.iter().map(|&(d, w)| w * u[d]).sum();
            let approx = fit(k, row);
            e2 += (approx - exact).powi(2);
            r2 += exact * exact;
        }
    }
    if r2 > 0.0 {
        (e2 / r2).sqrt()
    } else {
        0.0
    }
}

fn run() -> Result<(), Failure> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(scene), Some(scenarios)) = (args.first(), args.get(1)) else {
        return Err("usage: nonlinear_basis SCENE SCENARIO[,SCENARIO…] [--cache FILE] \
                    [--pooled R] [--tolerances a,b] [--max-order N] [--end-to-end] [--exact] [--ecsw-max N] [--ecsw-snapshots N]"
            .into());
    };
    check_flags(&args)?;
    let aids = *AIDS.get_or_init(|| Aids::of(&args));
    let full = FullOrder::build(&PathBuf::from(scene), &mut StageTimer::default())?;
    let spec = full
        .scene
        .scene
        .reduction
        .corotational
        .clone()
        .ok_or("the scene has no [reduction.corotational] table")?;
    let plan = TrainingPlan::of_scene(&full).ok_or("no training plan")?;
    let cache = flag(&args, "--cache").map(PathBuf::from);
    let pooled = flag(&args, "--pooled").map_or(Ok(spec.order()), |s| s.parse())?;
    let max_order = flag(&args, "--max-order").map_or(Ok(60), |s| s.parse())?;
    // `--tolerances none`: the pooled POD alone.
    let tolerances: Vec<f64> = match flag(&args, "--tolerances").as_deref() {
        Some("none") => Vec::new(),
        list => list
            .unwrap_or("1e-1,3e-2,1e-2")
            .split(',')
            .map(str::parse)
            .collect::<Result<_, _>>()?,
    };
    let exact = args.iter().any(|a| a == "--exact");
    let end_to_end = exact || args.iter().any(|a| a == "--end-to-end");
    let ecsw_snapshots = flag(&args, "--ecsw-snapshots")
        .map_or(Ok(EcswOptions::default().max_snapshots), |s| s.parse())?;
    let ecsw_max =
        flag(&args, "--ecsw-max").map_or(Ok(EcswOptions::default().max_elements), |s| s.parse())?;
    let quadratic: Vec<f64> = flag(&args, "--quadratic")
        .map(|list| list.split(',').map(str::parse).collect::<Result<_, _>>())
        .transpose()?
        .unwrap_or_default();
    let mut training = training(&full, &plan, cache.as_deref())?;
    // `--runs A|B|…`: keep only the snapshots of training runs whose label contains one of the
    // `|`-separated texts (which runs a basis needs; the plan itself is unchanged).
    if let Some(keep) = flag(&args, "--runs") {
        let texts: Vec<&str> = keep.split('|').collect();
        let kept: Vec<bool> = training
            .runs
            .iter()
            .map(|(label, _)| texts.iter().any(|t| label.contains(t)))
            .collect();
        let (snapshots, run_of): (Vec<Vec<f64>>, Vec<usize>) = training
            .snapshots
            .drain(..)
            .zip(training.run_of.drain(..))
            .filter(|(_, k)| kept[*k])
            .unzip();
        training.snapshots = snapshots;
        training.run_of = run_of;
        eprintln!(
            "--runs: {} of {} runs kept, {} snapshots",
            kept.iter().filter(|k| **k).count(),
            kept.len(),
            training.snapshots.len()
        );
    }
    let runs = training.runs.len();
    let references: Vec<Reference> = scenarios
        .split(',')
        .map(|s| reference(&full, Path::new(s), cache.as_deref()))
        .collect::<Result<_, _>>()?;
    let mass = &full.fem.mass;
    let fem = &full.fem;
    let (_, dofs) = displayed_dofs(&full);
    let displayed: Vec<Vec<(usize, f64)>> =
        dofs.iter().flatten().map(|&d| vec![(d, 1.0)]).collect();
    let sensor: Vec<Vec<(usize, f64)>> = (0..3)
        .map(|c| {
            full.operators.sensors[0]
                .weights
                .iter()
                .filter_map(|&(node, w)| fem.dofs.index[node][c].map(|d| (d, w)))
                .collect()
        })
        .collect();
    println!(
        "{scene}: n = {}, {} tetrahedra; training {} runs, {} snapshots; sensor 0 '{}'",
        fem.dof_count(),
        fem.elements.len(),
        runs,
        training.snapshots.len(),
        full.operators.sensors[0].name
    );

    if aids.compare_references {
        // Sensitivity of the reference itself: sensor-0 relative L2 of reference i against
        // reference 0 (e.g. the same scenario at 0.99× the load).
        for other in &references[1..] {
            let fit = |k: usize, row: &[(usize, f64)]| -> f64 {
                row.iter().map(|&(d, w)| w * other.states[k][d]).sum()
            };
            println!(
                "reference {} against {}: sensor {:.2e}, displayed {:.2e}",
                other.name,
                references[0].name,
                relative_l2(&references[0].states, &sensor, &fit),
                relative_l2(&references[0].states, &displayed, &fit)
            );
        }
    }
    if aids.dump_end {
        // End-face nodes (largest x) of the first reference at a few steps: rest (y, z) and
        // displacement.
        let xmax = fem.positions.iter().map(|p| p[0]).fold(f64::MIN, f64::max);
        let states = &references[0].states;
        for k in [49, 79, 99, 149, 199]
            .into_iter()
            .filter(|&k| k < states.len())
        {
            println!("step {}:", k + 1);
            for (node, p) in fem.positions.iter().enumerate() {
                if (p[0] - xmax).abs() < 1e-9 {
                    let d: Vec<f64> = (0..3)
                        .map(|c| fem.dofs.index[node][c].map_or(0.0, |i| states[k][i]))
                        .collect();
                    println!(
                        "  node at y {:.3} z {:.3}: u = ({:+.4}, {:+.4}, {:+.4})",
                        p[1], p[2], d[0], d[1], d[2]
                    );
                }
            }
        }
    }
    let mut candidates: Vec<(String, Basis, Vec<f64>)> = Vec::new();
    let per_run_errors = |b: &Basis| -> Vec<f64> {
        let mut left = vec![0.0; runs];
        let mut total = vec![0.0; runs];
        for (u, &k) in training.snapshots.iter().zip(&training.run_of) {
            let q = b.project(u);
            let n2: f64 = u
                .iter()
                .zip(crokf_compile::fem::sparse_mul(mass, u))
                .map(|(a, b)| a * b)
                .sum();
            left[k] += (n2 - q.norm_squared()).max(0.0);
            total[k] += n2;
        }
        left.iter()
            .zip(&total)
            .map(|(l, t)| if *t > 0.0 { (l / t).sqrt() } else { 0.0 })
            .collect()
    };
    // Inner product of the POD and of the per-run errors: M (default) or K (`--energy`).
    let energy = args.iter().any(|a| a == "--energy");
    // `--energy-enrich`: pooled POD in M (today's basis), enrichment measured in K.
    let energy_enrich = args.iter().any(|a| a == "--energy-enrich");
    let inner = if energy { &fem.stiffness } else { mass };
    let enrich_inner = if energy || energy_enrich {
        &fem.stiffness
    } else {
        mass
    };
    let started = std::time::Instant::now();
    let (mut all_modes, _) = pod(inner, &training.snapshots, max_order, 1e-14);
    basis::normalise_signs(&mut all_modes);
    eprintln!(
        "pooled POD ({} vectors) in {:.1} s",
        all_modes.len(),
        started.elapsed().as_secs_f64()
    );
    let pooled_pod = |r: usize| basis::m_orthonormalise(inner, &all_modes, 1e-8, r);
    // The same span made M-orthonormal (the tier's convention).
    let to_mass = |b: Basis| {
        let columns: Vec<(String, Vec<f64>)> = b.columns();
        basis::m_orthonormalise(mass, &columns, 1e-10, columns.len())
    };
    let b = to_mass(pooled_pod(pooled));
    let e = per_run_errors(&b);
    candidates.push((format!("pod {pooled}"), b, e));
    for &eps in &tolerances {
        let started = std::time::Instant::now();
        let start = pooled_pod(pooled);
        let start_columns: Vec<(String, Vec<f64>)> = start.columns();
        let pr = basis::enrich_per_run(
            enrich_inner,
            &training.snapshots,
            &training.run_of,
            runs,
            basis::m_orthonormalise(enrich_inner, &start_columns, 1e-10, start_columns.len()),
            eps,
            max_order,
        );
        eprintln!(
            "per-run ε = {eps:e}: r = {} ({} pooled + {} added, from runs {:?}) in {:.1} s",
            pr.basis.len(),
            pr.pooled,
            pr.enriched_from.len(),
            pr.enriched_from,
            started.elapsed().as_secs_f64()
        );
        let r = pr.basis.len();
        let errors = pr.run_errors.clone();
        let norm = if energy || energy_enrich { "K" } else { "M" };
        candidates.push((
            format!("per-run ε {eps:e} in the {norm}-norm (r = {r})"),
            to_mass(pr.basis),
            errors,
        ));
        let b = to_mass(pooled_pod(r));
        let e = per_run_errors(&b);
        candidates.push((format!("pod {r}"), b, e));
    }

    let newton = ReducedNewton {
        max_iterations: spec.newton_iterations.max(30),
        tolerance: spec.newton_tolerance,
        refresh: Refresh::WhenSlow { iterations: 4 },
        consistent: aids.consistent,
        predictor: !aids.no_predictor,
    };
    for (name, b, run_errors) in &candidates {
        let (worst, &we) = run_errors
            .iter()
            .enumerate()
            .max_by(|a, c| a.1.total_cmp(c.1))
            .unwrap_or((0, &0.0));
        println!(
            "\n{name}: r = {}; worst training run {:.2e} ('{}')",
            b.len(),
            we,
            training.runs[worst].0
        );
        let model = if exact {
            let all: Vec<(usize, f64)> = (0..fem.elements.len()).map(|e| (e, 1.0)).collect();
            println!(
                "  all {} elements, weight 1 (no hyper-reduction)",
                all.len()
            );
            Some(HyperReducedModel::new(fem, &b.vectors, &all, full.wilson)?)
        } else if end_to_end {
            let started = std::time::Instant::now();
            let sampling = ecsw::sample_elements(
                fem,
                &b.vectors,
                &b.mass_vectors,
                &training.snapshots,
                &EcswOptions {
                    tolerance: spec.ecsw_tolerance(),
                    max_elements: ecsw_max,
                    max_snapshots: ecsw_snapshots,
                },
            )?;
            let (lo, hi) = sampling
                .weights
                .iter()
                .fold((f64::MAX, 0.0f64), |(a, b), &(_, w)| (a.min(w), b.max(w)));
            println!(
                "  ECSW: {} elements (weights {lo:.3}…{hi:.3}), residual {:.2e} ({:.1} s)",
                sampling.weights.len(),
                sampling.relative_residual,
                started.elapsed().as_secs_f64()
            );
            Some(HyperReducedModel::new(
                fem,
                &b.vectors,
                &sampling.weights,
                full.wilson,
            )?)
        } else {
            None
        };
        if let (Some(model), true) = (&model, aids.static_check) {
            // Static check at each reference's last load: linear K⁻¹f and the co-rotational
            // static solution, full order against Galerkin on V (exact or sampled model).
            for reference in &references {
                let Some(f) = reference.loads.last() else {
                    continue;
                };
                let linear = crokf_compile::stepping::static_solve(fem, f)?;
                let mut sim =
                    CorotationalSimulator::new(fem, full.wilson, NewtonOptions::default())?;
                let nonlinear = sim.static_solve(f, 1e-9)?;
                let fr = b.vectors.tr_mul(&DVector::from_column_slice(f));
                let k_r = b.vectors.tr_mul(&nalgebra::DMatrix::from_columns(
                    &(0..b.len())
                        .map(|j| {
                            let col: Vec<f64> = b.vectors.column(j).iter().copied().collect();
                            DVector::from_vec(crokf_compile::fem::sparse_mul(&fem.stiffness, &col))
                        })
                        .collect::<Vec<_>>(),
                ));
                let q_lin = k_r.clone().cholesky().map(|c| c.solve(&fr));
                let q_nl = model.static_solve(&fr, 1e-10);
                let rel = |exact: &[f64], q: &DVector<f64>| {
                    let approx = &b.vectors * q;
                    let e: f64 = sensor
                        .iter()
                        .map(|row| {
                            let a: f64 = row.iter().map(|&(d, w)| w * approx[d]).sum();
                            let x: f64 = row.iter().map(|&(d, w)| w * exact[d]).sum();
                            (a - x).powi(2)
                        })
                        .sum();
                    let n: f64 = sensor
                        .iter()
                        .map(|row| row.iter().map(|&(d, w)| w * exact[d]).sum::<f64>().powi(2))
                        .sum();
                    (e / n).sqrt()
                };
                println!(
                    "  static at the last load of {}: linear Galerkin {:.2e} (M-projection {:.2e}); co-rotational Galerkin {} (M-projection {:.2e})",
                    reference.name,
                    q_lin.as_ref().map_or(f64::NAN, |q| rel(&linear, q)),
                    rel(&linear, &b.project(&linear)),
                    match &q_nl { Ok(q) => format!("{:.2e}", rel(&nonlinear, q)), Err(e) => format!("failed ({e})") },
                    rel(&nonlinear, &b.project(&nonlinear)),
                );
            }
        }
        for reference in &references {
            let m_norm = *basis::projection_errors(mass, b, &reference.states)
                .last()
                .unwrap_or(&f64::NAN);
            let projected: Vec<DVector<f64>> =
                reference.states.iter().map(|u| b.project(u)).collect();
            let row_fit = |k: usize, row: &[(usize, f64)]| -> f64 {
                row.iter()
                    .map(|&(d, w)| w * (b.vectors.row(d) * &projected[k])[0])
                    .sum()
            };
            let floor_displayed = relative_l2(&reference.states, &displayed, &row_fit);
            let floor_sensor = relative_l2(&reference.states, &sensor, &row_fit);
            print!(
                "  {}: floor M {:.2e}, displayed {:.2e}, sensor {:.2e}",
                reference.name, m_norm, floor_displayed, floor_sensor
            );
            if let Some(model) = &model {
                let mut stepper = ReducedStepper::new(model.clone(), newton)?;
                let mut q: Vec<DVector<f64>> = Vec::with_capacity(reference.loads.len());
                let mut failed = None;
                for (k, f) in reference.loads.iter().enumerate() {
                    let load = b.vectors.tr_mul(&DVector::from_column_slice(f));
                    if let Err(e) = stepper.step(&load) {
                        failed = Some(format!("step {}: {e}", k + 1));
                        break;
                    }
                    q.push(stepper.coordinates().clone());
                }
                if let Some(why) = failed {
                    print!("; reduced run failed at {why}");
                } else {
                    let fit = |k: usize, row: &[(usize, f64)]| -> f64 {
                        row.iter()
                            .map(|&(d, w)| w * (b.vectors.row(d) * &q[k])[0])
                            .sum()
                    };
                    if aids.trace {
                        for k in (9..reference.states.len()).step_by(10) {
                            let at = |fitk: &dyn Fn(&Row) -> f64| -> [f64; 3] {
                                std::array::from_fn(|c| fitk(&sensor[c]))
                            };
                            let exact = at(&|row| {
                                row.iter().map(|&(d, w)| w * reference.states[k][d]).sum()
                            });
                            let tier = at(&|row| fit(k, row));
                            let proj = at(&|row| row_fit(k, row));
                            println!(
                                "    step {:4}: reference {:+.4} {:+.4} {:+.4}  tier {:+.4} {:+.4} {:+.4}  projection {:+.4} {:+.4} {:+.4}",
                                k + 1, exact[0], exact[1], exact[2], tier[0], tier[1], tier[2], proj[0], proj[1], proj[2]
                            );
                        }
                    }
                    let s = stepper.stats();
                    print!(
                        "; tier open loop: displayed {:.2e}, sensor {:.2e} ({:.2} iterations/step, {} unconverged)",
                        relative_l2(&reference.states, &displayed, &fit),
                        relative_l2(&reference.states, &sensor, &fit),
                        s.iterations as f64 / s.steps.max(1) as f64,
                        s.unconverged
                    );
                }
            }
            println!();
        }
        if !quadratic.is_empty() {
            quadratic_rows(
                &full,
                b,
                &training,
                &references,
                &quadratic,
                &[("displayed", &displayed), ("sensor", &sensor)],
                spec.newton_tolerance,
            )?;
        }
    }
    Ok(())
}

/// The `--quadratic` rows of one candidate basis (module doc): W = 0 first (the driver's
/// check), then the manifold fitted with each regulariser γ: worst training run (M-norm), per
/// reference the floors and the open-loop Galerkin error over each set of read-out rows.
fn quadratic_rows(
    full: &FullOrder,
    b: &Basis,
    training: &Training,
    references: &[Reference],
    regularisers: &[f64],
    read_outs: &[ReadOut],
    tolerance: f64,
) -> Result<(), Failure> {
    let aids = aids();
    let mass = &full.fem.mass;
    let m_error = |u: &[f64], fit: &DVector<f64>| -> (f64, f64) {
        let e: Vec<f64> = u.iter().zip(fit.iter()).map(|(a, b)| a - b).collect();
        let me = crokf_compile::fem::sparse_mul(mass, &e);
        let mu = crokf_compile::fem::sparse_mul(mass, u);
        let dot = |a: &[f64], b: &[f64]| -> f64 { a.iter().zip(b).map(|(x, y)| x * y).sum() };
        (dot(&e, &me), dot(u, &mu))
    };
    let mut manifolds = Vec::new();
    if let Some(linear) = QuadraticManifold::fit(b, &training.snapshots, 1.0) {
        let zero = nalgebra::DMatrix::zeros(linear.quadratic.nrows(), linear.quadratic.ncols());
        manifolds.push((
            "W = 0 (linear, the driver's check)".to_string(),
            QuadraticManifold {
                quadratic: zero,
                ..linear
            },
        ));
    }
    for &gamma in regularisers {
        let started = std::time::Instant::now();
        match QuadraticManifold::fit(b, &training.snapshots, gamma) {
            Some(m) => {
                eprintln!(
                    "quadratic manifold γ = {gamma:e}: {} products, fitted in {:.1} s",
                    m.quadratic.ncols(),
                    started.elapsed().as_secs_f64()
                );
                manifolds.push((format!("quadratic γ = {gamma:e}"), m));
            }
            None => println!("  quadratic γ = {gamma:e}: no fit (degenerate snapshots)"),
        }
    }
    // `--static`: each reference's full-order co-rotational static equilibrium at its last load,
    // solved once for all the manifolds.
    let statics: Vec<Option<Vec<f64>>> = references
        .iter()
        .map(|reference| match reference.loads.last() {
            Some(f) if aids.static_check => {
                let mut sim =
                    CorotationalSimulator::new(&full.fem, full.wilson, NewtonOptions::default())?;
                Ok(Some(sim.static_solve(f, 1e-9)?))
            }
            _ => Ok(None),
        })
        .collect::<Result<_, Failure>>()?;
    for (name, m) in &manifolds {
        // Worst training run on the manifold, M-norm.
        let runs = training.runs.len();
        let (mut left, mut total) = (vec![0.0; runs], vec![0.0; runs]);
        for (u, &k) in training.snapshots.iter().zip(&training.run_of) {
            let (e, n) = m_error(u, &m.lift(m.project(u).as_slice()));
            left[k] += e;
            total[k] += n;
        }
        let worst = left
            .iter()
            .zip(&total)
            .map(|(l, t)| if *t > 0.0 { (l / t).sqrt() } else { 0.0 })
            .fold(0.0f64, f64::max);
        println!("  {name}: worst training run {worst:.2e}");
        for (r, reference) in references.iter().enumerate() {
            let lifted: Vec<DVector<f64>> = reference
                .states
                .iter()
                .map(|u| m.lift(m.project(u).as_slice()))
                .collect();
            let (mut e2, mut n2) = (0.0, 0.0);
            for (u, fit) in reference.states.iter().zip(&lifted) {
                let (e, n) = m_error(u, fit);
                e2 += e;
                n2 += n;
            }
            print!(
                "    {}: floor M {:.2e}",
                reference.name,
                (e2 / n2.max(f64::MIN_POSITIVE)).sqrt()
            );
            for (label, rows) in read_outs {
                let fit = |k: usize, row: &Row| -> f64 {
                    row.iter().map(|&(d, w)| w * lifted[k][d]).sum()
                };
                print!(
                    ", {label} {:.2e}",
                    relative_l2(&reference.states, rows, &fit)
                );
            }
            if let (Some(exact), Some(f)) = (&statics[r], reference.loads.last()) {
                // The co-rotational static equilibrium at the last load: full order against the
                // manifold's.
                match galerkin_static(full, m, f, 20, 1e-10) {
                    Ok(u) => {
                        for (label, rows) in read_outs {
                            let fit = |_: usize, row: &Row| -> f64 {
                                row.iter().map(|&(d, w)| w * u[d]).sum()
                            };
                            print!(
                                "; static {label} {:.2e}",
                                relative_l2(std::slice::from_ref(exact), rows, &fit)
                            );
                        }
                    }
                    Err(e) => print!("; static failed: {e}"),
                }
            }
            for (history, what) in [
                (History::FullOrder, "full-order history"),
                (History::Coordinates, "history in q"),
            ] {
                let started = std::time::Instant::now();
                match galerkin_run(full, m, &reference.loads, tolerance, 30, history) {
                    Ok(run) => {
                        print!("; Galerkin open loop ({what})");
                        for (label, rows) in read_outs {
                            let fit = |k: usize, row: &Row| -> f64 {
                                row.iter().map(|&(d, w)| w * run.states[k][d]).sum()
                            };
                            print!(
                                " {label} {:.2e}",
                                relative_l2(&reference.states, rows, &fit)
                            );
                        }
                        if aids.trace {
                            // The sensor's y, z (the last read-out's rows 1, 2), reference against run.
                            if let Some((_, rows)) = read_outs.last() {
                                let at = |u: &[f64], c: usize| -> f64 {
                                    rows[c].iter().map(|&(d, w)| w * u[d]).sum()
                                };
                                for k in (4..reference.states.len()).step_by(5) {
                                    println!(
                                        "    trace step {:4}: reference {:+.4} {:+.4}  run {:+.4} {:+.4}",
                                        k + 1,
                                        at(&reference.states[k], 1),
                                        at(&reference.states[k], 2),
                                        at(&run.states[k], 1),
                                        at(&run.states[k], 2)
                                    );
                                }
                            }
                        }
                        // The last step alone (after the transient: near the static state).
                        let last = reference.states.len() - 1;
                        let end = |_: usize, row: &Row| -> f64 {
                            row.iter().map(|&(d, w)| w * run.states[last][d]).sum()
                        };
                        if let Some((label, rows)) = read_outs.last() {
                            print!(
                                ", last step {label} {:.2e}",
                                relative_l2(&reference.states[last..], rows, &end)
                            );
                        }
                        print!(
                            " ({:.2} iterations/step, {} unconverged, {:.1} s)",
                            run.iterations as f64 / run.states.len().max(1) as f64,
                            run.unconverged,
                            started.elapsed().as_secs_f64()
                        );
                    }
                    Err(e) => print!("; Galerkin run ({what}) failed: {e}"),
                }
            }
            println!();
        }
    }
    Ok(())
}
