//! The viewer in a real browser: headless Chromium driven over W3C WebDriver (chromedriver)
//! loads the page of the meniscus, moves the probe's z force slider, and the drawn surface
//! must move with no script error; on the touch model (`scene_touch.toml`, compiled here) it
//! places the tool, pushes it into the body with the mouse wheel and drags it, and the printed
//! tool force must follow. Skipped, with a message, when `chromium` or `chromedriver` is not
//! installed (Debian: `apt-get install chromium chromium-driver`).
//!
//! Prints the measured stepping rate, step time, frame rates (sent, received, drawn) with
//! `-- --nocapture`. `CROKF_VIEWER_SCREENSHOT=path.png` saves a screenshot of the meniscus
//! under the probe there (the README's `viewer/screenshot.png`),
//! `CROKF_VIEWER_TOOL_SCREENSHOT=path.png` one of the tool pressing on the touch model.

use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use base64::Engine;
use crokf_viewer::{ServeOptions, Server};
use serde_json::{json, Value};

fn find_program(names: &[&str]) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .flat_map(|dir| names.iter().map(move |n| dir.join(n)))
        .find(|p| p.is_file())
}

/// chromedriver, killed when dropped.
struct Driver {
    child: Child,
    base: String,
}

impl Drop for Driver {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn agent() -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(Some(Duration::from_secs(60)))
        .build()
        .into()
}

fn wd(method: &str, url: &str, body: Option<Value>) -> Value {
    let a = agent();
    let response = match (method, body) {
        ("POST", Some(b)) => a.post(url).send_json(b),
        ("DELETE", _) => a.delete(url).call(),
        _ => a.get(url).call(),
    };
    let mut response = response.unwrap_or_else(|e| panic!("WebDriver {method} {url}: {e}"));
    let v: Value = response
        .body_mut()
        .read_json()
        .unwrap_or_else(|e| panic!("WebDriver {method} {url}: not JSON: {e}"));
    if let Some(err) = v["value"].get("error") {
        panic!("WebDriver {method} {url}: {err}: {}", v["value"]["message"]);
    }
    v["value"].clone()
}

struct Session {
    base: String,
}

impl Session {
    fn exec(&self, script: &str) -> Value {
        wd(
            "POST",
            &format!("{}/execute/sync", self.base),
            Some(json!({"script": script, "args": []})),
        )
    }

