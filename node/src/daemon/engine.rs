//! The node's state between messages and what each control message does to it: scenes by hash,
//! the active configuration, the downstream link and the last frame's packed bands. Each call
//! returns the one answer to its request (or, for a scene chunk that is not the last, none); a
//! failure is an `Error` with a code and the node stays ready for the next request. A frame may
//! also be abandoned half-way (its future dropped: a new configuration, a shutdown, a lost
//! control link); it is then not answered, and [`Engine::abandon`] (called by the session, or by
//! the next request if nobody did) closes the data link it may have left a partial frame on.

use super::bands::{BandLayout, LayerImages, PackedBand, assemble_frame, pack_frame, restamp};
use super::configure::{self, Checked};
use super::render_thread::{DeviceReport, Output, Pending, RenderHandle, RenderSetup};
use super::scene_cache::{self, SceneCache, SceneCacheError, hex};
use crate::gpu::device::max_lights_for;
use lightfold_net::Downstream;
use lightfold_net::NetError;
use lightfold_protocol::frame::Frame;
use lightfold_protocol::{
    ErrorCode, FrameParams, FrameStats, Hash, Message, NodeConfig, WireCamera,
};
use lightfold_scene::Camera;
use lightfold_telemetry::process::peak_rss_bytes;
use std::sync::Arc;
use std::time::Instant;
use tokio::sync::mpsc;

/// Packed bands waiting for the socket: enough to keep it busy, few enough to bound memory.
const BAND_QUEUE: usize = 8;
/// Bytes a band frame costs beyond its payload: length prefix, kind byte, header.
const BAND_OVERHEAD: u64 = lightfold_protocol::frame::BAND_PREFIX_LEN as u64;

/// A refused request: becomes `Message::Error` on the control link.
#[derive(Debug)]
struct Refusal {
    code: ErrorCode,
    message: String,
}

impl Refusal {
    /// The refusal as the error of the configuration of `epoch`.
    fn of_epoch(self, epoch: u64) -> Message {
        Message::epoch_error(epoch, self.code, self.message)
    }

    /// The refusal as the error of `frame` of `epoch`.
    fn of_frame(self, epoch: u64, frame: u64) -> Message {
        Message::frame_error(epoch, frame, self.code, self.message)
    }
}

impl From<Refusal> for Message {
    fn from(r: Refusal) -> Message {
        Message::error(r.code, r.message)
    }
}

fn refuse(code: ErrorCode, message: impl Into<String>) -> Refusal {
    let message = message.into();
    tracing::warn!(?code, %message, "request refused");
    Refusal { code, message }
}

fn error(code: ErrorCode, message: impl Into<String>) -> Message {
    refuse(code, message).into()
}

#[derive(Debug)]
struct Active {
    checked: Checked,
    camera: Camera,
    scale: f32,
    /// Scene time of the last frame (kept for frames that give none, like the camera).
    time: Option<f32>,
    /// Lights of the last frame that gave them (`FrameParams::lights`), in place of configured
    /// ones, and how many times they changed (part of the frame's key).
    frame_lights: super::render_thread::FrameLights,
    lights_changed: u64,
    /// Whether the configured scene moves over time (otherwise the time changes nothing).
    animated: bool,
    /// The image rows this node renders (a sort-first tile: `NodeConfig::rows`, moved by
    /// `FrameParams::rows`); `None`: every row.
    rows: Option<[u32; 2]>,
}

/// What makes two frames identical: in walkthrough mode the same key means the same bands.
#[derive(Debug, Clone, PartialEq)]
struct FrameKey {
    epoch: u64,
    camera: Camera,
    scale: u32,
    time: Option<u32>,
    /// Changes whenever a frame's lights (`FrameParams::lights`) differ from the last ones.
    lights: u64,
    rows: Option<[u32; 2]>,
}

/// A frame request that follows the one being rendered (already on the control link).
#[derive(Debug, Clone)]
pub(super) struct NextFrame {
    pub epoch: u64,
    pub frame: u64,
    pub camera: Option<WireCamera>,
    pub params: FrameParams,
}

/// The next frame's render, queued on the render thread while this frame's bands stream: the
/// device works on frame n + 1 while frame n goes to the socket. Bands still leave in frame
/// order (frame n + 1's are streamed only when its own request is handled, after frame n's).
#[derive(Debug)]
struct Prefetched {
    epoch: u64,
    frame: u64,
    key: FrameKey,
    pending: Pending,
}

#[derive(Debug)]
struct CachedFrame {
    key: FrameKey,
    bands: Vec<PackedBand>,
    peak: f32,
}

