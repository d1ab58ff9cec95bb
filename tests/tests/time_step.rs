//! The time step's own error (docs/design.md §2): on the bundled cantilever, the reduced model
//! stepped by Wilson-θ and by the exact zero-order-hold modal step, both against the full-order
//! linear FEM converged in time (Wilson-θ at Δt/16 with the acceleration restarted where the
//! load changes, `accuracy::Stepping::Converged`), and the reference's own convergence.

use std::path::{Path, PathBuf};

use crokf_compile::accuracy::{self, ReferenceResponses, Stepping};
use crokf_compile::reduce::Order;
use crokf_compile::reductor::Reductor;
use crokf_compile::scene::Scheme;
use crokf_compile::timer::StageTimer;
use crokf_compile::FullOrder;

fn cantilever() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/cantilever/scene.toml")
}

#[test]
fn the_exact_step_removes_the_time_steps_error() {
    let mut timer = StageTimer::default();
    let mut full = FullOrder::build(&cantilever(), &mut timer).unwrap();
    let mut figures = Vec::new();
    let mut converged_errors = Vec::new();
    for scheme in [Scheme::WilsonTheta, Scheme::Exact] {
        full.scene.scene.time.scheme = scheme;
        let reductor = Reductor::new(&full, None, &mut timer).unwrap();
        let reduced = reductor.reduce(Order::Fixed(30)).unwrap();
        let (steps, f_high) = reductor.measure_plan();
        let tests = accuracy::standard_tests(&full, steps, f_high);
        let at = |stepping| {
            ReferenceResponses::simulate_with(&full, &reductor.rows, tests.clone(), stepping)
                .unwrap()
        };
        let same = at(Stepping::SameScheme);
        let converged = at(Stepping::Converged { substeps: 16 });
        let coarser = at(Stepping::Converged { substeps: 8 });
        // Second order: the difference from Δt/8 is about three times the error at Δt/16.
        let own = converged.relative_difference(&coarser);
        let errors = converged.errors(&reduced);
        let wilson_full = converged.relative_difference(&same);
        for test in ["step", "chirp"] {
            assert!(
                own[test] < 1e-5,
                "{test}: the reference moves {:.2e}",
                own[test]
            );
            figures.push((scheme.name(), test, errors[test], wilson_full[test]));
        }
        converged_errors.push(errors);
        if scheme == Scheme::WilsonTheta {
            // Against its own scheme the reduction's error alone is small...
            let own_scheme = same.errors(&reduced);
            assert!(
                own_scheme["step"] < 1e-3 && own_scheme["chirp"] < 1e-3,
                "{own_scheme:?}"
            );
        }
    }
    eprintln!(
        "(scheme, test, reduced vs converged, full-order Wilson-θ vs converged): {figures:?}"
    );
    let (wilson, exact) = (&converged_errors[0], &converged_errors[1]);
    for test in ["step", "chirp"] {
        // ...but Wilson-θ at the scene's Δt is 0.8 % (step) and 1.6 % (chirp) off the
        // converged response; the exact step at the same order is 25–40 times closer.
        assert!(wilson[test] > 5e-3, "{test}: {wilson:?}");
        assert!(exact[test] < 1e-3, "{test}: {exact:?}");
        assert!(
            exact[test] < wilson[test] / 15.0,
            "{test}: {exact:?} against {wilson:?}"
        );
    }
}
