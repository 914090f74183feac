//! The live view (`docs/live-view.md`): an HTTP server on the coordinator's runtime that serves a
//! web page showing the newest frame as frames complete, and lets the people watching steer the
//! cluster — the camera of the next frame requested, the lights' colours and powers (the
//! compositors' per-frame `c_n`, with no node re-rendering), the scene's clock, and the exposure
//! frames are encoded at (applied by the view itself) — while it shows per-daemon timings,
//! the plan as a graph and the cluster's state (re-planning, degraded, who was lost).
//!
//! The view drives the coordinator's event loop (`control::Live`) itself: frame requests come from
//! the steering state, one at a time as room frees up (so a change reaches the next frame
//! requested), and only when something changed unless `continuous`; while nothing changes it
//! refines the frame step by step (`refine`), when asked to. Frames are encoded off the
//! loop; every viewer gets the newest frame when it can take one, so a slow viewer drops frames
//! and never slows the cluster.
//!
//! Security (`docs/live-view.md` § Access): a viewer connecting from loopback may steer; any
//! other sees nothing but the page until it presents the token (`ViewOptions::token`, the
//! cluster's or a separate viewer token), unless the view was started with `public_watch`, when it
//! watches (frames and status, daemon addresses removed). The view serves HTTPS and WSS when given
//! a certificate and key (`ViewOptions::tls`); without TLS the token is taken from beyond loopback
//! only with `allow_plain_token`.

mod access;
mod camera;
mod clock;
mod edit;
mod encode;
mod feed;
mod http;
mod hub;
mod json;
pub mod metrics;
mod objects;
mod open;
mod refine;
mod save;
mod tls;
mod ws;

pub use camera::{Steer, SteerError};
pub use clock::{Clock, MAX_SPEED, MIN_SPEED, clip_time};
pub use encode::{MAX_STOPS, MIN_STOPS};
pub use http::{HttpLimits, serve_router};
pub use hub::{MAX_VIEWERS, MAX_WATCHERS, ViewCounters};
pub use open::{MAX_LISTED, Opened, Opener, SceneCatalog};
pub use refine::{DEFAULT_MAX_SAMPLES, DEFAULT_SAMPLES_FACTOR, Ladder, RefineOptions, Step};

use lightfold_coordinator::control::{FrameResult, Live, LiveSummary, Session};
use lightfold_coordinator::plan::PlanOptions;
use lightfold_coordinator::run::RunOutcome;
use lightfold_scene::Scene;
use std::net::SocketAddr;
use std::sync::Arc;
use tokio_util::sync::CancellationToken;

/// How the view is served. Its `Debug` says whether there is a token, never the token.
#[derive(Clone)]
pub struct ViewOptions {
    /// Address to listen on (`127.0.0.1:8080` by default: loopback only).
    pub listen: String,
    /// Token a viewer beyond loopback must present to steer (its bytes, as typed in the page or
    /// held in a token file); `None`: such viewers only watch.
    pub token: Option<Vec<u8>>,
    /// Render frame after frame even when nothing changed (else only after a change).
    pub continuous: bool,
    /// Refine while no viewer changes anything: more samples per area light, then antialiasing,
    /// a frame a step (`None`: off, the default here; the command line's `--refine-after` is on
    /// by default).
    pub refine: Option<RefineOptions>,
    /// JPEG quality of the frames pushed to viewers (1–100).
    pub jpeg_quality: u8,
    /// Kernel send buffer of each viewer's socket, bytes: small, so that a slow viewer's queue
    /// holds a frame or two, not seconds of them (it gets the newest frame when it catches up).
    pub send_buffer: u32,
    /// A viewer that takes longer than this to take one message is dropped.
    pub send_timeout: std::time::Duration,
    /// Viewers beyond loopback without the token watch (frames and status, with daemon
    /// addresses removed); else they get the page and nothing more until they present it.
    pub public_watch: bool,
    /// Serve HTTPS and WSS with this certificate chain and key (PEM files).
    pub tls: Option<TlsFiles>,
    /// Without TLS, accept the token from beyond loopback anyway (it crosses the network
    /// readable); else it is refused there, so it is only ever sent over TLS or on loopback.
    pub allow_plain_token: bool,
    /// How the session's scene was named (a built-in, or a file's path): what a saved session
    /// (`/scene.toml`) names as its base. `None`: the view cannot save the session.
    pub scene_source: Option<String>,
    /// The scenes a viewer may open from the page (`None`: only the session's).
    pub scenes: Option<Arc<SceneCatalog>>,
}

