//! Adaptive load stepping of a quasi-static solve, one rule for the full-order
//! (`CorotationalSimulator::static_solve`) and the reduced (`HyperReducedModel::static_solve`)
//! co-rotational models: the load factor λ goes from 0 to 1 in increments; an increment whose
//! solve does not converge is halved, one that converges in at most [`FAST_ITERATIONS`] lets
//! the next grow by 1.5; below [`SMALLEST_INCREMENT`] the solve is stuck.

/// Iterations within which a converged increment lets the next one grow.
pub const FAST_ITERATIONS: usize = 6;

/// The smallest increment of λ tried.
pub const SMALLEST_INCREMENT: f64 = 1e-4;

/// Why [`load_steps`] stopped.
#[derive(Debug)]
pub enum LoadStepError<E> {
    /// The increment fell below [`SMALLEST_INCREMENT`] at this load factor λ.
    Stuck {
        /// The last converged λ.
        load_factor: f64,
    },
    /// The solve of an increment failed with an error of its own.
    Solve(E),
}

/// Drives λ from 0 to 1 from the state `start` (at λ = 0): `solve(state, target)` solves at
/// the load factor `target` from `state` and returns the converged state with its iteration
/// count, or `None` when it did not converge. Returns the state at λ = 1.
pub fn load_steps<S, E>(
    start: S,
    mut solve: impl FnMut(&S, f64) -> Result<Option<(S, usize)>, E>,
) -> Result<S, LoadStepError<E>> {
    let mut state = start;
    let (mut lambda, mut increment) = (0.0f64, 1.0f64);
    while lambda < 1.0 {
        let target = (lambda + increment).min(1.0);
        match solve(&state, target).map_err(LoadStepError::Solve)? {
            Some((next, iterations)) => {
                state = next;
                lambda = target;
                if iterations <= FAST_ITERATIONS {
                    increment *= 1.5;
                }
            }
            None => {
                increment *= 0.5;
                if increment < SMALLEST_INCREMENT {
                    return Err(LoadStepError::Stuck {
                        load_factor: lambda,
                    });
                }
            }
        }
    }
    Ok(state)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// x(λ) = λ solved by a "solver" that converges only for increments ≤ 0.3: the steps
    /// halve down to 0.25, grow by 1.5 after each fast convergence, halve again on failure.
    #[test]
    fn increments_halve_and_grow() {
        let mut targets = Vec::new();
        let end = load_steps(0.0f64, |&x, target| {
            targets.push(target);
            Ok::<_, ()>((target - x <= 0.3).then_some((target, 3)))
        })
        .unwrap();
        assert_eq!(end, 1.0);
        assert_eq!(targets, [1.0, 0.5, 0.25, 0.625, 0.4375, 0.71875, 1.0]);
        // A solver that never converges is stuck at λ = 0 after 14 halvings.
        let mut calls = 0;
        match load_steps(0.0f64, |_, _| {
            calls += 1;
            Ok::<Option<(f64, usize)>, ()>(None)
        }) {
            Err(LoadStepError::Stuck { load_factor }) => assert_eq!(load_factor, 0.0),
            other => panic!("{other:?}"),
        }
        assert_eq!(calls, 14);
    }
}
