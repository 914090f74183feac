//! The HTTP side (plain, or TLS): the page (embedded), the newest frame as JPEG, PNG and EXR
//! (to viewers allowed to see it: `refused_frames`), and the WebSocket.

use crate::access::Access;
use crate::hub::{Hub, MAX_VIEWERS};
use axum::extract::ws::WebSocketUpgrade;
use axum::extract::{ConnectInfo, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use bytes::Bytes;
use hyper::body::Incoming;
use hyper_util::rt::{TokioExecutor, TokioIo, TokioTimer};
use hyper_util::server::conn::auto::Builder;
use hyper_util::service::TowerToHyperService;
use lightfold_scene::Image;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration;
use tokio_util::sync::CancellationToken;
use tower::Service;

const INDEX: &str = include_str!("../static/index.html");
const APP: &str = include_str!("../static/app.js");
const STYLE: &str = include_str!("../static/style.css");
/// Largest message a page may send (steering messages are a few hundred bytes).
pub(crate) const MAX_MESSAGE: usize = 16 << 10;

/// Connections served at once (page loads, frame downloads, WebSocket handshakes), and from one
/// address; more are closed unread. Upgraded WebSockets count against `MAX_VIEWERS` instead. An
/// idle connection costs a task and a socket; the per-address share keeps one peer holding slow
/// connections from starving the others (128 of them failed 22 of 24 requests under the former
/// 128 in all).
pub(crate) const MAX_CONNECTIONS: usize = 512;
pub(crate) const MAX_PER_ADDRESS: usize = 64;
/// A request's header must arrive within this (a peer that trickles bytes is closed).
pub(crate) const HEADER_TIMEOUT: Duration = Duration::from_secs(5);
/// How long open requests get to finish when the view stops.
const DRAIN: Duration = Duration::from_secs(2);

/// Serves the view until it stops ([`serve_router`] with the view's limits: at most
/// `MAX_CONNECTIONS` at once, each with a deadline on its request header and, over TLS, on its
/// handshake).
pub(crate) async fn serve(
    listener: tokio::net::TcpListener,
    tls: Option<tokio_rustls::TlsAcceptor>,
    hub: Arc<Hub>,
) {
    let stop = hub.stop.clone();
    let app = axum::Router::new()
        .route(
            "/",
            get(|| async { page(INDEX, "text/html; charset=utf-8") }),
        )
        .route(
            "/app.js",
            get(|| async { page(APP, "text/javascript; charset=utf-8") }),
        )
        .route(
            "/style.css",
            get(|| async { page(STYLE, "text/css; charset=utf-8") }),
        )
        .route("/frame.jpg", get(jpeg))
        .route("/frame.png", get(png))
        .route("/frame.exr", get(exr))
        .route("/scene.toml", get(scene_file))
        .route("/ws", get(websocket))
        .with_state(hub);
    let limits = HttpLimits {
        connections: MAX_CONNECTIONS,
        per_address: MAX_PER_ADDRESS,
        header_timeout: HEADER_TIMEOUT,
        lifetime: None,
    };
    serve_router(listener, app, tls, limits, stop, "the view").await;
}

/// What an HTTP listener allows its connections.
#[derive(Debug, Clone, Copy)]
pub struct HttpLimits {
    /// Connections served at once; more are closed unread.
    pub connections: usize,
    /// Connections served at once from one address.
    pub per_address: usize,
    /// A request's header (and, over TLS, the handshake) must arrive within this.
    pub header_timeout: Duration,
    /// A connection is closed after this, whatever it is doing (`None`: when it ends).
    pub lifetime: Option<Duration>,
}

/// The one HTTP accept loop (the live view, every daemon's `/metrics`): connections admitted by a
/// gate of `limits`, each on a task of its own with hyper's header deadline (with a timer:
/// `axum::serve` sets none), over TLS when `tls` is given, the peer's address as `ConnectInfo`;
/// until `stop`, when open requests get [`DRAIN`] to finish. `what` names the listener in logs.
pub async fn serve_router(
    listener: tokio::net::TcpListener,
    app: axum::Router,
    tls: Option<tokio_rustls::TlsAcceptor>,
    limits: HttpLimits,
    stop: CancellationToken,
    what: &'static str,
) {
    let gate = lightfold_net::gate::Gate::new(limits.connections, limits.per_address);
    while let Some((stream, peer, permit)) = gate.next_admitted(&listener, &stop, what).await {
        let app = app.clone();
        let stop = stop.clone();
        let tls = tls.clone();
        tokio::spawn(async move {
            let _permit = permit;
            let served = async {
                match tls {
                    None => connection(stream, peer, app, limits, stop, what).await,
                    Some(tls) => {
                        // A peer speaking plain HTTP, or no TLS at all, fails here and is closed.
                        let handshake = tokio::select! {
                            r = tokio::time::timeout(limits.header_timeout, tls.accept(stream)) => r,
                            _ = stop.cancelled() => return,
                        };
                        match handshake {
                            Ok(Ok(stream)) => {
                                connection(stream, peer, app, limits, stop, what).await
                            }
                            Ok(Err(e)) => {
                                tracing::debug!(%peer, "{what}: TLS handshake failed: {e}")
                            }
                            Err(_) => tracing::debug!(%peer, "{what}: TLS handshake timed out"),
                        }
                    }
                }
            };
            match limits.lifetime {
                None => served.await,
                Some(lifetime) => {
                    if tokio::time::timeout(lifetime, served).await.is_err() {
                        tracing::debug!(%peer, "{what}: connection closed after {lifetime:?}");
                    }
                }
            }
        });
    }
}

/// Serves one connection (plain or TLS) until it ends or the listener stops.
async fn connection<S>(
    stream: S,
    peer: SocketAddr,
    app: axum::Router,
    limits: HttpLimits,
    stop: CancellationToken,
    what: &str,
) where
    S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send + 'static,
{
    let service = tower::service_fn(move |mut req: axum::extract::Request<Incoming>| {
        req.extensions_mut().insert(ConnectInfo(peer));
        let mut app = app.clone();
        async move { app.call(req.map(axum::body::Body::new)).await }
    });
    let mut builder = Builder::new(TokioExecutor::new());
    builder
        .http1()
        .timer(TokioTimer::new())
        .header_read_timeout(limits.header_timeout);
    let conn = builder
        .serve_connection_with_upgrades(TokioIo::new(stream), TowerToHyperService::new(service));
    tokio::pin!(conn);
    tokio::select! {
        r = conn.as_mut() => if let Err(e) = r {
            tracing::debug!(%peer, "{what}: connection ended: {e}");
        },
        _ = stop.cancelled() => {
            conn.as_mut().graceful_shutdown();
            let _ = tokio::time::timeout(DRAIN, conn).await;
        }
    }
}

/// `None` when a frame may go to `peer` (on loopback, with `--public-watch`, or to a request that
/// carries the token as `Authorization: Bearer TOKEN`, over TLS or with `--allow-plain-token`);
/// else the answer to send instead (401, or 403 for a token sent over plain HTTP).
fn refused_frames(hub: &Hub, peer: SocketAddr, headers: &HeaderMap) -> Option<Response> {
    let presented = headers.get(header::AUTHORIZATION).map(|h| {
        let h = h.to_str().unwrap_or("");
        match h.split_once(' ') {
            Some((scheme, token)) if scheme.eq_ignore_ascii_case("bearer") => Some(token.trim()),
            _ => None,
        }
    });
    let Some(presented) = presented else {
        return match hub.access_of(peer) {
            Access::Steer | Access::Watch => None,
            Access::Locked => Some(unauthorized(
                "this view shows its frames only to viewers who present the token: send it as \
                 `Authorization: Bearer TOKEN`, or open the page and enter it there",
            )),
        };
    };
    if crate::access::on_loopback(peer) {
        return None;
    }
    if let Some(why) = hub.token_refused(peer) {
        return Some((StatusCode::FORBIDDEN, why).into_response());
    }
    match presented {
        Some(t) if hub.token_matches(t) => None,
        Some(_) => Some(unauthorized("wrong token")),
        None => Some(unauthorized(
            "the view takes the token as `Authorization: Bearer TOKEN`",
        )),
    }
}

fn unauthorized(text: &'static str) -> Response {
    (
        StatusCode::UNAUTHORIZED,
        [(header::WWW_AUTHENTICATE, "Bearer realm=\"lightfold view\"")],
        text,
    )
        .into_response()
}

fn page(body: &'static str, kind: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, kind),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        body,
    )
        .into_response()
}

