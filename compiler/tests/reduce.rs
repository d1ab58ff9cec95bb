//! Model reduction against independent dense computations on small spring lattices.
//!
//! The reference discrete system is the full 3n-state Wilson-θ recursion assembled densely from
//! K, M, C (docs/design.md §2), independently of `WilsonTheta::modal_block`; its Gramians come from
//! Smith doubling and its Hankel singular values from eig(P Q).

// Index loops mirror the equations (σᵢ, ω²ᵢ compared entry by entry).
#![allow(clippy::needless_range_loop)]

use crokf_compile::dynamics::WilsonTheta;
use crokf_compile::reduce::{
    modal_basis, ModalBasis, ModalOptions, ModalSystem, Order, ReduceError,
};
use faer::linalg::solvers::{DenseSolveCore, Solve};
use faer::sparse::{SparseColMat, Triplet};
use faer::{Mat, MatRef, Side};

/// A 3-D lattice of nx×ny×nz unit-spaced nodes joined by axial springs along the edges, face
/// and body diagonals (stiffness `stiffness`/length), bar masses (density 1, consistent
/// 2-node mass or lumped). Nodes with x = 0 are fixed when `fix`.
struct Lattice {
    k: SparseColMat<usize, f64>,
    m: SparseColMat<usize, f64>,
    n: usize,
    /// DOF of (node, component), None when fixed.
    dof: Vec<Option<usize>>,
    dims: [usize; 3],
}

