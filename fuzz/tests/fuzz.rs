//! A few thousand mutated scenes, meshes and CSV files per reader (the long run is the
//! `crokf-fuzz` binary): no panic, no accepted input that breaks its invariants, and enough
//! of both outcomes that the mutations reach past the first check.

use crokf_fuzz::{run, Fixtures, Target};

fn check(target: Target, cases: u64, min_accepted: u64, min_refused: u64) {
    let fixtures = Fixtures::load().expect("fixtures");
    let t = run(target, cases, 7, &fixtures);
    println!(
        "{}: {} cases in {:.2} s: {} accepted, {} refused, {} failures",
        target.name(),
        t.cases,
        t.seconds,
        t.accepted,
        t.refused,
        t.failures.len()
    );
    for (case, what, data) in t.failures.iter().take(5) {
        println!("case {case}: {what}\n{}", String::from_utf8_lossy(data));
    }
    assert!(t.failures.is_empty(), "{} failures", t.failures.len());
    assert!(t.accepted >= min_accepted, "only {} accepted", t.accepted);
    assert!(t.refused >= min_refused, "only {} refused", t.refused);
}

#[test]
fn mutated_scenes() {
    check(Target::Scene, 5000, 150, 200);
}

#[test]
fn mutated_meshes() {
    check(Target::Mesh, 3000, 200, 200);
}

#[test]
fn mutated_csv() {
    check(Target::Csv, 3000, 200, 200);
}

#[test]
fn vtk_files_with_mutated_claims() {
    check(Target::Vtu, 3000, 300, 1000);
}

#[test]
fn mutated_node_lists() {
    check(Target::NodeList, 2000, 200, 200);
}

/// Every VTK layout of the generator reads as the box it encodes when nothing is mutated
/// (checked through a seed of cases: some have no mutation).
#[test]
fn unmutated_vtk_cases_are_accepted() {
    let mut rng = crokf_fuzz::Rng(3);
    let mut accepted = 0;
    for _ in 0..400 {
        let data = crokf_fuzz::grid::case(&mut rng);
        if crokf_fuzz::vtu(&data).expect("invariants") == crokf_fuzz::Outcome::Accepted {
            accepted += 1;
        }
    }
    assert!(accepted >= 100, "{accepted} of 400 accepted");
}

/// The seeds themselves are valid, so that mutations start from inputs that get past every check.
#[test]
fn seeds_are_accepted() {
    let fixtures = Fixtures::load().expect("fixtures");
    for (i, seed) in crokf_fuzz::scene_seeds().iter().enumerate() {
        let text = String::from_utf8_lossy(seed);
        let outcome = crokf_fuzz::scene(seed, &fixtures.mesh).expect("invariants");
        assert_eq!(
            outcome,
            crokf_fuzz::Outcome::Accepted,
            "scene seed {i}:\n{text}"
        );
    }
    for (name, bytes) in crokf_fuzz::mesh_seeds() {
        let outcome = crokf_fuzz::mesh(&bytes, &name).expect("invariants");
        assert_eq!(outcome, crokf_fuzz::Outcome::Accepted, "mesh seed {name}");
    }
    for (i, list) in crokf_fuzz::node_list_seeds().iter().enumerate() {
        let outcome = crokf_fuzz::node_list(list, &fixtures.mesh).expect("invariants");
        assert_eq!(outcome, crokf_fuzz::Outcome::Accepted, "node-list seed {i}");
    }
    let (inputs, measurements) = crokf_fuzz::csv_seeds(&fixtures.model);
    let outcome = crokf_fuzz::csv(&inputs, &measurements, &fixtures.model).expect("invariants");
    assert_eq!(outcome, crokf_fuzz::Outcome::Accepted);
}
