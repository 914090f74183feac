//! The HTTP side: the page (embedded), the newest frame as JPEG and EXR, and the WebSocket.

use crate::hub::{Hub, MAX_VIEWERS};
use axum::extract::ws::WebSocketUpgrade;
use axum::extract::{ConnectInfo, State};
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::Ordering;

const INDEX: &str = include_str!("../static/index.html");
const APP: &str = include_str!("../static/app.js");
const STYLE: &str = include_str!("../static/style.css");
/// Largest message a page may send (steering messages are a few hundred bytes).
pub const MAX_MESSAGE: usize = 16 << 10;

pub async fn serve(listener: tokio::net::TcpListener, hub: Arc<Hub>) {
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
        .route("/frame.exr", get(exr))
        .route("/ws", get(websocket))
        .with_state(hub);
    let served = axum::serve(
        listener,
        app.into_make_service_with_connect_info::<SocketAddr>(),
    )
    .with_graceful_shutdown(async move { stop.cancelled().await })
    .await;
    if let Err(e) = served {
        tracing::error!("the view's HTTP server stopped: {e}");
    }
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

async fn jpeg(State(hub): State<Arc<Hub>>) -> Response {
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

async fn exr(State(hub): State<Arc<Hub>>) -> Response {
    let image = hub.image.lock().unwrap_or_else(|e| e.into_inner()).clone();
    let Some(image) = image else {
        return no_frame();
    };
    match tokio::task::spawn_blocking(move || image.exr_bytes()).await {
        Ok(Ok(bytes)) => (
            [
                (header::CONTENT_TYPE, "image/x-exr"),
                (header::CACHE_CONTROL, "no-store"),
                (
                    header::CONTENT_DISPOSITION,
                    "attachment; filename=\"frame.exr\"",
                ),
            ],
            bytes,
        )
            .into_response(),
        Ok(Err(e)) => (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()).into_response(),
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()).into_response(),
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
