//! A render node on loopback with a test driver playing the coordinator (over `net`, as the real
//! one does) and a listener playing the compositor. Every wait has a deadline.

use bytes::Bytes;
use lightfold_harness::driver::ControlClient;
use lightfold_net::{Identity, NetError, Timeouts, accept};
use lightfold_node::daemon::calibrate::{calibration_lights, calibration_scene};
use lightfold_node::daemon::{NodeOptions, run};
use lightfold_protocol::frame::Frame;
use lightfold_protocol::{
    BandHeader, FrameParams, Hash, Layer, Message, NodeConfig, PixelFormat, Role, format,
};
use lightfold_scene::wire::{camera_to_wire, light_to_wire};
use lightfold_scene::{Image, LightSample, Scene};
use std::path::PathBuf;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::sync::mpsc;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;

pub(crate) const TOKEN: &[u8] = b"daemon test token";
pub(crate) const WAIT: Duration = Duration::from_secs(60);
pub(crate) const WIDTH: u32 = 160;
pub(crate) const HEIGHT: u32 = 120;

pub(crate) fn quick() -> Timeouts {
    Timeouts {
        connect: Duration::from_secs(5),
        handshake: Duration::from_secs(10),
        send: Duration::from_secs(30),
        ..Timeouts::default()
    }
}

/// The test scene: the calibration scene at a small size.
pub(crate) fn scene() -> Scene {
    let mut s = calibration_scene();
    s.camera.width = WIDTH;
    s.camera.height = HEIGHT;
    s
}

pub(crate) fn lights(n: usize) -> Vec<LightSample> {
    calibration_lights(n)
}

/// A running node.
pub(crate) struct TestNode {
    pub addr: String,
    pub shutdown: CancellationToken,
    pub handle: JoinHandle<anyhow::Result<()>>,
}

pub(crate) async fn start_node(id: &str, cache_dir: Option<PathBuf>) -> TestNode {
    start_node_with(id, |opts| opts.cache_dir = cache_dir).await
}

/// A node with the test defaults, then `tweak` applied to its options.
pub(crate) async fn start_node_with(id: &str, tweak: impl FnOnce(&mut NodeOptions)) -> TestNode {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let mut opts = NodeOptions::new(id, TOKEN);
    opts.timeouts = quick();
    opts.dial_deadline = Duration::from_secs(10);
    tweak(&mut opts);
    let shutdown = CancellationToken::new();
    let handle = tokio::spawn(run(listener, opts, shutdown.clone()));
    TestNode {
        addr,
        shutdown,
        handle,
    }
}

impl TestNode {
    /// Connects a test coordinator; if the node failed to start (no GPU adapter, say), fails
    /// with the node's own error.
    pub(crate) async fn coordinator(&mut self) -> Coordinator {
        match Coordinator::try_connect(&self.addr).await {
            Ok(c) => c,
            Err(e) => {
                if self.handle.is_finished() {
                    let r = (&mut self.handle).await.expect("node task");
                    panic!("the node did not start: {r:?}");
                }
                panic!("cannot connect to the node: {e}");
            }
        }
    }

    /// Cancels the node and waits for `run` to return.
    pub(crate) async fn stop(self) {
        self.shutdown.cancel();
        let r = tokio::time::timeout(WAIT, self.handle)
            .await
            .expect("node stops within the deadline")
            .expect("node task");
        r.expect("node ran without error");
    }
}

/// The test driver's side of a control link: the harness's fake coordinator with the answers
/// these tests expect (a failure panics with what came instead).
pub(crate) struct Coordinator {
    pub client: ControlClient,
}

impl Coordinator {
    pub(crate) async fn try_connect(addr: &str) -> Result<Coordinator, String> {
        let me = Identity::new(TOKEN, Role::Coordinator, "test-coordinator");
        let client = ControlClient::connect(addr, &me, quick(), WAIT)
            .await
            .map_err(|e| e.to_string())?;
        Ok(Coordinator { client })
    }

    /// Connects and claims the node for `session`; returns the node's answer (`Claimed`, or an
    /// `Error`) with the link.
    pub(crate) async fn claim(addr: &str, session: u64, take_over: bool) -> (Coordinator, Message) {
        let mut c = Coordinator::try_connect(addr).await.expect("connect");
        let answer = c.request(Message::Claim { session, take_over }).await;
        (c, answer)
    }

    /// The next message within `within`, or the link's error (closed, timed out).
    pub(crate) async fn recv_within(&mut self, within: Duration) -> Result<Message, NetError> {
        self.client.recv_raw(within).await
    }

    pub(crate) async fn send(&mut self, msg: Message) {
        self.client.send_msg(msg).await.expect("send to the node");
    }

    pub(crate) async fn recv(&mut self) -> Message {
        self.client
            .recv_raw(WAIT)
            .await
            .expect("answer from the node")
    }

    pub(crate) async fn request(&mut self, msg: Message) -> Message {
        self.send(msg).await;
        self.recv().await
    }

    /// Offers the scene and sends it if asked; returns its hash.
    pub(crate) async fn send_scene(&mut self, scene: &Scene) -> Hash {
        let bytes = scene.to_bytes().expect("scene encodes");
        let hash = scene.content_hash();
        let loaded = self
            .client
            .send_scene(hash, &bytes, 1000, WAIT)
            .await
            .expect("the node takes the scene");
        if let Some(triangles) = loaded {
            assert_eq!(triangles, scene.triangle_count() as u64);
        }
        hash
    }

    pub(crate) async fn send_chunks(&mut self, hash: Hash, bytes: &[u8], chunk: usize) {
        self.client
            .send_chunks(hash, bytes, chunk)
            .await
            .expect("send to the node");
    }

