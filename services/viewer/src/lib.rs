//! The viewer (`docs/viewer.md`): a web page with the 3D scene, each camera's monitor and
//! every service's health, served by this process on `127.0.0.1:8750` unless the rig's
//! `[viewer]` says otherwise, and fed over one WebSocket per browser from the Zenoh streams —
//! pose frames, the synthetic scene's truth, camera previews, health and a live wand
//! calibration's coverage. The thesis's fourth
//! computer "displays the 3D graphical model of the object" (§6.2); its lab watched each
//! camera on a monitor with the tracking windows drawn: this is both, in a browser.
//!
//! The page (`web/`) is bundled with three.js at build time and served from the binary:
//! nothing is fetched while it runs.
//!
//! *Faults.* Every message from Zenoh is checked (`Message::from_json`/`from_binary`) and
//! must be this rig's (and a camera of it) before it is forwarded; what fails is counted by
//! reason. A browser that sends garbage is answered with an error and counted, and cut off
//! after [`MAX_BAD_MESSAGES`]; a message over [`MAX_CLIENT_MESSAGE_BYTES`] closes its socket;
//! browsers beyond `max_clients` are answered 503; an unknown camera or page is answered 404.
//! A browser too slow for the stream skips frames (counted as `lagged`) and never holds up
//! the others. None of it stops the viewer.

pub mod cli;
pub mod scene;

use axum::Router;
use axum::body::Bytes;
use axum::extract::ws::{Message as WsMessage, Utf8Bytes, WebSocket, WebSocketUpgrade};
use axum::extract::{Path, State};
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use std::collections::{BTreeMap, HashMap};
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use stereoscope_proto::messages::{Detail, Health, PoseFrame, Preview, Truth, WandCoverage};
use stereoscope_proto::names::zenoh as keys;
use stereoscope_service::Context;
use stereoscope_transport::inlet::{self, Admission};
use stereoscope_transport::{Flow, Refusal, Service, ServiceNode, Shutdown, drive, net};
use tokio::sync::broadcast;

/// The page and its bundled script (three.js inside), made by `build.rs`.
const INDEX_HTML: &str = include_str!(concat!(env!("OUT_DIR"), "/index.html"));
const APP_JS: &str = include_str!(concat!(env!("OUT_DIR"), "/app.bundle.js"));

/// Browsers at once when the rig does not say.
pub use stereoscope_rig::settings::DEFAULT_VIEWER_MAX_CLIENTS as DEFAULT_MAX_CLIENTS;
/// Largest message a browser may send, bytes (its requests are a few dozen).
pub const MAX_CLIENT_MESSAGE_BYTES: usize = 4096;
/// Bad messages after which a browser's socket is closed.
pub const MAX_BAD_MESSAGES: u64 = 32;
/// Messages queued for the browsers; one that falls further behind skips the oldest.
const QUEUE: usize = 256;
/// Health reports kept (one per service; a flood of forged names cannot grow it further).
const MAX_SERVICES: usize = 256;
/// Rejections kept between two health reports.
const MAX_PENDING_REJECTIONS: usize = 64;

#[derive(Debug, Clone)]
pub struct ViewerConfig {
    pub ctx: Context,
    /// Listen here instead of the rig's `[viewer] listen` (tests give port 0).
    pub listen: Option<SocketAddr>,
}

