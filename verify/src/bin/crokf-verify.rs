//! `crokf-verify`: verification tools for CROKF-FEM models.
//!
//! ```text
//! crokf-verify simulate SCENE SCENARIO --model linear|corotational --out DIR [--vtu] [--every k]
//! crokf-verify report SCENE SCENARIO [--orders 4,8,16,32,64] --out DIR [--sweep 0.1,0.5,1]
//!                     [--corotational TIER_SCENE]
//! crokf-verify beam --tetrahedra N --out DIR      # a structured beam mesh + scene (benchmarks)
//! crokf-verify bench [--assembly 10000,50000,200000] [--steps 2000,20000,50000] [--orders 10,20,40,80]
//! crokf-verify identify SCENE MODEL --measurements M.csv [--inputs I.csv] [-o IDENTIFIED.toml]
//!                       [--fixed-point] [--lags L] [--skip S]   # = crokf-compile identify
//! ```
//! runs the full-order reference (linear or co-rotational Wilson-θ) through a scenario and
//! writes `DIR/trajectories.csv` and, with `--vtu`, `DIR/frames/frame_NNNN.vtu` + `DIR/series.pvd`.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand, ValueEnum};
use crokf_compile::mesh::procedural;
use crokf_compile::scene::SceneFile;
use crokf_compile::stepping::{Formulation, NewtonOptions};
use crokf_formats::output::{
    check_folder_inputs, check_paths, sweep_stale_temporaries, write_atomically, Output,
    OutputKind, StagedDir,
};

/// The files `report` writes into its `--out` folder (besides `tip_sigma_*.svg`).
const REPORT_FILES: [&str; 4] = ["report.md", "report.csv", "report.svg", "sweep.md"];
use crokf_compile::identify::command::{self as identify, IdentifyArgs};
use crokf_verify::simulate::{self, SimulationOptions};
use crokf_verify::{bench, comparison};
use indicatif::{ProgressBar, ProgressStyle};

#[derive(Parser)]
#[command(
    name = "crokf-verify",
    version,
    about = "Verification tools for CROKF-FEM models"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a full-order reference simulation of a scene through a scenario.
    Simulate(SimulateArgs),
    /// Speed against error: full-order linear and co-rotational FEM vs the reduced runtime at
    /// several orders (open loop and filtered); Markdown, CSV and SVG.
    Report(ReportArgs),
    /// Write a structured beam mesh (MSH 2.2) of about N tetrahedra and a scene, for benchmarks.
    Beam(BeamArgs),
    /// Benchmarks: assembly, full-order step and runtime step times, medians, ratios in one run.
    Bench(BenchArgs),
    // `crokf-compile identify` under this name: the same arguments, output and exit status.
    #[command(about = identify::ABOUT, long_about = None)]
    Identify(IdentifyArgs),
}

