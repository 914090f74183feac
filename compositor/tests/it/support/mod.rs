//! Helpers for the stage daemon tests: stages started in-process on `127.0.0.1:0`, identities,
//! short deadlines, HDR test content, configurations, and the in-memory reference a stage's
//! output is compared with (the same operators over whole frames, plus the link formats' bound).

use lightfold_compositor::daemon::{CompositorOptions, StageMetrics, run};
use lightfold_compositor::ops::{BandMut, BandView};
use lightfold_compositor::pipeline::Pipeline;
use lightfold_harness::driver::{ControlClient, FrameShape, LayerImage, Producer, Sink};
use lightfold_net::{Identity, Timeouts};
use lightfold_protocol::format::{channel_bound, clamp_to_range, quantisation_bound};
use lightfold_protocol::{CompositorConfig, Layer, OpSpec, PixelFormat, Role, StageInput};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::sync::Arc;
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;

pub(crate) const TOKEN: &[u8] = b"stage-test-token";
/// Deadline of every wait in these tests.
pub(crate) const WAIT: Duration = Duration::from_secs(10);

pub(crate) fn timeouts() -> Timeouts {
    Timeouts {
        connect: Duration::from_secs(2),
        handshake: Duration::from_secs(2),
        send: Duration::from_secs(10),
        ..Timeouts::default()
    }
}

pub(crate) fn identity(role: Role, id: &str) -> Identity {
    Identity::new(TOKEN, role, id)
}

/// A stage running in this process.
pub(crate) struct Stage {
    pub addr: String,
    pub metrics: Arc<StageMetrics>,
    pub shutdown: CancellationToken,
    pub handle: JoinHandle<anyhow::Result<()>>,
}

pub(crate) async fn start_stage(id: &str) -> Stage {
    start_stage_with(id, |_| {}).await
}

pub(crate) async fn start_stage_with(
    id: &str,
    tweak: impl FnOnce(&mut CompositorOptions),
) -> Stage {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let mut opts = CompositorOptions::new(id, addr.clone(), TOKEN);
    opts.timeouts = timeouts();
    opts.input_timeout = Duration::from_secs(3);
    opts.dial_timeout = Duration::from_secs(3);
    tweak(&mut opts);
    let metrics = Arc::clone(&opts.metrics);
    let shutdown = CancellationToken::new();
    let handle = tokio::spawn(run(listener, opts, shutdown.clone()));
    Stage {
        addr,
        metrics,
        shutdown,
        handle,
    }
}

impl Stage {
    /// Cancels the stage and waits (with a deadline) for `run` to return.
    pub(crate) async fn stop(self) {
        self.shutdown.cancel();
        tokio::time::timeout(WAIT, self.handle)
            .await
            .expect("stage stops within the deadline")
            .expect("stage task does not panic")
            .expect("stage run returns Ok");
    }

    pub(crate) async fn control(&self) -> ControlClient {
        ControlClient::connect(
            &self.addr,
            &identity(Role::Coordinator, "coord"),
            timeouts(),
            WAIT,
        )
        .await
        .expect("coordinator connects")
    }

    pub(crate) async fn producer(&self, id: &str) -> Producer {
        Producer::connect(&self.addr, &identity(Role::Node, id), timeouts(), WAIT)
            .await
            .expect("producer connects")
    }
}

/// The coordinator's data listener for a sink stage.
pub(crate) async fn sink() -> (Sink, String) {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    (
        Sink::new(listener, identity(Role::Coordinator, "coord"), timeouts()),
        addr,
    )
}

pub(crate) fn input(peer: &str, layers: &[(Layer, PixelFormat)]) -> StageInput {
    StageInput {
        peer: peer.into(),
        layers: layers.to_vec(),
    }
}

/// A configuration with the test defaults for what a test does not care about.
pub(crate) fn config(
    epoch: u64,
    (width, height, band_height): (u32, u32, u32),
    inputs: Vec<StageInput>,
    ops: &[(&str, &str)],
    outputs: &[(Layer, PixelFormat)],
    downstream: &str,
) -> CompositorConfig {
    CompositorConfig {
        epoch,
        width,
        height,
        band_height,
        inputs,
        ops: specs(ops),
        outputs: outputs.to_vec(),
        downstream: downstream.into(),
        input_index: 0,
        wiring: Vec::new(),
        frames_in_flight: 2,
    }
}

pub(crate) fn shape(
    epoch: u64,
    frame: u64,
    (width, height, band_height): (u32, u32, u32),
) -> FrameShape {
    FrameShape {
        epoch,
        frame,
        width,
        height,
        band_height,
        scale: 1.0,
    }
}

