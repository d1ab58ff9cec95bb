//! A few thousand structure-aware mutated model files (re-hashed): never a panic, every
//! accepted model valid and finite, NaN/inf in matrices refused (`support/mutate.rs`; the
//! long run is `cargo run --release -p crokf-formats --example mutate`).

#[path = "support/model.rs"]
mod model;
#[path = "support/mutate.rs"]
mod mutate;

#[test]
fn mutated_rehashed_payloads_never_panic_and_never_pass_invalid() {
    let t = mutate::run(4000, 0xC0FFEE);
    println!("{t:?}");
    assert_eq!(t.cases, 4000);
    // The mutations reach every layer: structure, validation, finiteness; and some survive.
    assert!(
        t.message_pack > 100 && t.invalid > 10 && t.non_finite > 10,
        "{t:?}"
    );
    assert!(t.accepted > 0, "{t:?}");
}

#[test]
fn nan_or_inf_in_any_matrix_is_refused_at_load() {
    let model = mutate::seed_model();
    let bad = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY];
    let mut cases = 0;
    for (i, v) in bad.iter().enumerate() {
        let mut m = model.clone();
        match i {
            0 => m.transition.data[4] = *v,
            1 => m.kalman.phases[1].gain.data[2] = *v,
            _ => m.node_sets[0].rotation_rows.data[5] = *v,
        }
        let err = crokf_formats::decode(&crokf_formats::encode(&m)).unwrap_err();
        assert!(
            matches!(err, crokf_formats::FormatError::NonFinite { .. }),
            "{err}"
        );
        cases += 1;
    }
    assert_eq!(cases, 3);
}