#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    #[error("viewer")]
    Rig(#[from] stereoscope_rig::RigError),
    #[error("viewer: [viewer] listen = {0:?} is not an address and port")]
    Listen(String),
    #[error("viewer: cannot listen on {addr} (is another viewer or program using the port?)")]
    Bind {
        addr: SocketAddr,
        #[source]
        source: std::io::Error,
    },
    #[error("viewer: the web server's runtime")]
    Runtime(#[source] std::io::Error),
    #[error("viewer")]
    Transport(#[from] stereoscope_transport::TransportError),
}

/// What the viewer did.
#[derive(Debug, Clone, Default)]
pub struct ViewerSummary {
    pub pose_frames: u64,
    pub connections: u64,
}

/// A connection that has not sent a request's headers within this long is closed (one that
/// connects and sends nothing, or a byte at a time, holds nothing for long).
pub const HEADER_TIMEOUT: Duration = Duration::from_secs(5);

/// Connections open at once (pages, their files, WebSockets being opened); more are closed as
/// they come, and counted with the refused sockets. Browsers beyond `max_clients` are
/// answered 503 below this.
pub const MAX_CONNECTIONS: usize = 256;

/// Serves `app` on `listener` until `stop`: HTTP/1 with WebSocket upgrades, each connection
/// given [`HEADER_TIMEOUT`] to send a request's headers, at most [`MAX_CONNECTIONS`] at once.
async fn serve(
    listener: tokio::net::TcpListener,
    app: Router,
    shared: Arc<Shared>,
    stop: tokio::sync::oneshot::Receiver<()>,
) {
    let open = Arc::new(tokio::sync::Semaphore::new(MAX_CONNECTIONS));
    let (closing, closed) = tokio::sync::watch::channel(false);
    tokio::pin!(stop);
    loop {
        let stream = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok((stream, _)) => stream,
                Err(e) => {
                    // Out of descriptors, or a connection reset before it was taken: wait a
                    // moment instead of spinning.
                    tracing::debug!("accepting a connection: {e}");
                    tokio::time::sleep(Duration::from_millis(20)).await;
                    continue;
                }
            },
            _ = &mut stop => break,
        };
        let Ok(permit) = open.clone().try_acquire_owned() else {
            shared.stats.refused.fetch_add(1, Ordering::Relaxed);
            drop(stream);
            continue;
        };
        let service = hyper_util::service::TowerToHyperService::new(app.clone());
        let mut closed = closed.clone();
        tokio::spawn(async move {
            let _permit = permit;
            let mut builder = hyper::server::conn::http1::Builder::new();
            builder
                .timer(hyper_util::rt::TokioTimer::new())
                .header_read_timeout(HEADER_TIMEOUT);
            let conn = builder
                .serve_connection(hyper_util::rt::TokioIo::new(stream), service)
                .with_upgrades();
            tokio::pin!(conn);
            tokio::select! {
                _ = conn.as_mut() => {}
                _ = closed.changed() => {
                    conn.as_mut().graceful_shutdown();
                    let _ = conn.await;
                }
            }
        });
    }
    let _ = closing.send(true);
}

#[derive(Debug, Default)]
struct Stats {
    clients: AtomicUsize,
    connections: AtomicU64,
    refused: AtomicU64,
    bad_requests: AtomicU64,
    lagged: AtomicU64,
    sent_bytes: AtomicU64,
    pose_frames: AtomicU64,
    previews: AtomicU64,
}

/// One message for the browsers.
#[derive(Debug, Clone)]
enum Out {
    Text(Utf8Bytes),
    Preview { camera: Arc<str>, bytes: Bytes },
}

#[derive(Debug)]
struct Shared {
    rig: String,
    cameras: Vec<String>,
    rig_json: String,
    max_clients: usize,
    tx: broadcast::Sender<Out>,
    /// The newest preview of each camera and health report of each service, for a browser
    /// that connects.
    previews: Mutex<HashMap<String, Bytes>>,
    health: Mutex<BTreeMap<String, Utf8Bytes>>,
    /// The camera whose truth is forwarded (each synthetic camera sends the same scene).
    truth_camera: Option<String>,
    rejections: Mutex<Vec<(&'static str, String)>>,
    stats: Stats,
}

impl Shared {
    fn reject(&self, reason: &'static str, message: String) {
        if let Ok(mut r) = self.rejections.lock()
            && r.len() < MAX_PENDING_REJECTIONS
        {
            r.push((reason, message));
        }
    }

