//! What a daemon shows its operator over HTTP, on a listener of its own (`--metrics-listen`):
//! Prometheus text at `/metrics`, `/healthz` (live: the daemon's runtime answers and its service
//! loop runs) and `/readyz` (ready: registered and configured by a coordinator, or serving) —
//! and the same states to systemd (`sd_notify`: `READY=1`, watchdog pings, `STOPPING=1`).
//!
//! The server runs on the daemon's own runtime, so a wedged runtime fails its liveness probe. It
//! reads no request body, answers GET only, and holds at most `MAX_CONNECTIONS` at once, each
//! with a deadline on its request header.

use anyhow::Context;
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use lightfold_telemetry::health;
use metrics_exporter_prometheus::{Matcher, PrometheusBuilder, PrometheusHandle};
use std::io::Write;
use std::net::SocketAddr;
use std::time::Duration;
use tokio_util::sync::CancellationToken;

/// Connections served at once, and from one address; more are closed unread. An idle
/// connection costs a task and a socket: the bound is for descriptors, and the per-address share
/// keeps one neighbour holding slow connections from starving a liveness probe (40 slow-header
/// connections failed 22 of 26 `/healthz` requests under the former 16 in all).
const MAX_CONNECTIONS: usize = 256;
const MAX_PER_ADDRESS: usize = 32;
/// A request's header must arrive within this.
const HEADER_TIMEOUT: Duration = Duration::from_secs(3);
/// A connection is closed after this, whatever it is doing.
const CONNECTION_LIFETIME: Duration = Duration::from_secs(30);
/// Histogram buckets of every `_seconds` metric: 1 ms to 60 s (frames here take 50 ms–2 s on a
/// software rasteriser, a few ms on a GPU).
const BUCKETS: &[f64] = &[
    0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0,
];
/// How often histograms are drained and idle series aged when nobody scrapes.
const UPKEEP_EVERY: Duration = Duration::from_secs(5);

/// Installs the exporter as this process's recorder, labelling every series with `role` and
/// `daemon`. Call once, before the daemon records anything.
pub fn install(role: &str, daemon: &str) -> anyhow::Result<PrometheusHandle> {
    let recorder = PrometheusBuilder::new()
        .add_global_label("role", role)
        .add_global_label("daemon", daemon)
        .set_buckets_for_metric(Matcher::Suffix("_seconds".into()), BUCKETS)
        .context("histogram buckets")?
        .build_recorder();
    let handle = recorder.handle();
    metrics::set_global_recorder(recorder)
        .map_err(|e| anyhow::anyhow!("cannot install the metrics recorder: {e}"))?;
    lightfold_telemetry::record::describe();
    lightfold_telemetry::record::zero_counters(role);
    lightfold_telemetry::record::build_info();
    process_metrics().describe();
    Ok(handle)
}

/// Starts a daemon's operations endpoints on the current runtime: with a `listen` address
/// (`--metrics-listen`), the exporter and the server (printing `metrics <addr>` on stdout once
/// bound); in any case the systemd notifications. Everything stops with `stop`.
pub async fn start(
    listen: Option<&str>,
    role: &str,
    daemon: &str,
    stop: CancellationToken,
) -> anyhow::Result<Option<SocketAddr>> {
    lightfold_telemetry::logging::set_daemon(daemon);
    tokio::spawn(systemd(stop.clone()));
    let Some(listen) = listen else {
        return Ok(None);
    };
    let handle = install(role, daemon)?;
    let listener = tokio::net::TcpListener::bind(listen)
        .await
        .with_context(|| format!("cannot listen for metrics on {listen}"))?;
    let local = listener.local_addr()?;
    {
        let mut out = std::io::stdout().lock();
        writeln!(out, "metrics {local}")?;
        out.flush()?;
    }
    tracing::info!(%local, "serving /metrics, /healthz and /readyz");
    let upkeep = handle.clone();
    let s = stop.clone();
    tokio::spawn(async move {
        loop {
            tokio::select! {
                _ = s.cancelled() => return,
                _ = tokio::time::sleep(UPKEEP_EVERY) => upkeep.run_upkeep(),
            }
        }
    });
    tokio::spawn(serve(listener, handle, stop));
    Ok(Some(local))
}

