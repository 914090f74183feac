//! What the view's tasks share: the steering state, the newest encoded frame, the cluster status
//! as the page shows it, and counters of what serving costs.

use crate::ViewOptions;
use crate::access::Access;
use crate::camera::Steer;
use bytes::Bytes;
use lightfold_coordinator::control::LiveStatus;
use lightfold_scene::{Image, Scene};
use sha2::{Digest, Sha256};
use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;
use tokio::sync::{Notify, watch};
use tokio_util::sync::CancellationToken;

/// Viewers served at once; more are refused (503).
pub const MAX_VIEWERS: usize = 64;
/// Of those, viewers that only watch (beyond loopback, no token presented): the rest are kept for
/// viewers who steer, so watchers cannot fill the view and lock its operator out (64 watch-only
/// viewers used to take every slot).
pub const MAX_WATCHERS: usize = 48;

/// Why the token is refused over plain HTTP from beyond loopback.
pub(crate) const PLAIN_TOKEN_REFUSED: &str = "this view is served over plain HTTP, so the token is not \
     accepted from beyond loopback (it would cross the network readable): serve the view over \
     HTTPS (--tls-cert, --tls-key), open it on the coordinator's machine (loopback), or start it \
     with --allow-plain-token";

/// What serving the view has cost, for the figures in `docs/live-view.md`.
#[derive(Debug, Default)]
pub struct ViewCounters {
    /// Frames the loop delivered, and those encoded for the view (the encoder skips frames
    /// when it falls behind).
    pub frames_delivered: AtomicU64,
    pub frames_encoded: AtomicU64,
    /// Time spent converting and encoding frames, microseconds: wall-clock, and CPU time of the
    /// encoding thread (Linux; 0 elsewhere) — on a machine the cluster keeps busy the two differ.
    pub encode_us: AtomicU64,
    pub encode_cpu_us: AtomicU64,
    /// JPEG bytes encoded.
    pub jpeg_bytes: AtomicU64,
    /// Frame messages sent to viewers, their bytes, and frames a viewer skipped because a newer
    /// one was ready before it could take the older.
    pub frames_sent: AtomicU64,
    pub bytes_sent: AtomicU64,
    pub frames_skipped: AtomicU64,
    /// Viewers dropped because a send did not finish within the deadline.
    pub viewers_dropped: AtomicU64,
}

/// What a frame was requested at: the steering revision, the clip time of an animated scene,
/// and the refinement step (`None`: the session's quality).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Requested {
    pub revision: u64,
    pub time: Option<f32>,
    pub refine: Option<crate::refine::Step>,
}

/// One encoded frame, ready to send: the binary WebSocket message and its JPEG part.
#[derive(Debug)]
pub(crate) struct ViewFrame {
    pub frame: u64,
    pub message: Bytes,
    pub jpeg: Bytes,
}