#[derive(Args)]
struct ReportArgs {
    /// Scene file (TOML); its mesh: gmsh .msh, VTK .vtu or legacy .vtk.
    scene: PathBuf,
    /// Scenario file (TOML) with a fixed horizon.
    scenario: PathBuf,
    /// Reduced orders r.
    #[arg(long, value_delimiter = ',', default_value = "4,8,16,32,64")]
    orders: Vec<usize>,
    /// Output directory: report.md, report.csv, report.svg, tip_sigma_rN.svg per order
    /// (tip_sigma_tier.svg with --corotational), and sweep.md.
    #[arg(long)]
    out: PathBuf,
    /// Seed of the synthetic measurement noise.
    #[arg(long, default_value_t = 0x5eed_c0ff_ee00_0001)]
    seed: u64,
    /// Noise draws of the N-run consistency test (seeds SEED, SEED + 1, …; docs/design.md
    /// §11.3): every filtered run is repeated with each and the report adds their table; 1:
    /// the single run only.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..=1000))]
    seeds: u64,
    /// Co-rotational reference: most Newton solves per step.
    #[arg(long, default_value_t = 10)]
    max_newton: usize,
    /// Co-rotational reference: Newton tolerance on ‖δ‖/‖Û‖.
    #[arg(long, default_value_t = 1e-8)]
    tolerance: f64,
    /// Sub-steps N of the full-order references: Wilson-θ at Δt/N, each step's load held
    /// over its sub-steps and the acceleration restarted at each step (the response converged
    /// in time; 32 has the reference within ~5e-4 of it on the example scenes). 1: Wilson-θ at
    /// Δt, the same scheme as a Wilson-θ model (its rows then show the reduction's error, not
    /// the time step's). Default: 1 for `[time] scheme = "wilson-theta"`, 32 for "exact".
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=4096))]
    substeps: Option<u64>,
    /// Give the runtime no load inputs: only the measurements carry the force.
    #[arg(long)]
    withhold_loads: bool,
    /// Also sweep the load scale (e.g. 0.05,0.1,0.25,0.5,1) to find where warping breaks down.
    #[arg(long, value_delimiter = ',')]
    sweep: Vec<f64>,
    /// Order of the sweep's reduced model.
    #[arg(long, default_value_t = 16)]
    sweep_order: usize,
    /// Add the co-rotational tier: a scene of the same body with `[reduction] model =
    /// "corotational"` (e.g. models/cantilever/scene_corotational.toml). It is compiled once,
    /// training included (minutes: ~2 on the cantilever, ~9 on the meniscus), and becomes a row
    /// of the table and of the filter-consistency table (ANIS, tip ANEES, 2σ coverage from its
    /// own filters), two stars on report.svg, tip_sigma_tier.svg and a column of the sweep
    /// (open-loop error per load
    /// scale, scales beyond its training envelope marked, and the rotations up to which it
    /// stays under 2 % and 5 %).
    #[arg(long, value_name = "TIER_SCENE")]
    corotational: Option<PathBuf>,
}

/// One progress bar per phase on stderr (indicatif: hidden when stderr is not a terminal, so
/// logs get no carriage-return noise; rate and ETA for the long full-order phases).
fn progress_bar() -> impl FnMut(comparison::Progress) {
    let style = ProgressStyle::with_template(
        "{msg:<26} [{bar:20}] {percent:>3}% {pos}/{len} {elapsed_precise} (eta {eta})",
    )
    .unwrap_or_else(|_| ProgressStyle::default_bar())
    .progress_chars("#>-");
    let mut current: Option<(String, ProgressBar)> = None;
    move |p: comparison::Progress| {
        let same = current.as_ref().is_some_and(|(phase, _)| phase == p.phase);
        if !same {
            if let Some((_, bar)) = current.take() {
                bar.finish();
            }
            let bar = ProgressBar::new(p.total as u64).with_style(style.clone());
            bar.set_message(p.phase.to_owned());
            current = Some((p.phase.to_owned(), bar));
        }
        if let Some((_, bar)) = &current {
            bar.set_length(p.total as u64);
            bar.set_position(p.done as u64);
            if p.done >= p.total {
                bar.finish();
            }
        }
    }
}

