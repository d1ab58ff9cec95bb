//! The full-order contact reference (docs/contact.md): the scene's full-order linear FEM with
//! the same rigid spherical tool and the same frictionless node-on-sphere contact law as the
//! runtime, solved to convergence by an algorithm of its own: normals taken at the solved
//! positions of the current iterate (a fixed point iterated to convergence within the call),
//! every region node tested at every iterate, the linear complementarity problem solved by
//! projected Gauss–Seidel on the exact full-order compliance of the contact nodes (no
//! reduction, no residual). Each call starts from the last call's contacts, so a staged press
//! follows its load path.
//!
//! Two references share that solve: [`ContactReference::new`] steps in time (Wilson-θ, J
//! factored once; the gap enforced at the θ-point t + θΔt, as the runtime does, where the
//! compliance is J⁻¹) and [`ContactReference::quasi_static`]
//! solves static equilibrium K u = f + contact forces (compliance K⁻¹) for each tool position:
//! the force against depth and path of a slow press or slide, without the body's inertia.

use std::collections::BTreeMap;

use crokf_compile::contact::ContactRegion;
use crokf_compile::full_order::FullOrder;
use crokf_compile::stepping::linear::{LinearSimulator, StaticSolver};
use crokf_compile::stepping::{Simulator, SteppingError};

/// Outer iterations (contact search and normals) of one step.
const MAX_OUTER: usize = 1000;
/// Gauss–Seidel sweeps of one complementarity problem.
const MAX_SWEEPS: usize = 20_000;

/// The result of one reference step.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ReferenceContact {
    /// Force of the body on the tool, N.
    pub force: [f64; 3],
    /// Region nodes pressing on the tool.
    pub active: usize,
    /// Largest penetration left by the solve, m (its residual).
    pub residual_penetration: f64,
    /// The pressing region nodes (region index) with their normal force, N.
    pub pressing: Vec<(usize, f64)>,
    /// Outer passes the solve took (at most its cap, when it did not settle).
    pub passes: usize,
}

/// How the reference relates force to displacement.
enum Kind {
    /// Wilson-θ time stepping: θ-point compliance J⁻¹.
    Dynamic(Box<LinearSimulator>),
    /// Static equilibrium: compliance K⁻¹.
    Static(StaticSolver),
}

/// The full-order linear FEM of a scene with a tool on its contact region.
pub struct ContactReference<'a> {
    full: &'a FullOrder,
    kind: Kind,
    region: ContactRegion,
    /// Displacement of every DOF per unit force on a region DOF, cached per DOF.
    columns: BTreeMap<usize, Vec<f64>>,
    free: Vec<f64>,
    /// The displacement of the last solve (with its contact forces).
    solved: Vec<f64>,
    /// The pressing nodes of the last solve (region index, force, normal): where the next
    /// solve starts, so that a staged press follows its load path (with a curved tool a
    /// frictionless problem can have more than one equilibrium).
    last: Vec<(usize, f64, [f64; 3])>,
}

impl<'a> ContactReference<'a> {
    /// The time-stepping reference of a full-order model whose scene declares a contact region.
    pub fn new(full: &'a FullOrder) -> Result<Self, String> {
        let sim = LinearSimulator::new(&full.fem, full.wilson).map_err(|e| e.to_string())?;
        Self::with(full, Kind::Dynamic(Box::new(sim)))
    }

    /// The quasi-static reference: each [`ContactReference::solve_static`] is the static
    /// equilibrium with the tool where it is, found from the last call's contacts.
    pub fn quasi_static(full: &'a FullOrder) -> Result<Self, String> {
        let solver = StaticSolver::new(&full.fem).map_err(|e| e.to_string())?;
        Self::with(full, Kind::Static(solver))
    }

    fn with(full: &'a FullOrder, kind: Kind) -> Result<Self, String> {
        let unit = full.scene.scene.mesh.units.to_metres();
        let region = ContactRegion::build(&full.mesh, &full.scene.scene, &full.fem, unit)
            .map_err(|e| e.to_string())?
            .ok_or_else(|| {
                format!(
                    "{}: the scene declares no [[contact]] region",
                    full.scene_path().display()
                )
            })?;
        let n = full.fem.dof_count();
        Ok(ContactReference {
            full,
            kind,
            region,
            columns: BTreeMap::new(),
            free: vec![0.0; n],
            solved: vec![0.0; n],
            last: Vec::new(),
        })
    }