    pub(crate) async fn frame(&mut self, epoch: u64, frame: u64) -> Message {
        self.request(Message::RenderFrame {
            epoch,
            frame,
            camera: None,
            params: FrameParams {
                colors: Vec::new(),
                scale: None,
                time: None,
                lights: Vec::new(),
                rows: None,
            },
        })
        .await
    }
}

/// A listener playing the compositor: accepts data links and forwards every band.
pub(crate) struct Compositor {
    pub addr: String,
    pub bands: mpsc::Receiver<(String, BandHeader, Bytes)>,
    /// Bumped by [`Compositor::let_go`]: every link accepted so far is closed.
    generation: tokio::sync::watch::Sender<u64>,
}

pub(crate) async fn start_compositor() -> Compositor {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let (tx, bands) = mpsc::channel(4096);
    let (generation, watch) = tokio::sync::watch::channel(0u64);
    tokio::spawn(async move {
        let me = Identity::new(TOKEN, Role::Compositor, "test-compositor");
        while let Ok((stream, _)) = listener.accept().await {
            let (me, tx, mut watch) = (me.clone(), tx.clone(), watch.clone());
            tokio::spawn(async move {
                let Ok(link) = accept(stream, &me, quick()).await else {
                    return;
                };
                watch.mark_unchanged();
                let peer = link.peer.daemon_id.clone();
                // Like a stage, keep the writing half open while the link is held.
                let (mut reader, _writer) = link.split();
                loop {
                    tokio::select! {
                        _ = watch.changed() => return,
                        f = reader.next() => match f {
                            Some(Ok(Frame::Band(h, payload))) => {
                                if tx.send((peer.clone(), h, payload)).await.is_err() {
                                    return;
                                }
                            }
                            _ => return,
                        },
                    }
                }
            });
        }
    });
    Compositor {
        addr,
        bands,
        generation,
    }
}

impl Compositor {
    /// The next `n` bands, each within the deadline.
    pub(crate) async fn take(&mut self, n: usize) -> Vec<(String, BandHeader, Bytes)> {
        let mut out = Vec::with_capacity(n);
        for _ in 0..n {
            let b = tokio::time::timeout(WAIT, self.bands.recv())
                .await
                .expect("band within the deadline")
                .expect("compositor running");
            out.push(b);
        }
        out
    }

    /// Closes every link accepted so far, as a stage does with the links of producers a new
    /// configuration leaves out.
    pub(crate) fn let_go(&self) {
        self.generation.send_modify(|g| *g += 1);
    }

    /// True if no band is waiting.
    pub(crate) fn idle(&mut self) -> bool {
        self.bands.try_recv().is_err()
    }
}

/// A node configuration for the test scene.
pub(crate) fn node_config(
    epoch: u64,
    scene: Hash,
    lights: &[LightSample],
    layers: Vec<(Layer, PixelFormat)>,
    downstream: &str,
) -> NodeConfig {
    let s = self::scene();
    NodeConfig {
        epoch,
        scene,
        lights: lights
            .iter()
            .enumerate()
            .map(|(i, l)| light_to_wire(l, i as u32))
            .collect(),
        shadows: Vec::new(),
        color: [1.0, 1.0, 1.0],
        layers,
        scale: 1.0,
        band_height: 32,
        camera: camera_to_wire(&s.camera),
        walkthrough: false,
        downstream: downstream.to_string(),
        input_index: 0,
        filter: 1,
        depth_bias: s.quality.depth_bias,
        slope_bias: s.quality.slope_bias,
        eye_meshes: None,
        rows: None,
        moves: Vec::new(),
        peel: None,
    }
}

/// Bands expected per frame.
pub(crate) fn band_count(config: &NodeConfig) -> usize {
    config.camera.height.div_ceil(config.band_height) as usize * config.layers.len()
}

/// Unpacks one layer's bands into an image (empty bands stay zero).
pub(crate) fn assemble(
    bands: &[(String, BandHeader, Bytes)],
    layer: Layer,
    width: u32,
    height: u32,
) -> Image {
    let mut img = Image::new(width, height, layer.channels());
    let c = layer.channels();
    for (_, h, payload) in bands.iter().filter(|(_, h, _)| h.layer == layer) {
        assert_eq!((h.x0, h.width), (0, width), "bands span the full width");
        if h.empty {
            assert!(payload.is_empty());
            continue;
        }
        let start = h.y0 as usize * width as usize * c;
        let end = start + h.height as usize * width as usize * c;
        format::unpack(h.format, payload, h.scale, &mut img.data[start..end]).expect("unpack");
    }
    img
}

/// Largest excess of `|got − want|` over the format's documented bound (≤ 0 means within).
pub(crate) fn worst_excess(format: PixelFormat, got: &Image, want: &Image, scale: f32) -> f32 {
    assert_eq!(
        (got.width, got.height, got.channels),
        (want.width, want.height, want.channels)
    );
    let c = want.channels;
    let mut worst = f32::NEG_INFINITY;
    for (g, w) in got.data.chunks(c).zip(want.data.chunks(c)) {
        for (i, (a, b)) in g.iter().zip(w).enumerate() {
            let bound = if format == PixelFormat::Rgb9e5x2 {
                // One exponent per triple: the bound follows the triple's largest value.
                let t = &w[i / 3 * 3..i / 3 * 3 + 3];
                format::bound(format, t.iter().cloned().fold(0.0f32, f32::max), scale)
            } else {
                format::channel_bound(format, i, *b, scale)
            };
            worst = worst.max((a - b).abs() - bound - 1e-6 * b.abs());
        }
    }
    worst
}