fn report(args: &ReportArgs) -> Result<(), String> {
    let options = comparison::ComparisonOptions {
        orders: args.orders.clone(),
        newton: NewtonOptions {
            max_newton: args.max_newton,
            tolerance: args.tolerance,
            consistent: true,
        },
        seed: args.seed,
        seeds: args.seeds as usize,
        withhold_loads: args.withhold_loads,
        substeps: args.substeps.map(|n| n as usize),
        ..comparison::ComparisonOptions::default()
    };
    // Every file the command reads is an input: the scenes, their meshes and node lists, the
    // scenario.
    let scenes: Vec<SceneFile> = std::iter::once(&args.scene)
        .chain(&args.corotational)
        .map(|p| SceneFile::read(p).map_err(|e| e.to_string()))
        .collect::<Result<_, _>>()?;
    let read: Vec<(&str, PathBuf)> = scenes.iter().flat_map(SceneFile::input_files).collect();
    let mut inputs: Vec<(&str, &std::path::Path)> =
        vec![("scene", &args.scene), ("scenario", &args.scenario)];
    if let Some(tier) = &args.corotational {
        inputs.push(("--corotational", tier));
    }
    inputs.extend(read.iter().map(|(role, p)| (*role, p.as_path())));
    let outputs = [Output {
        role: "--out",
        path: &args.out,
        kind: OutputKind::Folder,
    }];
    check_paths(&inputs, &outputs).map_err(|e| e.to_string())?;
    if args.out.is_dir() {
        check_folder_inputs(&inputs, "--out", &args.out, |name| {
            REPORT_FILES.contains(&name)
                || (name.starts_with("tip_sigma_") && name.ends_with(".svg"))
        })
        .map_err(|e| e.to_string())?;
    }
    for note in sweep_stale_temporaries(&outputs) {
        eprintln!("crokf-verify: {note}");
    }
    let mut bar = progress_bar();
    let tier = match &args.corotational {
        Some(path) => Some(comparison::compile_tier(path, &mut bar).map_err(|e| e.to_string())?),
        None => None,
    };
    let result = comparison::run(
        &args.scene,
        &args.scenario,
        &options,
        tier.as_ref(),
        &mut bar,
    )
    .map_err(|e| e.to_string())?;
    std::fs::create_dir_all(&args.out).map_err(|e| format!("{}: {e}", args.out.display()))?;
    let markdown = result.markdown();
    // The three files appear together, complete, or not at all.
    let mut staged = StagedDir::create(&args.out).map_err(|e| e.to_string())?;
    staged
        .write("report.md", markdown.as_bytes())
        .and_then(|()| staged.write("report.csv", result.csv().as_bytes()))
        .and_then(|()| staged.write("report.svg", result.svg().as_bytes()))
        .map_err(|e| e.to_string())?;
    // Error and ±2σ at the tip marker along the trajectory, one plot per order and one for the
    // co-rotational tier.
    let mut tip_plots = Vec::new();
    for (i, row) in result.reduced.iter().enumerate() {
        if let Some(svg) = result.tip_svg(i) {
            let name = format!("tip_sigma_r{}.svg", row.order - row.force_states);
            staged
                .write(&name, svg.as_bytes())
                .map_err(|e| e.to_string())?;
            tip_plots.push(name);
        }
    }
    // The co-rotational tier's, from its own filters.
    if let Some(svg) = result.tier_tip_svg() {
        let name = "tip_sigma_tier.svg".to_owned();
        staged
            .write(&name, svg.as_bytes())
            .map_err(|e| e.to_string())?;
        tip_plots.push(name);
    }
    staged.commit().map_err(|e| e.to_string())?;
    println!("{markdown}");
    println!(
        "wrote report.md, report.csv, report.svg{} in {}",
        tip_plots
            .iter()
            .map(|n| format!(", {n}"))
            .collect::<String>(),
        args.out.display()
    );
    for note in &result.notes {
        eprintln!("crokf-verify: note: {note}");
    }
    for note in &result.tier_notes {
        eprintln!("crokf-verify: note (co-rotational tier): {note}");
    }
    if let Some(why) = &result.tier_failure {
        eprintln!("crokf-verify: the co-rotational tier failed: {why}");
    }
    if !result.failures.is_empty() {
        eprintln!(
            "crokf-verify: {} of {} orders failed (reasons in report.md)",
            result.failures.len(),
            args.orders.len()
        );
    }
    if !args.sweep.is_empty() {
        let points = comparison::rotation_sweep(
            &args.scene,
            &args.scenario,
            args.sweep_order,
            &args.sweep,
            &options,
            tier.as_ref(),
            &mut bar,
        )
        .map_err(|e| e.to_string())?;
        let text = comparison::sweep_markdown(&points, args.sweep_order);
        let path = args.out.join("sweep.md");
        write_atomically(&path, text.as_bytes()).map_err(|e| e.to_string())?;
        println!("{text}");
    }
    Ok(())
}