fn no_frame() -> Response {
    (StatusCode::SERVICE_UNAVAILABLE, "no frame yet").into_response()
}

async fn jpeg(
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
    State(hub): State<Arc<Hub>>,
) -> Response {
    if let Some(r) = refused_frames(&hub, peer, &headers) {
        return r;
    }
    let frame = hub.frames.borrow().clone();
    match frame {
        Some(f) => (
            [
                (header::CONTENT_TYPE, "image/jpeg"),
                (header::CACHE_CONTROL, "no-store"),
            ],
            f.jpeg.clone(),
        )
            .into_response(),
        None => no_frame(),
    }
}

/// The newest frame's linear image for a download, or the answer that refuses it (no token,
/// no frame yet).
fn newest_image(
    hub: &Hub,
    peer: SocketAddr,
    headers: &HeaderMap,
) -> Result<Arc<lightfold_scene::Image>, Box<Response>> {
    if let Some(r) = refused_frames(hub, peer, headers) {
        return Err(Box::new(r));
    }
    let image = hub.image.lock().unwrap_or_else(|e| e.into_inner()).clone();
    image.ok_or_else(|| Box::new(no_frame()))
}

async fn exr(
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
    State(hub): State<Arc<Hub>>,
) -> Response {
    let image = match newest_image(&hub, peer, &headers) {
        Ok(image) => image,
        Err(r) => return *r,
    };
    let encoded = once_per_frame(&hub.exr, image, (), |i| Ok(i.exr_bytes()?)).await;
    download(encoded, "image/x-exr", "frame.exr")
}

