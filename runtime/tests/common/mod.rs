//! Small synthetic models and dense reference linear algebra for the runtime tests.
#![allow(dead_code)]

#[path = "../support/cdylib.rs"]
mod cdylib;
#[allow(unused_imports)]
pub use cdylib::{compile_c, find_cdylib};

use crokf_formats::*;
use std::collections::BTreeMap;

/// The shared test generator (SplitMix64).
pub use crokf_formats::synthetic::SplitMix64 as Rng;

// ---- dense row-major helpers (n×n unless stated) ----

pub fn mat(m: &Matrix) -> Vec<Vec<f64>> {
    (0..m.rows as usize).map(|i| m.row(i).to_vec()).collect()
}

pub fn to_matrix(a: &[Vec<f64>]) -> Matrix {
    let rows = a.len();
    let cols = if rows == 0 { 0 } else { a[0].len() };
    Matrix::from_fn(rows as u32, cols as u32, |i, j| a[i][j])
}

pub fn mul(a: &[Vec<f64>], b: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let (n, k) = (a.len(), b.len());
    let m = if k == 0 { 0 } else { b[0].len() };
    (0..n)
        .map(|i| {
            (0..m)
                .map(|j| (0..k).map(|l| a[i][l] * b[l][j]).sum())
                .collect()
        })
        .collect()
}

pub fn transpose(a: &[Vec<f64>]) -> Vec<Vec<f64>> {
    if a.is_empty() {
        return vec![];
    }
    (0..a[0].len())
        .map(|j| a.iter().map(|row| row[j]).collect())
        .collect()
}

pub fn add(a: &[Vec<f64>], b: &[Vec<f64>]) -> Vec<Vec<f64>> {
    a.iter()
        .zip(b)
        .map(|(x, y)| x.iter().zip(y).map(|(p, q)| p + q).collect())
        .collect()
}

pub fn matvec(a: &[Vec<f64>], x: &[f64]) -> Vec<f64> {
    a.iter()
        .map(|row| row.iter().zip(x).map(|(p, q)| p * q).sum())
        .collect()
}

pub fn identity(n: usize) -> Vec<Vec<f64>> {
    (0..n)
        .map(|i| (0..n).map(|j| (i == j) as u8 as f64).collect())
        .collect()
}

/// Gauss–Jordan inverse with partial pivoting.
pub fn inverse(a: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let n = a.len();
    let mut m: Vec<Vec<f64>> = a
        .iter()
        .enumerate()
        .map(|(i, row)| {
            let mut r = row.clone();
            r.extend((0..n).map(|j| (i == j) as u8 as f64));
            r
        })
        .collect();
    for c in 0..n {
        let p = (c..n)
            .max_by(|&x, &y| m[x][c].abs().partial_cmp(&m[y][c].abs()).unwrap())
            .unwrap();
        m.swap(c, p);
        let d = m[c][c];
        assert!(d.abs() > 1e-300, "singular");
        for v in m[c].iter_mut() {
            *v /= d;
        }
        for i in 0..n {
            if i != c {
                let f = m[i][c];
                let rc = m[c].clone();
                for (v, w) in m[i].iter_mut().zip(rc) {
                    *v -= f * w;
                }
            }
        }
    }
    m.into_iter().map(|r| r[n..].to_vec()).collect()
}

/// Lower Cholesky factor L (A = L Lᵀ) of a symmetric positive definite matrix.
pub fn cholesky(a: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let n = a.len();
    let mut l = vec![vec![0.0; n]; n];
    for j in 0..n {
        let d = a[j][j] - (0..j).map(|k| l[j][k] * l[j][k]).sum::<f64>();
        assert!(d > 0.0, "not positive definite");
        l[j][j] = d.sqrt();
        for i in j + 1..n {
            l[i][j] = (a[i][j] - (0..j).map(|k| l[i][k] * l[j][k]).sum::<f64>()) / l[j][j];
        }
    }
    l
}

/// Options for [`synthetic_model`].
pub struct Spec {
    pub seed: u64,
    pub r: usize,
    /// Scale of the rotation rows (0: no co-rotation).
    pub rotation: f64,
    /// `every` of the second sensor (1 → single rate).
    pub every2: u32,
}

impl Default for Spec {
    fn default() -> Self {
        Spec {
            seed: 1,
            r: 6,
            rotation: 0.0,
            every2: 1,
        }
    }
}