#[derive(Args)]
struct BeamArgs {
    /// Approximate number of tetrahedra.
    #[arg(long)]
    tetrahedra: usize,
    /// Output directory (beam.msh and scene.toml).
    #[arg(long)]
    out: PathBuf,
}

#[derive(Args)]
struct BenchArgs {
    /// Mesh sizes (tetrahedra) for the assembly benchmark.
    #[arg(long, value_delimiter = ',', default_value = "10000,50000,200000")]
    assembly: Vec<usize>,
    /// Mesh sizes (tetrahedra) for the full-order step benchmark.
    #[arg(long, value_delimiter = ',', default_value = "2000,20000,50000")]
    steps: Vec<usize>,
    /// Reduced orders for the runtime step benchmark.
    #[arg(long, value_delimiter = ',', default_value = "10,20,40,80")]
    orders: Vec<usize>,
    /// Measured components of the runtime benchmark.
    #[arg(long, default_value_t = 30)]
    measured: usize,
    /// Input channels of the runtime benchmark.
    #[arg(long, default_value_t = 6)]
    inputs: usize,
    /// Displayed nodes of the read-out benchmark.
    #[arg(long, default_value_t = 5000)]
    nodes: usize,
}

fn beam(args: &BeamArgs) -> Result<(), String> {
    if args.tetrahedra == 0 {
        return Err("--tetrahedra must be ≥ 1".into());
    }
    let mesh = bench::beam_of_size(args.tetrahedra);
    std::fs::create_dir_all(&args.out).map_err(|e| format!("{}: {e}", args.out.display()))?;
    let msh = args.out.join("beam.msh");
    procedural::write_msh22(&mesh, &msh).map_err(|e| format!("{}: {e}", msh.display()))?;
    let scene = args.out.join("scene.toml");
    write_atomically(&scene, bench::beam_scene_text("beam.msh").as_bytes())
        .map_err(|e| e.to_string())?;
    println!(
        "wrote {} ({} nodes, {} tetrahedra) and {}",
        msh.display(),
        mesh.nodes.len(),
        mesh.tetrahedra.len(),
        scene.display()
    );
    Ok(())
}

fn bench_cmd(args: &BenchArgs) -> Result<(), String> {
    println!("## Assembly (K and M, sparse), median of 3\n");
    println!("| tetrahedra | free DOFs | assembly |");
    println!("|---:|---:|---:|");
    for &n in &args.assembly {
        let b = bench::full_order(n, false, 3);
        println!("| {} | {} | {:.3} s |", b.tetrahedra, b.dofs, b.assembly_s);
    }
    println!("\n## Full-order Wilson-θ steps (Δt = 1 ms, tip load 1 N), medians\n");
    println!("| tetrahedra | free DOFs | linear step | co-rotational step (1 Newton solve) |");
    println!("|---:|---:|---:|---:|");
    let mut full = Vec::new();
    for &n in &args.steps {
        let b = bench::full_order(n, true, 5);
        println!(
            "| {} | {} | {:.3} ms | {:.1} ms |",
            b.tetrahedra,
            b.dofs,
            1e3 * b.linear_step_s,
            1e3 * b.corotational_step_s
        );
        full.push(b);
    }
    println!(
        "\n## Runtime (one core): predict + update with {} measured components and {} inputs; \
         warped read-out of {} displayed nodes\n",
        args.measured, args.inputs, args.nodes
    );
    let mut header = "| r | step | read-out |".to_owned();
    let mut rule = "|---:|---:|---:|".to_owned();
    for b in &full {
        header.push_str(&format!(" co-rot. step / step ({} tets) |", b.tetrahedra));
        rule.push_str("---:|");
    }
    println!("{header}\n{rule}");
    for &r in &args.orders {
        let b = bench::runtime(r, args.measured, args.inputs, args.nodes);
        let mut row = format!(
            "| {} | {:.3} µs | {:.1} µs |",
            b.order,
            1e6 * b.step_s,
            1e6 * b.readout_s
        );
        for f in &full {
            row.push_str(&format!(" {:.2e} |", f.corotational_step_s / b.step_s));
        }
        println!("{row}");
    }
    Ok(())
}

