//! `POST /control` refuses what it cannot apply: a message that is not an object, an unknown
//! key, a value of the wrong type, a gravity scale on a model without a gravity input and
//! forces beyond the runtime's plausibility bound are answered 400 with the reason, and change
//! nothing (the simulation stays paused at rest).

use std::path::PathBuf;
use std::time::Duration;

use crokf_viewer::{ServeOptions, Server};

mod support;
use support::post;

#[test]
fn control_messages_it_cannot_apply_are_answered_400() {
    // The meniscus model has one load group, "probe", and no gravity input.
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../models/meniscus/model.crokf");
    let model = crokf_runtime::load_model(&path).expect("model");
    let server = Server::start(
        model,
        ServeOptions {
            port: 0,
            playing: false,
            ..ServeOptions::default()
        },
    )
    .expect("server starts");
    let url = format!("{}control", server.url());
    for (body, reason) in [
        ("[1,2,3]", "must be a JSON object"),
        ("null", "must be a JSON object"),
        ("42", "must be a JSON object"),
        (r#"{"playing": "yes"}"#, "'playing' must be true or false"),
        (r#"{"reset": 1}"#, "'reset' must be true or false"),
        (r#"{"play": true}"#, "unknown control \"play\""),
        (r#"{"gravity": 1e308}"#, "no gravity input"),
        (r#"{"gravity": 1}"#, "no gravity input"),
        (r#"{"gravity": "1"}"#, "'gravity' must be a finite number"),
        (
            r#"{"forces": {"probe": [0, 0, 1e30]}}"#,
            "beyond the model's plausibility bound",
        ),
        // One bad key refuses the whole message: the valid "playing" is not applied either.
        (r#"{"playing": true, "reset": "no"}"#, "'reset' must be"),
    ] {
        let (status, message) = post(&url, body);
        assert_eq!(status, 400, "{body}: {message}");
        assert!(message.contains(reason), "{body}: {message}");
    }
    std::thread::sleep(Duration::from_millis(300));
    let stats = server.stats();
    assert!(!stats.playing, "a refused message changed the controls");
    assert_eq!(stats.steps, 0);
    // What is valid still works.
    let (status, message) = post(
        &url,
        r#"{"forces": {"probe": [0, 0, -0.3]}, "reset": true}"#,
    );
    assert_eq!(status, 204, "{message}");
    server.stop();
}
