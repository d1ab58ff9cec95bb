//! `crokf-view MODEL [--port 8080] [--address 127.0.0.1] [--node-set NAME] [--force-range N]`:
//! serves the live viewer of a model file (until `crokf-run MODEL --serve` is wired to
//! [`crokf_viewer::serve`]).

use std::net::IpAddr;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use crokf_viewer::{serve_file, ServeOptions};

/// Live browser viewer of a crokf model: steps it in real time and draws it with three.js.
#[derive(Parser)]
#[command(version)]
struct Args {
    /// Model file (.crokf).
    model: PathBuf,
    /// TCP port (0: any free port).
    #[arg(long, default_value_t = 8080)]
    port: u16,
    /// Listening address; loopback by default. Anything else exposes the viewer to the network.
    #[arg(long, default_value = "127.0.0.1")]
    address: IpAddr,
    /// Displayed node set to draw (default: "surface", else the first with triangles).
    #[arg(long)]
    node_set: Option<String>,
    /// Slider range of each world force component, ±N.
    #[arg(long, default_value_t = 1.0)]
    force_range: f64,
    /// Frames streamed per second, Hz.
    #[arg(long, default_value_t = 60.0)]
    frame_rate: f64,
    /// Start paused.
    #[arg(long)]
    paused: bool,
}

fn main() -> ExitCode {
    let args = Args::parse();
    if !args.address.is_loopback() {
        eprintln!(
            "crokf viewer: warning: listening on {}, reachable from the network",
            args.address
        );
    }
    let options = ServeOptions {
        address: args.address,
        port: args.port,
        node_set: args.node_set,
        frame_rate: args.frame_rate,
        force_range: args.force_range,
        playing: !args.paused,
        title: args
            .model
            .file_name()
            .map_or_else(|| "crokf".into(), |f| f.to_string_lossy().into_owned()),
    };
    match serve_file(&args.model, options) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("crokf-view: {e}");
            ExitCode::FAILURE
        }
    }
}
