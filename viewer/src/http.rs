//! The HTTP side: static assets compiled into the binary, the model description, the
//! server-sent event stream and the control endpoint. One thread per request (the event
//! streams are long-lived); a failed write (the tab was closed) ends that stream quietly.

use std::io::{Read, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use crate::sim::Shared;

/// Largest accepted control request body, bytes.
const MAX_BODY: usize = 64 * 1024;

pub(crate) struct State {
    pub shared: Arc<Shared>,
    pub stop: Arc<AtomicBool>,
    pub model_json: Arc<String>,
    pub title: String,
}

struct Asset {
    path: &'static str,
    content_type: &'static str,
    body: &'static [u8],
}

const ASSETS: &[Asset] = &[
    Asset {
        path: "/app.js",
        content_type: "text/javascript; charset=utf-8",
        body: include_bytes!("../assets/app.js"),
    },
    Asset {
        path: "/three/three.module.js",
        content_type: "text/javascript; charset=utf-8",
        body: include_bytes!("../assets/three/three.module.js"),
    },
    Asset {
        path: "/three/three.core.js",
        content_type: "text/javascript; charset=utf-8",
        body: include_bytes!("../assets/three/three.core.js"),
    },
    Asset {
        path: "/three/OrbitControls.js",
        content_type: "text/javascript; charset=utf-8",
        body: include_bytes!("../assets/three/OrbitControls.js"),
    },
    Asset {
        path: "/three/LICENSE",
        content_type: "text/plain; charset=utf-8",
        body: include_bytes!("../assets/three/LICENSE"),
    },
];

const INDEX: &str = include_str!("../assets/index.html");

fn header(name: &str, value: &str) -> Option<tiny_http::Header> {
    tiny_http::Header::from_bytes(name.as_bytes(), value.as_bytes()).ok()
}

fn respond(request: tiny_http::Request, status: u16, content_type: &str, body: Vec<u8>) {
    let mut response = tiny_http::Response::from_data(body).with_status_code(status);
    if let Some(h) = header("Content-Type", content_type) {
        response.add_header(h);
    }
    if let Some(h) = header("Cache-Control", "no-store") {
        response.add_header(h);
    }
    // A client that went away while we answer is not an error of the server.
    let _ = request.respond(response);
}

/// Serves requests until `state.stop` is set.
pub(crate) fn run(server: tiny_http::Server, state: State) {
    let state = Arc::new(state);
    while !state.stop.load(Ordering::SeqCst) {
        let request = match server.recv_timeout(Duration::from_millis(100)) {
            Ok(Some(r)) => r,
            Ok(None) => continue,
            Err(e) => {
                eprintln!("crokf viewer: accepting a connection failed: {e}");
                continue;
            }
        };
        let state = state.clone();
        let spawned = std::thread::Builder::new()
            .name("crokf-viewer-request".into())
            .spawn(move || handle(request, &state));
        if let Err(e) = spawned {
            eprintln!("crokf viewer: cannot start a request thread: {e}");
        }
    }
}

fn handle(mut request: tiny_http::Request, state: &State) {
    let path = request.url().split('?').next().unwrap_or("/").to_string();
    match (request.method(), path.as_str()) {
        (tiny_http::Method::Get, "/") | (tiny_http::Method::Get, "/index.html") => {
            let page = INDEX.replace("{{title}}", &escape_html(&state.title));
            respond(request, 200, "text/html; charset=utf-8", page.into_bytes());
        }
        (tiny_http::Method::Get, "/model.json") => {
            let body = state.model_json.as_bytes().to_vec();
            respond(request, 200, "application/json", body);
        }
        (tiny_http::Method::Get, "/stats.json") => {
            let body = serde_json::to_vec(&state.shared.stats()).unwrap_or_default();
            respond(request, 200, "application/json", body);
        }
        (tiny_http::Method::Get, "/events") => events(request, state),
        (tiny_http::Method::Post, "/control") => {
            let mut body = Vec::new();
            let read = request
                .as_reader()
                .take(MAX_BODY as u64 + 1)
                .read_to_end(&mut body);
            let result = match read {
                Err(e) => Err(format!("cannot read the request body: {e}")),
                Ok(n) if n > MAX_BODY => Err(format!("request body over {MAX_BODY} bytes")),
                Ok(_) => control(&body, state),
            };
            match result {
                Ok(()) => respond(request, 204, "text/plain", Vec::new()),
                Err(message) => respond(
                    request,
                    400,
                    "text/plain; charset=utf-8",
                    message.into_bytes(),
                ),
            }
        }
        (tiny_http::Method::Get, p) => match ASSETS.iter().find(|a| a.path == p) {
            Some(a) => respond(request, 200, a.content_type, a.body.to_vec()),
            None => respond(
                request,
                404,
                "text/plain",
                format!("no such page: {p}").into_bytes(),
            ),
        },
        (m, p) => {
            let message = format!("method {m} not allowed on {p}");
            respond(request, 405, "text/plain", message.into_bytes());
        }
    }
}

/// Applies a control message: a JSON object with any of `"forces": {"group": [fx, fy, fz]}`
/// (N, world frame), `"playing": bool`, `"reset": bool`, `"gravity": scale` and `"tool": [x, y,
/// z]` (the tool sphere's centre, m, model frame) or `"tool": null` (no tool). Anything else
/// (not an object, an unknown key, a value of the wrong type, a force or gravity scale beyond
/// the runtime's plausibility bound for its channel, a gravity scale on a model without a
/// gravity input, a tool on a model without a contact region, a tool coordinate that is not a
/// finite number) is refused with the reason, and nothing is applied.
fn control(body: &[u8], state: &State) -> Result<(), String> {
    const KEYS: &str = "\"forces\", \"playing\", \"reset\", \"gravity\", \"tool\"";
    let value: serde_json::Value =
        serde_json::from_slice(body).map_err(|e| format!("control message is not JSON: {e}"))?;
    let object = value.as_object().ok_or_else(|| {
        format!("control message must be a JSON object with any of {KEYS}, got {value}")
    })?;
    if let Some(key) = object
        .keys()
        .find(|k| !["forces", "playing", "reset", "gravity", "tool"].contains(&k.as_str()))
    {
        return Err(format!("unknown control {key:?}; the controls are {KEYS}"));
    }
    let names = state.shared.load_names();
    let bounds = state.shared.force_bounds();
    let mut forces = Vec::new();
    if let Some(f) = object.get("forces") {
        let f = f
            .as_object()
            .ok_or("'forces' must be an object {\"group\": [fx, fy, fz]}")?;
        for (name, v) in f {
            let g = names
                .iter()
                .position(|n| n == name)
                .ok_or_else(|| format!("no load group '{name}'; the model has {names:?}"))?;
            let a = v
                .as_array()
                .filter(|a| a.len() == 3)
                .ok_or_else(|| format!("force of '{name}' must be [fx, fy, fz] in N"))?;
            let mut force = [0.0; 3];
            for (c, x) in a.iter().enumerate() {
                force[c] = x.as_f64().filter(|x| x.is_finite()).ok_or_else(|| {
                    format!("force of '{name}': component {c} is not a finite number")
                })?;
                let bound = bounds.get(g).map_or(f64::INFINITY, |b| b[c]);
                if force[c].abs() > bound {
                    return Err(format!(
                        "force of '{name}': component {c} = {} N is beyond the model's \
                         plausibility bound of {bound:e} N",
                        force[c]
                    ));
                }
            }
            forces.push((g, force));
        }
    }
    let flag = |key: &str| -> Result<Option<bool>, String> {
        match object.get(key) {
            None => Ok(None),
            Some(v) => v
                .as_bool()
                .map(Some)
                .ok_or_else(|| format!("'{key}' must be true or false, got {v}")),
        }
    };
    let playing = flag("playing")?;
    let reset = flag("reset")? == Some(true);
    let gravity = match object.get("gravity") {
        Some(g) => {
            let scale = g
                .as_f64()
                .filter(|g| g.is_finite())
                .ok_or_else(|| format!("'gravity' must be a finite number, got {g}"))?;
            let bound = state.shared.gravity_bound().ok_or(
                "this model has no gravity input (its scene sets no gravity): 'gravity' does \
                 not apply",
            )?;
            if scale.abs() > bound {
                return Err(format!(
                    "'gravity' = {scale} is beyond the model's plausibility bound of {bound:e}"
                ));
            }
            Some(scale)
        }
        None => None,
    };
    let tool = match object.get("tool") {
        None => None,
        Some(t) => Some(tool(t, state.shared.has_contact())?),
    };
    state.shared.with_controls(|c| {
        if let Some(t) = tool {
            c.tool = t;
        }
        for (g, f) in forces {
            c.forces[g] = f;
        }
        if let Some(p) = playing {
            c.playing = p;
        }
        if let Some(g) = gravity {
            c.gravity = g;
        }
        c.reset |= reset;
    });
    Ok(())
}

/// The value of `"tool"`: `null` (no tool) or `[x, y, z]`, finite numbers (m, model frame), on
/// a model with a contact region.
fn tool(value: &serde_json::Value, has_contact: bool) -> Result<Option<[f64; 3]>, String> {
    if !has_contact {
        return Err(
            "this model has no contact region (its scene declares no [[contact]], \
                    docs/contact.md): 'tool' does not apply"
                .to_string(),
        );
    }
    if value.is_null() {
        return Ok(None);
    }
    let a = value.as_array().filter(|a| a.len() == 3).ok_or_else(|| {
        format!("'tool' must be [x, y, z] (the tool's centre, m, model frame) or null, got {value}")
    })?;
    let mut centre = [0.0; 3];
    for (c, x) in a.iter().enumerate() {
        centre[c] = x.as_f64().filter(|x| x.is_finite()).ok_or_else(|| {
            format!(
                "'tool': coordinate {c} ({}) must be a finite number of metres, got {x}",
                ["x", "y", "z"][c]
            )
        })?;
    }
    Ok(Some(centre))
}

/// A server-sent event stream: one `data:` line of JSON per published frame, a comment line
/// every second without one (keeps proxies and dead-connection detection honest). Ends when a
/// write fails (tab closed) or the server stops.
fn events(request: tiny_http::Request, state: &State) {
    let mut writer = request.into_writer();
    let head = "HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n";
    if writer
        .write_all(head.as_bytes())
        .and_then(|_| writer.flush())
        .is_err()
    {
        return;
    }
    let mut seen = 0;
    while !state.stop.load(Ordering::SeqCst) {
        let written = match state.shared.next_frame(seen, Duration::from_secs(1)) {
            Some((generation, frame)) => {
                seen = generation;
                writer
                    .write_all(b"data: ")
                    .and_then(|_| writer.write_all(frame.as_bytes()))
                    .and_then(|_| writer.write_all(b"\n\n"))
            }
            None => writer.write_all(b": idle\n\n"),
        };
        if written.and_then(|_| writer.flush()).is_err() {
            // The page went away (tab closed, reload): nothing to report but the end.
            return;
        }
    }
}

fn escape_html(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}
