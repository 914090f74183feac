//! Stage daemon benchmarks over loopback TCP, everything in this one process on real links:
//!
//! 1. Link cost: 1920×1080 dense frames, two inputs combined by `accumulate` (an upstream f16x6
//!    sum and a node's rgb9e5x2 illumination) and by `depth` (f16x6 illumination + f32 depth per
//!    input), one frame at a time: ms per frame (median, best) against the time the same bytes
//!    take over raw TCP sockets in the same topology (two senders → a relay that forwards a band's
//!    worth of bytes per band pair → a receiver), measured in the same run, frames alternating;
//!    the raw path runs once on one thread (the target's baseline) and once with its relay on a
//!    runtime worker, where the stage's tasks run (what threads alone cost).
//! 2. Pipelining: a chain of stages, each fed by a rate-paced synthetic source with its own
//!    period (one frame per period, never bursting to catch up); the steady-state frame interval
//!    at the sink against the slowest period, and the latency from the last source starting to
//!    stream a frame to the sink holding all of it.
//!
//! `cargo bench -p lightfold-compositor --bench link` (add `-- --frames N` for more link samples,
//! `--only link` or `--only pipeline` for one half, `--case NAME` for one link case, `--no-raw` to
//! profile the stage path alone, `--compute-threads N` for the stages' compute threads).

#[path = "link/raw.rs"]
mod raw;

use bytes::Bytes;
use lightfold_compositor::daemon::{CompositorOptions, run};
use lightfold_harness::driver::{ControlClient, FrameShape, LayerImage, Producer, Sink, pack_band};
use lightfold_net::{Identity, Timeouts};
use lightfold_protocol::{
    BandHeader, CompositorConfig, FrameParams, Layer, PixelFormat, Role, StageInput, stats,
};
use raw::{RawRelay, cpu_ms};
use std::time::Duration;
use tokio::net::TcpListener;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

const TOKEN: &[u8] = b"bench-token";
/// `--compute-threads N`: the stages' compute threads (default: `CompositorOptions`'s).
static COMPUTE_THREADS: std::sync::OnceLock<usize> = std::sync::OnceLock::new();
const WAIT: Duration = Duration::from_secs(60);
const ILL: Layer = Layer::Illumination;
/// Bytes of framing around a band payload: length prefix, kind byte, header.
const FRAMING: usize = lightfold_protocol::frame::BAND_PREFIX_LEN;

/// A typed operator from its name and JSON parameter text.
fn spec(name: &str, params: &str) -> lightfold_protocol::OpSpec {
    let params: serde_json::Value = serde_json::from_str(params).expect("JSON parameters");
    lightfold_compositor::ops::spec_from_json(name, &params).expect("operator")
}

fn me(role: Role, id: &str) -> Identity {
    Identity::new(TOKEN, role, id)
}

fn timeouts() -> Timeouts {
    Timeouts {
        send: WAIT,
        ..Timeouts::default()
    }
}

async fn stage(id: &str) -> (String, CancellationToken) {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let mut opts = CompositorOptions::new(id, addr.clone(), TOKEN);
    opts.timeouts = timeouts();
    if let Some(&n) = COMPUTE_THREADS.get() {
        opts.compute_threads = n;
    }
    let token = CancellationToken::new();
    tokio::spawn(run(listener, opts, token.clone()));
    (addr, token)
}

fn no_params() -> FrameParams {
    FrameParams {
        colors: vec![],
        scale: None,
        time: None,
        lights: Vec::new(),
        rows: None,
    }
}

/// Smooth HDR content (no empty bands: every band is dense).
fn content(seed: u32, width: u32, height: u32, layer: Layer) -> Vec<f32> {
    let ch = layer.channels();
    let mut v = Vec::with_capacity((width * height) as usize * ch);
    for y in 0..height {
        for x in 0..width {
            for c in 0..ch {
                let t = (x * 7 + y * 3 + c as u32 * 11 + seed * 101) % 997;
                v.push(if layer == Layer::Depth {
                    1.0 + t as f32
                } else {
                    0.01 + t as f32 * 0.1
                });
            }
        }
    }
    v
}