impl Lattice {
    fn new(dims: [usize; 3], fix: bool, stiffness: f64, lumped: bool) -> Self {
        let [nx, ny, nz] = dims;
        let node = |i: usize, j: usize, k: usize| (i * ny + j) * nz + k;
        let mut dof = vec![None; 3 * nx * ny * nz];
        let mut n = 0;
        for i in 0..nx {
            for j in 0..ny {
                for k in 0..nz {
                    if fix && i == 0 {
                        continue;
                    }
                    for c in 0..3 {
                        dof[3 * node(i, j, k) + c] = Some(n);
                        n += 1;
                    }
                }
            }
        }
        let offsets: [[i64; 3]; 13] = [
            [1, 0, 0],
            [0, 1, 0],
            [0, 0, 1],
            [1, 1, 0],
            [1, -1, 0],
            [1, 0, 1],
            [1, 0, -1],
            [0, 1, 1],
            [0, 1, -1],
            [1, 1, 1],
            [1, 1, -1],
            [1, -1, 1],
            [1, -1, -1],
        ];
        let (mut kt, mut mt) = (Vec::new(), Vec::new());
        for i in 0..nx {
            for j in 0..ny {
                for k in 0..nz {
                    for o in offsets {
                        let (i2, j2, k2) = (i as i64 + o[0], j as i64 + o[1], k as i64 + o[2]);
                        if i2 < 0
                            || j2 < 0
                            || k2 < 0
                            || i2 >= nx as i64
                            || j2 >= ny as i64
                            || k2 >= nz as i64
                        {
                            continue;
                        }
                        let (a, b) = (node(i, j, k), node(i2 as usize, j2 as usize, k2 as usize));
                        let len = ((o[0] * o[0] + o[1] * o[1] + o[2] * o[2]) as f64).sqrt();
                        let e = [o[0] as f64 / len, o[1] as f64 / len, o[2] as f64 / len];
                        let ks = stiffness / len;
                        for (p, q, sign) in [(a, a, 1.0), (b, b, 1.0), (a, b, -1.0), (b, a, -1.0)] {
                            for r in 0..3 {
                                for c in 0..3 {
                                    if let (Some(dr), Some(dc)) = (dof[3 * p + r], dof[3 * q + c]) {
                                        kt.push(Triplet::new(dr, dc, sign * ks * e[r] * e[c]));
                                    }
                                }
                                let (mpq, mpp) = if lumped {
                                    (0.0, len / 2.0)
                                } else {
                                    (len / 6.0, len / 3.0)
                                };
                                if let (Some(dr), Some(dc)) = (dof[3 * p + r], dof[3 * q + r]) {
                                    let v = if p == q { mpp } else { mpq };
                                    if v != 0.0 {
                                        mt.push(Triplet::new(dr, dc, v));
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
        let k = SparseColMat::try_new_from_triplets(n, n, &kt).unwrap();
        let m = SparseColMat::try_new_from_triplets(n, n, &mt).unwrap();
        Self { k, m, n, dof, dims }
    }

    fn node(&self, i: usize, j: usize, k: usize) -> usize {
        (i * self.dims[1] + j) * self.dims[2] + k
    }

    fn dof(&self, node: usize, c: usize) -> usize {
        self.dof[3 * node + c].unwrap()
    }

    /// Sparse rows: each row is a list of (DOF, weight).
    fn rows(&self, rows: &[Vec<(usize, f64)>]) -> SparseColMat<usize, f64> {
        let t: Vec<_> = rows
            .iter()
            .enumerate()
            .flat_map(|(r, row)| row.iter().map(move |&(d, w)| Triplet::new(r, d, w)))
            .collect();
        SparseColMat::try_new_from_triplets(rows.len(), self.n, &t).unwrap()
    }
}

fn symmetric_dense(a: &SparseColMat<usize, f64>) -> Mat<f64> {
    let d = a.to_dense();
    Mat::from_fn(d.nrows(), d.ncols(), |i, j| 0.5 * (d[(i, j)] + d[(j, i)]))
}

/// Eigenvalues of (K, M), ascending, by dense Cholesky of M and `self_adjoint_eigen`.
fn dense_eigenvalues(k: &Mat<f64>, m: &Mat<f64>) -> Vec<f64> {
    let llt = m.llt(Side::Lower).unwrap();
    let linv = llt.L().to_owned().partial_piv_lu().inverse();
    let c = &linv * k * linv.transpose();
    let c = Mat::from_fn(c.nrows(), c.ncols(), |i, j| 0.5 * (c[(i, j)] + c[(j, i)]));
    c.self_adjoint_eigenvalues(Side::Lower).unwrap()
}

/// Dense full-order Wilson-θ system s' = Φ s + Γ u, s = [U; U̇; Ü] (3n), from docs/design.md §2.
fn dense_wilson(
    k: &Mat<f64>,
    m: &Mat<f64>,
    alpha: f64,
    beta: f64,
    w: WilsonTheta,
    b: MatRef<'_, f64>,
) -> (Mat<f64>, Mat<f64>) {
    let n = k.nrows();
    let (dt, th) = (w.dt, w.theta);
    let tau = th * dt;
    let c = m * alpha + k * beta;
    let j = k + m * (6.0 / (tau * tau)) + &c * (3.0 / tau);
    let jinv = j.partial_piv_lu().inverse();
    let pu = &jinv * (m * (6.0 / (tau * tau)) + &c * (3.0 / tau));
    let pv = &jinv * (m * (6.0 / tau) + &c * 2.0);
    let pa = &jinv * (m * 2.0 + &c * (tau / 2.0));
    let pf = &jinv * b;
    let (b1, b2, b3) = (
        6.0 / (th * th * th * dt * dt),
        6.0 / (th * th * dt),
        1.0 - 3.0 / th,
    );
    let id = Mat::<f64>::identity(n, n);
    // Ü' = b1 (Û − U) − b2 U̇ + b3 Ü
    let a_row = [
        &pu * b1 - &id * b1,
        &pv * b1 - &id * b2,
        &pa * b1 + &id * b3,
    ];
    let a_f = &pf * b1;
    let mut phi = Mat::zeros(3 * n, 3 * n);
    let mut gamma = Mat::zeros(3 * n, b.ncols());
    for col in 0..3 {
        // U' = U + Δt U̇ + Δt²/6 (Ü' + 2Ü); U̇' = U̇ + Δt/2 (Ü' + Ü)
        let u_extra = [1.0, dt, dt * dt / 3.0][col];
        let v_extra = [0.0, 1.0, dt / 2.0][col];
        let ublk = &a_row[col] * (dt * dt / 6.0) + &id * u_extra;
        let vblk = &a_row[col] * (dt / 2.0) + &id * v_extra;
        phi.submatrix_mut(0, col * n, n, n).copy_from(&ublk);
        phi.submatrix_mut(n, col * n, n, n).copy_from(&vblk);
        phi.submatrix_mut(2 * n, col * n, n, n)
            .copy_from(&a_row[col]);
    }
    gamma
        .submatrix_mut(0, 0, n, b.ncols())
        .copy_from(&a_f * (dt * dt / 6.0));
    gamma
        .submatrix_mut(n, 0, n, b.ncols())
        .copy_from(&a_f * (dt / 2.0));
    gamma.submatrix_mut(2 * n, 0, n, b.ncols()).copy_from(&a_f);
    (phi, gamma)
}

/// X = Σ_j A^j Q (Aᵀ)^j by Smith doubling: X ← X + A X Aᵀ, A ← A².
fn smith(a: &Mat<f64>, q: &Mat<f64>) -> Mat<f64> {
    let (mut a, mut x) = (a.clone(), q.clone());
    for _ in 0..80 {
        x = &x + &a * &x * a.transpose();
        a = &a * &a;
        if a.norm_l2() < 1e-30 {
            break;
        }
    }
    x
}

/// Hankel singular values of the dense system, descending: sqrt(eig(P Q)).
fn dense_hsv(phi: &Mat<f64>, gamma: &Mat<f64>, cfull: &Mat<f64>) -> Vec<f64> {
    let p = smith(phi, &(gamma * gamma.transpose()));
    let q = smith(&phi.transpose().to_owned(), &(cfull.transpose() * cfull));
    let ev = (&p * &q).eigenvalues().unwrap();
    let mut s: Vec<f64> = ev.iter().map(|z| z.re.max(0.0).sqrt()).collect();
    s.sort_by(|a, b| b.total_cmp(a));
    s
}

/// Full output matrix [Cout, 0, 0] (p×3n).
fn full_output(cout: &SparseColMat<usize, f64>) -> Mat<f64> {
    let (p, n) = (cout.nrows(), cout.ncols());
    let d = cout.to_dense();
    Mat::from_fn(p, 3 * n, |i, j| if j < n { d[(i, j)] } else { 0.0 })
}

fn simulate_dense(phi: &Mat<f64>, gamma: &Mat<f64>, cfull: &Mat<f64>, u: &Mat<f64>) -> Mat<f64> {
    let mut s = Mat::<f64>::zeros(phi.nrows(), 1);
    let mut y = Mat::zeros(cfull.nrows(), u.ncols());
    for t in 0..u.ncols() {
        y.col_mut(t).copy_from((cfull * &s).col(0));
        s = phi * &s + gamma * u.subcols(t, 1);
    }
    y
}

fn l2(a: &Mat<f64>) -> f64 {
    a.norm_l2()
}

fn all_modes(n: usize) -> ModalOptions {
    ModalOptions {
        modes: Some(n),
        ..Default::default()
    }
}

/// The cantilever used by several tests: 5×2×2 nodes, x = 0 fixed, n = 48 DOFs.
/// Inputs: a y force and a z force at a tip corner, a distributed x load; outputs: tip
/// corner displacement (x, y, z) and the mean tip y displacement.
fn cantilever(stiffness: f64) -> (Lattice, Mat<f64>, SparseColMat<usize, f64>) {
    let lat = Lattice::new([5, 2, 2], true, stiffness, false);
    let tip = lat.node(4, 1, 1);
    let mut b = Mat::zeros(lat.n, 3);
    b[(lat.dof(tip, 1), 0)] = 1.0;
    b[(lat.dof(tip, 2), 1)] = 0.5;
    for i in 1..5 {
        for (j, k) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
            b[(lat.dof(lat.node(i, j, k), 0), 2)] = 0.25;
        }
    }
    let mean_y: Vec<(usize, f64)> = [(0, 0), (0, 1), (1, 0), (1, 1)]
        .iter()
        .map(|&(j, k)| (lat.dof(lat.node(4, j, k), 1), 0.25))
        .collect();
    let rows = lat.rows(&[
        vec![(lat.dof(tip, 0), 1.0)],
        vec![(lat.dof(tip, 1), 1.0)],
        vec![(lat.dof(tip, 2), 1.0)],
        mean_y,
    ]);
    (lat, b, rows)
}

/// Every mode of the lattice (k = n): the basis spans the whole space, so the reduced model
/// must equal the full-order one.
fn complete_basis(lat: &Lattice, b: &Mat<f64>) -> ModalBasis {
    modal_basis(
        lat.k.as_ref(),
        lat.m.as_ref(),
        b.as_ref(),
        &all_modes(lat.n),
    )
    .unwrap()
}

fn check_orthonormal(basis: &ModalBasis, lat: &Lattice) {
    let v = &basis.vectors;
    let mtm = v.transpose() * symmetric_dense(&lat.m) * v;
    let ktk = v.transpose() * symmetric_dense(&lat.k) * v;
    for i in 0..v.ncols() {
        for j in 0..v.ncols() {
            let want = if i == j { 1.0 } else { 0.0 };
            assert!(
                (mtm[(i, j)] - want).abs() < 1e-10,
                "VᵀMV[{i},{j}] = {}",
                mtm[(i, j)]
            );
            let scale = (basis.omega2[i] * basis.omega2[j]).sqrt();
            if i != j {
                assert!(
                    ktk[(i, j)].abs() < 1e-10 * scale,
                    "VᵀKV[{i},{j}] = {} (scale {scale})",
                    ktk[(i, j)]
                );
            } else {
                assert!((ktk[(i, i)] - basis.omega2[i]).abs() < 1e-10 * scale);
            }
        }
    }
}

#[test]
fn leading_hankel_singular_values_match_dense_full_order_system() {
    let (lat, b, rows) = cantilever(1e4);
    let basis = complete_basis(&lat, &b);
    assert_eq!(basis.len(), lat.n, "k = n: static correction adds nothing");
    let w = WilsonTheta {
        dt: 1e-3,
        theta: 1.4,
    };
    let (alpha, beta) = (0.5, 1e-4);
    let sys = ModalSystem::new(&basis, b.as_ref(), rows.as_ref(), alpha, beta, w).unwrap();
    let red = sys.balanced_truncation(Order::Fixed(12)).unwrap();

    let (kd, md) = (symmetric_dense(&lat.k), symmetric_dense(&lat.m));
    let (phi, gamma) = dense_wilson(&kd, &md, alpha, beta, w, b.as_ref());
    let reference = dense_hsv(&phi, &gamma, &full_output(&rows));
    let worst = (0..10)
        .map(|i| (red.hankel_singular_values[i] - reference[i]).abs() / reference[i])
        .fold(0.0, f64::max);
    eprintln!(
        "leading 10 HSVs vs dense 3n = {} states: max rel err {worst:.2e}",
        3 * lat.n
    );
    for i in 0..10 {
        let (got, want) = (red.hankel_singular_values[i], reference[i]);
        assert!(
            (got - want).abs() <= 1e-8 * want,
            "σ{i}: reduced {got:e}, dense {want:e}, rel {:e}",
            (got - want).abs() / want
        );
    }
    // Balanced: the Gramians of (F, G, H) are diag(σ₁..σ_r), exactly at full order, up to
    // O(σ_{r+1}) after truncation (discrete time adds F₁₂ Σ₂ F₁₂ᵀ).
    let full = sys.balanced_truncation(Order::Fixed(3 * lat.n)).unwrap();
    for (sys_r, tol) in [
        (&red, red.hankel_singular_values[red.order]),
        (&full, 1e-9 * full.hankel_singular_values[0]),
    ] {
        let r = sys_r.order;
        let f = &sys_r.transition;
        let p = smith(f, &(&sys_r.input * sys_r.input.transpose()));
        let q = smith(
            &f.transpose().to_owned(),
            &(sys_r.output.transpose() * &sys_r.output),
        );
        for i in 0..r {
            for j in 0..r {
                let want = if i == j {
                    sys_r.hankel_singular_values[i]
                } else {
                    0.0
                };
                assert!(
                    (p[(i, j)] - want).abs() < tol && (q[(i, j)] - want).abs() < tol,
                    "order {r}: Gramians of F not balanced at ({i},{j}): {} {} vs {want}",
                    p[(i, j)],
                    q[(i, j)]
                );
            }
        }
    }
    assert!(full.order > 12 && full.error_bound < 1e-9 * full.hankel_singular_values[0]);
    assert!(
        full.spectral_radius < 1.0,
        "full-rank balanced model: ρ(F) = {}",
        full.spectral_radius
    );
    assert!(red.spectral_radius < 1.0);
    // Petrov–Galerkin maps: Sᵀ T = I and F = Sᵀ Φ T with the modal blocks.
    let (sm, tm) = (&red.modal_to_reduced, &red.reduced_to_modal);
    let st = sm * tm;
    assert!(
        (&st - Mat::<f64>::identity(red.order, red.order)).norm_l2() < 1e-9,
        "SᵀT ≠ I"
    );
    let k = sys.n_modes();
    let phi_modal = Mat::from_fn(3 * k, 3 * k, |i, j| {
        if i / 3 == j / 3 {
            sys.phi[i / 3][i % 3][j % 3]
        } else {
            0.0
        }
    });
    let f2 = sm * &phi_modal * tm;
    assert!((&f2 - &red.transition).norm_l2() < 1e-9 * red.transition.norm_l2());
    // project_outputs reproduces H.
    let h2 = red.project_outputs(rows.as_ref()).unwrap();
    assert!((&h2 - &red.output).norm_l2() <= 1e-12 * red.output.norm_l2());
}

#[test]
fn krylov_modes_match_dense_eigenvalues_with_repeated_pairs() {
    // Square section: the lattice is invariant under a 90° rotation about x, so bending
    // eigenvalues come in exact pairs (to rounding).
    let lat = Lattice::new([10, 3, 3], true, 1e4, false);
    assert_eq!(lat.n, 243);
    let (kd, md) = (symmetric_dense(&lat.k), symmetric_dense(&lat.m));
    let exact = dense_eigenvalues(&kd, &md);
    let pairs = (0..20)
        .filter(|&i| (exact[i + 1] - exact[i]).abs() < 1e-12 * exact[i])
        .count();
    assert!(
        pairs >= 4,
        "expected repeated eigenvalues, found {pairs} pairs"
    );
    let b = Mat::<f64>::zeros(lat.n, 0);
    for dense_threshold in [0, 10_000] {
        let opts = ModalOptions {
            modes: Some(20),
            dense_threshold,
            ..Default::default()
        };
        let basis = modal_basis(lat.k.as_ref(), lat.m.as_ref(), b.as_ref(), &opts).unwrap();
        assert_eq!(basis.dense, dense_threshold > 0);
        assert_eq!(basis.len(), 20);
        assert!(basis.complete);
        for i in 0..20 {
            let rel = (basis.omega2[i] - exact[i]).abs() / exact[i];
            assert!(
                rel < 1e-10,
                "mode {i}: {} vs dense {} (rel {rel:e}), dense path {}",
                basis.omega2[i],
                exact[i],
                basis.dense
            );
        }
        let worst = (0..20)
            .map(|i| (basis.omega2[i] - exact[i]).abs() / exact[i])
            .fold(0.0, f64::max);
        eprintln!(
            "n = {}, 20 modes ({pairs} exact pairs), dense {}: max rel err {worst:.2e}, {} restarts, {} solves",
            lat.n, basis.dense, basis.restarts, basis.solves
        );
        check_orthonormal(&basis, &lat);
    }
}

#[test]
fn exhausted_restart_budget_returns_converged_modes_and_says_so() {
    let lat = Lattice::new([10, 3, 3], true, 1e4, false);
    let exact = dense_eigenvalues(&symmetric_dense(&lat.k), &symmetric_dense(&lat.m));
    let opts = ModalOptions {
        modes: Some(60),
        max_restarts: 0,
        block_size: 2,
        dense_threshold: 0,
        ..Default::default()
    };
    let b = Mat::<f64>::zeros(lat.n, 0);
    let basis = modal_basis(lat.k.as_ref(), lat.m.as_ref(), b.as_ref(), &opts).unwrap();
    assert!(
        !basis.complete && basis.len() < 60,
        "{} modes, complete {}",
        basis.len(),
        basis.complete
    );
    assert!(
        basis
            .warnings
            .iter()
            .any(|w| w.contains("stopped after 0 restarts")),
        "{:?}",
        basis.warnings
    );
    eprintln!("budget 0: {} of 60 modes converged", basis.len());
    for &w2 in &basis.omega2 {
        let nearest = exact
            .iter()
            .map(|e| (e - w2).abs() / e)
            .fold(f64::INFINITY, f64::min);
        assert!(
            nearest < 1e-10,
            "ω² = {w2} is not an eigenvalue (nearest rel {nearest:e})"
        );
    }
    check_orthonormal(&basis, &lat);
}

#[test]
fn krylov_finds_bitwise_identical_eigenvalues_of_two_copies() {
    // K = diag(K₁, K₁), M = diag(M₁, M₁): every eigenvalue exactly twice.
    let one = Lattice::new([6, 2, 2], true, 1e4, true);
    let n1 = one.n;
    let dup = |a: &SparseColMat<usize, f64>| {
        let t: Vec<_> = a
            .triplet_iter()
            .flat_map(|t| {
                [
                    Triplet::new(t.row, t.col, *t.val),
                    Triplet::new(t.row + n1, t.col + n1, *t.val),
                ]
            })
            .collect();
        SparseColMat::<usize, f64>::try_new_from_triplets(2 * n1, 2 * n1, &t).unwrap()
    };
    let (k, m) = (dup(&one.k), dup(&one.m));
    let exact = dense_eigenvalues(&symmetric_dense(&one.k), &symmetric_dense(&one.m));
    let opts = ModalOptions {
        modes: Some(16),
        dense_threshold: 0,
        ..Default::default()
    };
    let basis = modal_basis(
        k.as_ref(),
        m.as_ref(),
        Mat::<f64>::zeros(2 * n1, 0).as_ref(),
        &opts,
    )
    .unwrap();
    assert!(!basis.dense && basis.complete);
    for i in 0..16 {
        let want = exact[i / 2];
        assert!(
            (basis.omega2[i] - want).abs() < 1e-10 * want,
            "mode {i}: {} vs {want}",
            basis.omega2[i]
        );
    }
}

#[test]
fn frequency_cutoff_keeps_every_mode_below_it() {
    let lat = Lattice::new([12, 2, 3], true, 1e4, false);
    let exact = dense_eigenvalues(&symmetric_dense(&lat.k), &symmetric_dense(&lat.m));
    let f_cut = exact[37].sqrt() / (2.0 * std::f64::consts::PI) * 1.0001;
    let below = exact
        .iter()
        .filter(|&&l| l.sqrt() / (2.0 * std::f64::consts::PI) <= f_cut)
        .count();
    let opts = ModalOptions {
        max_frequency_hz: Some(f_cut),
        max_modes: 80,
        dense_threshold: 0,
        ..Default::default()
    };
    let b = Mat::from_fn(lat.n, 1, |i, _| if i == lat.n - 2 { 1.0 } else { 0.0 });
    let basis = modal_basis(lat.k.as_ref(), lat.m.as_ref(), b.as_ref(), &opts).unwrap();
    assert!(!basis.dense);
    assert_eq!(basis.n_eigenmodes, below);
    assert_eq!(basis.len(), below + 1, "one static-correction vector");
    assert!(basis.static_correction[below] && !basis.static_correction[below - 1]);
    for i in 0..below {
        assert!((basis.omega2[i] - exact[i]).abs() < 1e-10 * exact[i]);
    }
    check_orthonormal(&basis, &lat);
    // A cap below the count says so, on both paths.
    for dense_threshold in [0, 10_000] {
        let capped = ModalOptions {
            max_modes: 20,
            dense_threshold,
            ..opts.clone()
        };
        let basis = modal_basis(lat.k.as_ref(), lat.m.as_ref(), b.as_ref(), &capped).unwrap();
        assert_eq!(basis.n_eigenmodes, 20);
        assert!(
            basis
                .warnings
                .iter()
                .any(|w| w.contains("capped at max_modes = 20")),
            "{:?}",
            basis.warnings
        );
    }
}

/// Static correction: with few modes and a point load, the modal+static basis reproduces the
/// static deflection K⁻¹ b exactly (the modes alone do not).
#[test]
fn static_correction_spans_the_static_response() {
    let lat = Lattice::new([10, 2, 2], true, 1e4, false);
    let tip = lat.node(9, 1, 1);
    let b = Mat::from_fn(
        lat.n,
        1,
        |i, _| if i == lat.dof(tip, 1) { 1.0 } else { 0.0 },
    );
    let kd = symmetric_dense(&lat.k);
    let md = symmetric_dense(&lat.m);
    let u_static = kd.partial_piv_lu().inverse() * &b;
    let err_with = |static_correction: bool| {
        let opts = ModalOptions {
            modes: Some(4),
            static_correction,
            dense_threshold: 0,
            ..Default::default()
        };
        let basis = modal_basis(lat.k.as_ref(), lat.m.as_ref(), b.as_ref(), &opts).unwrap();
        // The stage's K⁻¹B, reused for the full-order static response (or none without the
        // static correction).
        if static_correction {
            let d = (&basis.static_response - &u_static).norm_l2() / u_static.norm_l2();
            assert!(d < 1e-10, "static response against the dense solve: {d:e}");
        } else {
            assert_eq!(basis.static_response.ncols(), 0);
        }
        let v = &basis.vectors;
        // M-orthogonal projection of u_static onto span V.
        let proj = v * (v.transpose() * &md * &u_static);
        (&proj - &u_static).norm_l2() / u_static.norm_l2()
    };
    let (with, without) = (err_with(true), err_with(false));
    assert!(with < 1e-10, "with static correction: {with:e}");
    assert!(without > 1e-4, "modes alone: {without:e}");
}

#[test]
fn reduced_response_error_within_bound_and_falls_with_order() {
    let (lat, b, rows) = cantilever(1e4);
    let b = b.subcols(0, 2).to_owned();
    let basis = complete_basis(&lat, &b);
    let w = WilsonTheta {
        dt: 2e-3,
        theta: 1.4,
    };
    let (alpha, beta) = (1.0, 2e-4);
    let sys = ModalSystem::new(&basis, b.as_ref(), rows.as_ref(), alpha, beta, w).unwrap();
    let (kd, md) = (symmetric_dense(&lat.k), symmetric_dense(&lat.m));
    let (phi, gamma) = dense_wilson(&kd, &md, alpha, beta, w, b.as_ref());
    let cfull = full_output(&rows);
    let steps = 3000;
    let step_input = Mat::from_fn(2, steps, |c, _| if c == 0 { 1.0 } else { -0.3 });
    let nyquist = 0.5 / w.dt;
    let chirp = Mat::from_fn(2, steps, |c, t| {
        let time = t as f64 * w.dt;
        let duration = steps as f64 * w.dt;
        // Linear sweep 0 → Nyquist/2.
        let phase = std::f64::consts::PI * (0.5 * nyquist) * time * time / duration;
        if c == 0 {
            phase.sin()
        } else {
            0.5 * (1.3 * phase).cos()
        }
    });
    // Modal system with k = n equals the full system (similarity transform).
    let y_modal = sys.simulate(chirp.as_ref());
    let y_full_chirp = simulate_dense(&phi, &gamma, &cfull, &chirp);
    assert!(l2(&(&y_modal - &y_full_chirp)) < 1e-8 * l2(&y_full_chirp));
    let y_full_step = simulate_dense(&phi, &gamma, &cfull, &step_input);
    let mut previous = [f64::INFINITY; 2];
    for r in [2, 4, 8, 16] {
        let red = sys.balanced_truncation(Order::Fixed(r)).unwrap();
        assert_eq!(red.order, r);
        assert!(red.spectral_radius < 1.0, "ρ(F) = {}", red.spectral_radius);
        for (case, (u, y_full)) in [(&step_input, &y_full_step), (&chirp, &y_full_chirp)]
            .into_iter()
            .enumerate()
        {
            let y_red = red.simulate(u.as_ref());
            let err = l2(&(&y_red - y_full));
            let allowed = red.error_bound * l2(u);
            assert!(
                err <= allowed,
                "r = {r}, case {case}: ‖y − y_r‖₂ = {err:e} > bound·‖u‖₂ = {allowed:e}"
            );
            assert!(
                err < previous[case],
                "r = {r}, case {case}: error {err:e} did not fall (previous {:e})",
                previous[case]
            );
            previous[case] = err;
            eprintln!(
                "r = {r:2}, case {case}: ‖y − y_r‖₂/‖u‖₂ = {:.3e}, bound {:.3e}",
                err / l2(u),
                red.error_bound
            );
        }
        // H∞ on a frequency grid: σ_max(G(e^{jω}) − G_r(e^{jω})) ≤ 2 Σ_{i>r} σᵢ.
        for f in (0..60).map(|i| nyquist * (i as f64 / 60.0).powi(2)) {
            let z = 2.0 * std::f64::consts::PI * f * w.dt;
            let g_full = freq_response(&phi, &gamma, &cfull, z);
            let g_red = freq_response(&red.transition, &red.input, &red.output, z);
            let diff = &g_full - &g_red;
            let gain = diff.singular_values().unwrap()[0];
            assert!(
                gain <= red.error_bound * (1.0 + 1e-9),
                "r = {r}, f = {f} Hz: {gain:e} > {:e}",
                red.error_bound
            );
        }
    }
}

/// ‖D A D‖_F with D = diag(1, 1/ν, 1/ν²) per mode (`inverse` = false: D⁻¹ A D⁻¹).
fn scaled(a: &Mat<f64>, nu: f64, forward: bool) -> f64 {
    let d = |i: usize| {
        let e = [1.0, 1.0 / nu, 1.0 / (nu * nu)][i % 3];
        if forward {
            e
        } else {
            1.0 / e
        }
    };
    Mat::from_fn(a.nrows(), a.ncols(), |i, j| d(i) * a[(i, j)] * d(j)).norm_l2()
}

/// G(e^{jz}) = C (e^{jz} I − A)⁻¹ B as the real 2p×2m embedding [[Re, −Im], [Im, Re]].
fn freq_response(a: &Mat<f64>, b: &Mat<f64>, c: &Mat<f64>, z: f64) -> Mat<f64> {
    let n = a.nrows();
    let (cs, sn) = (z.cos(), z.sin());
    let big = Mat::from_fn(2 * n, 2 * n, |i, j| {
        let (bi, bj) = (i / n, j / n);
        let (ii, jj) = (i % n, j % n);
        let diag = if ii == jj { 1.0 } else { 0.0 };
        match (bi, bj) {
            (0, 0) | (1, 1) => cs * diag - a[(ii, jj)],
            (0, 1) => -sn * diag,
            _ => sn * diag,
        }
    });
    let m = b.ncols();
    let rhs = Mat::from_fn(2 * n, 2 * m, |i, j| {
        let (bi, bj) = (i / n, j / m);
        if bi == bj {
            b[(i % n, j % m)]
        } else {
            0.0
        }
    });
    let x = big.partial_piv_lu().solve(&rhs);
    let p = c.nrows();
    let c2 = Mat::from_fn(2 * p, 2 * n, |i, j| {
        if i / p == j / n {
            c[(i % p, j % n)]
        } else {
            0.0
        }
    });
    c2 * x
}

#[test]
fn normalised_hankel_singular_values_invariant_to_physical_scale() {
    // E → sE with Δt → Δt/√s, α → √s α, β → β/√s is the same discrete system in scaled time:
    // σᵢ/σ₁ must not change, whatever the scale. Both eigensolver paths.
    for (modes, dense_threshold) in [(20, 10_000), (6, 0)] {
        let base = |s: f64| {
            let (lat, b, rows) = cantilever(1e4 * s);
            let opts = ModalOptions {
                modes: Some(modes),
                dense_threshold,
                ..Default::default()
            };
            let basis = modal_basis(lat.k.as_ref(), lat.m.as_ref(), b.as_ref(), &opts).unwrap();
            assert_eq!(basis.dense, dense_threshold > 0);
            let w = WilsonTheta {
                dt: 1e-3 / s.sqrt(),
                theta: 1.4,
            };
            let sys = ModalSystem::new(
                &basis,
                b.as_ref(),
                rows.as_ref(),
                0.5 * s.sqrt(),
                1e-4 / s.sqrt(),
                w,
            )
            .unwrap();
            let red = sys.balanced_truncation(Order::Tolerance(1e-6)).unwrap();
            (basis.frequencies_hz.clone(), red)
        };
        let (f1, r1) = base(1.0);
        for s in [1e-3, 1e8] {
            let (fs, rs) = base(s);
            for (a, b) in f1.iter().zip(&fs) {
                assert!(
                    (b / a - s.sqrt()).abs() < 1e-9 * s.sqrt(),
                    "frequency scale {} vs √s = {}",
                    b / a,
                    s.sqrt()
                );
            }
            assert_eq!(r1.order, rs.order, "order at s = {s}");
            let (h1, hs) = (&r1.hankel_singular_values, &rs.hankel_singular_values);
            for i in 0..h1.len().min(hs.len()) {
                let (a, b) = (h1[i] / h1[0], hs[i] / hs[0]);
                assert!((a - b).abs() <= 1e-8, "s = {s}: σ{i}/σ₁ = {b:e} vs {a:e}");
            }
            let worst = (0..h1.len().min(hs.len()))
                .filter(|&i| h1[i] > 1e-8 * h1[0])
                .map(|i| ((hs[i] / hs[0]) / (h1[i] / h1[0]) - 1.0).abs())
                .fold(0.0, f64::max);
            eprintln!(
                "{modes} modes, s = {s:e}: σᵢ/σ₁ ≥ 1e-8 agree to {worst:.2e} relative, order {}",
                rs.order
            );
            // Physical HSVs scale as 1/s (displacement per force).
            assert!((hs[0] * s / h1[0] - 1.0).abs() < 1e-9);
        }
    }
}

#[test]
fn time_steps_from_haptics_to_video_match_dense_reference() {
    let (lat, b, rows) = cantilever(1e4);
    let basis = complete_basis(&lat, &b);
    let (kd, md) = (symmetric_dense(&lat.k), symmetric_dense(&lat.m));
    let cfull = full_output(&rows);
    for dt in [1e-4, 1.0 / 30.0] {
        let w = WilsonTheta { dt, theta: 1.4 };
        let (alpha, beta) = (0.5, 1e-4);
        let sys = ModalSystem::new(&basis, b.as_ref(), rows.as_ref(), alpha, beta, w).unwrap();
        let red = sys.balanced_truncation(Order::Tolerance(1e-8)).unwrap();
        assert!(red.spectral_radius < 1.0);
        let (phi, gamma) = dense_wilson(&kd, &md, alpha, beta, w, b.as_ref());
        let reference = dense_hsv(&phi, &gamma, &cfull);
        for i in 0..6 {
            let (got, want) = (red.hankel_singular_values[i], reference[i]);
            assert!(
                (got - want).abs() <= 1e-7 * want,
                "Δt = {dt}: σ{i} = {got:e} vs dense {want:e}"
            );
        }
    }
}

#[test]
fn undamped_model_relies_on_wilson_damping_or_is_refused_by_name() {
    let (lat, b, rows) = cantilever(1e4);
    let basis = complete_basis(&lat, &b);
    // Video rate: Wilson-θ's numerical damping makes every block strictly stable.
    let w = WilsonTheta {
        dt: 1.0 / 30.0,
        theta: 1.4,
    };
    let sys = ModalSystem::new(&basis, b.as_ref(), rows.as_ref(), 0.0, 0.0, w).unwrap();
    assert!(sys.spectral_radii.iter().all(|&r| r < 1.0 - 1e-12));
    let red = sys.balanced_truncation(Order::Fixed(10)).unwrap();
    assert!(red.spectral_radius < 1.0 && red.hankel_singular_values.iter().all(|s| s.is_finite()));
    // Haptics rate: the lowest mode's ωΔt is tiny, ρ rounds to 1: refused, naming the mode.
    let w = WilsonTheta {
        dt: 1e-4,
        theta: 1.4,
    };
    let sys = ModalSystem::new(&basis, b.as_ref(), rows.as_ref(), 0.0, 0.0, w).unwrap();
    match sys.balanced_truncation(Order::Fixed(10)) {
        Err(ReduceError::MarginallyStable {
            mode,
            frequency_hz,
            spectral_radius,
        }) => {
            assert!(spectral_radius >= 1.0 - 1e-12);
            assert!((frequency_hz - basis.frequencies_hz[mode]).abs() < 1e-12);
            let msg = ReduceError::MarginallyStable {
                mode,
                frequency_hz,
                spectral_radius,
            }
            .to_string();
            assert!(msg.contains("Hz") && msg.contains("damping"), "{msg}");
        }
        Ok(red) => {
            assert!(red.spectral_radius < 1.0);
            assert!(sys.spectral_radii.iter().all(|&r| r < 1.0 - 1e-12));
        }
        Err(e) => panic!("unexpected error {e}"),
    }
}

#[test]
fn singular_stiffness_is_refused_as_rigid_body_modes() {
    // Free-floating lattice: 6 rigid-body modes. One pinned node: 3 rotations about it.
    let free = Lattice::new([4, 2, 2], false, 1e4, false);
    let keep = |d: usize| d >= 3; // node 0 is (0, 0, 0): DOFs 0, 1, 2
    let pinned = |a: &SparseColMat<usize, f64>| {
        let t: Vec<_> = a
            .triplet_iter()
            .filter(|t| keep(t.row) && keep(t.col))
            .map(|t| Triplet::new(t.row - 3, t.col - 3, *t.val))
            .collect();
        SparseColMat::<usize, f64>::try_new_from_triplets(free.n - 3, free.n - 3, &t).unwrap()
    };
    let cases = [
        (free.k.clone(), free.m.clone(), 6),
        (pinned(&free.k), pinned(&free.m), 3),
    ];
    for (k, m, rigid) in &cases {
        let b = Mat::<f64>::zeros(k.nrows(), 0);
        for dense_threshold in [10_000, 0] {
            let opts = ModalOptions {
                modes: Some(10),
                dense_threshold,
                ..Default::default()
            };
            let err = modal_basis(k.as_ref(), m.as_ref(), b.as_ref(), &opts).unwrap_err();
            match &err {
                ReduceError::RigidBody { count, .. } => {
                    assert_eq!(count, rigid, "dense_threshold {dense_threshold}")
                }
                e => panic!("expected rigid-body error, got {e}"),
            }
            let msg = err.to_string();
            assert!(
                msg.contains(&format!("{rigid} rigid-body modes")) && msg.contains("fix a group"),
                "{msg}"
            );
        }
    }
}

#[test]
fn output_blind_to_some_modes_still_gives_stable_model() {
    // Mean axial tip displacement: blind (to rounding) to bending and torsion by symmetry.
    let lat = Lattice::new([6, 2, 2], true, 1e4, false);
    let mean_x: Vec<(usize, f64)> = [(0, 0), (0, 1), (1, 0), (1, 1)]
        .iter()
        .map(|&(j, k)| (lat.dof(lat.node(5, j, k), 0), 0.25))
        .collect();
    let rows = lat.rows(&[mean_x]);
    let corner = lat.node(5, 0, 0);
    let b = Mat::from_fn(lat.n, 1, |i, _| {
        if (0..3).any(|c| i == lat.dof(corner, c)) {
            1.0
        } else {
            0.0
        }
    });
    let basis = modal_basis(
        lat.k.as_ref(),
        lat.m.as_ref(),
        b.as_ref(),
        &ModalOptions {
            modes: Some(24),
            ..Default::default()
        },
    )
    .unwrap();
    let w = WilsonTheta {
        dt: 1e-3,
        theta: 1.4,
    };
    let sys = ModalSystem::new(&basis, b.as_ref(), rows.as_ref(), 0.5, 1e-4, w).unwrap();
    let blind = (0..sys.n_modes())
        .filter(|&i| sys.modal_outputs[(0, i)].abs() < 1e-12 * sys.modal_outputs.norm_l2())
        .count();
    assert!(blind >= 10, "only {blind} blind modes");
    let red = sys.balanced_truncation(Order::Tolerance(1e-10)).unwrap();
    assert!(red.spectral_radius < 1.0, "ρ(F) = {}", red.spectral_radius);
    // The Gramians solve the Stein equations of the modal system.
    let (x, y) = sys.gramians().unwrap();
    let k = sys.n_modes();
    let phi = Mat::from_fn(3 * k, 3 * k, |i, j| {
        if i / 3 == j / 3 {
            sys.phi[i / 3][i % 3][j % 3]
        } else {
            0.0
        }
    });
    let gam = Mat::from_fn(3 * k, 1, |i, c| {
        sys.gamma[i / 3][i % 3] * sys.modal_inputs[(i / 3, c)]
    });
    let cm = Mat::from_fn(1, 3 * k, |r, j| {
        if j % 3 == 0 {
            sys.modal_outputs[(r, j / 3)]
        } else {
            0.0
        }
    });
    // Weighted by the state scales (q, q̇/ν, q̈/ν²) so every block counts.
    let res_x = &phi * &x * phi.transpose() - &x + &gam * gam.transpose();
    let res_y = phi.transpose() * &y * &phi - &y + cm.transpose() * &cm;
    let nu = (sys.omega2[0].sqrt()).min(1.0 / w.dt);
    let (dx, dy) = (scaled(&res_x, nu, true), scaled(&res_y, nu, false));
    let (nx, ny) = (scaled(&x, nu, true), scaled(&y, nu, false));
    assert!(
        dx <= 1e-9 * nx && dy <= 1e-9 * ny,
        "Stein residuals {:e}, {:e}",
        dx / nx,
        dy / ny
    );
    assert!(
        red.order < sys.n_states() - 3 * blind,
        "blind modes kept: r = {}",
        red.order
    );
    let steps = 2000;
    let u = Mat::from_fn(1, steps, |_, t| (t as f64 * 0.05).sin());
    let err = l2(&(&red.simulate(u.as_ref()) - &sys.simulate(u.as_ref())));
    assert!(err <= red.error_bound * l2(&u) + 1e-12 * l2(&sys.simulate(u.as_ref())));
}

#[test]
fn bad_inputs_are_refused_with_clear_errors() {
    let (lat, b, rows) = cantilever(1e4);
    let e = modal_basis(
        lat.k.as_ref(),
        lat.m.as_ref(),
        b.as_ref(),
        &ModalOptions::default(),
    )
    .unwrap_err();
    assert!(matches!(e, ReduceError::InvalidOption(_)), "{e}");
    let short = Mat::<f64>::zeros(lat.n - 1, 1);
    let e = modal_basis(
        lat.k.as_ref(),
        lat.m.as_ref(),
        short.as_ref(),
        &all_modes(4),
    )
    .unwrap_err();
    assert!(e.to_string().contains("input matrix B"), "{e}");
    let basis = modal_basis(lat.k.as_ref(), lat.m.as_ref(), b.as_ref(), &all_modes(4)).unwrap();
    let w = WilsonTheta {
        dt: 1e-3,
        theta: 1.4,
    };
    let e = ModalSystem::new(&basis, b.as_ref(), rows.as_ref(), -1.0, 0.0, w).unwrap_err();
    assert!(matches!(e, ReduceError::InvalidOption(_)), "{e}");
    let zero_rows = lat.rows(&[vec![]]);
    let sys = ModalSystem::new(&basis, b.as_ref(), zero_rows.as_ref(), 0.5, 1e-4, w).unwrap();
    assert!(matches!(
        sys.balanced_truncation(Order::Fixed(2)),
        Err(ReduceError::NothingObservable)
    ));
}

/// Timings at scale (not a pass/fail speed test): `cargo test --release -p crokf-compile --test
/// reduce -- --ignored --nocapture large`.
#[test]
#[ignore]
fn large_lattice_stage_timings() {
    for (dims, modes) in [([40, 8, 8], 60), ([40, 8, 8], 200), ([100, 12, 12], 60)] {
        let t = std::time::Instant::now();
        let lat = Lattice::new(dims, true, 1e4, false);
        let assembly = t.elapsed().as_secs_f64();
        let m_in = 12;
        let b = Mat::from_fn(
            lat.n,
            m_in,
            |i, c| if i % 97 == c * 7 % 97 { 1.0 } else { 0.0 },
        );
        let rows: Vec<Vec<(usize, f64)>> =
            (0..300).map(|r| vec![((r * 131) % lat.n, 1.0)]).collect();
        let rows = lat.rows(&rows);
        let opts = ModalOptions {
            modes: Some(modes),
            ..Default::default()
        };
        let basis = modal_basis(lat.k.as_ref(), lat.m.as_ref(), b.as_ref(), &opts).unwrap();
        let w = WilsonTheta {
            dt: 1e-3,
            theta: 1.4,
        };
        let t = std::time::Instant::now();
        let sys = ModalSystem::new(&basis, b.as_ref(), rows.as_ref(), 0.5, 1e-4, w).unwrap();
        let modal = t.elapsed().as_secs_f64();
        let red = sys.balanced_truncation(Order::Tolerance(1e-4)).unwrap();
        eprintln!(
            "n = {}: assembly {assembly:.2}s, {:?}, {} restarts, {} solves, k = {}; modal system {modal:.2}s; {:?}; r = {}, ρ(F) = {:.6}",
            lat.n, basis.timings, basis.restarts, basis.solves, basis.len(), red.timings, red.order, red.spectral_radius
        );
        check_orthonormal_sparse(&basis, &lat);
    }
}

/// ‖VᵀMV − I‖_max and the off-diagonal of VᵀKV through sparse products (large n).
fn check_orthonormal_sparse(basis: &ModalBasis, lat: &Lattice) {
    use faer::sparse::linalg::matmul::sparse_dense_matmul;
    let v = &basis.vectors;
    let mut mv = Mat::zeros(lat.n, v.ncols());
    sparse_dense_matmul(
        mv.as_mut(),
        faer::Accum::Replace,
        lat.m.as_ref(),
        v.as_ref(),
        1.0,
        faer::Par::Seq,
    );
    let mut kv = Mat::zeros(lat.n, v.ncols());
    sparse_dense_matmul(
        kv.as_mut(),
        faer::Accum::Replace,
        lat.k.as_ref(),
        v.as_ref(),
        1.0,
        faer::Par::Seq,
    );
    let (mtm, ktk) = (v.transpose() * &mv, v.transpose() * &kv);
    let mut worst: (f64, f64) = (0.0, 0.0);
    for i in 0..v.ncols() {
        for j in 0..v.ncols() {
            let want = if i == j { 1.0 } else { 0.0 };
            worst.0 = worst.0.max((mtm[(i, j)] - want).abs());
            if i != j {
                worst.1 = worst
                    .1
                    .max(ktk[(i, j)].abs() / (basis.omega2[i] * basis.omega2[j]).sqrt());
            }
        }
    }
    eprintln!(
        "max |VᵀMV − I| = {:.2e}, max |VᵀKV|ᵢⱼ/ωᵢωⱼ = {:.2e}",
        worst.0, worst.1
    );
    assert!(worst.0 < 1e-10 && worst.1 < 1e-10);
}
