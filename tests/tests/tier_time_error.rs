//! The co-rotational tier's time-discretisation error on the small
//! co-rotational beam of `tier.rs` (12×2×2 cells, Δt = 5 ms, 30 steps a run): the converged
//! full-order reference converges at second order, and the figures split the tier's error
//! against it into the reduction's and the Wilson-θ step's
//! (`crokf_compile::nonlinear::time_error`).
//!
//! `cargo test -p crokf-tests --test tier_time_error -- --nocapture` prints the figures.

use crokf_compile::nonlinear::self_check::runtime_newton;
use crokf_compile::nonlinear::time_error::{self, Substepping};
use crokf_compile::nonlinear::training::{self, History};
use crokf_compile::outputs::Measurements;
use crokf_compile::reductor::tier::TierReductor;
use crokf_compile::timer::StageTimer;
use crokf_compile::FullOrder;

#[path = "support/beam_tier.rs"]
mod beam_tier;
use beam_tier::{tip_beam, write_tier_scene};

#[test]
fn the_converged_reference_converges_and_the_step_error_is_measured() {
    let dir = std::env::temp_dir().join(format!("crokf-tier-time-{}", std::process::id()));
    let path = write_tier_scene(&dir, "scene.toml", &tip_beam());
    let mut timer = StageTimer::default();
    let full = FullOrder::build(&path, &mut timer).unwrap();
    let measurements = Measurements::new(&full.operators);
    let tier = TierReductor::new(&full, &measurements, None, &mut timer, &mut |_| {}).unwrap();
    let newton = runtime_newton(tier.spec.newton_tolerance, tier.spec.newton_iterations);
    let runs = tier.plan.runs();
    let dt = full.wilson.dt;
    let mut figures = Vec::new();
    for run in runs.iter().filter(|r| r.label.contains("(+0, +0, -1)")) {
        let e = time_error::measure_run(&full, &tier.plan, &tier.tier, newton, run, 16).unwrap();
        eprintln!(
            "{}: reduction {:.2e}, tier vs converged {:.2e}, step {:.2e}, at Δt/2 {:.2e} \
             (order {:.2}), restarted at Δt {:.2e}, reference's own {:.1e} (ratio {:.2}), \
             Δt for 1 % {:.2e} s",
            e.label,
            e.reduction,
            e.against_converged,
            e.step,
            e.step_half,
            e.step_order(),
            e.step_restarted,
            e.reference_error,
            e.reference_ratio,
            e.dt_for(dt, 0.01)
        );
        figures.push(e);
    }
    assert_eq!(figures.len(), 2, "a ramp and a step along −z");
    // Measured on the ramp / the step: reference ratio 4.05 / 3.99, its own error 4.7e-6 /
    // 1.3e-5 against the step's 7.2e-2 / 5.8e-2 (order 0.99 from Δt/2), the reduction's
    // 8.2e-3 / 7.5e-3.
    for e in &figures {
        // The reference converges at second order, far below the errors it measures.
        assert!(
            e.reference_ratio > 3.5 && e.reference_ratio < 4.5,
            "second order expected: {e:?}"
        );
        assert!(e.reference_error < 1e-2 * e.step, "{e:?}");
        // The Wilson-θ step on loads that jump, without a restart: first order.
        assert!(
            e.step_order() > 0.8 && e.step_order() < 1.2,
            "first order expected: {e:?}"
        );
        // On this beam the step's own error, not the reduction, dominates what a user sees
        // (the tier's self-check, same scheme, shows only the reduction's).
        assert!(e.step > 4.0 * e.reduction, "{e:?}");
        assert!(e.against_converged > 0.5 * e.step, "{e:?}");
        assert!(e.reduction < 2e-2, "{e:?}");
        // Δt for 1 %, extrapolated at the measured order: below the scene's Δt.
        let dt1 = e.dt_for(dt, 0.01);
        assert!(dt1 < 0.25 * dt && dt1 > 0.05 * dt, "{dt1}");
    }
    // Without the restart the sub-stepped reference converges at first order only: the
    // differences from Δt/16 of Δt/4 and Δt/8 are in the ratio 3 (second order: 5).
    let step_run = runs
        .iter()
        .find(|r| r.label.contains("(+0, +0, -1)") && matches!(r.history, History::Step { .. }))
        .unwrap();
    let groups = training::plan_groups(&full, &tier.plan).unwrap();
    let unit = training::run_load(&full, &tier.plan, &groups, step_run);
    let rows = time_error::measured_rows(&full);
    let steps = tier.plan.steps(dt);
    let response = |substeps, restart| {
        time_error::full_order_response(
            &full,
            &tier.plan,
            &unit,
            &step_run.history,
            steps,
            Substepping { substeps, restart },
            &rows,
        )
        .unwrap()
    };
    let (a, b, c) = (response(4, false), response(8, false), response(16, false));
    let ratio = time_error::relative_l2(&c, &a) / time_error::relative_l2(&c, &b);
    eprintln!("without the restart: Δt/4, Δt/8 vs Δt/16 ratio {ratio:.2}");
    assert!(ratio > 2.7 && ratio < 3.3, "first order expected: {ratio}");
    let _ = std::fs::remove_dir_all(&dir);
}