/// A random stable model: F with ‖F‖_F = 0.95 (so ρ(F) < 1), inputs = one load group (x, y, z)
/// and gravity, sensor "tip" (x, y, z, every 1), sensor "mid" (x, z, every `every2`), node set
/// "surface" (4 nodes, 2 triangles) and "probe" (1 node, no triangles). Gains from iterating
/// the periodic Riccati recursion to convergence (no DARE solver needed).
pub fn synthetic_model(spec: &Spec) -> Model {
    let mut g = Rng(spec.seed);
    let r = spec.r;
    let mut f = g.matrix(r, r, 1.0);
    let norm = f.data.iter().map(|v| v * v).sum::<f64>().sqrt();
    f.data.iter_mut().for_each(|v| *v *= 0.95 / norm);
    let input = g.matrix(r, 4, 1.0);
    let rot = spec.rotation;
    let sensors = vec![
        SensorInfo {
            name: "tip".into(),
            position: [1.0, 0.0, 0.0],
            displacement_rows: g.matrix(3, r, 1.0),
            rotation_rows: g.matrix(3, r, rot),
            components: vec![0, 1, 2],
            every: 1,
        },
        SensorInfo {
            name: "mid".into(),
            position: [0.5, 0.0, 0.0],
            displacement_rows: g.matrix(3, r, 1.0),
            rotation_rows: g.matrix(3, r, rot),
            components: vec![0, 2],
            every: spec.every2,
        },
    ];
    let measurements: Vec<MeasurementChannel> = [(0, 0), (0, 1), (0, 2), (1, 0), (1, 2)]
        .iter()
        .map(|&(s, c)| MeasurementChannel {
            sensor: s,
            component: c,
        })
        .collect();
    // σ = 0.1 m on "tip", 0.2 m on "mid".
    let variance: Vec<f64> = measurements
        .iter()
        .map(|m| [0.1f64, 0.2][m.sensor as usize].powi(2))
        .collect();
    let period = spec.every2.max(1) as usize;
    let measured_of = |p: usize| -> Vec<u32> {
        (0..measurements.len() as u32)
            .filter(|&j| {
                p.checked_rem(sensors[measurements[j as usize].sensor as usize].every as usize)
                    == Some(0)
            })
            .collect()
    };
    // Periodic Riccati recursion: P⁻_k = F P_{k-1} Fᵀ + Q, phase p = k mod period.
    let fm = mat(&f);
    let q = {
        let b = mat(&g.matrix(r, r, 0.3));
        add(
            &mul(&b, &transpose(&b)),
            &identity(r)
                .iter()
                .map(|row| row.iter().map(|v| 1e-3 * v).collect())
                .collect::<Vec<_>>(),
        )
    };
    let h = {
        let mut rows = vec![];
        for m in &measurements {
            rows.push(
                sensors[m.sensor as usize]
                    .displacement_rows
                    .row(m.component as usize)
                    .to_vec(),
            );
        }
        rows
    };
    let mut p = q.clone();
    let mut phases: Vec<Option<KalmanPhase>> = vec![None; period];
    let cycles = 400;
    for k in 1..=cycles * period {
        let prior = add(&mul(&mul(&fm, &p), &transpose(&fm)), &q);
        let ph = k % period;
        let measured = measured_of(ph);
        let hp: Vec<Vec<f64>> = measured.iter().map(|&j| h[j as usize].clone()).collect();
        let (gain, post) = if measured.is_empty() {
            (vec![vec![0.0; 0]; r], prior.clone())
        } else {
            let mut s = mul(&mul(&hp, &prior), &transpose(&hp));
            for (a, &j) in measured.iter().enumerate() {
                s[a][a] += variance[j as usize];
            }
            let kgain = mul(&mul(&prior, &transpose(&hp)), &inverse(&s));
            let ikh = add(
                &identity(r),
                &mul(&kgain, &hp)
                    .iter()
                    .map(|row| row.iter().map(|v| -v).collect())
                    .collect::<Vec<_>>(),
            );
            // Joseph form keeps P symmetric positive definite.
            let mut post = mul(&mul(&ikh, &prior), &transpose(&ikh));
            let krk = {
                let kr: Vec<Vec<f64>> = kgain
                    .iter()
                    .map(|row| {
                        row.iter()
                            .zip(&measured)
                            .map(|(v, &j)| v * variance[j as usize])
                            .collect()
                    })
                    .collect();
                mul(&kr, &transpose(&kgain))
            };
            post = add(&post, &krk);
            (kgain, post)
        };
        if k > (cycles - 1) * period {
            phases[ph] = Some(KalmanPhase {
                measured: measured.clone(),
                gain: Matrix::from_fn(r as u32, measured.len() as u32, |i, j| gain[i][j]),
                prior_covariance: to_matrix(&prior),
                posterior_covariance: to_matrix(&post),
            });
        }
        p = post;
    }
    let surface_n = 4;
    Model {
        dt: 0.01,
        theta: 1.4,
        state_dim: r as u32,
        transition: f,
        input,
        inputs: [
            crokf_formats::synthetic::load_inputs("push", 0),
            vec![crokf_formats::synthetic::gravity_input()],
        ]
        .concat(),
        loads: vec![LoadGroup {
            name: "push".into(),
            rotation_rows: g.matrix(3, r, rot),
        }],
        sensors,
        measurements,
        kalman: KalmanGains {
            period: period as u32,
            phases: phases
                .into_iter()
                .map(|p| p.expect("every phase recorded"))
                .collect(),
            process_noise: to_matrix(&q),
            measurement_variance: variance,
        },
        node_sets: vec![
            NodeSet {
                name: "surface".into(),
                node_tags: vec![1, 2, 3, 4],
                rest_positions: g.matrix(surface_n, 3, 1.0),
                triangles: vec![[0, 1, 2], [0, 2, 3]],
                displacement_rows: g.matrix(3 * surface_n, r, 1.0),
                rotation_rows: g.matrix(3 * surface_n, r, rot),
            },
            NodeSet {
                name: "probe".into(),
                node_tags: vec![9],
                rest_positions: g.matrix(1, 3, 1.0),
                triangles: vec![],
                displacement_rows: g.matrix(3, r, 1.0),
                rotation_rows: g.matrix(3, r, rot),
            },
        ],
        report: CompileReport {
            order: r as u32,
            measured_errors: BTreeMap::new(),
            ..Default::default()
        },
        inputs_digest: InputsDigest::default(),
        tier: None,
        contact: None,
    }
}

/// A fresh scratch directory under the system temp dir.
pub fn scratch_dir(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("crokf-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}
