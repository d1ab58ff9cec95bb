//! `crokf-run MODEL --inputs inputs.csv [--measurements m.csv] [--tool tool.csv] --out estimates.csv [--vtu DIR]`
//! `crokf-run MODEL --serve [--port 8080]`: the live browser viewer (`crokf-viewer`).
//!
//! Runs the estimator over an input history (and optional measurements) and writes the
//! estimated sensor displacements (world frame) and their standard deviations per step.
//! Output paths are checked before any work (not an input, not twice, folder exists); the
//! outputs are written to temporary files and renamed into place only when every step has
//! succeeded.

use clap::Parser;
use crokf_formats::output::{self, AtomicFile, Output, OutputKind, StagedDir};
use crokf_run::{table, vtu, RunError};
use crokf_runtime::{load_model, Estimator};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Run a crokf model over recorded inputs and measurements.
#[derive(Parser, Debug)]
#[command(version, about)]
struct Args {
    /// Model file written by crokf-compile.
    model: PathBuf,
    /// Inputs CSV: `step` (or `t`), then one column per input label; rows are steps 1, 2, ….
    #[arg(long, required_unless_present = "serve")]
    inputs: Option<PathBuf>,
    /// Measurements CSV: `step` (or `t`), then columns `sensor.x|y|z`; empty cell = missing.
    #[arg(long)]
    measurements: Option<PathBuf>,
    /// Tool path CSV (a model with a contact region, docs/contact.md): `step` (or `t`), then
    /// `tool0.x,tool0.y,tool0.z` [and `tool1.…`], m, optionally `toolT.grasp` (0/1: grasp the
    /// node nearest the tool where it turns 1, let go where it turns 0), one row per input row;
    /// the estimates gain each tool's force, pressing nodes and status.
    #[arg(long)]
    tool: Option<PathBuf>,
    /// Output CSV: step, t, estimated sensor displacements, their standard deviations.
    #[arg(long, required_unless_present = "serve")]
    out: Option<PathBuf>,
    /// Also write one .vtu per step and estimates.pvd into this existing folder (the series
    /// replaces an older one whole: its step files that the new run does not write are
    /// removed; other files in the folder are left alone).
    #[arg(long)]
    vtu: Option<PathBuf>,
    /// Innovation gate in standard deviations of the innovation: a measurement beyond it is
    /// skipped for that step and counted (summary on stderr); 0 turns the gate off.
    #[arg(long, default_value_t = crokf_runtime::DEFAULT_GATE_SIGMAS)]
    gate: f64,
    /// Serve the live viewer instead: step the model in real time and draw it in the browser
    /// (three.js page served from this binary; loopback only unless --address says otherwise).
    #[arg(long, conflicts_with_all = ["inputs", "measurements", "tool", "out", "vtu"])]
    serve: bool,
    /// With --serve: TCP port (0: any free port).
    #[arg(long, default_value_t = 8080, requires = "serve")]
    port: u16,
    /// With --serve: listening address. Anything but loopback exposes the viewer.
    #[arg(long, default_value = "127.0.0.1", requires = "serve")]
    address: std::net::IpAddr,
    /// With --serve: slider range of each world force component, ±N.
    #[arg(long, default_value_t = 1.0, requires = "serve")]
    force_range: f64,
    /// With --serve: displayed node set to draw (default "surface", else the first with
    /// triangles).
    #[arg(long, requires = "serve")]
    node_set: Option<String>,
    /// With --vtu: write every N-th step only.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    vtu_every: u64,
}

/// Refuses outputs that are inputs or collide, a `--vtu` folder that does not exist, and a
/// series file inside it that is an input or `--out`, before any work; then removes (and
/// names) the temporaries an earlier, killed run left next to the outputs.
fn check_outputs(args: &Args, inputs_path: &Path, out_path: &Path) -> Result<(), RunError> {
    let mut inputs: Vec<(&str, &Path)> = vec![("model", &args.model), ("--inputs", inputs_path)];
    if let Some(m) = &args.measurements {
        inputs.push(("--measurements", m));
    }
    if let Some(t) = &args.tool {
        inputs.push(("--tool", t));
    }
    let mut outputs = vec![Output {
        role: "--out",
        path: out_path,
        kind: OutputKind::File,
    }];
    if let Some(dir) = &args.vtu {
        outputs.push(Output {
            role: "--vtu",
            path: dir,
            kind: OutputKind::ExistingFolder,
        });
    }
    output::check_paths(&inputs, &outputs)?;
    // A file of the VTU series inside --vtu must not be an input or --out either.
    if let Some(dir) = &args.vtu {
        output::check_folder_inputs(&inputs, "--vtu", dir, vtu::is_series_file_name)?;
        if output::check_folder_inputs(
            &[("--out", out_path)],
            "--vtu",
            dir,
            vtu::is_series_file_name,
        )
        .is_err()
        {
            return Err(output::OutputError::SameOutput {
                first_role: "--vtu".into(),
                second_role: "--out".into(),
                path: out_path.to_path_buf(),
            }
            .into());
        }
    }
    for note in output::sweep_stale_temporaries(&outputs) {
        eprintln!("crokf-run: {note}");
    }
    Ok(())
}

