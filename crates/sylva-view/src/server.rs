//! The web server: one page, its two assets and a WebSocket, behind a random token.
//!
//! [`Server::start`] binds the address and serves at once, while the scene is prepared on
//! a thread of its own (the page shows that work's lines); then that thread becomes the
//! render worker ([`crate::worker`]). The token (like Jupyter's) is required for the page
//! and the WebSocket; the WebSocket also checks that the page's Origin is this server, so
//! another site open in the same browser cannot drive it. Messages are bounded in size and
//! rate; a bad one is answered with an error, and every other page goes on being served.

use std::net::{SocketAddr, TcpListener};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Query, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use futures_util::{SinkExt, StreamExt};
use serde::Deserialize;
use sylva_pipeline::PreparedScene;
use tokio::sync::watch;

use crate::assets;
use crate::protocol::{
    parse_client_message, ClientMessage, Hello, ServerMessage, MAX_MESSAGES_PER_SECOND,
    MAX_MESSAGE_BYTES,
};
use crate::worker::{Hub, SaveFormat, Worker, WorkerOptions};

/// Lines of preparation a page joining late still sees.
const STATUS_LINES: usize = 12;

/// Why the server could not run.
#[derive(Debug, thiserror::Error)]
pub enum ViewError {
    #[error("cannot listen on {addr}: {source}")]
    Bind {
        addr: String,
        source: std::io::Error,
    },
    #[error("the web server: {0}")]
    Runtime(std::io::Error),
    /// The scene could not be prepared (the pages were told too).
    #[error("{0}")]
    Prepare(String),
}

/// Where and how to serve.
#[derive(Debug, Clone)]
pub struct ServeOptions {
    /// Address to bind: 127.0.0.1 unless the user asks for another.
    pub host: String,
    /// 0: any free port.
    pub port: u16,
    /// The URL token; `None` draws a random one.
    pub token: Option<String>,
    pub worker: WorkerOptions,
}

/// A scene ready to view, and what the page is told of it.
pub struct ReadyScene {
    pub scene: PreparedScene,
    /// The frame size the page starts from (the scene camera's, or the command's).
    pub width: u32,
    pub height: u32,
    /// What lights it, in words.
    pub light: String,
    /// Where the time-of-day control starts.
    pub lat: f64,
    pub lon: f64,
}

impl ReadyScene {
    /// `scene` at `size` (width, height), the time-of-day control starting at `place`
    /// (latitude, longitude); what lights it is read from the scene.
    pub fn new(scene: PreparedScene, size: (u32, u32), place: (f64, f64)) -> ReadyScene {
        let light = match (&scene.physical, &scene.relit) {
            (Some(_), _) => "the physical light, relit from its base solutions",
            (_, Some(_)) => "the paper light, relit from its base solutions",
            _ => "the local light (no LB light)",
        };
        ReadyScene {
            scene,
            width: size.0,
            height: size.1,
            light: light.into(),
            lat: place.0,
            lon: place.1,
        }
    }
}

/// Whether `host` is a loopback address (or `localhost`): anything else lets other machines
/// reach the server.
pub fn is_loopback(host: &str) -> bool {
    host.eq_ignore_ascii_case("localhost")
        || host
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback())
}

/// Checks what `sylva view` is asked before any work: the folder saved frames go to, the
/// time-of-day control's place. A warning to print when `host` lets other machines in.
pub fn check_options(
    host: &str,
    output: &std::path::Path,
    (lat, lon): (f64, f64),
) -> Result<Option<String>, String> {
    sylva_core::solar::Place::new(lat, lon).map_err(|e| format!("--lat/--lon: {e}"))?;
    if output.exists() && !output.is_dir() {
        return Err(format!(
            "--output {}: not a folder (saved frames go there)",
            output.display()
        ));
    }
    Ok((!is_loopback(host)).then(|| {
        format!(
            "listening on {host}: other machines can reach the viewer (they need the URL's \
             token); an SSH tunnel to 127.0.0.1 keeps it private (README: Viewer)"
        )
    }))
}

/// Where the scene's preparation stands.
#[derive(Debug, Clone)]
enum Phase {
    Preparing(Vec<String>),
    Ready(Box<Hello>),
    Failed(String),
}

struct App {
    token: String,
    hub: Arc<Hub>,
    phase: watch::Sender<Phase>,
    max_pixels: u64,
}

/// A running server.
pub struct Server {
    addr: SocketAddr,
    token: String,
    hub: Arc<Hub>,
    phase: watch::Receiver<Phase>,
    stop: watch::Sender<bool>,
    runtime: Option<tokio::runtime::Runtime>,
    served: Option<tokio::task::JoinHandle<std::io::Result<()>>>,
    worker: Option<std::thread::JoinHandle<()>>,
}

