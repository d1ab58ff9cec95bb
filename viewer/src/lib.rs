//! crokf-viewer: a live browser view of a crokf model.
//!
//! [`serve`] steps the runtime's [`crokf_runtime::Estimator`] in real time (one step per Δt of
//! wall-clock time, 1 kHz for the meniscus; docs/design.md §5: x⁻ = F x + G Rᵀ(ω_g) f_world,
//! read-outs X + R̃(ω) C x) and streams the displayed node set's world positions (m) and
//! read-out standard deviations (m) to a page drawn with three.js, as server-sent events at
//! the frame rate (60 Hz by default). The page sets each load group's world-frame force (N)
//! with sliders, plays and pauses, and shows the step time and rates. The page, its script
//! and three.js are compiled into the binary: no network at run time. Loopback only by
//! default.
//!
//! Routes: `GET /` page, `GET /app.js`, `GET /three/*` (vendored three.js), `GET /model.json`
//! (rest geometry, triangles, sensors, loads, the contact region or null), `GET /events`
//! (server-sent events, one JSON frame each), `POST /control` (a JSON object with any of
//! `{"forces": {"group": [fx, fy, fz]}, "playing": bool, "reset": bool, "gravity": scale,
//! "tool": [x, y, z] | null}`; anything else, a value of the wrong type, a force or gravity
//! beyond the runtime's plausibility bound, a gravity on a model without a gravity input, a
//! tool on a model without a contact region or a tool coordinate that is not a finite number
//! is answered 400 with the reason, and changes nothing).
//!
//! The tool: on a model with a contact region (docs/contact.md), while the page has set a
//! tool (a rigid sphere of the region's radius, centre in m, model frame) the stepping thread
//! calls [`crokf_runtime::Estimator::step_with_tools`] instead of `step`, and every frame
//! carries the tool's centre, the force of the body on it (N), its magnitude, the pressing
//! nodes and the contact status.

mod http;
mod sim;

use std::net::{IpAddr, Ipv4Addr, SocketAddr, TcpListener};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use crokf_formats::Model;

pub use sim::Stats;

/// Everything that can go wrong when starting or running the viewer.
#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    /// The model file could not be loaded or verified.
    #[error(transparent)]
    Model(#[from] crokf_runtime::RuntimeError),
    /// The listening socket could not be opened (port in use, no permission, bad address).
    #[error("cannot listen on {address}: {source}{hint}")]
    Bind {
        /// Requested address.
        address: SocketAddr,
        /// Cause.
        source: std::io::Error,
        /// What to do about it.
        hint: &'static str,
    },
    /// The model has no displayed node set with surface triangles to draw.
    #[error("the model has no displayed node set with triangles to draw (node sets: {available:?}); add `[[display]] group = \"surface\"` to the scene")]
    NothingToDraw {
        /// Node set names of the model.
        available: Vec<String>,
    },
    /// The requested node set does not exist.
    #[error("node set '{name}' does not exist; the model has {available:?}")]
    NoSuchNodeSet {
        /// Requested name.
        name: String,
        /// Node set names of the model.
        available: Vec<String>,
    },
    /// An option is out of range.
    #[error("option {option}: {message}")]
    Option {
        /// Which option.
        option: &'static str,
        /// What is wrong.
        message: String,
    },
    /// The HTTP server failed.
    #[error("viewer server: {0}")]
    Server(String),
}

/// Options of [`serve`] / [`Server::start`].
#[derive(Clone, Debug)]
pub struct ServeOptions {
    /// Address to listen on; loopback (127.0.0.1) by default. Anything else exposes the
    /// viewer to the network.
    pub address: IpAddr,
    /// TCP port; 0 picks a free one (see [`Server::url`]).
    pub port: u16,
    /// Node set to draw; `None`: "surface" if present, else the first set with triangles.
    pub node_set: Option<String>,
    /// Frames per second streamed to the page, Hz.
    pub frame_rate: f64,
    /// Slider range of each world force component, ±N.
    pub force_range: f64,
    /// Start stepping immediately (otherwise paused until the page presses play).
    pub playing: bool,
    /// Title shown on the page (e.g. the model file name).
    pub title: String,
}

impl Default for ServeOptions {
    fn default() -> Self {
        Self {
            address: IpAddr::V4(Ipv4Addr::LOCALHOST),
            port: 8080,
            node_set: None,
            frame_rate: 60.0,
            force_range: 1.0,
            playing: true,
            title: "crokf".to_string(),
        }
    }
}

/// A running viewer: a simulation thread stepping the estimator and an HTTP thread.
pub struct Server {
    url: String,
    stop: Arc<AtomicBool>,
    shared: Arc<sim::Shared>,
    threads: Vec<JoinHandle<()>>,
    handover: Arc<sim::Handover>,
}

