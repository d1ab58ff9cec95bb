//! HTTP on loopback for the viewer's tests: an agent that returns every status (no error on
//! 4xx), a GET and a JSON POST, each giving (status, body).

use std::time::Duration;

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