    /// Polls `script` (returning a bool) until true, at most `limit`.
    fn wait_for(&self, script: &str, limit: Duration) -> bool {
        let start = Instant::now();
        while start.elapsed() < limit {
            if self.exec(script) == Value::Bool(true) {
                return true;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        false
    }
}

fn free_port() -> u16 {
    TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free loopback port")
}

fn start_driver(chromedriver: &Path) -> Driver {
    let port = free_port();
    let child = Command::new(chromedriver)
        .arg(format!("--port={port}"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("chromedriver starts");
    let driver = Driver {
        child,
        base: format!("http://127.0.0.1:{port}"),
    };
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(20) {
        let ok = agent()
            .get(&format!("{}/status", driver.base))
            .call()
            .ok()
            .and_then(|mut r| r.body_mut().read_json::<Value>().ok())
            .is_some_and(|v| v["value"]["ready"] == true);
        if ok {
            return driver;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    panic!("chromedriver did not become ready within 20 s");
}

/// Chromium and chromedriver from PATH, or `None` (the test then says SKIPPED).
fn browser() -> Option<(PathBuf, PathBuf)> {
    let (Some(chromium), Some(chromedriver)) = (
        find_program(&["chromium", "chromium-browser", "google-chrome"]),
        find_program(&["chromedriver"]),
    ) else {
        println!("SKIPPED browser test: chromium and chromedriver not found on PATH (apt-get install chromium chromium-driver)");
        return None;
    };
    Some((chromium, chromedriver))
}

/// A headless Chromium session on `driver` with its profile in `profile`, showing `url`.
fn open(driver: &Driver, chromium: &Path, profile: &Path, url: &str) -> Session {
    let caps = json!({"capabilities": {"alwaysMatch": {
        "browserName": "chrome",
        "goog:chromeOptions": {
            "binary": chromium.to_string_lossy(),
            "args": ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                     "--disable-component-update", "--disable-sync", "--no-first-run",
                     "--window-size=1280,800", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                     format!("--user-data-dir={}", profile.display())]
        }
    }}});
    let created = wd("POST", &format!("{}/session", driver.base), Some(caps));
    let id = created["sessionId"]
        .as_str()
        .expect("session id")
        .to_string();
    let session = Session {
        base: format!("{}/session/{id}", driver.base),
    };
    wd(
        "POST",
        &format!("{}/url", session.base),
        Some(json!({"url": url})),
    );
    session
}

fn save_screenshot(session: &Session, variable: &str) {
    if let Some(path) = std::env::var_os(variable) {
        let png = wd("GET", &format!("{}/screenshot", session.base), None);
        let bytes = base64::engine::general_purpose::STANDARD
            .decode(png.as_str().expect("base64 PNG"))
            .expect("valid base64");
        std::fs::write(&path, bytes).expect("write screenshot");
        println!("screenshot: {}", PathBuf::from(path).display());
    }
}

#[test]
fn slider_moves_the_drawn_meniscus() {
    let Some((chromium, chromedriver)) = browser() else {
        return;
    };
    let model_path =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../models/meniscus/model.crokf");
    let model = crokf_runtime::load_model(&model_path).expect("meniscus model");
    let server = Server::start(
        model,
        ServeOptions {
            port: 0,
            force_range: 0.5,
            title: "meniscus/model.crokf".into(),
            ..ServeOptions::default()
        },
    )
    .expect("viewer starts");
    let driver = start_driver(&chromedriver);
    let profile = std::env::temp_dir().join(format!("crokf-viewer-test-{}", std::process::id()));
    let session = open(&driver, &chromium, &profile, server.url());

    let loaded = session.wait_for(
        "return window.crokf.ready === true && window.crokf.framesDrawn > 10 && window.crokf.step > 0;",
        Duration::from_secs(30),
    );
    let errors = session.exec("return window.crokf.errors;");
    assert!(
        loaded,
        "page did not draw frames within 30 s; script errors: {errors}"
    );
    let before = session
        .exec("return window.crokf.displacementSum;")
        .as_f64()
        .expect("number");

    // Move the probe's z slider to -0.5 N the way a user does (value + input event).
    session.exec(
        "const s = document.getElementById('force-probe-z'); s.value = -0.5; \
         s.dispatchEvent(new Event('input')); return s.value;",
    );
    let moved = session.wait_for(
        "return window.crokf.maxDisplacement > 1e-4;",
        Duration::from_secs(20),
    );
    let after = session
        .exec("return window.crokf.displacementSum;")
        .as_f64()
        .expect("number");
    let max = session
        .exec("return window.crokf.maxDisplacement;")
        .as_f64()
        .expect("number");
    assert!(moved, "drawn surface did not move: max |u| = {max} m");
    assert!(
        after > before + 1e-3,
        "sum of |u| over drawn nodes: {before} -> {after} m"
    );

    // Let the figures settle over a few seconds, then read them.
    std::thread::sleep(Duration::from_secs(4));
    let page = session.exec(
        "return {drawn: window.crokf.drawnFps, received: window.crokf.receivedFps, errors: window.crokf.errors};",
    );
    let stats = server.stats();
    println!(
        "viewer, meniscus (r = {}): stepping {:.0} Hz (target 1000), step {:.2} µs median, read-out {:.0} µs per frame, \
         frames {:.1} Hz sent, {:.1} Hz received, {:.1} fps drawn (headless Chromium, software GL), {} steps dropped",
        crokf_runtime::load_model(&model_path).map(|m| m.r()).unwrap_or(0),
        stats.step_rate_hz,
        stats.step_time_median_us,
        stats.readout_time_median_us,
        stats.frame_rate_hz,
        page["received"].as_f64().unwrap_or(f64::NAN),
        page["drawn"].as_f64().unwrap_or(f64::NAN),
        stats.dropped_steps,
    );
    assert_eq!(page["errors"], json!([]), "script errors on the page");
    assert!(stats.step_rate_hz > 0.0 && stats.frames > 0);

    save_screenshot(&session, "CROKF_VIEWER_SCREENSHOT");

    // Closing the tab (ending the session) leaves the server running.
    wd("DELETE", &session.base, None);
    std::thread::sleep(Duration::from_millis(300));
    let frames = server.stats().frames;
    std::thread::sleep(Duration::from_millis(300));
    assert!(
        server.stats().frames > frames,
        "server stopped after the tab closed"
    );
    server.stop();
    drop(driver);
    let _ = std::fs::remove_dir_all(&profile);
}

/// Where the page draws the tool's centre (client pixels, rounded).
fn tool_on_screen(session: &Session) -> (i64, i64) {
    let p = session.exec("return window.crokf.toolScreen();");
    let c = |i: usize| p[i].as_f64().expect("tool on screen").round() as i64;
    (c(0), c(1))
}

/// W3C actions: one input source with its action list.
fn act(session: &Session, source: Value) {
    wd(
        "POST",
        &format!("{}/actions", session.base),
        Some(json!({"actions": [source]})),
    );
}

#[test]
fn the_tool_is_dragged_and_its_force_printed() {
    let Some((chromium, chromedriver)) = browser() else {
        return;
    };
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/meniscus/scene_touch.toml");
    let options = crokf_compile::compile::CompileOptions {
        skip_measured_error: true,
        ..Default::default()
    };
    let model = crokf_compile::compile::compile(&scene, &options)
        .expect("compile the touch scene")
        .model;
    let server = Server::start(
        model,
        ServeOptions {
            port: 0,
            title: "meniscus/scene_touch.toml".into(),
            ..ServeOptions::default()
        },
    )
    .expect("viewer starts");
    let driver = start_driver(&chromedriver);
    let profile =
        std::env::temp_dir().join(format!("crokf-viewer-tool-test-{}", std::process::id()));
    let session = open(&driver, &chromium, &profile, server.url());
    let loaded = session.wait_for(
        "return window.crokf.ready === true && window.crokf.framesDrawn > 10 && window.crokf.step > 0;",
        Duration::from_secs(30),
    );
    let errors = session.exec("return window.crokf.errors;");
    assert!(loaded, "page did not draw frames within 30 s: {errors}");
    let shown = session.exec(
        "return [document.getElementById('tool').hidden, document.getElementById('tool-force').textContent];",
    );
    assert_eq!(
        shown,
        json!([false, "no tool"]),
        "the tool panel on a contact model"
    );

    // Place the tool (1 mm off the middle of the region, the view turned to look at it).
    session.exec("document.getElementById('tool-place').click(); return true;");
    assert!(
        session.wait_for(
            "return window.crokf.toolStatus === 'Free';",
            Duration::from_secs(20)
        ),
        "the placed tool did not come back in the frames: {}",
        session.exec("return [window.crokf.toolStatus, window.crokf.errors];")
    );

    // Push it in with the mouse wheel over the sphere: 6 × 0.3 mm along the view direction.
    let (x, y) = tool_on_screen(&session);
    let scrolls: Vec<Value> = (0..6)
        .map(|_| json!({"type": "scroll", "x": x, "y": y, "deltaX": 0, "deltaY": -300, "origin": "viewport", "duration": 0}))
        .collect();
    act(
        &session,
        json!({"type": "wheel", "id": "wheel", "actions": scrolls}),
    );
    let pressed = session.wait_for(
        "return window.crokf.toolForce > 1e-4 && window.crokf.toolStatus === 'Touching' && \
         document.getElementById('tool-force').textContent.startsWith('|F| ') && \
         !document.getElementById('tool-force').textContent.startsWith('|F| 0 N');",
        Duration::from_secs(20),
    );
    let printed = session.exec(
        "return [window.crokf.toolForce, window.crokf.toolStatus, document.getElementById('tool-force').textContent, window.crokf.errors];",
    );
    assert!(pressed, "the wheel did not press the tool in: {printed}");
    save_screenshot(&session, "CROKF_VIEWER_TOOL_SCREENSHOT");

    // Drag it 40 px to the side with the mouse: the tool moves on the view plane (the orbit
    // controls do not take the gesture) and the printed force changes.
    let before = session.exec("return window.crokf.toolPosition;");
    let label = printed[2].clone();
    let (x, y) = tool_on_screen(&session);
    act(
        &session,
        json!({"type": "pointer", "id": "mouse", "parameters": {"pointerType": "mouse"}, "actions": [
            {"type": "pointerMove", "x": x, "y": y, "origin": "viewport", "duration": 0},
            {"type": "pointerDown", "button": 0},
            {"type": "pointerMove", "x": x + 40, "y": y, "origin": "viewport", "duration": 300},
            {"type": "pointerUp", "button": 0}
        ]}),
    );
    let after = session.exec("return window.crokf.toolPosition;");
    assert_ne!(before, after, "the drag did not move the tool");
    let moved_on_screen = tool_on_screen(&session);
    assert!(
        (moved_on_screen.0 - x - 40).abs() <= 2 && (moved_on_screen.1 - y).abs() <= 2,
        "the tool followed the pointer: ({x}, {y}) + (40, 0) -> {moved_on_screen:?}"
    );
    let script = format!(
        "return JSON.stringify(window.crokf.toolServerPosition) === JSON.stringify(window.crokf.toolPosition) && \
         document.getElementById('tool-force').textContent !== {label};"
    );
    let changed = session.wait_for(&script, Duration::from_secs(20));
    let printed_after = session.exec(
        "return [window.crokf.toolForce, document.getElementById('tool-force').textContent];",
    );
    assert!(
        changed,
        "the printed force did not follow the drag: {label} -> {printed_after}"
    );

    // Remove it.
    session.exec("document.getElementById('tool-remove').click(); return true;");
    assert!(
        session.wait_for(
            "return window.crokf.toolStatus === null && \
             document.getElementById('tool-force').textContent === 'no tool';",
            Duration::from_secs(20)
        ),
        "the tool was not removed"
    );
    let errors = session.exec("return window.crokf.errors;");
    assert_eq!(errors, json!([]), "script errors on the page");
    println!(
        "viewer tool: pressed {} -> dragged {}",
        printed[2], printed_after[1]
    );
    wd("DELETE", &session.base, None);
    server.stop();
    drop(driver);
    let _ = std::fs::remove_dir_all(&profile);
}
