//! Wilson-θ time stepping (docs/design.md §2) as a linear recursion in s = [U; U̇; Ü]: the
//! scheme, its constants and its per-mode blocks are [`crokf_kernel::wilson`]'s, one definition
//! for the compiler, the runtime and the verification; here the scene's `[time]` table becomes
//! one ([`WilsonTheta::from`]).

pub use crokf_kernel::wilson::WilsonTheta;

use crate::scene::TimeSpec;

/// The scene's time spec `[time]`: the one place Δt and θ become a Wilson-θ scheme.
impl From<&TimeSpec> for WilsonTheta {
    fn from(time: &TimeSpec) -> Self {
        WilsonTheta {
            dt: time.dt,
            theta: time.theta,
        }
    }
}