/// HDR content with a 1e4 : 1 range (log-uniform), and a block of all-zero rows so some bands
/// travel empty.
pub(crate) fn hdr(
    seed: u64,
    width: u32,
    height: u32,
    layer: Layer,
    zero_rows: std::ops::Range<u32>,
) -> Vec<f32> {
    let mut r = ChaCha8Rng::seed_from_u64(seed);
    let ch = layer.channels();
    let mut v = Vec::with_capacity(width as usize * height as usize * ch);
    for y in 0..height {
        for _ in 0..width as usize * ch {
            v.push(if zero_rows.contains(&y) {
                0.0
            } else {
                10f32.powf(r.random_range(-2.0..2.0f32))
            });
        }
    }
    v
}

pub(crate) fn image(layer: Layer, format: PixelFormat, data: Vec<f32>) -> LayerImage {
    LayerImage {
        layer,
        format,
        data,
    }
}

/// Values as they come out of a link format (so the in-memory reference sees what the stage sees).
pub(crate) fn quantised(format: PixelFormat, layer: Layer, data: Vec<f32>) -> Vec<f32> {
    let px = data.len() / layer.channels();
    let mut bytes = vec![0u8; px * format.bytes_per_pixel()];
    lightfold_protocol::format::pack(format, &data, 1.0, &mut bytes).unwrap();
    let mut out = vec![0.0; data.len()];
    lightfold_protocol::format::unpack(format, &bytes, 1.0, &mut out).unwrap();
    out
}

/// The operators of `ops` applied to whole frames in memory (no quantisation).
/// Typed operators from (name, JSON parameter text; empty: defaults).
pub(crate) fn specs(ops: &[(&str, &str)]) -> Vec<OpSpec> {
    ops.iter()
        .map(|(n, p)| {
            let p: serde_json::Value = if p.trim().is_empty() {
                serde_json::Value::Null
            } else {
                serde_json::from_str(p).expect("JSON parameters")
            };
            lightfold_compositor::ops::spec_from_json(n, &p).expect("operator")
        })
        .collect()
}

pub(crate) fn reference(
    ops: &[(&str, &str)],
    inputs: &[&LayerImage],
    width: u32,
    height: u32,
) -> Vec<Vec<f32>> {
    let ops = specs(ops);
    let layers: Vec<Vec<Layer>> = inputs.iter().map(|i| vec![i.layer]).collect();
    let p = Pipeline::from_ops(&ops, &layers).expect("reference pipeline");
    let pixels = width as usize * height as usize;
    let views: Vec<BandView<'_>> = inputs
        .iter()
        .map(|i| BandView::new(pixels).with(i.layer, &i.data))
        .collect();
    let outs = p.output_layers();
    let mut bufs: Vec<Vec<f32>> = outs
        .iter()
        .map(|l| vec![0.0; pixels * l.channels()])
        .collect();
    let mut m = outs
        .iter()
        .zip(bufs.iter_mut())
        .fold(BandMut::new(pixels), |m, (l, d)| m.with(*l, d));
    p.run(&views, &mut m, &mut Default::default())
        .expect("reference runs");
    bufs
}

/// Per value, the round-trip error bound of packing `values` (pixels of `format`), the
/// shared-exponent formats judged by each triple's largest channel as the protocol documents.
pub(crate) fn link_bound(format: PixelFormat, values: &[f32], scale: f32) -> Vec<f32> {
    let ch = format.channels();
    let mut out = Vec::with_capacity(values.len());
    for px in values.chunks_exact(ch) {
        for (c, &v) in px.iter().enumerate() {
            let b = if format == PixelFormat::Rgb9e5x2 {
                let triple = &px[c / 3 * 3..c / 3 * 3 + 3];
                let max = triple.iter().fold(0.0f32, |m, &x| m.max(x));
                (v - clamp_to_range(format, v, scale)).abs()
                    + quantisation_bound(format, c, max, scale)
            } else {
                channel_bound(format, c, v, scale)
            };
            out.push(b);
        }
    }
    out
}

/// Asserts `got` is within `bound` of `want` value by value (plus f32 rounding of the sums).
pub(crate) fn assert_within(got: &[f32], want: &[f32], bound: &[f32], what: &str) {
    assert_eq!(got.len(), want.len(), "{what}: length");
    let mut worst = (0.0f32, 0usize);
    for (k, ((g, w), b)) in got.iter().zip(want).zip(bound).enumerate() {
        let err = (g - w).abs();
        let allowed = b + 4.0 * f32::EPSILON * w.abs();
        assert!(
            err <= allowed,
            "{what}: value {k} is {g}, expected {w} within {allowed} (error {err})"
        );
        if allowed > 0.0 && err / allowed > worst.0 {
            worst = (err / allowed, k);
        }
    }
    eprintln!(
        "{what}: worst error is {:.2} of the bound (value {})",
        worst.0, worst.1
    );
}

/// Frame parameters that change nothing.
pub(crate) fn no_params() -> lightfold_protocol::FrameParams {
    lightfold_protocol::FrameParams {
        colors: Vec::new(),
        scale: None,
        time: None,
        lights: Vec::new(),
        rows: None,
    }
}