#[derive(Debug)]
pub(crate) struct Hub {
    pub started: Instant,
    pub continuous: bool,
    /// Refinement when idle (`None`: off).
    pub refine: Option<crate::refine::Ladder>,
    pub jpeg_quality: u8,
    pub send_timeout: std::time::Duration,
    /// The scene frames show now (a viewer may open another: `crate::open`).
    pub scene: watch::Sender<Arc<crate::open::SceneInfo>>,
    /// The scenes viewers may open (`None`: none but the session's).
    pub catalog: Option<Arc<crate::open::SceneCatalog>>,
    /// A scene is being loaded; the scene and steering before the last one opened (what a
    /// scene the loop refuses goes back to); the next scene's id.
    pub opening: AtomicBool,
    previous: Mutex<Option<(Arc<crate::open::SceneInfo>, Steer)>>,
    next_scene: AtomicU64,
    /// Notices of the view's own (numbered apart from the loop's).
    told: AtomicU64,
    token: Option<[u8; 32]>,
    /// Viewers beyond loopback without the token watch (`ViewOptions::public_watch`).
    pub public_watch: bool,
    /// The token is taken over plain HTTP from beyond loopback (`allow_plain_token`).
    pub allow_plain_token: bool,
    /// The view serves HTTPS and WSS.
    pub tls: bool,
    /// Addresses removed from what viewers without the token are sent.
    pub addresses: crate::access::Addresses,
    pub steer: watch::Sender<Steer>,
    /// A viewer asked for a frame although nothing changed.
    pub render_now: Notify,
    /// The number of the last frame the loop delivered.
    pub delivered: watch::Sender<u64>,
    /// What each frame was requested at, by frame number (pruned as frames are delivered).
    pub revisions: Mutex<BTreeMap<u64, Requested>>,
    /// The exposure frames are encoded at, stops (`to_srgb8(2^stops)`): the viewers' to set; not
    /// part of the steering revision, since no node renders again for it.
    pub exposure: watch::Sender<f32>,
    /// The encoding thread's queue, to tell it the exposure changed (it then encodes the last
    /// frame again); `None` before it starts and after it stops.
    pub encoder: Mutex<Option<std::sync::mpsc::Sender<crate::encode::Work>>>,
    pub frames: watch::Sender<Option<Arc<ViewFrame>>>,
    /// The newest frame, linear (for `/frame.exr`).
    pub image: Mutex<Option<Arc<Image>>>,
    /// `/frame.exr`'s bytes, encoded once per frame and shared by every download of it (each
    /// download used to hold its own copy: 120 unread downloads took the coordinator from 35 to
    /// 782 MB at 800×600).
    pub exr: tokio::sync::Mutex<Option<(Arc<Image>, (), bytes::Bytes)>>,
    /// `/frame.png`'s bytes, likewise, with the exposure (stops, as bits) they were encoded at.
    pub png: tokio::sync::Mutex<Option<(Arc<Image>, u32, bytes::Bytes)>>,
    live: watch::Receiver<LiveStatus>,
    /// The status as the page gets it, and the newest notice.
    pub status: watch::Sender<Option<Arc<serde_json::Value>>>,
    pub notice: watch::Sender<Option<(u64, String)>>,
    /// Why the session ended, once it has: every viewer is told before the view stops.
    pub ended: watch::Sender<Option<String>>,
    pub viewers: AtomicUsize,
    /// Viewers that only watch (`MAX_WATCHERS`).
    pub watchers: AtomicUsize,
    pub counters: Arc<ViewCounters>,
    /// Cancelled when the view stops serving.
    pub stop: CancellationToken,
}

impl Hub {
    pub(crate) fn new(
        scene: &Scene,
        opts: &ViewOptions,
        counters: Arc<ViewCounters>,
        live: watch::Receiver<LiveStatus>,
        stop: CancellationToken,
    ) -> Hub {
        Hub {
            started: Instant::now(),
            continuous: opts.continuous,
            refine: None,
            jpeg_quality: opts.jpeg_quality.clamp(1, 100),
            send_timeout: opts.send_timeout,
            scene: watch::Sender::new(Arc::new(crate::open::SceneInfo::new(
                0,
                opts.scene_source
                    .clone()
                    .unwrap_or_else(|| scene.name.clone()),
                scene,
                opts.scene_source.as_deref(),
            ))),
            catalog: opts.scenes.clone(),
            opening: AtomicBool::new(false),
            previous: Mutex::new(None),
            next_scene: AtomicU64::new(1),
            told: AtomicU64::new(0),
            token: opts.token.as_deref().map(digest),
            public_watch: opts.public_watch,
            allow_plain_token: opts.allow_plain_token,
            tls: false,
            addresses: crate::access::Addresses::default(),
            steer: watch::Sender::new(Steer::new(scene)),
            render_now: Notify::new(),
            delivered: watch::Sender::new(0),
            revisions: Mutex::new(BTreeMap::new()),
            exposure: watch::Sender::new(crate::encode::stops_of(scene.exposure)),
            encoder: Mutex::new(None),
            frames: watch::Sender::new(None),
            image: Mutex::new(None),
            exr: tokio::sync::Mutex::new(None),
            png: tokio::sync::Mutex::new(None),
            live,
            status: watch::Sender::new(None),
            notice: watch::Sender::new(None),
            ended: watch::Sender::new(None),
            viewers: AtomicUsize::new(0),
            watchers: AtomicUsize::new(0),
            counters,
            stop,
        }
    }

    /// Whether `presented` is the view's token (compared as SHA-256 digests, every byte of
    /// them whatever the first difference).
    pub(crate) fn token_matches(&self, presented: &str) -> bool {
        self.token
            .is_some_and(|t| crate::access::same_digest(&t, &digest(presented.as_bytes())))
    }