    /// The region (its nodes, in the model file's order).
    pub fn region(&self) -> &ContactRegion {
        &self.region
    }

    fn column(&mut self, dof: usize) -> &[f64] {
        let n = self.full.fem.dof_count();
        let kind = &self.kind;
        self.columns.entry(dof).or_insert_with(|| {
            let mut b = vec![0.0; n];
            b[dof] = 1.0;
            match kind {
                Kind::Dynamic(sim) => sim.theta_compliance(&mut b),
                Kind::Static(solver) => solver.solve_in_place(&mut b),
            }
            b
        })
    }

    /// One time step with the tool's centre at `tool` (m) and the external load `f` (n DOFs,
    /// N) held over it. Fails on the quasi-static reference.
    pub fn step(&mut self, tool: [f64; 3], f: &[f64]) -> Result<ReferenceContact, SteppingError> {
        let Kind::Dynamic(sim) = &mut self.kind else {
            return Err(SteppingError::Solver(
                "step works on the time-stepping reference (ContactReference::new)".into(),
            ));
        };
        sim.theta_displacement(f, &mut self.free)?;
        let (result, load) = self.solve(tool, f);
        if let Kind::Dynamic(sim) = &mut self.kind {
            sim.step(&load)?;
            self.solved.copy_from_slice(sim.displacement());
        }
        Ok(result)
    }

    /// The static equilibrium with the tool's centre at `tool` (m) and the external load `f`
    /// (n DOFs, N). Fails on the time-stepping reference.
    pub fn solve_static(
        &mut self,
        tool: [f64; 3],
        f: &[f64],
    ) -> Result<ReferenceContact, SteppingError> {
        self.static_free("solve_static", f, None)?;
        let (result, load) = self.solve(tool, f);
        self.solved.copy_from_slice(&load);
        if let Kind::Static(solver) = &self.kind {
            solver.solve_in_place(&mut self.solved);
        }
        Ok(result)
    }

    /// The static equilibrium with region node `node` held at `target` (m) in all three
    /// directions by a grasping tool (a bilateral constraint, the runtime's grasp) and the
    /// external load `f` (n DOFs, N): the force λ on the node solves G_aa λ = target − X_a −
    /// (K⁻¹ f)_a with G_aa the node's exact 3×3 static compliance. The tool pushes nowhere
    /// else. Fails on the time-stepping reference.
    pub fn solve_static_grasp(
        &mut self,
        node: usize,
        target: [f64; 3],
        f: &[f64],
    ) -> Result<ReferenceContact, SteppingError> {
        self.static_free("solve_static_grasp", f, Some(node))?;
        let dofs = [0, 1, 2].map(|c| self.region.dofs[3 * node + c]);
        let rest = self.full.fem.positions[self.region.nodes[node]];
        let mut g = [[0.0f64; 3]; 3];
        for (b, &db) in dofs.iter().enumerate() {
            let col = self.column(db).to_vec();
            for (a, &da) in dofs.iter().enumerate() {
                g[a][b] = col[da];
            }
        }
        let want = [0, 1, 2].map(|c| target[c] - rest[c] - self.free[dofs[c]]);
        let lambda = solve3(g, want).ok_or_else(|| {
            SteppingError::Solver(format!("node {node}: its static compliance is singular"))
        })?;
        let mut load = f.to_vec();
        for c in 0..3 {
            load[dofs[c]] += lambda[c];
        }
        self.solved.copy_from_slice(&load);
        if let Kind::Static(solver) = &self.kind {
            solver.solve_in_place(&mut self.solved);
        }
        self.last.clear();
        Ok(ReferenceContact {
            force: lambda.map(|v| -v),
            active: 1,
            residual_penetration: 0.0,
            pressing: vec![(node, lambda.iter().map(|v| v * v).sum::<f64>().sqrt())],
            passes: 1,
        })
    }

    /// The free static displacement K⁻¹ f into `self.free`, for the quasi-static solve `what`;
    /// fails on the time-stepping reference, on a load vector of the wrong length, or a
    /// region node (`node`) past the region.
    fn static_free(
        &mut self,
        what: &str,
        f: &[f64],
        node: Option<usize>,
    ) -> Result<(), SteppingError> {
        let Kind::Static(solver) = &self.kind else {
            return Err(SteppingError::Solver(format!(
                "{what} works on the quasi-static reference (ContactReference::quasi_static)"
            )));
        };
        if f.len() != self.free.len() {
            return Err(SteppingError::Solver(format!(
                "load vector f has {} entries, the model {}",
                f.len(),
                self.free.len()
            )));
        }
        if let Some(node) = node.filter(|&i| i >= self.region.len()) {
            return Err(SteppingError::Solver(format!(
                "node {node}: the region has {}",
                self.region.len()
            )));
        }
        self.free.copy_from_slice(f);
        solver.solve_in_place(&mut self.free);
        Ok(())
    }