/// The node's state.
#[derive(Debug)]
pub(super) struct Engine {
    pub daemon_id: String,
    render: RenderHandle,
    pub report: DeviceReport,
    scenes: SceneCache,
    active: Option<Active>,
    downstream: Downstream,
    cached: Option<CachedFrame>,
    max_frame: usize,
    /// A frame has started and not returned: if its future was dropped, the data link may hold
    /// part of it.
    in_frame: bool,
    prefetched: Option<Prefetched>,
    /// Whether a following request's frame is rendered while this one streams.
    ahead: bool,
}

impl Engine {
    pub(super) fn new(
        daemon_id: String,
        render: RenderHandle,
        report: DeviceReport,
        scenes: SceneCache,
        downstream: Downstream,
        max_frame: usize,
    ) -> Engine {
        Engine {
            daemon_id,
            render,
            report,
            scenes,
            active: None,
            downstream,
            cached: None,
            max_frame,
            in_frame: false,
            prefetched: None,
            ahead: true,
        }
    }

    /// Whether a following request's frame is rendered while this one's bands stream.
    pub(super) fn render_ahead(mut self, on: bool) -> Engine {
        self.ahead = on;
        self
    }

    /// Stops the render thread (the device is released when this returns).
    pub(super) async fn stop(self) {
        self.render.stop().await;
    }

    /// `SceneOffer`: `SceneNeed { need: false }` when the scene is in memory or in the disk cache,
    /// else starts a transfer and answers `need: true`.
    pub(super) async fn scene_offer(&mut self, hash: Hash, size: u64) -> Message {
        if self.scenes.get(&hash).is_some() {
            return Message::SceneNeed { hash, need: false };
        }
        if let Some(path) = self.scenes.disk_path(&hash) {
            let loaded =
                tokio::task::spawn_blocking(move || scene_cache::load_file(&path, &hash)).await;
            if let Ok(Some(scene)) = loaded {
                tracing::info!(scene = %hex(&hash), "scene loaded from the disk cache");
                self.scenes.insert(hash, Arc::new(scene));
                return Message::SceneNeed { hash, need: false };
            }
        }
        match self.scenes.begin(hash, size) {
            Ok(()) => Message::SceneNeed { hash, need: true },
            Err(e) => error(e.code(), e.to_string()),
        }
    }

    /// `SceneChunk`: nothing until the last chunk, then `SceneReady` once the bytes match the hash
    /// and decode.
    pub(super) async fn scene_chunk(
        &mut self,
        hash: Hash,
        offset: u64,
        data: Vec<u8>,
        last: bool,
    ) -> Option<Message> {
        let bytes = match self.scenes.chunk(hash, offset, &data, last) {
            Ok(None) => return None,
            Ok(Some(bytes)) => bytes,
            Err(e) => return Some(error(e.code(), e.to_string())),
        };
        let path = self.scenes.disk_path(&hash);
        let decoded = tokio::task::spawn_blocking(move || {
            let scene = scene_cache::decode_verified(&bytes, &hash)?;
            if let Some(path) = path
                && let Err(e) = scene_cache::store_file(&path, &bytes)
            {
                tracing::warn!(path = %path.display(), error = %e, "cannot cache scene on disk");
            }
            Ok::<_, SceneCacheError>(scene)
        })
        .await;
        match decoded {
            Ok(Ok(scene)) => {
                let triangles = scene.triangle_count() as u64;
                tracing::info!(scene = %hex(&hash), triangles, "scene received");
                self.scenes.insert(hash, Arc::new(scene));
                Some(Message::SceneReady { hash, triangles })
            }
            Ok(Err(e)) => Some(error(e.code(), e.to_string())),
            Err(e) => Some(error(
                ErrorCode::Internal,
                format!("scene decoding task: {e}"),
            )),
        }
    }

    /// Forgets a frame whose future was dropped half-way: its bands may be half on the data link
    /// (a cancelled write leaves the rest queued), so the link is closed and the next frame dials
    /// afresh; the walkthrough cache is cleared. The render thread needs nothing: it finishes the
    /// render it was given and its answer is discarded.
    pub(super) fn abandon(&mut self) {
        self.downstream.close();
        self.cached = None;
        self.in_frame = false;
        self.prefetched = None;
    }

    /// Abandons a frame dropped half-way that nobody has abandoned yet.
    fn recover(&mut self) {
        if self.in_frame {
            tracing::info!("the previous frame was abandoned half-way: closing the data link");
            self.abandon();
        }
    }