#[derive(Clone, Copy, ValueEnum)]
enum ModelArg {
    /// Linear FEM, Wilson-θ matrix factored once.
    Linear,
    /// Co-rotational FEM (per-element polar decomposition, warped stiffness).
    Corotational,
}

#[derive(Args)]
struct SimulateArgs {
    /// Scene file (TOML); its mesh: gmsh .msh, VTK .vtu or legacy .vtk.
    scene: PathBuf,
    /// Scenario file (TOML): load histories, duration or steady, named points.
    scenario: PathBuf,
    /// Full-order model.
    #[arg(long, value_enum, default_value = "linear")]
    model: ModelArg,
    /// Output directory (created if missing).
    #[arg(long)]
    out: PathBuf,
    /// Also write a VTU time series (frames/frame_NNNN.vtu and series.pvd).
    #[arg(long)]
    vtu: bool,
    /// Record every k-th step (the first and last are always recorded).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    every: u64,
    /// Co-rotational: most Newton solves per step (1 = one linearised solve).
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u64).range(1..))]
    max_newton: u64,
    /// Co-rotational: Newton tolerance on ‖δ‖/‖Û‖.
    #[arg(long, default_value_t = 1e-8)]
    tolerance: f64,
    /// Co-rotational: Newton matrix from the warped stiffness R K Rᵀ (classic stiffness
    /// warping) instead of the consistent tangent.
    #[arg(long)]
    warped: bool,
}

fn simulate(args: &SimulateArgs) -> Result<(), simulate::SimulateError> {
    let options = SimulationOptions {
        formulation: match args.model {
            ModelArg::Linear => Formulation::Linear,
            ModelArg::Corotational => Formulation::Corotational,
        },
        newton: NewtonOptions {
            max_newton: args.max_newton as usize,
            tolerance: args.tolerance,
            consistent: !args.warped,
        },
        every: args.every as usize,
    };
    let summary = simulate::run(&args.scene, &args.scenario, &options, &args.out, args.vtu)?;
    let t = &summary.trajectories;
    println!(
        "{} DOFs, {} tetrahedra; {} steps to t = {:.6} s, {:.3} ms per step",
        summary.dofs,
        summary.elements,
        t.total_steps,
        t.times.last().copied().unwrap_or(0.0),
        1e3 * t.seconds_per_step
    );
    if let Some(n) = t.newton {
        println!(
            "Newton: {} solves in {} steps, {} steps unconverged, {} warped fallbacks, \
             worst final increment {:.2e}",
            n.solves, n.steps, n.unconverged, n.fallbacks, n.worst_increment
        );
    }
    if let Some(last) = t.values.last() {
        for (label, u) in t.labels.iter().zip(last) {
            println!(
                "  {label}: u = ({:.6e}, {:.6e}, {:.6e}) m",
                u[0], u[1], u[2]
            );
        }
    }
    for note in &summary.notes {
        eprintln!("crokf-verify: note: {note}");
    }
    let shown = summary.files.len().min(3);
    for f in &summary.files[..shown] {
        println!("wrote {}", f.display());
    }
    if summary.files.len() > shown {
        println!("  ... and {} more files", summary.files.len() - shown);
    }
    Ok(())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    #[cfg(unix)]
    if let Err(e) = crokf_formats::output::install_interrupt_cleanup("crokf-verify") {
        eprintln!("crokf-verify: warning: no cleanup on interrupt: {e}");
    }
    let result = match &cli.command {
        Command::Simulate(args) => simulate(args).map_err(|e| e.to_string()),
        Command::Report(args) => report(args),
        Command::Beam(args) => beam(args),
        Command::Bench(args) => bench_cmd(args),
        Command::Identify(args) => return identify::run(args, "crokf-verify"),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("crokf-verify: error: {e}");
            ExitCode::FAILURE
        }
    }
}