impl std::fmt::Debug for ViewOptions {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ViewOptions")
            .field("listen", &self.listen)
            .field("token", &self.token.as_ref().map(|_| "<set>"))
            .field("continuous", &self.continuous)
            .field("refine", &self.refine)
            .field("jpeg_quality", &self.jpeg_quality)
            .field("send_buffer", &self.send_buffer)
            .field("send_timeout", &self.send_timeout)
            .field("public_watch", &self.public_watch)
            .field("tls", &self.tls)
            .field("allow_plain_token", &self.allow_plain_token)
            .field("scene_source", &self.scene_source)
            .field("scenes", &self.scenes)
            .finish()
    }
}

/// A certificate chain and its private key, PEM files (`--tls-cert`, `--tls-key`).
#[derive(Debug, Clone)]
pub struct TlsFiles {
    pub cert: std::path::PathBuf,
    pub key: std::path::PathBuf,
}

impl Default for ViewOptions {
    fn default() -> Self {
        ViewOptions {
            listen: DEFAULT_LISTEN.to_string(),
            token: None,
            continuous: false,
            refine: None,
            jpeg_quality: 85,
            send_buffer: 256 << 10,
            send_timeout: std::time::Duration::from_secs(10),
            public_watch: false,
            tls: None,
            allow_plain_token: false,
            scene_source: None,
            scenes: None,
        }
    }
}

/// Whether the view can serve TLS with `files` (a clear error if not: unreadable, not PEM, or a
/// key that is not the certificate's).
pub fn check_tls(files: &TlsFiles) -> anyhow::Result<()> {
    tls::acceptor(files).map(drop)
}

/// Where the view listens unless told otherwise.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:8080";
/// How long viewers get to receive why the session ended before the view stops serving.
const ENDED_GRACE: std::time::Duration = std::time::Duration::from_millis(500);

/// A bound view server, ready to drive a session.
pub struct View {
    listener: tokio::net::TcpListener,
    tls: Option<tokio_rustls::TlsAcceptor>,
    addr: SocketAddr,
    opts: ViewOptions,
    counters: Arc<ViewCounters>,
}

impl std::fmt::Debug for View {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("View")
            .field("addr", &self.addr)
            .field("tls", &self.tls.is_some())
            .finish_non_exhaustive()
    }
}

impl View {
    /// Binds the HTTP listener (after loading the TLS certificate and key, if given: a file
    /// that cannot be read, holds no certificate or key, or a key that is not the certificate's
    /// is an error here, before anything listens).
    pub async fn bind(opts: ViewOptions) -> anyhow::Result<View> {
        use anyhow::Context;
        let tls = opts.tls.as_ref().map(tls::acceptor).transpose()?;
        let addr: SocketAddr = tokio::net::lookup_host(&opts.listen)
            .await
            .with_context(|| format!("cannot resolve the view's address {}", opts.listen))?
            .next()
            .with_context(|| format!("{} names no address", opts.listen))?;
        let socket = if addr.is_ipv4() {
            tokio::net::TcpSocket::new_v4()?
        } else {
            tokio::net::TcpSocket::new_v6()?
        };
        socket.set_reuseaddr(true)?;
        // Accepted sockets inherit it.
        socket.set_send_buffer_size(opts.send_buffer.max(4096))?;
        socket
            .bind(addr)
            .with_context(|| format!("cannot listen for the view on {}", opts.listen))?;
        let listener = socket.listen(128)?;
        let addr = listener.local_addr()?;
        Ok(View {
            listener,
            tls,
            addr,
            opts,
            counters: Arc::default(),
        })
    }

    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// Whether the view serves HTTPS and WSS.
    pub fn is_tls(&self) -> bool {
        self.tls.is_some()
    }