    /// `Release`: the plan of `epoch` leaves this node out. It drops its configuration, its
    /// walkthrough frame and its data link (a frame in progress was abandoned by the preempting
    /// reader), and waits for the next configuration.
    pub(super) fn release(&mut self, epoch: u64) {
        self.abandon();
        self.active = None;
        tracing::info!(
            epoch,
            "released: the plan of this epoch leaves the node out"
        );
    }

    /// `ConfigureNode`: checks the configuration, hands it to the render thread (which rebuilds
    /// the renderer only for a new scene or new build options) and points the data link at the
    /// new downstream. A refused configuration leaves the node unconfigured.
    pub(super) async fn configure(&mut self, config: NodeConfig) -> Message {
        self.recover();
        self.active = None;
        self.cached = None;
        self.prefetched = None;
        let epoch = config.epoch;
        let hash = config.scene;
        let Some(scene) = self.scenes.get(&hash) else {
            let e = SceneCacheError::Unknown { hash: hex(&hash) };
            return Message::epoch_error(epoch, e.code(), e.to_string());
        };
        let animated = scene.is_animated();
        let limits = self.report.limits.clone();
        let checked = match configure::check(
            config,
            &scene,
            |size| max_lights_for(&limits, size),
            limits.max_texture_dimension_2d,
            self.max_frame,
        ) {
            Ok(c) => c,
            Err(e) => {
                let message = format!("configuration {epoch}: {e}");
                return refuse(e.code(), message).of_epoch(epoch);
            }
        };
        let setup = RenderSetup {
            scene_hash: hash,
            scene,
            checked: checked.clone(),
        };
        if let Err(e) = self.render.configure(setup).await {
            return refuse(
                ErrorCode::RenderFailed,
                format!("configuration {epoch}: {e}"),
            )
            .of_epoch(epoch);
        }
        self.downstream.set_address(&checked.config.downstream);
        tracing::info!(
            epoch,
            lights = checked.lights.len(),
            layers = ?checked.config.layers,
            walkthrough = checked.config.walkthrough,
            downstream = %checked.config.downstream,
            "configured"
        );
        self.active = Some(Active {
            camera: checked.camera,
            scale: checked.config.scale,
            rows: checked.config.rows,
            checked,
            time: None,
            frame_lights: Arc::default(),
            lights_changed: 0,
            animated,
        });
        Message::Configured { epoch }
    }

    /// `RenderFrame`: renders (or, in walkthrough mode with nothing changed, reuses the last
    /// frame's bands), streams the bands downstream and answers `FrameDone`. Dropping the future
    /// abandons the frame (see [`Engine::abandon`]).
    ///
    /// `next`, the request that follows on the control link if it has arrived, is rendered on
    /// the device while this frame's bands stream (see [`NextFrame`]).
    pub(super) async fn render_frame(
        &mut self,
        epoch: u64,
        frame: u64,
        camera: Option<WireCamera>,
        params: FrameParams,
        next: Option<NextFrame>,
    ) -> Message {
        self.recover();
        self.in_frame = true;
        let answer = self.frame(epoch, frame, camera, params, next).await;
        self.in_frame = false;
        answer
    }

    async fn frame(
        &mut self,
        epoch: u64,
        frame: u64,
        camera: Option<WireCamera>,
        params: FrameParams,
        next: Option<NextFrame>,
    ) -> Message {
        let start = Instant::now();
        let key = match self.frame_key(epoch, frame, camera, &params) {
            Ok(k) => k,
            Err(r) => return r.of_frame(epoch, frame),
        };
        let Some(active) = &self.active else {
            return refuse(ErrorCode::BadConfig, "not configured").of_frame(epoch, frame);
        };
        let walkthrough = active.checked.config.walkthrough;
        let mut stats = FrameStats {
            epoch,
            frame,
            daemon_id: self.daemon_id.clone(),
            ..FrameStats::default()
        };
        let reuse = walkthrough && self.cached.as_ref().is_some_and(|c| c.key == key);
        let sent = if reuse {
            self.prefetched = None;
            self.resend(frame, &mut stats).await
        } else {
            self.render_and_send(key, frame, walkthrough, &mut stats, next)
                .await
        };
        if let Err(r) = sent {
            return r.of_frame(epoch, frame);
        }
        stats.total_us = start.elapsed().as_micros() as u64;
        stats.peak_rss_bytes = peak_rss_bytes();
        Message::FrameDone(stats)
    }

