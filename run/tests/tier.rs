//! `crokf-run` on a co-rotational tier with a marker missing for a stretch of a recording: the
//! run completes, the tip marker's σ in `estimates.csv` grows while its values are missing and
//! the summary names the steps on the filter's own covariance (docs/design.md §11.11); a tier
//! that failed the compiler's check is named on loading.

use std::process::Command;

#[path = "../../tests/tests/support/beam_tier.rs"]
mod beam_tier;
use beam_tier::{compile_beam, estimated_load_beam};

#[test]
fn a_marker_missing_for_a_while_shows_in_the_sigma_and_the_summary() {
    let dir = std::env::temp_dir().join(format!("crokf-run-tier-{}", std::process::id()));
    let (_, model) = compile_beam(&dir, &estimated_load_beam(true));
    let mp = dir.join("model.crokf");
    std::fs::write(&mp, crokf_formats::encode(&model)).unwrap();
    // 60 steps at rest; every marker at 0, the tip's cells empty on steps 20 … 30.
    let steps = 60;
    let inputs = model.input_labels();
    let mut csv = format!("step,{}\n", inputs.join(","));
    for k in 1..=steps {
        csv += &format!("{k}{}\n", ",0".repeat(inputs.len()));
    }
    let ip = dir.join("inputs.csv");
    std::fs::write(&ip, csv).unwrap();
    let labels = model.measurement_labels();
    let mut csv = format!("step,{}\n", labels.join(","));
    for k in 1..=steps {
        csv += &k.to_string();
        for l in &labels {
            let lost = l.starts_with("tip.") && (20..=30).contains(&k);
            csv += if lost { "," } else { ",0" };
        }
        csv += "\n";
    }
    let yp = dir.join("measurements.csv");
    std::fs::write(&yp, csv).unwrap();
    let op = dir.join("estimates.csv");
    // crokf-run on a model file over the inputs (and the measurements when given): its stderr.
    let replay = |model: &std::path::Path, measurements: Option<&std::path::Path>| {
        let mut command = Command::new(env!("CARGO_BIN_EXE_crokf-run"));
        command.arg(model).arg("--inputs").arg(&ip);
        if let Some(m) = measurements {
            command.arg("--measurements").arg(m);
        }
        let out = command.arg("--out").arg(&op).output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        assert!(out.status.success(), "{stderr}");
        stderr
    };
    let stderr = replay(&mp, Some(&yp));
    assert!(
        stderr.contains("the filter carried its own covariance after")
            && stderr.contains("(steps 20 … "),
        "{stderr}"
    );
    // The tip's σ (its first σ column) at steps 19 … 31.
    let text = std::fs::read_to_string(&op).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let column = header.iter().position(|&h| h == "tip.z_std").unwrap();
    let sigma: Vec<f64> = lines
        .map(|l| l.split(',').nth(column).unwrap().parse().unwrap())
        .collect();
    let lost = &sigma[19..30];
    assert!(
        lost.windows(2).all(|w| w[1] > w[0]) && lost[0] > sigma[17],
        "tip σ around the loss: {:?}",
        &sigma[16..32]
    );
    assert!(sigma[40] < sigma[29], "{:?}", &sigma[28..42]);
    // A tier that passed its check says nothing of it; one written after failing it (format
    // v10, `accept_failed_check = true`) is named on loading, with the compiler's reason.
    assert!(
        !stderr.contains("failed the compiler's own check"),
        "{stderr}"
    );
    let mut failed = model.clone();
    let why =
        "the co-rotational tier fails its check: 9 of 10 of its own training runs are above 5 %";
    failed.tier.as_mut().unwrap().failed_check = Some(why.into());
    let fp = dir.join("failed.crokf");
    std::fs::write(&fp, crokf_formats::encode(&failed)).unwrap();
    let stderr = replay(&fp, None);
    assert!(
        stderr.contains("crokf-run: warning: ")
            && stderr.contains("failed.crokf")
            && stderr.contains("failed the compiler's own check")
            && stderr.contains(why),
        "{stderr}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