/// `--serve`: the live viewer until interrupted.
fn serve(args: &Args) -> Result<(), String> {
    if !args.address.is_loopback() {
        eprintln!(
            "crokf-run: warning: the viewer listens on {}, reachable from the network",
            args.address
        );
    }
    let options = crokf_viewer::ServeOptions {
        address: args.address,
        port: args.port,
        node_set: args.node_set.clone(),
        force_range: args.force_range,
        title: args
            .model
            .file_name()
            .map_or_else(|| "crokf".into(), |f| f.to_string_lossy().into_owned()),
        ..crokf_viewer::ServeOptions::default()
    };
    crokf_viewer::serve_file(&args.model, options).map_err(|e| e.to_string())
}

fn run(args: &Args) -> Result<(), RunError> {
    let (Some(inputs_path), Some(out_path)) = (args.inputs.as_deref(), args.out.as_deref()) else {
        return Err(RunError::Usage(
            "--inputs and --out are required (or --serve for the live viewer)".into(),
        ));
    };
    check_outputs(args, inputs_path, out_path)?;
    let model = load_model(&args.model)?;
    if let Some(warning) = model.tier_failed_check_warning() {
        eprintln!("crokf-run: warning: {}: {warning}", args.model.display());
    }
    let inputs = table::read_inputs(inputs_path, &model)?;
    let measurements = match &args.measurements {
        Some(p) => table::read_measurements(p, &model)?,
        None => Default::default(),
    };
    let tools = match &args.tool {
        Some(p) => {
            if model.contact.is_none() {
                return Err(RunError::Usage(format!(
                    "--tool {}: the model {} has no contact region (declare a [[contact]] in \
                     its scene, docs/contact.md)",
                    p.display(),
                    args.model.display()
                )));
            }
            let t = table::read_tools(p, &model)?;
            if t.rows.len() != inputs.rows.len() {
                return Err(RunError::Usage(format!(
                    "--tool {} has {} rows, --inputs {} has {}: one tool row per step",
                    p.display(),
                    t.rows.len(),
                    inputs_path.display(),
                    inputs.rows.len()
                )));
            }
            Some(t)
        }
        None => None,
    };
    let tool_count = tools.as_ref().map_or(0, |t| t.rows[0].len());
    let mut est = Estimator::new(&model)?;
    est.set_innovation_gate(Some(args.gate));
    let q = model.measurements.len();
    let ns = model.sensors.len();
    let none = vec![None; q];
    let mut u = vec![0.0; 3 * ns];
    let mut sd = vec![0.0; 3 * ns];
    let write_err = |source| output::OutputError::Io {
        path: out_path.to_path_buf(),
        source,
    };
    let mut out = AtomicFile::create(out_path)?;
    writeln!(
        out,
        "{}{}",
        table::estimates_header(&model),
        table::tool_header(tool_count)
    )
    .map_err(write_err)?;
    let mut staged = match &args.vtu {
        Some(dir) => Some(StagedDir::create_owning(dir, vtu::is_series_file_name)?),
        None => None,
    };
    let mut pvd = Vec::new();
    let mut offered = 0u64;
    // Co-rotational tier (docs/design.md §10): steps outside the training envelope, the
    // largest load and state ratios, Newton iterations.
    let (mut outside, mut worst_load, mut worst_state, mut newton) = (0u64, 0.0f64, 0.0f64, 0u64);
    // Steps after which the tier's filter carried its own covariance (a value missing or
    // gated, docs/design.md §11.11), and the first and last of them.
    let (mut own, mut own_span) = (0u64, None::<(u64, u64)>);
    let inputs_name = inputs_path.display().to_string();
    for (row, &line) in inputs.rows.iter().zip(&inputs.lines) {
        let k = est.step_index() + 1;
        let measured = measurements.get(&k);
        let y = measured.map_or(&none, |m| &m.values);
        let step_err = |source| {
            let mut location = format!("{inputs_name}:{line}");
            if let (Some(m), Some(p)) = (measured, &args.measurements) {
                location.push_str(&format!(", {}:{}", p.display(), m.line));
            }
            RunError::Step {
                step: k,
                location,
                source,
            }
        };
        let active = est.model().kalman.phases[(k % est.model().kalman.period as u64) as usize]
            .measured
            .iter()
            .filter(|&&j| y[j as usize].is_some())
            .count();
        match &tools {
            Some(t) => {
                let i = (k - 1) as usize;
                // A grasp column turning 1 takes hold before the step, turning 0 lets go.
                for (tool, &holds) in t.grasp[i].iter().enumerate() {
                    let held = est.grasped(tool).is_some();
                    if holds && !held {
                        est.grasp(tool).map_err(|source| {
                            let mut e = step_err(source);
                            if let (RunError::Step { location, .. }, Some(p)) = (&mut e, &args.tool)
                            {
                                location.push_str(&format!(", {}:{}", p.display(), t.lines[i]));
                            }
                            e
                        })?;
                    } else if !holds && held {
                        est.release(tool);
                    }
                }
                est.step_with_tools(&t.rows[i], row, y).map_err(|source| {
                    let mut e = step_err(source);
                    if let (RunError::Step { location, .. }, Some(p)) = (&mut e, &args.tool) {
                        location.push_str(&format!(", {}:{}", p.display(), t.lines[i]));
                    }
                    e
                })?;
            }
            None => {
                est.step(row, y).map_err(step_err)?;
            }
        }
        offered += active as u64;
        let status = est.tier_status();
        if status.envelope.outside() {
            outside += 1;
        }
        worst_load = worst_load.max(status.envelope.load_ratio);
        worst_state = worst_state.max(status.envelope.state_ratio);
        newton += status.iterations as u64;
        if est.tier_covariance().is_some() {
            own += 1;
            own_span = Some(own_span.map_or((k, k), |(first, _)| (first, k)));
        }
        est.sensor_displacements(&mut u).map_err(step_err)?;
        est.sensor_std(&mut sd).map_err(step_err)?;
        let mut text = format!("{},{}", k, est.time());
        for v in u.iter().chain(&sd) {
            text.push_str(&format!(",{v:e}"));
        }
        for t in 0..tool_count {
            let c = est.tool_contact(t).copied().unwrap_or_default();
            text.push_str(&format!(
                ",{:e},{:e},{:e},{},{:?}",
                c.force[0], c.force[1], c.force[2], c.active, c.status
            ));
        }
        writeln!(out, "{text}").map_err(write_err)?;
        if let Some(dir) = staged.as_mut() {
            if k % args.vtu_every == 0 {
                pvd.push((est.time(), vtu::write_step(dir, &est)?));
            }
        }
    }
    if let Some(mut dir) = staged {
        vtu::write_pvd(&mut dir, &pvd)?;
        dir.commit()?;
    }
    out.commit()?;
    eprintln!("{}", gate_summary(&est, offered));
    if est.is_corotational() {
        let steps = inputs.rows.len().max(1);
        eprintln!(
            "co-rotational tier: {outside} of {} steps outside the training envelope (largest \
             load / trained load {worst_load:.3}, largest |q| / trained |q| {worst_state:.3}); \
             {:.2} Newton iterations per step",
            inputs.rows.len(),
            newton as f64 / steps as f64
        );
        if let Some((first, last)) = own_span {
            eprintln!(
                "co-rotational tier: the filter carried its own covariance after {own} of {}                  steps (steps {first} … {last}: marker values missing or gated; its σ in the                  estimates grow where those markers looked)",
                inputs.rows.len()
            );
        }
    }
    if let Some(&last) = measurements.keys().next_back() {
        if last > inputs.rows.len() as u64 {
            eprintln!(
                "crokf-run: warning: measurements after step {} (the last input row) were ignored",
                inputs.rows.len()
            );
        }
    }
    Ok(())
}

/// `innovation gate 5σ: skipped 2 of 1200 measurements (tip.x 2)`.
fn gate_summary(est: &Estimator, offered: u64) -> String {
    let Some(g) = est.innovation_gate() else {
        return format!("innovation gate off: {offered} measurements used");
    };
    let labels = est.model().measurement_labels();
    let per: Vec<String> = est
        .gated_per_channel()
        .iter()
        .zip(&labels)
        .filter(|(&n, _)| n > 0)
        .map(|(n, l)| format!("{l} {n}"))
        .collect();
    let mut s = format!(
        "innovation gate {g}σ: skipped {} of {offered} measurements",
        est.gated_total()
    );
    if !per.is_empty() {
        s.push_str(&format!(" ({})", per.join(", ")));
    }
    s
}

fn main() -> ExitCode {
    let args = Args::parse();
    if args.serve {
        return match serve(&args) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("crokf-run: error: {e}");
                ExitCode::FAILURE
            }
        };
    }
    #[cfg(unix)]
    if let Err(e) = output::install_interrupt_cleanup("crokf-run") {
        eprintln!("crokf-run: warning: no cleanup on interrupt: {e}");
    }
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("crokf-run: error: {e}");
            ExitCode::FAILURE
        }
    }
}