/// Every band of a frame, packed once; the frame id is patched per frame (the checksum covers
/// only the payload).
fn prepack(shape: &FrameShape, layers: &[LayerImage]) -> Vec<(BandHeader, Bytes)> {
    let mut out = Vec::new();
    for b in 0..shape.bands() {
        for img in layers {
            out.push(pack_band(shape, b, img).unwrap());
        }
    }
    out
}

async fn send_bands(p: &mut Producer, bands: &[(BandHeader, Bytes)], frame: u64) {
    for (h, payload) in bands {
        let h = BandHeader { frame, ..*h };
        p.send_band(h, payload.clone()).await.unwrap();
    }
}

/// The median (`stats::median`) and the least of some timings.
fn median_and_best(v: &[f64]) -> (f64, f64) {
    let s = stats::sorted(v);
    (stats::median(&s).expect("timed frames"), s[0])
}

struct LinkCase {
    name: &'static str,
    inputs: [Vec<(Layer, PixelFormat)>; 2],
    op: (&'static str, &'static str),
    outputs: Vec<(Layer, PixelFormat)>,
}

async fn link_cost(case: &LinkCase, frames: usize, with_raw: bool) {
    let (width, height, band_height) = (1920u32, 1080u32, 64u32);
    let (stage_addr, stop) = stage("stage").await;
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let sink_addr = listener.local_addr().unwrap().to_string();
    let mut sink = Sink::new(listener, me(Role::Coordinator, "coord"), timeouts());
    let mut ctl = ControlClient::connect(
        &stage_addr,
        &me(Role::Coordinator, "coord"),
        timeouts(),
        WAIT,
    )
    .await
    .unwrap();
    let cfg = CompositorConfig {
        epoch: 1,
        width,
        height,
        band_height,
        inputs: ["a", "b"]
            .iter()
            .zip(&case.inputs)
            .map(|(p, l)| StageInput {
                peer: p.to_string(),
                layers: l.clone(),
            })
            .collect(),
        ops: vec![spec(case.op.0, case.op.1)],
        outputs: case.outputs.clone(),
        downstream: sink_addr,
        input_index: 0,
        wiring: Vec::new(),
        frames_in_flight: 2,
    };
    ctl.configure(cfg, WAIT).await.unwrap();
    let shape = |frame| FrameShape {
        epoch: 1,
        frame,
        width,
        height,
        band_height,
        scale: 1.0,
    };
    let packed: Vec<Vec<(BandHeader, Bytes)>> = case
        .inputs
        .iter()
        .enumerate()
        .map(|(i, layers)| {
            let imgs: Vec<LayerImage> = layers
                .iter()
                .map(|&(l, f)| LayerImage {
                    layer: l,
                    format: f,
                    data: content(i as u32, width, height, l),
                })
                .collect();
            prepack(&shape(0), &imgs)
        })
        .collect();
    let mut a = Producer::connect(&stage_addr, &me(Role::Node, "a"), timeouts(), WAIT)
        .await
        .unwrap();
    let mut b = Producer::connect(&stage_addr, &me(Role::Node, "b"), timeouts(), WAIT)
        .await
        .unwrap();
    let bands = height.div_ceil(band_height);
    let out_sizes: Vec<usize> = (0..bands)
        .flat_map(|b| {
            let rows = band_height.min(height - b * band_height) as usize;
            case.outputs
                .iter()
                .map(move |(_, f)| width as usize * rows * f.bytes_per_pixel() + FRAMING)
        })
        .collect();
    let in_sizes: Vec<Vec<usize>> = packed
        .iter()
        .map(|bs| bs.iter().map(|(_, p)| p.len() + FRAMING).collect())
        .collect();
    let mut raw = RawRelay::new(in_sizes.clone(), out_sizes.clone()).await;
    let mut spawned = RawRelay::new(in_sizes.clone(), out_sizes.clone())
        .await
        .spawn_relay();

    // Stage and raw frames alternate, so both see the same machine.
    let mut times = Vec::new();
    let mut raw_times = Vec::new();
    let mut spawned_times = Vec::new();
    let mut cpu = (0.0, 0.0, 0.0);
    let mut work = Vec::new();
    let mut out_bytes = 0usize;
    for f in 0..frames as u64 + 3 {
        ctl.render(1, f, no_params()).await.unwrap();
        let start = Instant::now();
        let cpu0 = cpu_ms();
        let recv = async {
            let mut bytes = 0;
            for _ in 0..out_sizes.len() {
                let (_, p) = sink.next_band(Instant::now() + WAIT).await.unwrap();
                bytes += p.len() + FRAMING;
            }
            bytes
        };
        let (_, _, bytes) = tokio::join!(
            send_bands(&mut a, &packed[0], f),
            send_bands(&mut b, &packed[1], f),
            recv
        );
        let t = start.elapsed().as_secs_f64() * 1e3;
        let cpu1 = cpu_ms();
        let done = ctl.frame_done(f, WAIT).await.unwrap();
        let cpu2 = cpu_ms();
        let r = if with_raw {
            raw.frame().await
        } else {
            f64::NAN
        };
        let cpu3 = cpu_ms();
        let r2 = if with_raw {
            spawned.frame().await
        } else {
            f64::NAN
        };
        let cpu4 = cpu_ms();
        out_bytes = bytes;
        if f >= 3 {
            times.push(t);
            raw_times.push(r);
            spawned_times.push(r2);
            cpu.0 += cpu1 - cpu0;
            cpu.1 += cpu3 - cpu2;
            cpu.2 += cpu4 - cpu3;
            work.push((
                done.composite_us as f64 / 1e3,
                done.pack_us as f64 / 1e3,
                done.send_us as f64 / 1e3,
            ));
        }
    }
    stop.cancel();
    assert_eq!(
        out_bytes,
        out_sizes.iter().sum::<usize>(),
        "dense output bands"
    );
    let raw = raw_times;

    let in_bytes: usize = in_sizes.iter().flatten().sum();
    let (med, best) = median_and_best(&times);
    let (rmed, rbest) = median_and_best(&raw);
    let (smed, sbest) = median_and_best(&spawned_times);
    let part = |k: fn(&(f64, f64, f64)) -> f64| work.iter().map(k).collect::<Vec<_>>();
    let (combine, _) = median_and_best(&part(|w| w.0));
    let (pack, _) = median_and_best(&part(|w| w.1));
    let (send, _) = median_and_best(&part(|w| w.2));
    println!(
        "link {:<10} in {:>5.1} MB + out {:>5.1} MB per frame | stage median {:>6.1} ms best {:>6.1} ms | raw TCP median {:>6.1} ms best {:>6.1} ms | ratio {:.2} (best {:.2})",
        case.name,
        in_bytes as f64 / 1e6,
        out_bytes as f64 / 1e6,
        med,
        best,
        rmed,
        rbest,
        med / rmed,
        best / rbest
    );
    println!(
        "     {:<10} raw TCP, relay on a runtime worker: median {smed:>6.1} ms best {sbest:>6.1} ms | stage ratio to it {:.2} (best {:.2})",
        case.name,
        med / smed,
        best / sbest
    );
    println!(
        "     {:<10} stage work per frame (median): unpack+operate {combine:.1} ms, pack {pack:.1} ms, writing {send:.1} ms; process CPU per frame: stage path {:.1} ms, raw {:.1} ms, raw relay on a worker {:.1} ms",
        case.name,
        cpu.0 / frames as f64,
        cpu.1 / frames as f64,
        cpu.2 / frames as f64
    );
}