#[derive(Deserialize)]
struct TokenQuery {
    token: Option<String>,
}

impl Server {
    /// Binds `opts.host:opts.port` and serves; `prepare(status)` runs on a thread of its own
    /// (its `status` lines reach every page), and the scene it returns is then rendered for
    /// the pages on that thread.
    pub fn start<F>(opts: ServeOptions, prepare: F) -> Result<Server, ViewError>
    where
        F: FnOnce(&(dyn Fn(String) + Sync)) -> Result<ReadyScene, String> + Send + 'static,
    {
        let addr_text = format!("{}:{}", opts.host, opts.port);
        let bind = |source| ViewError::Bind {
            addr: addr_text.clone(),
            source,
        };
        let listener = TcpListener::bind(&addr_text).map_err(bind)?;
        listener.set_nonblocking(true).map_err(bind)?;
        let addr = listener.local_addr().map_err(bind)?;
        let token = match opts.token.clone() {
            Some(t) => t,
            None => random_token().map_err(ViewError::Runtime)?,
        };
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("sylva-view-http")
            .enable_all()
            .build()
            .map_err(ViewError::Runtime)?;
        let hub = Hub::new();
        let (phase, phase_rx) = watch::channel(Phase::Preparing(Vec::new()));
        let app = Arc::new(App {
            token: token.clone(),
            hub: hub.clone(),
            phase,
            max_pixels: opts.worker.max_pixels,
        });
        let router = Router::new()
            .route("/", get(page))
            .route(
                "/app.js",
                get(|| async { asset("text/javascript", assets::APP_JS) }),
            )
            .route(
                "/style.css",
                get(|| async { asset("text/css", assets::STYLE_CSS) }),
            )
            .route("/ws", get(socket))
            .with_state(app.clone());
        let (stop, mut stop_rx) = watch::channel(false);
        let served = {
            let _guard = runtime.enter();
            let listener = tokio::net::TcpListener::from_std(listener).map_err(bind)?;
            runtime.spawn(async move {
                axum::serve(listener, router)
                    .with_graceful_shutdown(async move {
                        let _ = stop_rx.wait_for(|s| *s).await;
                    })
                    .await
            })
        };
        let worker = {
            let hub = hub.clone();
            let wopts = opts.worker.clone();
            std::thread::Builder::new()
                .name("sylva-view-render".into())
                .spawn(move || {
                    let lines = Mutex::new(Vec::<String>::new());
                    let status = |line: String| {
                        let mut l = lines.lock().expect("status lines");
                        l.push(line);
                        let start = l.len().saturating_sub(STATUS_LINES);
                        app.phase
                            .send_replace(Phase::Preparing(l[start..].to_vec()));
                    };
                    let ready = match prepare(&status) {
                        Ok(r) => r,
                        Err(e) => {
                            app.phase.send_replace(Phase::Failed(e));
                            return;
                        }
                    };
                    app.phase
                        .send_replace(Phase::Ready(Box::new(hello(&ready, &wopts))));
                    Worker::new(ready.scene, hub, wopts).run();
                })
                .map_err(ViewError::Runtime)?
        };
        Ok(Server {
            addr,
            token,
            hub,
            phase: phase_rx,
            stop,
            runtime: Some(runtime),
            served: Some(served),
            worker: Some(worker),
        })
    }

    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    pub fn token(&self) -> &str {
        &self.token
    }

    /// The page's URL, token included (`host` as the user would type it).
    pub fn url(&self, host: &str) -> String {
        format!("http://{host}:{}/?token={}", self.addr.port(), self.token)
    }

    /// Pages connected now.
    pub fn clients(&self) -> usize {
        self.hub.clients()
    }

    /// Blocks until the scene is ready (`Ok`) or its preparation failed.
    pub fn wait_ready(&mut self) -> Result<(), ViewError> {
        let rt = self.runtime.as_ref().expect("running");
        let phase = rt.block_on(async {
            self.phase
                .wait_for(|p| !matches!(p, Phase::Preparing(_)))
                .await
                .map(|p| p.clone())
        });
        match phase {
            Ok(Phase::Failed(e)) => Err(ViewError::Prepare(e)),
            _ => Ok(()),
        }
    }

