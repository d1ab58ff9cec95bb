//! The viewer's server without a browser: errors, routes, and the streamed frames against the
//! runtime stepped directly with the same force.

use std::io::Write;
use std::net::{TcpListener, TcpStream};
use std::path::PathBuf;
use std::time::Duration;

use base64::Engine;
use crokf_viewer::{serve_file, ServeOptions, Server, ViewerError};

mod support;
use support::{get, post};

fn meniscus() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../models/meniscus/model.crokf")
}

fn options() -> ServeOptions {
    ServeOptions {
        port: 0,
        ..ServeOptions::default()
    }
}

/// Reads frames from `/events` until `accept` returns true for one (10 s at most).
fn read_event(base: &str, accept: impl Fn(&serde_json::Value) -> bool) -> serde_json::Value {
    support::read_event(base, Duration::from_secs(10), accept)
}

fn floats(b64: &serde_json::Value) -> Vec<f32> {
    let bytes = base64::engine::general_purpose::STANDARD
        .decode(b64.as_str().expect("base64 string"))
        .expect("valid base64");
    bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

#[test]
fn bad_model_path_names_the_file() {
    let err = serve_file("/nonexistent/model.crokf", options()).expect_err("must fail");
    let text = err.to_string();
    assert!(text.contains("/nonexistent/model.crokf"), "{text}");
}

#[test]
fn port_in_use_is_a_clear_error() {
    let taken = TcpListener::bind("127.0.0.1:0").expect("bind");
    let port = taken.local_addr().expect("addr").port();
    let model = crokf_runtime::load_model(meniscus()).expect("model");
    let err = Server::start(
        model,
        ServeOptions {
            port,
            ..ServeOptions::default()
        },
    )
    .err()
    .expect("port is taken");
    assert!(matches!(err, ViewerError::Bind { .. }));
    let text = err.to_string();
    assert!(text.contains(&format!("127.0.0.1:{port}")), "{text}");
    assert!(text.contains("--port"), "{text}");
}

#[test]
fn unknown_node_set_lists_the_sets() {
    let model = crokf_runtime::load_model(meniscus()).expect("model");
    let err = Server::start(
        model,
        ServeOptions {
            node_set: Some("nope".into()),
            ..options()
        },
    )
    .err()
    .expect("no such set");
    assert!(err.to_string().contains("\"surface\""), "{err}");
}

#[test]
fn routes_controls_and_frames_match_the_runtime() {
    let model = crokf_runtime::load_model(meniscus()).expect("model");
    let set = model
        .node_sets
        .iter()
        .position(|s| s.name == "surface")
        .expect("surface");
    let server = Server::start(
        model.clone(),
        ServeOptions {
            playing: false,
            ..options()
        },
    )
    .expect("server starts");
    let base = server.url().to_string();
    assert!(base.starts_with("http://127.0.0.1:"), "{base}");

    let (status, page) = get(&base);
    assert_eq!(status, 200);
    assert!(page.contains("importmap") && page.contains("/app.js"));
    for asset in [
        "app.js",
        "three/three.module.js",
        "three/three.core.js",
        "three/OrbitControls.js",
        "three/LICENSE",
    ] {
        assert_eq!(get(&format!("{base}{asset}")).0, 200, "{asset}");
    }
    assert_eq!(get(&format!("{base}missing.js")).0, 404);

    let (status, body) = get(&format!("{base}model.json"));
    assert_eq!(status, 200);
    let description: serde_json::Value = serde_json::from_str(&body).expect("JSON");
    let ns = &model.node_sets[set];
    assert_eq!(
        description["triangles"].as_array().map(Vec::len),
        Some(3 * ns.triangles.len())
    );
    assert_eq!(description["loads"][0]["name"], "probe");

    // Bad control messages are refused with a message; the simulation is untouched.
    let (status, message) = post(&format!("{base}control"), "{not json");
    assert_eq!(status, 400);
    assert!(message.contains("not JSON"), "{message}");
    let (status, message) = post(
        &format!("{base}control"),
        r#"{"forces": {"push": [0, 0, 1]}}"#,
    );
    assert_eq!(status, 400);
    assert!(
        message.contains("no load group 'push'") && message.contains("probe"),
        "{message}"
    );

    // Paused at rest: the frame shows the rest positions (float32).
    let rest = read_event(&base, |f| f["step"] == 0);
    let p0 = floats(&rest["positions"]);
    assert_eq!(p0.len(), ns.rest_positions.data.len());
    for (a, b) in p0.iter().zip(&ns.rest_positions.data) {
        assert_eq!(*a, *b as f32);
    }

    // Force first, then play: every step uses -0.3 N along z. The streamed frame at step k
    // must equal the runtime stepped k times with the same input (float32 rounding).
    let force = [0.0, 0.0, -0.3];
    let (status, _) = post(
        &format!("{base}control"),
        r#"{"forces": {"probe": [0, 0, -0.3]}}"#,
    );
    assert_eq!(status, 204);
    let (status, _) = post(&format!("{base}control"), r#"{"playing": true}"#);
    assert_eq!(status, 204);
    let frame = read_event(&base, |f| f["step"].as_u64().is_some_and(|k| k >= 50));
    let k = frame["step"].as_u64().expect("step");
    let mut est = crokf_runtime::Estimator::new(&model).expect("estimator");
    let none = vec![None; model.measurements.len()];
    for _ in 0..k {
        est.step(&force, &none).expect("step");
    }
    let mut expected = vec![0.0; ns.rest_positions.data.len()];
    est.node_positions(set, &mut expected).expect("read-out");
    let drawn = floats(&frame["positions"]);
    let mut moved = 0.0f64;
    for (i, (a, b)) in drawn.iter().zip(&expected).enumerate() {
        assert_eq!(*a, *b as f32, "coordinate {i} at step {k}");
        moved = moved.max((b - ns.rest_positions.data[i]).abs());
    }
    assert!(
        moved > 1e-5,
        "the probe force moved the surface by {moved} m only"
    );
    let sigma = floats(&frame["std"]);
    assert_eq!(sigma.len(), ns.node_tags.len());
    assert!(sigma.iter().all(|s| s.is_finite() && *s >= 0.0));

    // A client that goes away (closed tab) does not disturb the server.
    let addr = base.trim_start_matches("http://").trim_end_matches('/');
    let mut s = TcpStream::connect(addr).expect("connect");
    write!(s, "GET /events HTTP/1.1\r\nHost: {addr}\r\n\r\n").expect("request");
    drop(s);
    std::thread::sleep(Duration::from_millis(300));
    let frames = server.stats().frames;
    std::thread::sleep(Duration::from_millis(300));
    assert!(
        server.stats().frames > frames,
        "frames stopped after a client left"
    );
    assert_eq!(get(&format!("{base}stats.json")).0, 200);
    server.stop();
}
