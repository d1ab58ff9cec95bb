//! A few thousand mutated `inputs.csv` / `measurements.csv` texts through the CSV reader:
//! never a panic; every accepted table has one finite value per channel and increasing steps.

#[path = "../../runtime/tests/common/mod.rs"]
mod common;
use common::*;
use crokf_run::table;
use std::path::Path;

const ALPHABET: &[u8] = b",;\"\n\r#e.-+0123456789 tx\xef\xbb\xbf";

fn mutate(text: &mut Vec<u8>, rng: &mut Rng) {
    let n = text.len().max(1);
    let at = (rng.next_u64() % n as u64) as usize;
    let byte = ALPHABET[(rng.next_u64() % ALPHABET.len() as u64) as usize];
    match rng.next_u64() % 4 {
        0 if at < text.len() => text[at] = byte,
        1 => text.insert(at.min(text.len()), byte),
        2 if at < text.len() => {
            text.remove(at);
        }
        _ => {
            let end = (at + 1 + (rng.next_u64() % 12) as usize).min(text.len());
            let chunk = text[at.min(end)..end].to_vec();
            text.splice(at.min(text.len())..at.min(text.len()), chunk);
        }
    }
}

#[test]
fn mutated_csv_never_panics_and_accepted_tables_are_sound() {
    let model = synthetic_model(&Spec::default());
    let inputs =
        b"step,push.x,push.y,push.z,gravity\n1,0.1,0.2,0.3,1\n2,0,0,0,1\n3,-1e-3,2,0,1\n".to_vec();
    let measurements = b"t,tip.x,mid.z\n0.01,0.001,\n0.03,,0.002\n".to_vec();
    let mut rng = Rng(77);
    let (mut ok, mut err) = (0, 0);
    for case in 0..3000 {
        let mut a = inputs.clone();
        let mut b = measurements.clone();
        for _ in 0..1 + case % 4 {
            mutate(&mut a, &mut rng);
            mutate(&mut b, &mut rng);
        }
        match table::parse_inputs(Path::new("inputs.csv"), &a, &model) {
            Ok(t) => {
                ok += 1;
                assert!(!t.rows.is_empty() && t.rows.len() == t.lines.len());
                assert!(t.rows.iter().flatten().all(|v| v.is_finite()));
                assert!(t.rows.iter().all(|r| r.len() == 4));
            }
            Err(e) => {
                err += 1;
                assert!(e.to_string().starts_with("inputs.csv:"), "{e}");
            }
        }
        match table::parse_measurements(Path::new("m.csv"), &b, &model) {
            Ok(t) => {
                ok += 1;
                assert!(t.values().all(
                    |r| r.values.len() == 5 && r.values.iter().flatten().all(|v| v.is_finite())
                ));
            }
            Err(e) => {
                err += 1;
                assert!(e.to_string().starts_with("m.csv:"), "{e}");
            }
        }
    }
    println!("6000 mutated CSV texts: {ok} accepted, {err} refused with file:line");
    assert!(ok > 100 && err > 100, "{ok} {err}");
}

/// `measurements_text` writes what `parse_measurements` reads back bit for bit: missing cells
/// stay missing, values keep every bit (shortest round-trip `e` notation).
#[test]
fn written_measurements_read_back_unchanged() {
    let model = synthetic_model(&Spec::default());
    let mut rng = Rng(5);
    let rows: Vec<Vec<Option<f64>>> = (0..40)
        .map(|k| {
            (0..5)
                .map(|c| (k + c) % 3 != 0)
                .map(|present| present.then(|| rng.normal() * 1e-3))
                .collect()
        })
        .collect();
    let text = table::measurements_text(&model, &rows);
    let table = table::parse_measurements(Path::new("m.csv"), text.as_bytes(), &model).unwrap();
    let back: Vec<_> = table.values().map(|r| r.values.clone()).collect();
    assert_eq!(back.len(), rows.len());
    for (a, b) in back.iter().zip(&rows) {
        assert_eq!(
            a.iter().map(|v| v.map(f64::to_bits)).collect::<Vec<_>>(),
            b.iter().map(|v| v.map(f64::to_bits)).collect::<Vec<_>>()
        );
    }
}
