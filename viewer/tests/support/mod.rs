//! HTTP on loopback for the viewer's tests: an agent that returns every status (no error on
//! 4xx), a GET and a JSON POST, each giving (status, body), and a reader of the streamed frames.

use std::io::{BufRead, BufReader, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

pub fn agent() -> ureq::Agent {
    ureq::Agent::config_builder()
        .http_status_as_error(false)
        .timeout_global(Some(Duration::from_secs(10)))
        .build()
        .into()
}

#[allow(dead_code)] // not every test file GETs
pub fn get(url: &str) -> (u16, String) {
    let mut r = agent().get(url).call().expect("GET on loopback");
    let status = r.status().as_u16();
    (status, r.body_mut().read_to_string().unwrap_or_default())
}

pub fn post(url: &str, body: &str) -> (u16, String) {
    let mut r = agent()
        .post(url)
        .header("Content-Type", "application/json")
        .send(body)
        .expect("POST on loopback");
    let status = r.status().as_u16();
    (status, r.body_mut().read_to_string().unwrap_or_default())
}

/// Reads server-sent events from `/events` until `accept` returns true for one, for `patience`
/// at most; panics when none does.
#[allow(dead_code)] // not every test file reads frames
pub fn read_event(
    base: &str,
    patience: Duration,
    accept: impl Fn(&serde_json::Value) -> bool,
) -> serde_json::Value {
    let addr = base.trim_start_matches("http://").trim_end_matches('/');
    let mut stream = TcpStream::connect(addr).expect("connect");
    stream.set_read_timeout(Some(patience)).expect("timeout");
    write!(stream, "GET /events HTTP/1.1\r\nHost: {addr}\r\n\r\n").expect("request");
    let mut reader = BufReader::new(stream);
    let start = Instant::now();
    let mut line = String::new();
    while start.elapsed() < patience {
        line.clear();
        if reader.read_line(&mut line).unwrap_or(0) == 0 {
            break;
        }
        if let Some(data) = line.strip_prefix("data: ") {
            let v: serde_json::Value = serde_json::from_str(data).expect("frame is JSON");
            if accept(&v) {
                return v;
            }
        }
    }
    panic!("no matching frame within {patience:?}");
}