    fn send(&self, out: Out) {
        // No browser connected is not an error.
        let _ = self.tx.send(out);
    }

    fn bad_request(&self) {
        self.stats.bad_requests.fetch_add(1, Ordering::Relaxed);
    }
}

/// `{"type": kind, field: raw}` around a message that was checked and is valid JSON.
fn wrap(kind: &str, field: &str, raw: &[u8]) -> Option<Utf8Bytes> {
    let raw = std::str::from_utf8(raw).ok()?;
    Some(Utf8Bytes::from(format!(
        "{{\"type\":\"{kind}\",\"{field}\":{raw}}}"
    )))
}

/// A preview as the page reads it: a 4-byte little-endian length, that many bytes of JSON
/// (everything but the pixels), then the pixels.
fn preview_bytes(p: &Preview) -> Bytes {
    let head = serde_json::json!({
        "camera": p.camera,
        "sequence": p.sequence,
        "timestamp_ns": p.timestamp_ns,
        "width_px": p.width_px,
        "height_px": p.height_px,
        "scale": p.scale,
        "preview_width_px": p.preview_width_px,
        "preview_height_px": p.preview_height_px,
        "level_shift": p.level_shift,
        "threshold": p.threshold,
        "dark": p.dark,
        "histogram": p.histogram,
        "blobs": p.blobs,
    })
    .to_string();
    let mut out = Vec::with_capacity(4 + head.len() + p.pixels.len());
    out.extend_from_slice(&(head.len() as u32).to_le_bytes());
    out.extend_from_slice(head.as_bytes());
    out.extend_from_slice(&p.pixels);
    Bytes::from(out)
}

/// Runs until shutdown.
pub fn run(cfg: ViewerConfig, shutdown: Shutdown) -> Result<ViewerSummary, ViewerError> {
    drive(ViewerService::setup(cfg)?, &shutdown)
}

pub struct ViewerService {
    node: ServiceNode,
    shared: Arc<Shared>,
    addr: SocketAddr,
    _subs: Vec<net::NetSubscriber>,
    runtime: Option<tokio::runtime::Runtime>,
    stop: Option<tokio::sync::oneshot::Sender<()>>,
}

impl std::fmt::Debug for ViewerService {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "ViewerService({})", self.addr)
    }
}

impl ViewerService {
    pub fn setup(cfg: ViewerConfig) -> Result<Self, ViewerError> {
        let ctx = &cfg.ctx;
        let spec = stereoscope_rig::settings::ViewerSettings::of_rig(&ctx.rig.spec);
        let addr = match cfg.listen {
            Some(a) => a,
            None => spec
                .listen
                .parse()
                .map_err(|_| ViewerError::Listen(spec.listen.clone()))?,
        };
        let listener = std::net::TcpListener::bind(addr)
            .and_then(|l| l.set_nonblocking(true).map(|()| l))
            .map_err(|source| ViewerError::Bind { addr, source })?;
        let addr = listener
            .local_addr()
            .map_err(|source| ViewerError::Bind { addr, source })?;
        let node = ServiceNode::start(ctx.node_spec("viewer"))?;
        let rig = ctx.rig.name.clone();
        let cameras: Vec<String> = ctx.rig.cameras.iter().map(|c| c.id.clone()).collect();
        let (tx, _) = broadcast::channel(QUEUE);
        let shared = Arc::new(Shared {
            rig: rig.clone(),
            cameras: cameras.clone(),
            rig_json: scene::rig_json(&ctx.rig).to_string(),
            max_clients: spec.max_clients,
            tx,
            previews: Mutex::new(HashMap::new()),
            health: Mutex::new(BTreeMap::new()),
            truth_camera: cameras.first().cloned(),
            rejections: Mutex::new(Vec::new()),
            stats: Stats::default(),
        });
        let subs = subscribe(&node.session, &shared)?;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name("viewer-http")
            .enable_all()
            .build()
            .map_err(ViewerError::Runtime)?;
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let app = router(shared.clone());
        let listener = {
            let _guard = runtime.enter();
            tokio::net::TcpListener::from_std(listener)
                .map_err(|source| ViewerError::Bind { addr, source })?
        };
        runtime.spawn(serve(listener, app, shared.clone(), stopped));
        tracing::info!("live view on http://{addr}/ (rig {rig:?}, cameras {cameras:?})");
        Ok(ViewerService {
            node,
            shared,
            addr,
            _subs: subs,
            runtime: Some(runtime),
            stop: Some(stop),
        })
    }