/// A chain of stages, source k paced at `periods[k]`; returns (interval, latency) medians in ms.
async fn pipelining(periods: &[u64], frames: u64) {
    let (width, height, band_height) = (800u32, 600u32, 32u32);
    let n = periods.len();
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let sink_addr = listener.local_addr().unwrap().to_string();
    let mut sink = Sink::new(listener, me(Role::Coordinator, "coord"), timeouts());
    let mut stages = Vec::new();
    for k in 0..n {
        stages.push(stage(&format!("c{k}")).await);
    }
    let node_fmt = PixelFormat::Rgb9e5x2;
    let link_fmt = PixelFormat::F16x6;
    let mut ctls = Vec::new();
    for k in 0..n {
        let mut ctl = ControlClient::connect(
            &stages[k].0,
            &me(Role::Coordinator, "coord"),
            timeouts(),
            WAIT,
        )
        .await
        .unwrap();
        let node = StageInput {
            peer: format!("n{k}"),
            layers: vec![(ILL, node_fmt)],
        };
        let (inputs, params) = if k == 0 {
            (vec![node], r#"{"upstream": false, "colors": [[1, 1, 1]]}"#)
        } else {
            let up = StageInput {
                peer: format!("c{}", k - 1),
                layers: vec![(ILL, link_fmt)],
            };
            (vec![up, node], r#"{"colors": [[1, 1, 1]]}"#)
        };
        let last = k + 1 == n;
        let cfg = CompositorConfig {
            epoch: 1,
            width,
            height,
            band_height,
            inputs,
            ops: vec![spec("accumulate", params)],
            outputs: vec![(ILL, if last { PixelFormat::F32x6 } else { link_fmt })],
            downstream: if last {
                sink_addr.clone()
            } else {
                stages[k + 1].0.clone()
            },
            input_index: 0,
            wiring: Vec::new(),
            frames_in_flight: 2,
        };
        ctl.configure(cfg, WAIT).await.unwrap();
        for f in 0..frames {
            ctl.render(1, f, no_params()).await.unwrap();
        }
        ctls.push(ctl);
    }
    let shape = FrameShape {
        epoch: 1,
        frame: 0,
        width,
        height,
        band_height,
        scale: 1.0,
    };
    // A source renders one frame per period and never bursts to catch up (as a render node):
    // each records when it started streaming each frame.
    let mut started = Vec::new();
    for (k, &period) in periods.iter().enumerate() {
        let img = LayerImage {
            layer: ILL,
            format: node_fmt,
            data: content(k as u32, width, height, ILL),
        };
        let bands = prepack(&shape, &[img]);
        let mut p = Producer::connect(
            &stages[k].0,
            &me(Role::Node, &format!("n{k}")),
            timeouts(),
            WAIT,
        )
        .await
        .unwrap();
        started.push(tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_millis(period));
            tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
            let mut starts = Vec::new();
            for f in 0..frames {
                tick.tick().await;
                starts.push(Instant::now());
                send_bands(&mut p, &bands, f).await;
            }
            starts
        }));
    }
    let bands = height.div_ceil(band_height);
    let mut done = Vec::new();
    for _ in 0..frames {
        for _ in 0..bands {
            sink.next_band(Instant::now() + WAIT).await.unwrap();
        }
        done.push(Instant::now());
    }
    for (ctl, (_, stop)) in ctls.iter_mut().zip(&stages) {
        ctl.frame_done(frames - 1, WAIT).await.unwrap();
        stop.cancel();
    }
    let slowest = *periods.iter().max().unwrap();
    let warm = (frames / 4) as usize;
    // The steady-state interval: the least-squares slope of completion time over frame number
    // (endpoints alone would be at the mercy of one late frame).
    let steady = &done[warm..];
    let base = steady[0];
    let n_s = steady.len() as f64;
    let xs: Vec<f64> = (0..steady.len()).map(|i| i as f64).collect();
    let ys: Vec<f64> = steady
        .iter()
        .map(|t| (*t - base).as_secs_f64() * 1e3)
        .collect();
    let (mx, my) = (xs.iter().sum::<f64>() / n_s, ys.iter().sum::<f64>() / n_s);
    let cov: f64 = xs.iter().zip(&ys).map(|(x, y)| (x - mx) * (y - my)).sum();
    let var: f64 = xs.iter().map(|x| (x - mx) * (x - mx)).sum();
    let interval = cov / var;
    let mut last_start = vec![Instant::now(); frames as usize];
    for (k, s) in started.into_iter().enumerate() {
        let starts = s.await.unwrap();
        for (f, t) in starts.into_iter().enumerate() {
            last_start[f] = if k == 0 { t } else { last_start[f].max(t) };
        }
    }
    // From the moment the last source starts streaming frame f to the sink holding all of it.
    let latencies: Vec<f64> = done
        .iter()
        .zip(&last_start)
        .skip(warm)
        .map(|(d, s)| (*d - *s).as_secs_f64() * 1e3)
        .collect();
    let worst = latencies.iter().copied().fold(0.0, f64::max);
    let (latency, _) = median_and_best(&latencies);
    println!(
        "pipeline {n} stages, source periods {periods:?} ms: interval {interval:.1} ms = {:.3} x slowest ({slowest} ms); latency median {latency:.1} ms = {:.2} frames (worst {:.2})",
        interval / slowest as f64,
        latency / slowest as f64,
        worst / slowest as f64
    );
}

