//! The viewer's tool: on a model with a contact region (the meniscus's `scene_touch.toml`,
//! compiled here), `POST /control {"tool": [x, y, z]}` makes the stepping thread call
//! `step_with_tools`, and the streamed force equals the runtime stepped directly with the same
//! tool; `{"tool": null}` takes it away; bad tool values and a tool on a model without a
//! contact region are answered 400 naming the field, and change nothing.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::Duration;

use crokf_compile::compile::{compile, CompileOptions};
use crokf_formats::{InputKind, Model};
use crokf_runtime::Estimator;
use crokf_viewer::{ServeOptions, Server};
use serde_json::Value;

mod support;
use support::{get, post};

/// The touch model, compiled once for the tests of this file.
fn touch_model() -> &'static Model {
    static MODEL: OnceLock<Model> = OnceLock::new();
    MODEL.get_or_init(|| {
        let scene =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/meniscus/scene_touch.toml");
        let options = CompileOptions {
            skip_measured_error: true,
            ..CompileOptions::default()
        };
        compile(&scene, &options).expect("compile").model
    })
}

fn paused(model: &Model) -> Server {
    Server::start(
        model.clone(),
        ServeOptions {
            port: 0,
            playing: false,
            ..ServeOptions::default()
        },
    )
    .expect("server starts")
}

/// Reads frames from `/events` until `accept` returns true for one (30 s at most: the debug build's contact step is slow).
fn read_event(base: &str, accept: impl Fn(&serde_json::Value) -> bool) -> serde_json::Value {
    support::read_event(base, Duration::from_secs(30), accept)
}

/// The inputs the viewer steps with when no slider moved: 0 N on every load channel, the
/// scene's gravity (scale 1) on gravity channels.
fn rest_inputs(model: &Model) -> Vec<f64> {
    model
        .inputs
        .iter()
        .map(|i| match i.kind {
            InputKind::Load { .. } => 0.0,
            InputKind::Gravity { .. } => 1.0,
        })
        .collect()
}

/// A tool centre pressing `depth` (m) into the region along the normal of region node `node`.
fn pressing(model: &Model, node: usize, depth: f64) -> [f64; 3] {
    let region = model.contact.as_ref().expect("contact region");
    let p = &region.rest_positions.data[3 * node..3 * node + 3];
    let n = &region.normals.data[3 * node..3 * node + 3];
    [0, 1, 2].map(|i| p[i] + n[i] * (region.tool_radius - depth))
}

fn json_vec(v: &Value) -> Vec<f64> {
    v.as_array()
        .expect("array")
        .iter()
        .map(|x| x.as_f64().expect("number"))
        .collect()
}

/// Equal to 1e-12 of the larger magnitude (JSON text carries every f64 to the last bit, up to
/// the parser's rounding).
fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-12 * a.abs().max(b.abs()).max(1e-300)
}