    /// The contact forces on the free displacement `self.free`: the result and the load with
    /// the contact forces added.
    fn solve(&mut self, tool: [f64; 3], f: &[f64]) -> (ReferenceContact, Vec<f64>) {
        self.solve_with(tool, f, None)
    }

    /// [`ContactReference::solve_static`] with a second tool holding region node `node` at
    /// `target` (m) in all three directions (the runtime's grasp), solved together with the
    /// pushing tool's contacts. The result is the pushing tool's; the grasp's force on its
    /// tool is the second value.
    pub fn solve_static_with_grasp(
        &mut self,
        tool: [f64; 3],
        node: usize,
        target: [f64; 3],
        f: &[f64],
    ) -> Result<(ReferenceContact, [f64; 3]), SteppingError> {
        self.static_free("solve_static_with_grasp", f, Some(node))?;
        self.last.retain(|l| l.0 != node);
        let (result, load) = self.solve_with(tool, f, Some((node, target)));
        let held = [0, 1, 2]
            .map(|c| f[self.region.dofs[3 * node + c]] - load[self.region.dofs[3 * node + c]]);
        self.solved.copy_from_slice(&load);
        if let Kind::Static(solver) = &self.kind {
            solver.solve_in_place(&mut self.solved);
        }
        Ok((result, held))
    }