    /// Serves until `stop_when()` turns true (polled every 100 ms: Ctrl-C) or preparation
    /// fails; then stops cleanly.
    pub fn run_until(mut self, stop_when: impl Fn() -> bool) -> Result<(), ViewError> {
        let failed = loop {
            if stop_when() {
                break None;
            }
            if let Phase::Failed(e) = &*self.phase.borrow() {
                break Some(e.clone());
            }
            std::thread::sleep(Duration::from_millis(100));
        };
        self.shutdown();
        match failed {
            Some(e) => Err(ViewError::Prepare(e)),
            None => Ok(()),
        }
    }

    /// Stops serving: open pages are closed, the worker ends after its current strip.
    pub fn shutdown(&mut self) {
        self.hub.shutdown();
        let _ = self.stop.send(true);
        if let (Some(rt), Some(served)) = (self.runtime.take(), self.served.take()) {
            let _ =
                rt.block_on(async { tokio::time::timeout(Duration::from_secs(5), served).await });
            rt.shutdown_timeout(Duration::from_secs(1));
        }
        // The worker may still be preparing the scene: it ends when that does (a thread
        // left behind holds no file open for writing: caches are written atomically).
        if let Some(w) = self.worker.take() {
            if w.is_finished() {
                let _ = w.join();
            }
        }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.shutdown();
    }
}

fn hello(ready: &ReadyScene, opts: &WorkerOptions) -> Hello {
    let s = &ready.scene;
    Hello {
        scene: s.scene.name.clone(),
        camera: crate::orbit::Orbit::of_camera(&s.scene.camera),
        sun: crate::protocol::SunPosition {
            elevation: s.scene.sun.elevation_deg(),
            // World azimuth (from +x towards +z) as a compass one (north -z, east +x).
            azimuth: (s.scene.sun.azimuth_deg() + 90.0).rem_euclid(360.0),
        },
        width: ready.width,
        height: ready.height,
        max_pixels: opts.max_pixels,
        gather_rays: s.shading.gather_rays,
        max_gather_rays: crate::protocol::MAX_GATHER_RAYS,
        max_samples: opts.max_samples,
        light: ready.light.clone(),
        // Without base solutions the sun is fixed, unless nothing has LB light at all.
        sun_moves: s.physical.is_some()
            || s.relit.is_some()
            || (0..s.scene.models.len()).all(|m| s.light.model(m).is_none()),
        // The adapter's name alone: the tracer's full description is a paragraph.
        device: match s.tracer.adapter() {
            Some(a) => format!("GPU {a}"),
            None => s.tracer.describe(),
        },
        lat: ready.lat,
        lon: ready.lon,
    }
}

/// 128 random bits as hex.
fn random_token() -> std::io::Result<String> {
    let mut bytes = [0u8; 16];
    getrandom::fill(&mut bytes).map_err(|e| std::io::Error::other(e.to_string()))?;
    Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
}

/// Compares without stopping at the first difference (the token's length is public).
fn token_matches(given: Option<&str>, token: &str) -> bool {
    let Some(given) = given else {
        return false;
    };
    given.len() == token.len()
        && given
            .bytes()
            .zip(token.bytes())
            .fold(0u8, |acc, (a, b)| acc | (a ^ b))
            == 0
}

fn forbidden(why: &str) -> Response {
    (StatusCode::FORBIDDEN, format!("sylva view: {why}\n")).into_response()
}

fn asset(content_type: &'static str, body: &'static str) -> Response {
    ([(header::CONTENT_TYPE, content_type)], body).into_response()
}

async fn page(State(app): State<Arc<App>>, Query(q): Query<TokenQuery>) -> Response {
    if !token_matches(q.token.as_deref(), &app.token) {
        return forbidden("open the URL the server printed: it carries the token");
    }
    (
        [(header::CACHE_CONTROL, "no-store")],
        Html(assets::INDEX_HTML),
    )
        .into_response()
}

/// Whether a WebSocket's Origin is this server: the same host and port as the request's
/// Host. A client that sends no Origin (not a browser: the benchmark, curl) is let through;
/// it still needs the token.
fn origin_allowed(headers: &HeaderMap) -> bool {
    let Some(origin) = headers.get(header::ORIGIN) else {
        return true;
    };
    let (Ok(origin), Some(Ok(host))) = (
        origin.to_str(),
        headers.get(header::HOST).map(|h| h.to_str()),
    ) else {
        return false;
    };
    origin
        .strip_prefix("http://")
        .or_else(|| origin.strip_prefix("https://"))
        .is_some_and(|o| o.eq_ignore_ascii_case(host))
}