    /// Applies a frame request's camera and scale to the active configuration.
    fn frame_key(
        &mut self,
        epoch: u64,
        frame: u64,
        camera: Option<WireCamera>,
        params: &FrameParams,
    ) -> Result<FrameKey, Refusal> {
        let Some(active) = self.active.as_mut() else {
            return Err(refuse(
                ErrorCode::BadConfig,
                format!("frame {frame} requested, but this node is not configured"),
            ));
        };
        let configured = active.checked.config.epoch;
        if epoch != configured {
            return Err(refuse(
                ErrorCode::BadConfig,
                format!(
                    "frame {frame} is for plan epoch {epoch}, this node is configured for epoch {configured}"
                ),
            ));
        }
        if let Some(w) = camera {
            let c = configure::check_camera(&w)
                .map_err(|e| refuse(ErrorCode::BadConfig, format!("frame {frame}: {e}")))?;
            if (c.width, c.height) != (active.camera.width, active.camera.height) {
                return Err(refuse(
                    ErrorCode::BadConfig,
                    format!(
                        "frame {frame} asks for {}x{}, the plan of epoch {epoch} is {}x{}",
                        c.width, c.height, active.camera.width, active.camera.height
                    ),
                ));
            }
            active.camera = c;
        }
        if let Some(s) = params.scale {
            configure::check_scale(s, &active.checked.config.layers)
                .map_err(|e| refuse(ErrorCode::BadConfig, format!("frame {frame}: {e}")))?;
            active.scale = s;
        }
        if let Some(t) = params.time {
            if !t.is_finite() {
                return Err(refuse(
                    ErrorCode::BadConfig,
                    format!("frame {frame}: scene time {t} is not finite"),
                ));
            }
            active.time = Some(t);
        }
        if let Some(rows) = params.rows {
            configure::check_rows(rows, active.camera.height)
                .map_err(|e| refuse(ErrorCode::BadConfig, format!("frame {frame}: {e}")))?;
            active.rows = Some(rows);
        }
        if !params.lights.is_empty() {
            let b = configure::check_frame_lights(&params.lights, &active.checked.config.lights)
                .map_err(|e| refuse(ErrorCode::BadConfig, format!("frame {frame}: {e}")))?;
            if *active.frame_lights != b {
                active.lights_changed += 1;
                active.frame_lights = Arc::new(b);
            }
        }
        Ok(FrameKey {
            epoch,
            camera: active.camera,
            scale: active.scale.to_bits(),
            time: active.time.filter(|_| active.animated).map(f32::to_bits),
            lights: active.lights_changed,
            rows: active.rows,
        })
    }

    /// Queues `next`'s render on the render thread (see [`Prefetched`]), unless it would not
    /// render: a request the node refuses (it is refused again when handled, with the same
    /// answer), or a walkthrough frame identical to `current` (its bands are resent).
    async fn prefetch(&mut self, next: NextFrame, current: &FrameKey) {
        let Ok(key) = self.frame_key(next.epoch, next.frame, next.camera, &next.params) else {
            return;
        };
        let Some(active) = &self.active else {
            return;
        };
        if active.checked.config.walkthrough && key == *current {
            return;
        }
        if let Ok(pending) = self
            .render
            .submit(
                active.camera,
                active.time,
                active.scale,
                Arc::clone(&active.frame_lights),
                active.rows,
            )
            .await
        {
            self.prefetched = Some(Prefetched {
                epoch: next.epoch,
                frame: next.frame,
                key,
                pending,
            });
        }
    }

    async fn resend(&mut self, frame: u64, stats: &mut FrameStats) -> Result<(), Refusal> {
        let Some(cached) = self.cached.take() else {
            return Err(refuse(ErrorCode::Internal, "no cached frame"));
        };
        let result = self.send_bands(restamp(&cached.bands, frame), stats).await;
        stats.empty_bands = cached.bands.iter().filter(|b| b.header.empty).count() as u32;
        stats.saturated = cached
            .bands
            .iter()
            .map(|b| u64::from(b.header.saturated))
            .sum();
        stats.peak = cached.peak;
        stats.scale = f32::from_bits(cached.key.scale);
        self.cached = Some(cached);
        result
    }