    /// The solve with an optional grasp (region node, target): its three bilateral rows along
    /// the axes join the complementarity problem, unprojected.
    fn solve_with(
        &mut self,
        tool: [f64; 3],
        f: &[f64],
        grasp: Option<(usize, [f64; 3])>,
    ) -> (ReferenceContact, Vec<f64>) {
        let n = self.full.fem.dof_count();
        let radius = self.region.radius;
        let nodes = self.region.len();
        let rest: Vec<[f64; 3]> = self
            .region
            .nodes
            .iter()
            .map(|&i| self.full.fem.positions[i])
            .collect();
        // Active nodes (region index) with their force vectors λ n.
        let mut active: Vec<usize> = self.last.iter().map(|l| l.0).collect();
        let mut lambda: Vec<f64> = self.last.iter().map(|l| l.1).collect();
        let mut normals: Vec<[f64; 3]> = self.last.iter().map(|l| l.2).collect();
        // The grasp's rows first, if any: bilateral, along the axes.
        let held = grasp.map(|(g, _)| g);
        if let Some((g, _)) = grasp {
            for axis in 0..3 {
                let mut e = [0.0; 3];
                e[axis] = 1.0;
                active.insert(axis, g);
                lambda.insert(axis, 0.0);
                normals.insert(axis, e);
            }
        }
        let fixed = if grasp.is_some() { 3 } else { 0 };
        let mut position = vec![[0.0; 3]; nodes];
        let mut converged_penetration = 0.0;
        let mut passes = 0;
        for _ in 0..MAX_OUTER {
            passes += 1;
            // Positions (θ-point or static) of every region node under the current forces.
            let mut u = self.free.clone();
            for (k, &a) in active.iter().enumerate() {
                for c in 0..3 {
                    let d = self.region.dofs[3 * a + c];
                    let fc = lambda[k] * normals[k][c];
                    if fc != 0.0 {
                        let col = self.column(d).to_vec();
                        u.iter_mut().zip(&col).for_each(|(u, v)| *u += fc * v);
                    }
                }
            }
            let mut deepest = 0.0f64;
            let mut added = false;
            for i in 0..nodes {
                let d3 = [0, 1, 2].map(|c| self.region.dofs[3 * i + c]);
                let p = [0, 1, 2].map(|c| rest[i][c] + u[d3[c]]);
                position[i] = p;
                let d = [p[0] - tool[0], p[1] - tool[1], p[2] - tool[2]];
                let gap = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() - radius;
                if gap < 0.0 && held != Some(i) {
                    deepest = deepest.max(-gap);
                    if !active.contains(&i) {
                        active.push(i);
                        lambda.push(0.0);
                        normals.push([0.0; 3]);
                        added = true;
                    }
                }
            }
            converged_penetration = deepest;
            // Normals at the current positions.
            let mut moved = 0.0f64;
            for (k, &a) in active.iter().enumerate().skip(fixed) {
                let p = position[a];
                let d = [p[0] - tool[0], p[1] - tool[1], p[2] - tool[2]];
                let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-300);
                let nn = [d[0] / len, d[1] / len, d[2] / len];
                moved = moved.max(
                    (0..3)
                        .map(|c| (nn[c] - normals[k][c]).abs())
                        .fold(0.0, f64::max),
                );
                normals[k] = nn;
            }
            let slip = grasp.map_or(0.0, |(g, target)| {
                (0..3)
                    .map(|c| (position[g][c] - target[c]).abs())
                    .fold(0.0, f64::max)
            });
            if !added && moved < 1e-10 && deepest < 1e-9 * radius && slip < 1e-12 * radius {
                break;
            }
            // The complementarity problem on the free positions with the current normals:
            // gap_a(λ) = |p_free,a − c| − R (linearised along n_a) + Σ_b n_aᵀ W_ab n_b λ_b.
            let m = active.len();
            let mut a_mat = vec![0.0; m * m];
            let mut g0 = vec![0.0; m];
            for (ka, &a) in active.iter().enumerate() {
                let pa = [0, 1, 2].map(|c| rest[a][c] + self.free[self.region.dofs[3 * a + c]]);
                g0[ka] = match grasp {
                    Some((_, target)) if ka < fixed => pa[ka] - target[ka],
                    _ => {
                        (0..3)
                            .map(|c| (pa[c] - tool[c]) * normals[ka][c])
                            .sum::<f64>()
                            - radius
                    }
                };
                for (kb, &b) in active.iter().enumerate() {
                    let mut v = 0.0;
                    for cb in 0..3 {
                        let col = self.column(self.region.dofs[3 * b + cb]).to_vec();
                        for ca in 0..3 {
                            v += normals[ka][ca]
                                * col[self.region.dofs[3 * a + ca]]
                                * normals[kb][cb];
                        }
                    }
                    a_mat[ka * m + kb] = v;
                }
            }
            let scale = g0.iter().fold(0.0f64, |s, v| s.max(v.abs())).max(1e-300);
            for _ in 0..MAX_SWEEPS {
                let mut change = 0.0f64;
                for ka in 0..m {
                    let w: f64 = g0[ka]
                        + (0..m)
                            .map(|kb| a_mat[ka * m + kb] * lambda[kb])
                            .sum::<f64>();
                    let step = lambda[ka] - w / a_mat[ka * m + ka];
                    let next = if ka < fixed { step } else { step.max(0.0) };
                    change = change.max(((next - lambda[ka]) * a_mat[ka * m + ka]).abs());
                    lambda[ka] = next;
                }
                if change < 1e-14 * scale {
                    break;
                }
            }
        }
        // Commit the step with the contact forces.
        let mut load = f.to_vec();
        let mut force = [0.0; 3];
        let mut pressing = Vec::new();
        self.last.clear();
        for (k, &a) in active.iter().enumerate() {
            if lambda[k] > 0.0 && k >= fixed {
                pressing.push((a, lambda[k]));
                self.last.push((a, lambda[k], normals[k]));
            }
            for c in 0..3 {
                load[self.region.dofs[3 * a + c]] += lambda[k] * normals[k][c];
                if k >= fixed {
                    force[c] -= lambda[k] * normals[k][c];
                }
            }
        }
        debug_assert_eq!(load.len(), n);
        (
            ReferenceContact {
                force,
                active: pressing.len(),
                residual_penetration: converged_penetration,
                pressing,
                passes,
            },
            load,
        )
    }

    /// Full-order displacement after the last step or static solve (n DOFs).
    pub fn displacement(&self) -> &[f64] {
        &self.solved
    }
}

/// x with g x = b (3×3, Cramer's rule), `None` when g is singular.
fn solve3(g: [[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(g);
    if d == 0.0 || !d.is_finite() {
        return None;
    }
    Some([0, 1, 2].map(|c| {
        let mut m = g;
        for (row, &bv) in m.iter_mut().zip(&b) {
            row[c] = bv;
        }
        det(m) / d
    }))
}