    /// Where the page is served (tests ask for port 0).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    fn report(&mut self) {
        let s = &self.shared.stats;
        let c = &mut self.node.counters;
        if let Ok(mut r) = self.shared.rejections.lock() {
            for (reason, message) in r.drain(..) {
                c.reject(reason, &message);
            }
        }
        c.processed = s.pose_frames.load(Ordering::Relaxed);
        c.dropped = s.lagged.load(Ordering::Relaxed);
        c.set(Detail::Clients, s.clients.load(Ordering::Relaxed));
        c.set(Detail::Connections, s.connections.load(Ordering::Relaxed));
        c.set(Detail::Refused, s.refused.load(Ordering::Relaxed));
        c.set(Detail::BadRequests, s.bad_requests.load(Ordering::Relaxed));
        c.set(Detail::SentBytes, s.sent_bytes.load(Ordering::Relaxed));
        c.set(Detail::Previews, s.previews.load(Ordering::Relaxed));
        c.set(Detail::Url, format!("http://{}/", self.addr));
    }
}

impl Drop for ViewerService {
    fn drop(&mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
        if let Some(rt) = self.runtime.take() {
            rt.shutdown_timeout(Duration::from_millis(500));
        }
    }
}

impl Service for ViewerService {
    type Summary = ViewerSummary;
    type Error = ViewerError;

    fn node(&mut self) -> &mut ServiceNode {
        &mut self.node
    }

    fn step(&mut self, shutdown: &Shutdown) -> Result<Flow, ViewerError> {
        // The work is on Zenoh's and the web server's threads; this one reports.
        shutdown.sleep(Duration::from_millis(50));
        if self.node.report_due() {
            self.report();
        }
        Ok(Flow::Continue)
    }

    fn summary(&self) -> ViewerSummary {
        ViewerSummary {
            pose_frames: self.shared.stats.pose_frames.load(Ordering::Relaxed),
            connections: self.shared.stats.connections.load(Ordering::Relaxed),
        }
    }
}