    /// What a viewer at `peer` may do before it presents the token.
    pub(crate) fn access_of(&self, peer: SocketAddr) -> Access {
        if crate::access::on_loopback(peer) {
            Access::Steer
        } else if self.public_watch {
            Access::Watch
        } else {
            Access::Locked
        }
    }

    /// Why a viewer at `peer` may not present the token over this connection (`None`: it may):
    /// beyond loopback without TLS the token would cross the network readable, so it is refused
    /// there unless the view was started with `--allow-plain-token`.
    pub(crate) fn token_refused(&self, peer: SocketAddr) -> Option<&'static str> {
        if crate::access::on_loopback(peer) || self.tls || self.allow_plain_token {
            None
        } else {
            Some(PLAIN_TOKEN_REFUSED)
        }
    }

    /// The plan in use.
    pub(crate) fn plan(&self) -> Option<Arc<lightfold_coordinator::plan::Plan>> {
        self.live.borrow().plan.clone()
    }

    /// The loop delivered frame `frame`.
    pub(crate) fn delivered(&self, frame: u64) {
        self.counters
            .frames_delivered
            .fetch_add(1, Ordering::Relaxed);
        self.delivered.send_replace(frame);
    }

    /// What frame `frame` was requested at (and forgets older frames).
    pub(crate) fn requested(&self, frame: u64) -> Requested {
        let mut r = self.revisions.lock().unwrap_or_else(|e| e.into_inner());
        let at = r.get(&frame).copied().unwrap_or_default();
        r.retain(|&f, _| f > frame);
        at
    }

    /// Sets the exposure frames are encoded at (stops: finite, clamped to the range); the next
    /// frame encoded uses it, and the last frame is encoded again at it. The stops applied.
    pub(crate) fn set_exposure(&self, stops: f32) -> Result<f32, crate::SteerError> {
        let stops = crate::encode::check_stops(stops)?;
        if self
            .exposure
            .send_if_modified(|s| std::mem::replace(s, stops) != stops)
        {
            let tx = self.encoder.lock().unwrap_or_else(|e| e.into_inner());
            if let Some(tx) = tx.as_ref() {
                let _ = tx.send(crate::encode::Work::Exposure);
            }
        }
        Ok(stops)
    }

    /// The `stats` message: what serving the view has cost so far.
    pub(crate) fn stats(&self) -> serde_json::Value {
        let c = &self.counters;
        let get = |a: &AtomicU64| a.load(Ordering::Relaxed);
        serde_json::json!({
            "type": "stats",
            "uptime_s": self.started.elapsed().as_secs_f64(),
            "viewers": self.viewers.load(Ordering::Relaxed),
            "frames_delivered": get(&c.frames_delivered),
            "frames_encoded": get(&c.frames_encoded),
            "encode_us": get(&c.encode_us),
            "encode_cpu_us": get(&c.encode_cpu_us),
            "jpeg_bytes": get(&c.jpeg_bytes),
            "frames_sent": get(&c.frames_sent),
            "bytes_sent": get(&c.bytes_sent),
            "frames_skipped": get(&c.frames_skipped),
            "viewers_dropped": get(&c.viewers_dropped),
        })
    }

    /// A notice of the view's own to every page (and the log).
    pub(crate) fn tell(&self, text: String) {
        tracing::info!("{text}");
        let n = (1 << 48) + self.told.fetch_add(1, Ordering::Relaxed);
        self.notice.send_replace(Some((n, text)));
    }

    /// Makes `opened` the scene frames ask for (`FrameSpec::scene`): the steering starts from
    /// its camera and lights (the frame budget a viewer set stays), and every page is welcomed
    /// again. The scene and steering before are kept for the loop's refusal.
    pub(crate) fn install_scene(
        &self,
        name: String,
        source: String,
        opened: crate::open::Opened,
    ) -> u64 {
        let id = self.next_scene.fetch_add(1, Ordering::Relaxed);
        let crate::open::Opened { scene, options } = opened;
        let info = Arc::new(crate::open::SceneInfo::new(
            id,
            name.clone(),
            &scene,
            Some(&source),
        ));
        let steer = Steer::new(&scene);
        let open = Arc::new(lightfold_coordinator::control::OpenScene {
            id,
            name: name.clone(),
            scene,
            options,
        });
        let before = self.steer.borrow().clone();
        *self.previous.lock().unwrap_or_else(|e| e.into_inner()) =
            Some((Arc::clone(&self.scene.borrow()), before));
        self.exposure.send_replace(info.stops);
        self.scene.send_replace(info);
        self.steer.send_modify(|s| {
            let revision = s.revision + 1;
            let budget = s.frame_budget_us;
            *s = steer;
            s.open = Some(open);
            s.frame_budget_us = budget;
            s.revision = revision;
        });
        self.tell(format!("opening scene {name:?}"));
        id
    }

    /// Waits until the loop shows scene `id` or has refused it (at most `within`, or until the
    /// view stops).
    pub(crate) async fn scene_settled(&self, id: u64, within: std::time::Duration) {
        let mut live = self.live.clone();
        let settled = live
            .wait_for(|s| s.scene == id || s.scene_refused.as_ref().is_some_and(|(r, _)| *r == id));
        tokio::select! {
            _ = settled => {}
            _ = tokio::time::sleep(within) => {}
            _ = self.stop.cancelled() => {}
        }
    }

    /// The loop refused scene `id`: back to the scene and steering before it, if it is still
    /// the one shown.
    fn scene_refused(&self, id: u64) {
        if self.scene.borrow().id != id {
            return;
        }
        let Some((info, steer)) = self
            .previous
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .take()
        else {
            return;
        };
        self.exposure.send_replace(info.stops);
        self.scene.send_replace(info);
        self.steer.send_modify(|s| {
            let revision = s.revision + 1;
            *s = steer;
            s.revision = revision;
            s.changed_at = Instant::now();
        });
    }

    /// Turns the loop's status into the page's, whenever it changes, until the view stops.
    pub(crate) async fn relay_status(self: Arc<Self>) {
        let mut live = self.live.clone();
        live.mark_changed();
        let (mut taken_back, mut colors_taken_back, mut moves_taken_back) = (0, 0, 0);
        loop {
            let (value, notice, put_back, colors_back, moves_back, scene_refused) = {
                let s = live.borrow_and_update();
                (
                    crate::json::status(&s, self.started),
                    s.notice.clone(),
                    s.lights_put_back.clone(),
                    s.colors_put_back.clone(),
                    s.moves_put_back.clone(),
                    s.scene_refused.as_ref().map(|(id, _)| *id),
                )
            };
            if let Some(id) = scene_refused {
                self.scene_refused(id);
            }
            if let Some((n, colors)) = colors_back
                && n > colors_taken_back
            {
                // Daemons refused what a colour needed: the loop renders the colours before it.
                colors_taken_back = n;
                self.steer.send_modify(|s| {
                    for (light, color) in &colors {
                        if let Some(set) = s.lights.get_mut(*light as usize) {
                            *set = crate::camera::LightSetting {
                                color: *color,
                                intensity: 1.0,
                            };
                        }
                    }
                    s.changed();
                });
            }
            if let Some((n, moves)) = moves_back
                && n > moves_taken_back
            {
                // The loop could not plan or make a move and renders the objects as they were:
                // so does every page.
                moves_taken_back = n;
                self.steer.send_modify(|s| {
                    s.put_back_moves(&moves);
                    s.changed();
                });
            }
            if let Some((n, lights)) = put_back
                && n > taken_back
            {
                // The loop could not plan an edit and renders the lights as they were: so does
                // every page.
                taken_back = n;
                self.steer.send_modify(|s| {
                    s.put_back_lights(&lights);
                    s.changed();
                });
            }
            self.status.send_replace(Some(Arc::new(value)));
            if notice.is_some() && *self.notice.borrow() != notice {
                self.notice.send_replace(notice);
            }
            tokio::select! {
                _ = self.stop.cancelled() => return,
                r = live.changed() => if r.is_err() {
                    // The loop ended; keep the last status until the view stops.
                    self.stop.cancelled().await;
                    return;
                },
            }
        }
    }
}

fn digest(s: &[u8]) -> [u8; 32] {
    Sha256::digest(s).into()
}
