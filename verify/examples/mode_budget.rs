//! How many vibration modes and which truncation tolerance a scene needs:
//! for each mode budget m (`0` = the default rule: every mode up to 1/(4Δt), at most 60) the
//! modal system is built once, then truncated at each tolerance; printed per row: m, the
//! highest kept frequency, r, σ_{r+1}/σ₁ and the measured error (relative L2 over the output
//! rows against the full-order linear reference, step / chirp; docs/design.md §7).
//!
//! ```sh
//! cargo run --release -p crokf-verify --example mode_budget -- SCENE [MODES,..] [TOLERANCES,..]
//! ```

use std::path::PathBuf;
use std::process::ExitCode;

use crokf_compile::reduce::Order;
use crokf_compile::report::StageTimer;
use crokf_compile::{FullOrder, Reductor};

fn list<T: std::str::FromStr>(arg: Option<&String>, default: &str) -> Option<Vec<T>> {
    arg.map(String::as_str)
        .unwrap_or(default)
        .split(',')
        .map(|s| s.trim().parse().ok())
        .collect()
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let Some(scene) = args.first() else {
        eprintln!("usage: mode_budget SCENE [MODES,..] [TOLERANCES,..]");
        return ExitCode::FAILURE;
    };
    let (Some(budgets), Some(tolerances)) = (
        list::<usize>(args.get(1), "0,10,20,40,60,100"),
        list::<f64>(args.get(2), "1e-2,3e-3,1e-3,3e-4,1e-4"),
    ) else {
        eprintln!("MODES and TOLERANCES are comma-separated numbers");
        return ExitCode::FAILURE;
    };
    let mut timer = StageTimer::default();
    let full = match FullOrder::build(&PathBuf::from(scene), &mut timer) {
        Ok(f) => f,
        Err(e) => {
            eprintln!("{e}");
            return ExitCode::FAILURE;
        }
    };
    println!(
        "{scene}: {} free DOFs, Δt = {} s",
        full.fem.dof_count(),
        full.wilson.dt
    );
    println!("| modes | highest kept Hz | tolerance | r | σ_(r+1)/σ₁ | error step | error chirp | modes s |");
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|");
    for &m in &budgets {
        let started = std::time::Instant::now();
        let reductor = match Reductor::new(&full, (m > 0).then_some(m), &mut timer) {
            Ok(r) => r,
            Err(e) => {
                println!("| {m} | failed: {e} |");
                continue;
            }
        };
        let modes_s = started.elapsed().as_secs_f64();
        for &tol in &tolerances {
            let reduced = match reductor.reduce(Order::Tolerance(tol)) {
                Ok(r) => r,
                Err(e) => {
                    println!("| {m} | | {tol:e} | failed: {e} |");
                    continue;
                }
            };
            let r = reduced.balanced_order;
            let hsv = &reduced.hankel_singular_values;
            let next = hsv.get(r).map_or(0.0, |s| s / hsv[0]);
            let errors = match reductor.measured_errors(&reduced) {
                Ok(e) => e,
                Err(e) => {
                    println!("| {m} | | {tol:e} | {r} | failed: {e} |");
                    continue;
                }
            };
            let get = |k: &str| errors.get(k).copied().unwrap_or(f64::NAN);
            println!(
                "| {} | {:.1} | {tol:.0e} | {r} | {next:.1e} | {:.1e} | {:.1e} | {modes_s:.1} |",
                if m == 0 {
                    "default".to_string()
                } else {
                    m.to_string()
                },
                reductor.highest_kept_frequency_hz(),
                get("step"),
                get("chirp"),
            );
        }
    }
    ExitCode::SUCCESS
}