/// The Zenoh streams the page shows, each checked (`transport::inlet`) before it is
/// forwarded as the bytes that came.
fn subscribe(
    session: &zenoh::Session,
    shared: &Arc<Shared>,
) -> Result<Vec<net::NetSubscriber>, ViewerError> {
    let rig = shared.rig.clone();
    let mut subs = Vec::new();
    let refused = |s: &Arc<Shared>| {
        let s = s.clone();
        move |r: Refusal| s.reject(r.reason, r.message)
    };
    let s = shared.clone();
    subs.extend(inlet::listen(
        session,
        &[keys::poses(&rig)],
        Admission::<PoseFrame>::new(&rig, "pose frame"),
        move |_, b| {
            if let Some(t) = wrap("poses", "frame", b) {
                s.stats.pose_frames.fetch_add(1, Ordering::Relaxed);
                s.send(Out::Text(t));
            }
        },
        refused(shared),
    )?);
    if let Some(cam) = &shared.truth_camera {
        let s = shared.clone();
        subs.extend(inlet::listen(
            session,
            &[keys::truth(&rig, cam)],
            Admission::<Truth>::new(&rig, "truth"),
            move |_, b| {
                if let Some(t) = wrap("truth", "truth", b) {
                    s.send(Out::Text(t));
                }
            },
            refused(shared),
        )?);
    }
    let s = shared.clone();
    let cameras = shared.cameras.clone();
    subs.extend(inlet::listen(
        session,
        &[keys::all_previews(&rig)],
        Admission::<Preview>::new(&rig, "preview")
            .binary()
            .expecting(move |_, p: &Preview| {
                if cameras.contains(&p.camera) {
                    Ok(())
                } else {
                    Err(format!("of camera {:?}, not one of the rig's", p.camera).into())
                }
            }),
        move |p, _| {
            let bytes = preview_bytes(&p);
            s.stats.previews.fetch_add(1, Ordering::Relaxed);
            if let Ok(mut m) = s.previews.lock() {
                m.insert(p.camera.clone(), bytes.clone());
            }
            s.send(Out::Preview {
                camera: Arc::from(p.camera.as_str()),
                bytes,
            });
        },
        refused(shared),
    )?);
    let s = shared.clone();
    subs.extend(inlet::listen(
        session,
        &[keys::wand_coverage(&rig)],
        Admission::<WandCoverage>::new(&rig, "coverage"),
        move |_, b| {
            if let Some(t) = wrap("coverage", "coverage", b) {
                s.send(Out::Text(t));
            }
        },
        refused(shared),
    )?);
    let s = shared.clone();
    subs.extend(inlet::listen(
        session,
        &[keys::all_health(&rig)],
        Admission::<Health>::new(&rig, "health"),
        move |h, b| {
            if let Some(t) = wrap("health", "health", b) {
                let key = format!("{}/{}", h.host, h.service);
                if let Ok(mut m) = s.health.lock()
                    && (m.len() < MAX_SERVICES || m.contains_key(&key))
                {
                    m.insert(key, t.clone());
                }
                s.send(Out::Text(t));
            }
        },
        refused(shared),
    )?);
    Ok(subs)
}

fn router(shared: Arc<Shared>) -> Router {
    Router::new()
        .route("/", get(index))
        .route("/app.js", get(app_js))
        .route("/api/rig", get(api_rig))
        .route("/api/status", get(api_status))
        .route("/camera/{id}", get(camera_page))
        .route("/ws", get(ws))
        .fallback(not_found)
        .with_state(shared)
}

fn html(body: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, "text/html; charset=utf-8"),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        body,
    )
        .into_response()
}

async fn index() -> Response {
    html(INDEX_HTML)
}