    /// Where the view is and who may do what there, as its one line on start-up: the address,
    /// and beyond loopback what a viewer must present and how (`docs/live-view.md` § Access).
    pub fn address_line(&self) -> String {
        let addr = self.addr;
        let scheme = if self.is_tls() { "https" } else { "http" };
        if addr.ip().is_loopback() {
            return format!("view: {scheme}://{addr}/");
        }
        let who = if self.opts.public_watch {
            "viewers beyond loopback watch (no daemon addresses); to steer they present"
        } else {
            "viewers beyond loopback see nothing until they present"
        };
        let how = if self.is_tls() || self.opts.allow_plain_token {
            format!(
                "in the page or as {scheme}://HOST:{}/#token=TOKEN",
                addr.port()
            )
        } else {
            "which plain HTTP does not take from them: give --tls-cert and --tls-key".into()
        };
        format!("view: {scheme}://{addr}/ ({who} the token, {how})")
    }

    /// What serving the view has cost so far (encoding time, bytes sent, frames dropped).
    pub fn counters(&self) -> Arc<ViewCounters> {
        Arc::clone(&self.counters)
    }

    /// Serves the page and drives the session's event loop until `stop` is cancelled (the
    /// frames in flight are then finished) or the loop fails.
    pub async fn run(
        self,
        session: &mut Session,
        scene: &Scene,
        plan: &PlanOptions,
        stop: CancellationToken,
    ) -> RunOutcome {
        self.run_with(session, scene, plan, stop, |_| {}).await
    }

    /// As `run`, handing every finished frame to `on_frame` as well (in order, once).
    pub async fn run_with(
        self,
        session: &mut Session,
        scene: &Scene,
        plan: &PlanOptions,
        stop: CancellationToken,
        mut on_frame: impl FnMut(FrameResult),
    ) -> RunOutcome {
        let in_flight = session.opts.frames_in_flight.max(1) as u64;
        // Addresses a viewer without the token must not see (`access::Addresses::redact`).
        let addresses = access::Addresses::new(
            session
                .daemons
                .values()
                .map(|d| d.address.as_str())
                .chain(session.unreachable.iter().map(|(a, _)| a.as_str()))
                .chain(std::iter::once(session.sink_address.as_str())),
        );
        let mut live = match Live::new(session, scene, plan) {
            Ok(l) => l,
            Err(e) => {
                return RunOutcome {
                    summary: LiveSummary::default(),
                    error: Some(e),
                };
            }
        };
        // Daemons whose links end once the view is told to stop are stopping with it, not lost.
        live.stop_on(stop.clone());
        let serving = CancellationToken::new();
        let mut hub = hub::Hub::new(
            scene,
            &self.opts,
            self.counters,
            live.observe(),
            serving.clone(),
        );
        hub.tls = self.tls.is_some();
        hub.refine = self
            .opts
            .refine
            .map(|o| refine::Ladder::new(scene, plan.supersample, &o))
            .filter(|l| l.top() > 0);
        hub.addresses = addresses;
        let hub = Arc::new(hub);
        let server = tokio::spawn(http::serve(self.listener, self.tls, Arc::clone(&hub)));
        let relay = tokio::spawn(Arc::clone(&hub).relay_status());
        let (tx, rx) = tokio::sync::mpsc::channel(1);
        let feeder = tokio::spawn(feed::run(Arc::clone(&hub), tx, in_flight, stop));
        let mut encoder = encode::Encoder::start(Arc::clone(&hub));
        let error = live
            .run(rx, |f| {
                hub.delivered(f.frame);
                encoder.send(&f);
                on_frame(f);
            })
            .await
            .err();
        feeder.abort();
        encoder.finish();
        // Every viewer is told why before the page loses its connection.
        let why = match &error {
            Some(e) => format!("the session ended: {e}"),
            None => "the session ended: the coordinator was stopped".to_string(),
        };
        hub.ended.send_replace(Some(why));
        tokio::time::sleep(ENDED_GRACE).await;
        serving.cancel();
        let _ = server.await;
        let _ = relay.await;
        RunOutcome {
            summary: std::mem::take(&mut live.summary),
            error,
        }
    }
}

#[cfg(test)]
mod options_tests {
    use super::ViewOptions;

    #[test]
    fn debug_never_prints_the_token() {
        let opts = ViewOptions {
            token: Some(b"s3cret-token".to_vec()),
            ..ViewOptions::default()
        };
        let text = format!("{opts:?}");
        assert!(!text.contains("s3cret"), "{text}");
        // Control: the token's bytes as the derived Debug would print them are absent too, and
        // the field still says a token is set.
        assert!(!text.contains("115, 51"), "{text}");
        assert!(text.contains("token: Some(\"<set>\")"), "{text}");
    }
}