impl Server {
    /// Validates the model and options, binds the socket and starts the threads.
    pub fn start(model: Model, options: ServeOptions) -> Result<Self, ViewerError> {
        if !(options.frame_rate.is_finite()
            && options.frame_rate > 0.0
            && options.frame_rate <= 1000.0)
        {
            return Err(ViewerError::Option {
                option: "frame_rate",
                message: format!("must be in (0, 1000] Hz, got {}", options.frame_rate),
            });
        }
        if !(options.force_range.is_finite() && options.force_range > 0.0) {
            return Err(ViewerError::Option {
                option: "force_range",
                message: format!(
                    "must be a positive number of newtons, got {}",
                    options.force_range
                ),
            });
        }
        let set = choose_node_set(&model, options.node_set.as_deref())?;
        let estimator = crokf_runtime::Estimator::new(&model)?;
        let address = SocketAddr::new(options.address, options.port);
        let listener = TcpListener::bind(address).map_err(|source| ViewerError::Bind {
            address,
            hint: if source.kind() == std::io::ErrorKind::AddrInUse {
                " (another program uses this port: choose another with --port, or 0 for any free port)"
            } else {
                ""
            },
            source,
        })?;
        let local = listener.local_addr().map_err(|source| ViewerError::Bind {
            address,
            source,
            hint: "",
        })?;
        let http = tiny_http::Server::from_listener(listener, None)
            .map_err(|e| ViewerError::Server(e.to_string()))?;
        let stop = Arc::new(AtomicBool::new(false));
        let model_json = sim::model_json(&model, set, &options);
        let shared = Arc::new(sim::Shared::new(
            &model,
            options.playing,
            estimator.prepared().input_bounds(),
        ));
        let handover = Arc::new(sim::Handover::default());
        let view = estimator.clone();
        let sim_thread = {
            let shared = shared.clone();
            let handover = handover.clone();
            let stop = stop.clone();
            let frame_interval = Duration::from_secs_f64(1.0 / options.frame_rate);
            let sim = sim::Simulation::new(estimator, frame_interval);
            std::thread::Builder::new()
                .name("crokf-viewer-step".into())
                .spawn(move || sim.run(&shared, &handover, &stop))
                .map_err(|e| {
                    ViewerError::Server(format!("cannot start the stepping thread: {e}"))
                })?
        };
        let frame_thread = {
            let shared = shared.clone();
            let handover = handover.clone();
            let stop = stop.clone();
            let framer = sim::Framer::new(view, set);
            std::thread::Builder::new()
                .name("crokf-viewer-frames".into())
                .spawn(move || framer.run(&shared, &handover, &stop))
                .map_err(|e| ViewerError::Server(format!("cannot start the frame thread: {e}")))?
        };
        let http_thread = {
            let state = http::State {
                shared: shared.clone(),
                stop: stop.clone(),
                model_json: Arc::new(model_json),
                title: options.title.clone(),
            };
            std::thread::Builder::new()
                .name("crokf-viewer-http".into())
                .spawn(move || http::run(http, state))
                .map_err(|e| ViewerError::Server(format!("cannot start the HTTP thread: {e}")))?
        };
        let host = match local.ip() {
            IpAddr::V6(ip) => format!("[{ip}]"),
            ip => ip.to_string(),
        };
        Ok(Self {
            url: format!("http://{host}:{}/", local.port()),
            stop,
            shared,
            threads: vec![sim_thread, frame_thread, http_thread],
            handover,
        })
    }

    /// The page's address, e.g. `http://127.0.0.1:8080/`.
    pub fn url(&self) -> &str {
        &self.url
    }

    /// Current stepping and streaming figures.
    pub fn stats(&self) -> Stats {
        self.shared.stats()
    }

    /// Blocks until the server stops (it runs until [`Server::stop`] or the process ends).
    pub fn wait(mut self) {
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }

    /// Stops both threads and waits for them.
    pub fn stop(mut self) {
        self.shutdown();
    }

    fn shutdown(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        self.shared.wake_all();
        self.handover.wake_all();
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// Starts the viewer and blocks while it runs (what `crokf-run MODEL --serve` calls).
/// Prints the page's address on stderr.
pub fn serve(model: Model, options: ServeOptions) -> Result<(), ViewerError> {
    if let Some(warning) = model.tier_failed_check_warning() {
        eprintln!("crokf viewer: warning: {warning}");
    }
    let server = Server::start(model, options)?;
    eprintln!("crokf viewer: open {} (Ctrl-C to stop)", server.url());
    server.wait();
    Ok(())
}

/// Loads a model file with the runtime's verification and serves it.
pub fn serve_file(path: impl Into<PathBuf>, options: ServeOptions) -> Result<(), ViewerError> {
    let model = crokf_runtime::load_model(path.into())?;
    serve(model, options)
}

fn choose_node_set(model: &Model, name: Option<&str>) -> Result<usize, ViewerError> {
    let available = || {
        model
            .node_sets
            .iter()
            .map(|s| s.name.clone())
            .collect::<Vec<_>>()
    };
    match name {
        Some(name) => {
            let i = model
                .node_sets
                .iter()
                .position(|s| s.name == name)
                .ok_or_else(|| ViewerError::NoSuchNodeSet {
                    name: name.to_string(),
                    available: available(),
                })?;
            if model.node_sets[i].triangles.is_empty() {
                return Err(ViewerError::NothingToDraw {
                    available: available(),
                });
            }
            Ok(i)
        }
        None => model
            .node_sets
            .iter()
            .position(|s| s.name == "surface" && !s.triangles.is_empty())
            .or_else(|| model.node_sets.iter().position(|s| !s.triangles.is_empty()))
            .ok_or_else(|| ViewerError::NothingToDraw {
                available: available(),
            }),
    }
}