async fn app_js() -> Response {
    (
        [
            (header::CONTENT_TYPE, "text/javascript; charset=utf-8"),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        APP_JS,
    )
        .into_response()
}

fn json(body: String) -> Response {
    ([(header::CONTENT_TYPE, "application/json")], body).into_response()
}

async fn api_rig(State(s): State<Arc<Shared>>) -> Response {
    json(s.rig_json.clone())
}

async fn api_status(State(s): State<Arc<Shared>>) -> Response {
    let items: Vec<String> = s
        .health
        .lock()
        .map(|m| m.values().map(|v| v.as_str().to_string()).collect())
        .unwrap_or_default();
    json(format!("[{}]", items.join(",")))
}

/// The page showing one camera's monitor large; an unknown camera is answered 404, naming
/// the rig's cameras.
async fn camera_page(State(s): State<Arc<Shared>>, Path(id): Path<String>) -> Response {
    if s.cameras.contains(&id) {
        return html(INDEX_HTML);
    }
    s.bad_request();
    let shown: String = id.chars().take(64).collect();
    (
        StatusCode::NOT_FOUND,
        format!(
            "no camera {shown:?} in rig {:?} (cameras: {:?})\n",
            s.rig, s.cameras
        ),
    )
        .into_response()
}

async fn not_found(State(s): State<Arc<Shared>>) -> Response {
    s.bad_request();
    (StatusCode::NOT_FOUND, "not found\n").into_response()
}

/// A browser's place among `max_clients`, given back when its socket closes.
struct Seat(Arc<Shared>);

impl Drop for Seat {
    fn drop(&mut self) {
        self.0.stats.clients.fetch_sub(1, Ordering::Relaxed);
    }
}

async fn ws(State(s): State<Arc<Shared>>, upgrade: WebSocketUpgrade) -> Response {
    let taken = s.stats.clients.fetch_add(1, Ordering::Relaxed);
    let seat = Seat(s.clone());
    if taken >= s.max_clients {
        s.stats.refused.fetch_add(1, Ordering::Relaxed);
        return (
            StatusCode::SERVICE_UNAVAILABLE,
            format!(
                "{} browsers are connected, the most this viewer serves\n",
                taken
            ),
        )
            .into_response();
    }
    s.stats.connections.fetch_add(1, Ordering::Relaxed);
    upgrade
        .max_message_size(MAX_CLIENT_MESSAGE_BYTES)
        .max_frame_size(MAX_CLIENT_MESSAGE_BYTES)
        .on_upgrade(move |socket| client(socket, seat))
}

fn error_text(message: &str) -> WsMessage {
    WsMessage::Text(Utf8Bytes::from(
        serde_json::json!({"type": "error", "message": message}).to_string(),
    ))
}

/// Why a browser's message is not a request (answered to it, and counted).
#[derive(Debug, thiserror::Error)]
pub enum BadRequest {
    #[error("not a JSON request ({0}); send {{\"type\":\"monitor\",\"cameras\":[…]}}")]
    NotJson(#[source] serde_json::Error),
    #[error("\"cameras\" must be a list of camera names")]
    CamerasNotAList,
    #[error("no camera {shown} in rig {rig:?} (cameras: {cameras:?})")]
    UnknownCamera {
        /// The value sent, cut to 64 characters.
        shown: String,
        rig: String,
        cameras: Vec<String>,
    },
    #[error("unknown request type; known: \"monitor\", \"ping\"")]
    UnknownType,
    #[error("binary messages are not requests; send JSON text")]
    Binary,
}

/// What a browser asked for: which cameras' previews to receive (`None`: a ping).
fn request(s: &Shared, text: &str) -> Result<Option<Vec<String>>, BadRequest> {
    let v: serde_json::Value = serde_json::from_str(text).map_err(BadRequest::NotJson)?;
    match v.get("type").and_then(|t| t.as_str()) {
        Some("monitor") => {
            let list = v
                .get("cameras")
                .and_then(|c| c.as_array())
                .ok_or(BadRequest::CamerasNotAList)?;
            let mut out = Vec::new();
            for c in list {
                match c.as_str() {
                    Some(id) if s.cameras.iter().any(|x| x == id) => out.push(id.to_string()),
                    _ => {
                        return Err(BadRequest::UnknownCamera {
                            shown: c.to_string().chars().take(64).collect(),
                            rig: s.rig.clone(),
                            cameras: s.cameras.clone(),
                        });
                    }
                }
            }
            Ok(Some(out))
        }
        Some("ping") => Ok(None),
        _ => Err(BadRequest::UnknownType),
    }
}

async fn client(mut socket: WebSocket, seat: Seat) {
    let s = seat.0.clone();
    let mut rx = s.tx.subscribe();
    let hello = serde_json::json!({
        "type": "hello",
        "rig": s.rig,
        "cameras": s.cameras,
    })
    .to_string();
    let mut first = vec![WsMessage::Text(Utf8Bytes::from(hello))];
    if let Ok(m) = s.health.lock() {
        first.extend(m.values().map(|t| WsMessage::Text(t.clone())));
    }
    if let Ok(m) = s.previews.lock() {
        first.extend(m.values().map(|b| WsMessage::Binary(b.clone())));
    }
    for m in first {
        if socket.send(m).await.is_err() {
            return;
        }
    }
    // Every camera until the page says which it shows.
    let mut monitored: Option<Vec<String>> = None;
    let mut bad = 0u64;
    loop {
        tokio::select! {
            incoming = socket.recv() => {
                // A reply, and whether the request was a bad one.
                let reply = match incoming {
                    None | Some(Err(_)) => break,
                    Some(Ok(WsMessage::Text(t))) => match request(&s, t.as_str()) {
                        Ok(Some(list)) => {
                            monitored = Some(list);
                            None
                        }
                        Ok(None) => Some((
                            WsMessage::Text(Utf8Bytes::from_static("{\"type\":\"pong\"}")),
                            false,
                        )),
                        Err(e) => Some((error_text(&e.to_string()), true)),
                    },
                    Some(Ok(WsMessage::Binary(_))) => {
                        Some((error_text(&BadRequest::Binary.to_string()), true))
                    }
                    Some(Ok(WsMessage::Close(_))) => break,
                    Some(Ok(_)) => None,
                };
                if let Some((r, is_bad)) = reply {
                    if is_bad {
                        bad += 1;
                        s.bad_request();
                        if bad > MAX_BAD_MESSAGES {
                            let _ = socket.send(error_text("too many bad requests; closing")).await;
                            break;
                        }
                    }
                    if socket.send(r).await.is_err() {
                        break;
                    }
                }
            }
            out = rx.recv() => {
                let m = match out {
                    Ok(Out::Text(t)) => WsMessage::Text(t),
                    Ok(Out::Preview { camera, bytes }) => {
                        if monitored.as_ref().is_some_and(|l| !l.iter().any(|c| **c == *camera)) {
                            continue;
                        }
                        WsMessage::Binary(bytes)
                    }
                    Err(broadcast::error::RecvError::Lagged(n)) => {
                        s.stats.lagged.fetch_add(n, Ordering::Relaxed);
                        continue;
                    }
                    Err(broadcast::error::RecvError::Closed) => break,
                };
                let len = match &m {
                    WsMessage::Text(t) => t.len(),
                    WsMessage::Binary(b) => b.len(),
                    _ => 0,
                };
                if socket.send(m).await.is_err() {
                    break;
                }
                s.stats.sent_bytes.fetch_add(len as u64, Ordering::Relaxed);
            }
        }
    }
    drop(seat);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shared() -> Shared {
        let (tx, _) = broadcast::channel(4);
        Shared {
            rig: "lab".into(),
            cameras: vec!["cam0".into(), "cam1".into()],
            rig_json: String::new(),
            max_clients: 2,
            tx,
            previews: Mutex::new(HashMap::new()),
            health: Mutex::new(BTreeMap::new()),
            truth_camera: None,
            rejections: Mutex::new(Vec::new()),
            stats: Stats::default(),
        }
    }

    /// The server closes a connection that sends no complete request head within
    /// [`HEADER_TIMEOUT`] (a request line alone, then nothing), answers one that does, and
    /// closes the connections over [`MAX_CONNECTIONS`] as they come, counting them.
    #[test]
    fn slow_headers_are_cut_off_and_connections_capped() {
        use std::io::{Read, Write};
        let s = Arc::new(shared());
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .unwrap();
        let std_listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        std_listener.set_nonblocking(true).unwrap();
        let addr = std_listener.local_addr().unwrap();
        let listener = {
            let _guard = rt.enter();
            tokio::net::TcpListener::from_std(std_listener).unwrap()
        };
        let (stop, stopped) = tokio::sync::oneshot::channel();
        let app = Router::new().route("/", get(|| async { "here" }));
        rt.spawn(serve(listener, app, s.clone(), stopped));
        // A whole request is answered.
        let mut ok = std::net::TcpStream::connect(addr).unwrap();
        ok.write_all(b"GET / HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
            .unwrap();
        let mut answer = String::new();
        ok.read_to_string(&mut answer).unwrap();
        assert!(
            answer.starts_with("HTTP/1.1 200") && answer.ends_with("here"),
            "{answer}"
        );
        // A request line and nothing more: closed after the timeout, not before.
        let started = std::time::Instant::now();
        let mut slow = std::net::TcpStream::connect(addr).unwrap();
        slow.write_all(b"GET / HTTP/1.1\r\n").unwrap();
        slow.set_read_timeout(Some(HEADER_TIMEOUT * 3)).unwrap();
        let mut buf = [0u8; 512];
        let n = slow.read(&mut buf);
        let waited = started.elapsed();
        assert!(
            n.is_ok() && waited >= HEADER_TIMEOUT && waited < HEADER_TIMEOUT * 3,
            "{n:?} after {waited:?}"
        );
        // Connections beyond the cap are closed as they come, and counted.
        let held: Vec<_> = (0..MAX_CONNECTIONS)
            .map(|_| std::net::TcpStream::connect(addr).unwrap())
            .collect();
        let end = std::time::Instant::now() + Duration::from_secs(10);
        let mut extra = std::net::TcpStream::connect(addr).unwrap();
        extra
            .set_read_timeout(Some(Duration::from_secs(10)))
            .unwrap();
        assert_eq!(extra.read(&mut buf).unwrap_or(0), 0);
        while s.stats.refused.load(Ordering::Relaxed) == 0 {
            assert!(
                std::time::Instant::now() < end,
                "the extra connection was not counted"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        drop(held);
        let _ = stop.send(());
        rt.shutdown_timeout(Duration::from_secs(1));
    }

    /// A browser's requests: a camera list is taken only if every camera is the rig's, and
    /// each wrong request is answered naming what was wrong.
    #[test]
    fn requests_are_checked_and_answered() {
        let s = shared();
        let said = |text: &str| request(&s, text).unwrap_err().to_string();
        assert_eq!(
            request(&s, r#"{"type":"monitor","cameras":["cam1"]}"#).unwrap(),
            Some(vec!["cam1".to_string()])
        );
        assert_eq!(request(&s, r#"{"type":"ping"}"#).unwrap(), None);
        let e = said(r#"{"type":"monitor","cameras":["cam1","cam7"]}"#);
        assert!(e.contains("\"cam7\"") && e.contains("cam0"), "{e}");
        let e = said(r#"{"type":"monitor","cameras":"cam1"}"#);
        assert!(e.contains("cameras"), "{e}");
        assert!(said("{{{").contains("not a JSON request"));
        assert!(said(r#"{"type":"reboot"}"#).contains("unknown"));
        // A long name is shown cut, not echoed whole.
        let long = format!(
            r#"{{"type":"monitor","cameras":["{}"]}}"#,
            "x".repeat(10_000)
        );
        assert!(said(&long).len() < 300);
    }

    /// The preview's binary form: the length, the JSON head (no pixels), the pixels.
    #[test]
    fn a_preview_is_sent_as_length_head_pixels() {
        let p = Preview {
            schema: stereoscope_proto::messages::SCHEMA_VERSION,
            rig: "lab".into(),
            camera: "cam0".into(),
            sequence: 9,
            timestamp_ns: 1,
            width_px: 6,
            height_px: 4,
            scale: 2,
            preview_width_px: 3,
            preview_height_px: 2,
            level_shift: 0,
            threshold: 50,
            dark: false,
            histogram: vec![0; 256],
            pixels: vec![1, 2, 3, 4, 5, 6],
            blobs: Vec::new(),
        };
        let b = preview_bytes(&p);
        let n = u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize;
        let head: serde_json::Value = serde_json::from_slice(&b[4..4 + n]).unwrap();
        assert_eq!(head["camera"], "cam0");
        assert_eq!(head["preview_width_px"], 3);
        assert!(head.get("pixels").is_none());
        assert_eq!(&b[4 + n..], &[1, 2, 3, 4, 5, 6]);
    }
}