    async fn render_and_send(
        &mut self,
        key: FrameKey,
        frame: u64,
        walkthrough: bool,
        stats: &mut FrameStats,
        next: Option<NextFrame>,
    ) -> Result<(), Refusal> {
        self.cached = None;
        let epoch = key.epoch;
        let prefetched = self
            .prefetched
            .take()
            .filter(|p| (p.epoch, p.frame) == (epoch, frame) && p.key == key);
        let Some(active) = &self.active else {
            return Err(refuse(ErrorCode::BadConfig, "not configured"));
        };
        let cfg = &active.checked.config;
        let layout_scale = active.scale;
        let layout = BandLayout {
            epoch: cfg.epoch,
            frame,
            width: active.camera.width,
            height: active.camera.height,
            band_height: cfg.band_height,
            scale: active.scale,
        };
        let configured = cfg.layers.clone();
        let lights: Vec<u32> = cfg.lights.iter().map(|l| l.sample).collect();
        let rendered = match prefetched {
            Some(p) => {
                stats.prefetched = true;
                p.pending.wait().await
            }
            None => {
                self.render
                    .render(
                        active.camera,
                        active.time,
                        active.scale,
                        Arc::clone(&active.frame_lights),
                        active.rows,
                    )
                    .await
            }
        }
        .map_err(|e| refuse(ErrorCode::RenderFailed, format!("frame {frame}: {e}")))?;
        if let Some(n) = next.filter(|_| self.ahead) {
            self.prefetch(n, &key).await;
        }
        let r = &rendered.stats;
        stats.setup_us = r.setup_us;
        stats.shadow_us = r.shadow_us;
        stats.eye_us = r.eye_us;
        stats.readback_us = r.readback_us;
        stats.read_bytes = r.read_bytes;
        stats.shadow_passes = r.shadow_passes;
        stats.maps_kept = r.maps_kept;
        stats.pose_us = r.pose_us;
        stats.lights_rendered = lights;

        let (tx, mut rx) = mpsc::channel::<PackedBand>(BAND_QUEUE);
        let packer = match rendered.output {
            Output::Packed(packed) => tokio::task::spawn_blocking(move || {
                assemble_frame(&layout, &configured, &packed, &tx)
            }),
            Output::Images(images) => {
                let images: LayerImages = images
                    .into_iter()
                    .zip(configured)
                    .map(|((layer, img), (_, format))| (layer, format, img))
                    .collect();
                let rows = rendered.rows;
                tokio::task::spawn_blocking(move || pack_frame(&layout, &images, rows, &tx))
            }
        };
        let mut kept = Vec::new();
        let stream = async {
            let writer = self.downstream.writer().await?;
            let mut send_us = 0u64;
            let mut bytes = 0u64;
            while let Some(band) = rx.recv().await {
                bytes += BAND_OVERHEAD + band.payload.len() as u64;
                let t = Instant::now();
                writer
                    .feed(Frame::Band(band.header, band.payload.clone()))
                    .await?;
                send_us += t.elapsed().as_micros() as u64;
                if walkthrough {
                    kept.push(band);
                }
            }
            let t = Instant::now();
            writer.flush().await?;
            Ok::<_, NetError>((send_us + t.elapsed().as_micros() as u64, bytes))
        };
        let streamed = stream.await;
        drop(rx);
        let totals = match packer.await {
            Ok(Ok(t)) => t,
            Ok(Err(e)) => {
                return Err(refuse(
                    ErrorCode::RenderFailed,
                    format!("frame {frame}: {e}"),
                ));
            }
            Err(e) => return Err(refuse(ErrorCode::Internal, format!("packing task: {e}"))),
        };
        let (send_us, bytes) = streamed.map_err(|e| self.link_lost(frame, e))?;
        stats.pack_us = totals.pack_us;
        stats.send_us = send_us;
        stats.bytes_out = bytes;
        stats.empty_bands = totals.empty_bands;
        stats.saturated = totals.saturated;
        stats.peak = totals.peak;
        stats.scale = layout_scale;
        if walkthrough {
            self.cached = Some(CachedFrame {
                key,
                bands: kept,
                peak: totals.peak,
            });
        }
        Ok(())
    }

    async fn send_bands(
        &mut self,
        bands: impl Iterator<Item = PackedBand>,
        stats: &mut FrameStats,
    ) -> Result<(), Refusal> {
        let t = Instant::now();
        let frame = stats.frame;
        let result = async {
            let writer = self.downstream.writer().await?;
            let mut bytes = 0u64;
            for band in bands {
                bytes += BAND_OVERHEAD + band.payload.len() as u64;
                writer.feed(Frame::Band(band.header, band.payload)).await?;
            }
            writer.flush().await?;
            Ok::<_, NetError>(bytes)
        }
        .await;
        stats.bytes_out = result.map_err(|e| self.link_lost(frame, e))?;
        stats.send_us = t.elapsed().as_micros() as u64;
        Ok(())
    }

    /// A failed data link: dropped (the next frame dials again) and reported.
    fn link_lost(&mut self, frame: u64, e: NetError) -> Refusal {
        self.downstream.close();
        refuse(
            ErrorCode::PeerLost,
            format!("frame {frame}: data link to the compositor failed: {e}"),
        )
    }
}
