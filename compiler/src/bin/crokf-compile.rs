//! `crokf-compile`: mesh (gmsh MSH, VTK .vtu/.vtk) + scene → hashed, deterministic reduced
//! Kalman model file.
//!
//! `crokf-compile identify SCENE MODEL --measurements M.csv [--inputs I.csv] [-o IDENTIFIED.toml]
//! [--fixed-point] [--lags L] [--skip S]`: the tier's noise identified from a recording
//! ([`crokf_compile::identify`], docs/identify.md). A first argument that is exactly `identify`
//! selects it; a scene file of that name is compiled as `crokf-compile ./identify`.

use std::ffi::OsString;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;

use crokf_compile::check::{check, CheckOutcome};
use crokf_compile::fem::export::{self, export_matrices};
use crokf_compile::identify::command::{self as identify, IdentifyArgs};
use crokf_compile::nonlinear::cases::{run_into, scene_cases, CaseCache};
use crokf_compile::report::StageTimer;
use crokf_compile::scene::SceneFile;
use crokf_compile::{compile, CompileOptions, FullOrder};
use crokf_formats::output::{
    check_folder_inputs, check_paths, sweep_stale_temporaries, AtomicFile, Output, OutputKind,
};

/// The first argument that selects `crokf-compile identify`.
const IDENTIFY: &str = "identify";

/// Compile a scene (TOML) and its tetrahedral mesh (gmsh .msh, VTK .vtu or legacy .vtk) into a
/// crokf model file.
#[derive(Parser, Debug)]
#[command(
    version,
    about,
    long_about = None,
    after_help = "crokf-compile identify SCENE MODEL --measurements M.csv [...]: the force σ and \
        the tier's model error identified from a recording (crokf-compile identify --help). A \
        first argument `identify` selects it; a scene file named `identify` is given as \
        ./identify."
)]
struct Args {
    /// Scene file (TOML).
    scene: PathBuf,
    /// Output model file.
    #[arg(short, long)]
    output: Option<PathBuf>,
    /// Write the compile report as JSON.
    #[arg(long)]
    report: Option<PathBuf>,
    /// Balanced truncation order r (overrides the scene).
    #[arg(long)]
    order: Option<usize>,
    /// Relative Hankel singular value tolerance σ_{r+1}/σ₁ (overrides the scene).
    #[arg(long)]
    tolerance: Option<f64>,
    /// Number of vibration modes kept before balancing (overrides the scene).
    #[arg(long)]
    modes: Option<usize>,
    /// Skip the measured error against the full-order linear reference (step and chirp).
    #[arg(long)]
    no_measure: bool,
    /// Write K, M, C, B, H (Matrix Market) and dofs.csv into this existing folder and stop
    /// (the six files replace each other's old versions together, or not at all).
    #[arg(long, value_name = "DIR")]
    export_matrices: Option<PathBuf>,
    /// Check that MODEL was compiled from SCENE's current inputs by this compiler version;
    /// exits non-zero when it is stale (for CI).
    #[arg(long, value_name = "MODEL")]
    check: Option<PathBuf>,
    /// Training case cache of the co-rotational tier (created if missing): cases found there
    /// are read, the others run and stored as each finishes, so an interrupted compile resumes.
    /// The model is the same with or without it.
    #[arg(long, value_name = "DIR")]
    cache: Option<PathBuf>,
    /// Print the tier's training cases (index, identity, label; tab-separated) and stop.
    #[arg(long, conflicts_with_all = ["output", "report", "check", "export_matrices", "run_case"])]
    list_cases: bool,
    /// Run training case K into the `--cache` folder (unless it is there already) and stop:
    /// one task of a job array; a compile with the same `--cache` then gathers the cases.
    #[arg(long, value_name = "K", requires = "cache",
          conflicts_with_all = ["output", "report", "check", "export_matrices"])]
    run_case: Option<usize>,
}

/// `crokf-compile identify …` ([`identify::run`]).
#[derive(Parser, Debug)]
#[command(
    name = "crokf-compile identify",
    bin_name = "crokf-compile identify",
    version,
    about = identify::ABOUT
)]
struct IdentifyCli {
    #[command(flatten)]
    args: IdentifyArgs,
}

fn main() -> ExitCode {
    let mut argv: Vec<OsString> = std::env::args_os().collect();
    if argv.get(1).is_some_and(|a| a == IDENTIFY) {
        argv.remove(1);
        let cli = IdentifyCli::parse_from(argv);
        install_interrupt_cleanup();
        return identify::run(&cli.args, "crokf-compile");
    }
    let args = Args::parse_from(argv);
    install_interrupt_cleanup();
    match run(&args) {
        Ok(code) => code,
        Err(message) => {
            eprintln!("crokf-compile: error: {message}");
            ExitCode::FAILURE
        }
    }
}

/// Removes the temporaries of an interrupted write on SIGINT/SIGTERM (warns where it cannot).
fn install_interrupt_cleanup() {
    #[cfg(unix)]
    if let Err(e) = crokf_formats::output::install_interrupt_cleanup("crokf-compile") {
        eprintln!("crokf-compile: warning: no cleanup on interrupt: {e}");
    }
}

/// The files `--export-matrices` writes into its folder.
fn is_matrix_file(name: &str) -> bool {
    export::FILES.contains(&name)
}