#[test]
fn the_streamed_tool_force_is_the_runtimes() {
    let model = touch_model();
    let region = model.contact.as_ref().expect("contact region");
    let server = paused(model);
    let base = server.url().to_string();

    let (status, body) = get(&format!("{base}model.json"));
    assert_eq!(status, 200);
    let description: Value = serde_json::from_str(&body).expect("JSON");
    let contact = &description["contact"];
    assert_eq!(contact["radius"].as_f64(), Some(region.tool_radius));
    assert_eq!(contact["max_force"].as_f64(), Some(region.max_force));
    assert_eq!(contact["region"], region.name.as_str());
    assert_eq!(
        contact["positions"].as_array().map(Vec::len),
        Some(3 * region.len())
    );

    // No tool yet: frames carry "tool": null.
    let frame = read_event(&base, |f| f["step"] == 0);
    assert!(frame["tool"].is_null(), "{}", frame["tool"]);

    // A tool 0.8 mm into the region along its first node's normal, set while paused: the
    // frame shows it, not yet stepped (zero force).
    let centre = pressing(model, 0, 8e-4);
    let body = format!(
        r#"{{"tool": [{:e}, {:e}, {:e}]}}"#,
        centre[0], centre[1], centre[2]
    );
    let (status, message) = post(&format!("{base}control"), &body);
    assert_eq!(status, 204, "{message}");
    let frame = read_event(&base, |f| !f["tool"].is_null());
    assert_eq!(json_vec(&frame["tool"]["position"]), centre.to_vec());
    assert_eq!(frame["tool"]["stepped"], false);
    assert_eq!(frame["tool"]["force_magnitude"].as_f64(), Some(0.0));

    // Play: every step is a contact step with that tool. The frame at step k must carry the
    // force of the runtime stepped k times with the same tool and inputs.
    let (status, _) = post(&format!("{base}control"), r#"{"playing": true}"#);
    assert_eq!(status, 204);
    let frame = read_event(&base, |f| {
        f["step"].as_u64().is_some_and(|k| k >= 50) && f["tool"]["stepped"] == true
    });
    let k = frame["step"].as_u64().expect("step");
    let (status, _) = post(&format!("{base}control"), r#"{"playing": false}"#);
    assert_eq!(status, 204);
    let mut est = Estimator::new(model).expect("estimator");
    let inputs = rest_inputs(model);
    let none = vec![None; model.measurements.len()];
    for _ in 0..k {
        est.step_with_tools(&[centre], &inputs, &none)
            .expect("contact step");
    }
    let expected = *est.tool_contact(0).expect("tool result");
    let tool = &frame["tool"];
    let force = json_vec(&tool["force"]);
    for c in 0..3 {
        assert!(
            close(force[c], expected.force[c]),
            "force component {c} at step {k}: streamed {} N, runtime {} N",
            force[c],
            expected.force[c]
        );
    }
    let magnitude = expected.force.iter().map(|f| f * f).sum::<f64>().sqrt();
    assert!(close(
        tool["force_magnitude"].as_f64().expect("number"),
        magnitude
    ));
    assert!(magnitude > 1e-4, "the tool presses: |F| = {magnitude} N");
    assert_eq!(tool["active"].as_u64(), Some(expected.active as u64));
    assert!(expected.active > 0);
    assert_eq!(tool["status"], format!("{:?}", expected.status).as_str());
    assert_eq!(json_vec(&tool["position"]), centre.to_vec());
    // The drawn surface is the runtime's too (float32).
    let set = model
        .node_sets
        .iter()
        .position(|s| s.name == "surface")
        .expect("surface");
    let mut positions = vec![0.0; model.node_sets[set].rest_positions.data.len()];
    est.node_positions(set, &mut positions).expect("read-out");
    let drawn = base64_floats(&frame["positions"]);
    for (i, (a, b)) in drawn.iter().zip(&positions).enumerate() {
        assert_eq!(*a, *b as f32, "coordinate {i} at step {k}");
    }

    // Taking the tool away: frames carry no tool (no force on anything), and stepping goes on
    // with plain steps.
    let (status, _) = post(
        &format!("{base}control"),
        r#"{"tool": null, "playing": true}"#,
    );
    assert_eq!(status, 204);
    let frame = read_event(&base, |f| {
        f["tool"].is_null() && f["step"].as_u64().is_some_and(|s| s > k)
    });
    assert!(frame["error"].is_null(), "{}", frame["error"]);
    server.stop();
}

fn base64_floats(b64: &Value) -> Vec<f32> {
    use base64::Engine;
    base64::engine::general_purpose::STANDARD
        .decode(b64.as_str().expect("base64 string"))
        .expect("valid base64")
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

#[test]
fn bad_tools_are_answered_400_and_change_nothing() {
    let model = touch_model();
    let server = paused(model);
    let base = server.url().to_string();
    let url = format!("{base}control");
    // A valid tool first, so that "nothing changed" is visible in the frames.
    let centre = pressing(model, 0, 8e-4);
    let valid = format!(
        r#"{{"tool": [{:e}, {:e}, {:e}]}}"#,
        centre[0], centre[1], centre[2]
    );
    assert_eq!(post(&url, &valid).0, 204);
    for (body, reason) in [
        (r#"{"tool": [0, 0]}"#, "'tool' must be [x, y, z]"),
        (r#"{"tool": [0, 0, 0, 0]}"#, "'tool' must be [x, y, z]"),
        (r#"{"tool": "here"}"#, "'tool' must be [x, y, z]"),
        (r#"{"tool": {"x": 0}}"#, "'tool' must be [x, y, z]"),
        (r#"{"tool": 1}"#, "'tool' must be [x, y, z]"),
        (
            r#"{"tool": [0, "1", 0]}"#,
            "'tool': coordinate 1 (y) must be a finite number",
        ),
        (
            r#"{"tool": [0, 0, null]}"#,
            "'tool': coordinate 2 (z) must be a finite number",
        ),
        (
            r#"{"tool": [[0], 0, 0]}"#,
            "'tool': coordinate 0 (x) must be a finite number",
        ),
        // JSON has no NaN or infinity: an overflowing number is not JSON.
        (r#"{"tool": [0, 0, 1e999]}"#, "not JSON"),
        (r#"{"tool": [0, 0, NaN]}"#, "not JSON"),
        // One bad key refuses the whole message: neither the tool nor "playing" is applied.
        (
            r#"{"tool": null, "playing": true, "reset": "no"}"#,
            "'reset' must be",
        ),
        (
            r#"{"tool": [0, 0, 0], "playing": "yes"}"#,
            "'playing' must be",
        ),
        (r#"{"tools": [0, 0, 0]}"#, "unknown control \"tools\""),
    ] {
        let (status, message) = post(&url, body);
        assert_eq!(status, 400, "{body}: {message}");
        assert!(message.contains(reason), "{body}: {message}");
    }
    let frame = read_event(&base, |f| f["stats"]["frames"].as_u64() > Some(2));
    assert_eq!(
        json_vec(&frame["tool"]["position"]),
        centre.to_vec(),
        "a refused message moved the tool"
    );
    assert_eq!(frame["step"], 0, "a refused message started stepping");
    assert!(!server.stats().playing);
    server.stop();
}

#[test]
fn a_model_without_a_contact_region_refuses_a_tool() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../models/meniscus/model.crokf");
    let model = crokf_runtime::load_model(&path).expect("model");
    assert!(model.contact.is_none());
    let server = paused(&model);
    let base = server.url().to_string();
    let (status, body) = get(&format!("{base}model.json"));
    assert_eq!(status, 200);
    let description: Value = serde_json::from_str(&body).expect("JSON");
    assert!(description["contact"].is_null());
    for body in [
        r#"{"tool": [0.02, 0, 0.006]}"#,
        r#"{"tool": null}"#,
        r#"{"tool": [0.02, 0, 0.006], "playing": true}"#,
    ] {
        let (status, message) = post(&format!("{base}control"), body);
        assert_eq!(status, 400, "{body}: {message}");
        assert!(
            message.contains("no contact region") && message.contains("'tool'"),
            "{body}: {message}"
        );
    }
    let frame = read_event(&base, |f| f["stats"]["frames"].as_u64() > Some(2));
    assert!(frame["tool"].is_null());
    assert!(!server.stats().playing);
    server.stop();
}