/// The newest frame as a PNG: 8-bit sRGB at the exposure the view encodes frames at now.
async fn png(
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
    State(hub): State<Arc<Hub>>,
) -> Response {
    let image = match newest_image(&hub, peer, &headers) {
        Ok(image) => image,
        Err(r) => return *r,
    };
    let stops = *hub.exposure.borrow();
    let encoded = once_per_frame(&hub.png, image, stops.to_bits(), move |i| {
        crate::encode::png(i, stops)
    })
    .await;
    download(encoded, "image/png", "frame.png")
}

/// The session as a scene file (`crate::save`): its base, with the camera, exposure and lights
/// as the viewers left them. Shown to whom the frames are.
async fn scene_file(
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
    State(hub): State<Arc<Hub>>,
) -> Response {
    if let Some(r) = refused_frames(&hub, peer, &headers) {
        return r;
    }
    let info = Arc::clone(&hub.scene.borrow());
    let base = match &info.save_base {
        Ok(b) => b,
        Err(why) => {
            return (
                StatusCode::CONFLICT,
                format!("this session cannot be saved: {why}"),
            )
                .into_response();
        }
    };
    let steer = hub.steer.borrow().clone();
    let stops = *hub.exposure.borrow();
    match crate::save::session_toml(&info.skeleton, &steer, stops, base) {
        Ok(text) => (
            [
                (
                    header::CONTENT_TYPE,
                    "application/toml; charset=utf-8".to_string(),
                ),
                (header::CACHE_CONTROL, "no-store".to_string()),
                (
                    header::CONTENT_DISPOSITION,
                    "attachment; filename=\"session.toml\"".to_string(),
                ),
            ],
            text,
        )
            .into_response(),
        Err(why) => (
            StatusCode::CONFLICT,
            format!("this session cannot be saved: {why}"),
        )
            .into_response(),
    }
}

/// `image` encoded by `encode`: once per frame and `key`, however many download it at once
/// (they wait for it here and share its bytes).
async fn once_per_frame<K: PartialEq>(
    cache: &tokio::sync::Mutex<Option<(Arc<Image>, K, Bytes)>>,
    image: Arc<Image>,
    key: K,
    encode: impl FnOnce(&Image) -> anyhow::Result<Vec<u8>> + Send + 'static,
) -> Result<Bytes, String> {
    let mut cache = cache.lock().await;
    if let Some((_, _, b)) = cache
        .as_ref()
        .filter(|(of, k, _)| Arc::ptr_eq(of, &image) && *k == key)
    {
        return Ok(b.clone());
    }
    let of = Arc::clone(&image);
    let bytes = tokio::task::spawn_blocking(move || encode(&of).map(Bytes::from))
        .await
        .map_err(|e| e.to_string())?
        .map_err(|e| e.to_string())?;
    *cache = Some((image, key, bytes.clone()));
    Ok(bytes)
}

fn download(encoded: Result<Bytes, String>, kind: &'static str, name: &str) -> Response {
    match encoded {
        Ok(bytes) => (
            [
                (header::CONTENT_TYPE, kind.to_string()),
                (header::CACHE_CONTROL, "no-store".to_string()),
                (
                    header::CONTENT_DISPOSITION,
                    format!("attachment; filename=\"{name}\""),
                ),
            ],
            bytes,
        )
            .into_response(),
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, e).into_response(),
    }
}

async fn websocket(
    ws: WebSocketUpgrade,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    State(hub): State<Arc<Hub>>,
) -> Response {
    if hub.viewers.load(Ordering::Relaxed) >= MAX_VIEWERS {
        return (
            StatusCode::SERVICE_UNAVAILABLE,
            format!("{MAX_VIEWERS} viewers are watching already"),
        )
            .into_response();
    }
    ws.max_message_size(MAX_MESSAGE)
        .max_frame_size(MAX_MESSAGE)
        .on_upgrade(move |socket| crate::ws::serve(socket, hub, peer))
}