/// Refuses, before any work, an output that is one of the files the command reads (the scene,
/// its mesh, its node lists, the model being checked), two outputs on one path, an output
/// whose folder does not exist, and an `--export-matrices` folder that does not exist or
/// whose files would replace an input; then removes (and names) the temporaries an earlier,
/// killed run left next to the outputs.
fn check_outputs(args: &Args) -> Result<(), String> {
    let scene = SceneFile::read(&args.scene).map_err(|e| e.to_string())?;
    let read = scene.input_files();
    let mut inputs = vec![("scene", args.scene.as_path())];
    inputs.extend(read.iter().map(|(role, p)| (*role, p.as_path())));
    if let Some(model) = &args.check {
        inputs.push(("--check model", model.as_path()));
    }
    let mut outputs = Vec::new();
    let file = |role, path| Output {
        role,
        path,
        kind: OutputKind::File,
    };
    if let Some(path) = &args.output {
        outputs.push(file("-o", path.as_path()));
    }
    if let Some(path) = &args.report {
        outputs.push(file("--report", path.as_path()));
    }
    if let Some(dir) = &args.export_matrices {
        outputs.push(Output {
            role: "--export-matrices",
            path: dir.as_path(),
            kind: OutputKind::ExistingFolder,
        });
    }
    check_paths(&inputs, &outputs).map_err(|e| e.to_string())?;
    if let Some(dir) = &args.export_matrices {
        check_folder_inputs(&inputs, "--export-matrices", dir, is_matrix_file)
            .map_err(|e| e.to_string())?;
        for name in export::FILES {
            if dir.join(name).is_dir() {
                return Err(format!(
                    "--export-matrices {}: {} is a folder; the export writes a file of that name",
                    dir.display(),
                    dir.join(name).display()
                ));
            }
        }
    }
    for note in sweep_stale_temporaries(&outputs) {
        eprintln!("crokf-compile: {note}");
    }
    Ok(())
}

/// Writes `bytes` to `path` through a temporary sibling; the target appears only on commit.
fn staged(path: &std::path::Path, bytes: &[u8]) -> Result<AtomicFile, String> {
    use std::io::Write as _;
    let mut file = AtomicFile::create(path).map_err(|e| e.to_string())?;
    file.write_all(bytes)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    Ok(file)
}

/// `--list-cases` and `--run-case K`: the scene's FEM only (no eigen-solve), then its training
/// plan.
fn training_cases(args: &Args) -> Result<ExitCode, String> {
    let mut timer = StageTimer::default();
    let full = FullOrder::build(&args.scene, &mut timer).map_err(|e| e.to_string())?;
    let (plan, cases) = scene_cases(&full)?;
    let Some(k) = args.run_case else {
        for case in &cases {
            println!("{}\t{}\t{}", case.index, case.id, case.label);
        }
        return Ok(ExitCode::SUCCESS);
    };
    // Checked by clap (`requires`).
    let dir = args
        .cache
        .as_deref()
        .ok_or("--run-case needs --cache DIR")?;
    let cache = CaseCache::open(dir)?;
    let started = std::time::Instant::now();
    let ran = run_into(&full, &plan, &cases, k, &cache)?;
    let path = cache.path(&cases[k]);
    if ran {
        eprintln!(
            "case {k} of {} ({}): wrote {} in {:.1} s",
            cases.len(),
            cases[k].label,
            path.display(),
            started.elapsed().as_secs_f64()
        );
    } else {
        eprintln!(
            "case {k} of {} ({}): already in the cache ({})",
            cases.len(),
            cases[k].label,
            path.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}

fn run(args: &Args) -> Result<ExitCode, String> {
    check_outputs(args)?;
    if let Some(model) = &args.check {
        return match check(model, &args.scene).map_err(|e| e.to_string())? {
            CheckOutcome::UpToDate => {
                eprintln!(
                    "{}: up to date with {}",
                    model.display(),
                    args.scene.display()
                );
                Ok(ExitCode::SUCCESS)
            }
            CheckOutcome::Stale(why) => {
                eprintln!(
                    "crokf-compile: {}: STALE: {why}; rebuild with `crokf-compile {} -o {}`",
                    model.display(),
                    args.scene.display(),
                    model.display()
                );
                Ok(ExitCode::from(2))
            }
        };
    }
    if args.list_cases || args.run_case.is_some() {
        return training_cases(args);
    }
    if let Some(dir) = &args.export_matrices {
        let mut timer = StageTimer::default();
        let full = FullOrder::build(&args.scene, &mut timer).map_err(|e| e.to_string())?;
        export_matrices(&full.fem, &full.operators, dir).map_err(|e| e.to_string())?;
        eprintln!(
            "wrote K, M, C ({n}×{n}), B ({n}×{m}), H and dofs.csv to {}",
            dir.display(),
            n = full.fem.dof_count(),
            m = full.operators.inputs.len()
        );
        return Ok(ExitCode::SUCCESS);
    }
    let options = CompileOptions {
        order: args.order,
        tolerance: args.tolerance,
        modes: args.modes,
        skip_measured_error: args.no_measure,
        training_cache: args.cache.clone(),
    };
    let compiled = compile(&args.scene, &options).map_err(|e| e.to_string())?;
    eprint!("{}", compiled.summary());
    // Both files are written in full to temporary siblings before either replaces its target.
    let model = match &args.output {
        Some(path) => Some(staged(path, &compiled.bytes)?),
        None => None,
    };
    let report = match &args.report {
        Some(path) => Some(staged(path, compiled.report_json().as_bytes())?),
        None => None,
    };
    for file in [model, report].into_iter().flatten() {
        let path = file.target().to_path_buf();
        file.commit().map_err(|e| e.to_string())?;
        eprintln!("wrote {}", path.display());
    }
    if args.output.is_none() && args.report.is_none() {
        eprintln!("(no -o given: nothing written)");
    }
    Ok(ExitCode::SUCCESS)
}