/// Tells systemd (when it started us with `NOTIFY_SOCKET`) that the daemon is ready once its
/// service loop runs and pings the watchdog at half its period from this runtime (`STOPPING=1`
/// comes from `notify_stopping`). Without systemd every call is a no-op.
async fn systemd(stop: CancellationToken) {
    if std::env::var_os("NOTIFY_SOCKET").is_none() {
        return;
    }
    while !health::is_live() {
        tokio::select! {
            _ = stop.cancelled() => return,
            _ = tokio::time::sleep(Duration::from_millis(100)) => {}
        }
    }
    if let Err(e) = sd_notify::notify(&[sd_notify::NotifyState::Ready]) {
        tracing::warn!("cannot tell systemd the daemon is ready: {e}");
    }
    let period = sd_notify::watchdog_enabled().map(|d| (d / 2).max(Duration::from_millis(100)));
    loop {
        let tick = async {
            match period {
                Some(p) => tokio::time::sleep(p).await,
                None => std::future::pending().await,
            }
        };
        tokio::select! {
            _ = stop.cancelled() => break,
            _ = tick => {
                let _ = sd_notify::notify(&[sd_notify::NotifyState::Watchdog]);
            }
        }
    }
}

/// Tells systemd the daemon is stopping (`STOPPING=1`): called where the stop is decided, since
/// the runtime may drop its tasks before they run again. A no-op without systemd.
pub fn notify_stopping() {
    if std::env::var_os("NOTIFY_SOCKET").is_some() {
        let _ = sd_notify::notify(&[sd_notify::NotifyState::Stopping]);
    }
}

/// Accepts scrapes until `stop` (the view's HTTP accept loop, with the limits above).
pub async fn serve(
    listener: tokio::net::TcpListener,
    handle: PrometheusHandle,
    stop: CancellationToken,
) {
    let limits = crate::HttpLimits {
        connections: MAX_CONNECTIONS,
        per_address: MAX_PER_ADDRESS,
        header_timeout: HEADER_TIMEOUT,
        lifetime: Some(CONNECTION_LIFETIME),
    };
    crate::serve_router(listener, router(handle), None, limits, stop, "metrics").await;
}

fn router(handle: PrometheusHandle) -> axum::Router {
    axum::Router::new()
        .route(
            "/metrics",
            get(move || {
                let handle = handle.clone();
                async move { metrics_text(&handle) }
            }),
        )
        .route("/healthz", get(|| async { healthz() }))
        .route("/readyz", get(|| async { readyz() }))
}

/// The standard `process_*` series (CPU seconds, resident and virtual memory, open and maximum
/// file descriptors, threads, start time), read from `/proc` at each scrape.
fn process_metrics() -> &'static metrics_process::Collector {
    static COLLECTOR: std::sync::OnceLock<metrics_process::Collector> = std::sync::OnceLock::new();
    COLLECTOR.get_or_init(metrics_process::Collector::default)
}

fn metrics_text(handle: &PrometheusHandle) -> Response {
    process_metrics().collect();
    lightfold_telemetry::record::peak_rss_bytes(lightfold_telemetry::process::peak_rss_bytes());
    lightfold_telemetry::record::ready(health::readiness().ready);
    (
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        handle.render(),
    )
        .into_response()
}

fn healthz() -> Response {
    if health::is_live() {
        (StatusCode::OK, "ok\n").into_response()
    } else {
        (StatusCode::SERVICE_UNAVAILABLE, "starting\n").into_response()
    }
}

fn readyz() -> Response {
    let r = health::readiness();
    let code = if r.ready {
        StatusCode::OK
    } else {
        StatusCode::SERVICE_UNAVAILABLE
    };
    (code, format!("{}\n", r.why)).into_response()
}
