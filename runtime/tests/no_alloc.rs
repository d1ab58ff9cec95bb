//! No heap allocation in predict, update, step or any read-out (counting global allocator).

mod common;
use common::*;
use crokf_runtime::Estimator;

#[path = "support/counting_alloc.rs"]
mod counting_alloc;
use counting_alloc::count;

#[test]
fn the_counter_counts() {
    assert!(count(|| drop(std::hint::black_box(vec![1u8; 10]))) >= 1);
}

#[test]
fn no_allocation_per_step() {
    let model = synthetic_model(&Spec {
        rotation: 0.2,
        every2: 2,
        ..Default::default()
    });
    let mut est = Estimator::new(&model).unwrap();
    let mut rng = Rng(31);
    let inputs: Vec<Vec<f64>> = (0..50).map(|_| rng.vec(4, 1.0)).collect();
    let ys: Vec<Vec<Option<f64>>> = (0..50)
        .map(|k| {
            (0..5)
                .map(|j| {
                    if (k + j) % 4 == 0 {
                        None
                    } else {
                        Some(0.01 * rng.uniform())
                    }
                })
                .collect()
        })
        .collect();
    let mut s = vec![0.0; 6];
    let mut q = vec![0.0; 5];
    let mut n0 = vec![0.0; 12];
    let mut n1 = vec![0.0; 3];
    let mut total = 0;
    for (k, (u, y)) in inputs.iter().zip(&ys).enumerate() {
        total += count(|| {
            if k % 3 == 0 {
                est.step(u, y).unwrap();
            } else {
                est.predict(u).unwrap();
                est.sensor_displacements(&mut s).unwrap();
                est.sensor_std(&mut s).unwrap();
                if k % 5 != 0 {
                    est.update(y).unwrap();
                }
            }
            est.sensor_displacements(&mut s).unwrap();
            est.sensor_std(&mut s).unwrap();
            est.measurement_estimates(&mut q).unwrap();
            est.node_displacements(0, &mut n0).unwrap();
            est.node_positions(0, &mut n0).unwrap();
            est.node_std(0, &mut n0).unwrap();
            est.node_positions(1, &mut n1).unwrap();
            est.node_std(1, &mut n1).unwrap();
            std::hint::black_box(est.state());
        });
    }
    assert_eq!(total, 0, "allocations during 50 steps with read-outs");
    // The compact display rows (16-bit rotation rows) read out without allocating either.
    let compact = crokf_runtime::PreparedModel::with_display_format(
        model.clone(),
        crokf_runtime::DisplayRowFormat::Compact,
    )
    .unwrap();
    let mut other = Estimator::from_prepared(std::sync::Arc::new(compact));
    other.set_state(est.state()).unwrap();
    assert_eq!(count(|| other.node_displacements(0, &mut n0).unwrap()), 0);
    assert!(est.state().iter().any(|&v| v != 0.0));
    assert_eq!(count(|| est.reset()), 0);
}