fn main() {
    let mut frames = 30usize;
    let args: Vec<String> = std::env::args().collect();
    if let Some(i) = args.iter().position(|a| a == "--frames") {
        frames = args
            .get(i + 1)
            .and_then(|v| v.parse().ok())
            .unwrap_or(frames);
    }
    if let Some(n) = args
        .iter()
        .position(|a| a == "--compute-threads")
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
    {
        let _ = COMPUTE_THREADS.set(n);
    }
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let only = args
        .iter()
        .position(|a| a == "--only")
        .and_then(|i| args.get(i + 1).cloned())
        .unwrap_or_default();
    let (links, pipes) = (only != "pipeline", only != "link");
    // For profiling the stage path alone: no raw frames (the ratios then read NaN).
    let with_raw = !args.iter().any(|a| a == "--no-raw");
    // One link case by name: `--case accumulate`, `--case depth`, ….
    let case_filter = args
        .iter()
        .position(|a| a == "--case")
        .and_then(|i| args.get(i + 1).cloned());
    rt.block_on(async {
        let accumulate = LinkCase {
            name: "accumulate",
            inputs: [
                vec![(ILL, PixelFormat::F16x6)],
                vec![(ILL, PixelFormat::Rgb9e5x2)],
            ],
            op: ("accumulate", r#"{"colors": [[1, 1, 1]]}"#),
            outputs: vec![(ILL, PixelFormat::F16x6)],
        };
        let layers = vec![
            (ILL, PixelFormat::F16x6),
            (Layer::Depth, PixelFormat::DepthF32),
        ];
        let depth = LinkCase {
            name: "depth",
            inputs: [layers.clone(), layers.clone()],
            op: ("depth", r#"{"inputs": 2, "layers": ["illumination"]}"#),
            outputs: vec![
                (Layer::Depth, PixelFormat::DepthF32),
                (ILL, PixelFormat::F16x6),
            ],
        };
        let floats = LinkCase {
            name: "acc f32x6",
            inputs: [
                vec![(ILL, PixelFormat::F32x6)],
                vec![(ILL, PixelFormat::F32x6)],
            ],
            op: ("accumulate", r#"{"colors": [[1, 1, 1]]}"#),
            outputs: vec![(ILL, PixelFormat::F32x6)],
        };
        if links {
            for case in [&accumulate, &floats, &depth] {
                if case_filter.as_deref().is_none_or(|c| c == case.name) {
                    link_cost(case, frames, with_raw).await;
                }
            }
        }
        if pipes {
            pipelining(&[40, 60, 50, 45], 80).await;
            pipelining(&[60, 60, 60, 60], 80).await;
        }
    });
}