async fn socket(
    State(app): State<Arc<App>>,
    Query(q): Query<TokenQuery>,
    headers: HeaderMap,
    ws: WebSocketUpgrade,
) -> Response {
    if !token_matches(q.token.as_deref(), &app.token) {
        return forbidden("the WebSocket needs the page's token");
    }
    if !origin_allowed(&headers) {
        return forbidden("the WebSocket's Origin is not this server");
    }
    // The transport refuses far larger messages outright; ours are checked in size below.
    ws.max_message_size(16 * MAX_MESSAGE_BYTES)
        .max_frame_size(16 * MAX_MESSAGE_BYTES)
        .on_upgrade(move |socket| session(socket, app))
}

fn text(m: &ServerMessage) -> Message {
    Message::Text(
        serde_json::to_string(m)
            .expect("server messages serialise")
            .into(),
    )
}

/// One page: its preparation status, then its input to the worker and its frames back.
async fn session(socket: WebSocket, app: Arc<App>) {
    let (mut tx, mut rx) = socket.split();
    let mut phase = app.phase.subscribe();
    // While preparing: the lines so far, and again as they change.
    let hello = loop {
        let now = phase.borrow_and_update().clone();
        match now {
            Phase::Preparing(lines) => {
                if let Some(line) = lines.last() {
                    let m = ServerMessage::Status { line: line.clone() };
                    if tx.send(text(&m)).await.is_err() {
                        return;
                    }
                }
                tokio::select! {
                    changed = phase.changed() => if changed.is_err() { return },
                    incoming = rx.next() => match incoming {
                        // Input before the scene is ready is dropped; a close ends it.
                        Some(Ok(Message::Close(_))) | None | Some(Err(_)) => return,
                        Some(Ok(_)) => {}
                    },
                }
            }
            Phase::Ready(hello) => break hello,
            Phase::Failed(e) => {
                let m = ServerMessage::Error {
                    seq: None,
                    message: format!("the scene could not be prepared: {e}"),
                };
                let _ = tx.send(text(&m)).await;
                return;
            }
        }
    };
    if tx.send(text(&ServerMessage::Hello(*hello))).await.is_err() {
        return;
    }
    let mut conn = app.hub.connect();
    let mailbox = conn.mailbox.clone();
    let writer = tokio::spawn(async move {
        loop {
            tokio::select! {
                changed = conn.frames.changed() => {
                    if changed.is_err() {
                        break;
                    }
                    let frame = conn.frames.borrow_and_update().clone();
                    if let Some(frame) = frame {
                        if tx.send(Message::Binary(frame)).await.is_err() {
                            break;
                        }
                    }
                }
                message = conn.messages.recv() => match message {
                    Some(m) => if tx.send(text(&m)).await.is_err() { break },
                    None => break,
                },
            }
        }
        let _ = tx.close().await;
    });
    let mut window = (Instant::now(), 0u32);
    while let Some(incoming) = rx.next().await {
        let message = match incoming {
            Ok(m) => m,
            // A transport error (a message over the transport's limit, a broken frame):
            // this page ends, no other.
            Err(_) => break,
        };
        let text = match message {
            Message::Text(t) => t,
            Message::Close(_) => break,
            Message::Ping(_) | Message::Pong(_) => continue,
            Message::Binary(_) => {
                mailbox
                    .tell(error("binary messages are not understood: send JSON text"))
                    .await;
                continue;
            }
        };
        // At most MAX_MESSAGES_PER_SECOND per one-second window.
        if window.0.elapsed() >= Duration::from_secs(1) {
            window = (Instant::now(), 0);
        }
        window.1 += 1;
        if window.1 > MAX_MESSAGES_PER_SECOND {
            if window.1 == MAX_MESSAGES_PER_SECOND + 1 {
                mailbox
                    .tell(error(&format!(
                        "more than {MAX_MESSAGES_PER_SECOND} messages a second: the rest of \
                         this second's are dropped"
                    )))
                    .await;
            }
            continue;
        }
        match parse_client_message(text.as_str()) {
            Ok(ClientMessage::View(request)) => match request.resolve(app.max_pixels) {
                Ok(view) => app.hub.post_view(&mailbox, view),
                Err(message) => {
                    mailbox
                        .tell(ServerMessage::Error {
                            seq: Some(request.seq),
                            message,
                        })
                        .await
                }
            },
            Ok(ClientMessage::Save { format }) => match SaveFormat::parse(&format) {
                Ok(f) => app.hub.post_save(&mailbox, f),
                Err(message) => mailbox.tell(error(&message)).await,
            },
            Err(message) => mailbox.tell(error(&message)).await,
        }
    }
    // The page is gone: its refinement stops at the next strip and its state is freed.
    app.hub.disconnect(&mailbox);
    writer.abort();
}

fn error(message: &str) -> ServerMessage {
    ServerMessage::Error {
        seq: None,
        message: message.to_string(),
    }
}
