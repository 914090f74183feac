//! Eight `lightfold compositor` processes on loopback, driven over the real protocol: first as a
//! chain of `accumulate` stages (the paper's topology), then — reconfigured to a new epoch without
//! restarting — as a tree of `accumulate` leaves and `join`s. Fed random HDR content (1e4 : 1)
//! with an odd image size and a band height that does not divide it, each produces the operators'
//! in-memory result within the bound of its link formats. The stages then exit cleanly on the
//! coordinator's `Shutdown` or on SIGTERM; every process is killed at the end, even on failure.

use lightfold_compositor::ops::{BandMut, BandView};
use lightfold_compositor::pipeline::Pipeline;
use lightfold_harness::driver::{ControlClient, FrameShape, LayerImage, Producer, Sink};
use lightfold_net::{Identity, Timeouts};
use lightfold_protocol::format::{channel_bound, clamp_to_range, quantisation_bound};
use lightfold_protocol::{CompositorConfig, FrameParams, Layer, PixelFormat, Role, StageInput};
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::Duration;
use tokio::net::TcpListener;

const TOKEN: &str = "chain-test-token";
const STAGES: usize = 8;
const WIDTH: u32 = 61;
const HEIGHT: u32 = 37;
const BAND: u32 = 8;
const WAIT: Duration = Duration::from_secs(15);
const ILL: Layer = Layer::Illumination;
const NODE_FMT: PixelFormat = PixelFormat::Rgb9e5x2;
const LINK_FMT: PixelFormat = PixelFormat::F16x6;
const SINK_FMT: PixelFormat = PixelFormat::F32x6;

/// The spawned daemons; killed and reaped on drop, so a failing test leaves no process behind.
struct Daemons(Vec<Child>);

impl Drop for Daemons {
    fn drop(&mut self) {
        for c in &mut self.0 {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

fn spawn(id: &str) -> (Child, String) {
    let log = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("compositor-chain-{id}.log"));
    let mut child = Command::new(env!("CARGO_BIN_EXE_lightfold"))
        .args([
            "compositor",
            "--listen",
            "127.0.0.1:0",
            "--id",
            id,
            "--input-timeout",
            "10",
        ])
        .env("LIGHTFOLD_TOKEN", TOKEN)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(&log).expect("log file"))
        .spawn()
        .expect("spawn lightfold compositor");
    let stdout = child.stdout.take().expect("stdout");
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut lines = BufReader::new(stdout).lines();
        let _ = tx.send(lines.next());
        for _ in lines {}
    });
    let line = match rx.recv_timeout(WAIT) {
        Ok(Some(Ok(line))) => line,
        other => {
            let _ = child.kill();
            panic!("{id} did not announce its address: {other:?}");
        }
    };
    let addr = line
        .strip_prefix("listening ")
        .expect("listening line")
        .trim()
        .to_string();
    (child, addr)
}

fn timeouts() -> Timeouts {
    Timeouts {
        connect: Duration::from_secs(2),
        handshake: Duration::from_secs(5),
        send: Duration::from_secs(15),
        ..Timeouts::default()
    }
}

fn me(role: Role, id: &str) -> Identity {
    Identity::new(TOKEN.as_bytes(), role, id)
}

/// xorshift64*: the test's own deterministic generator.
struct Rng(u64);

impl Rng {
    fn unit(&mut self) -> f32 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// Log-uniform HDR illumination over [0.01, 100] (1e4 : 1); rows `zero` are black (empty bands).
fn hdr(seed: u64, zero: std::ops::Range<u32>) -> LayerImage {
    let mut r = Rng(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1);
    let mut data = Vec::new();
    for y in 0..HEIGHT {
        for _ in 0..WIDTH * 6 {
            let v = 10f32.powf(4.0 * r.unit() - 2.0);
            data.push(if zero.contains(&y) { 0.0 } else { v });
        }
    }
    LayerImage {
        layer: ILL,
        format: NODE_FMT,
        data,
    }
}

fn colour(k: usize) -> [f32; 3] {
    [0.5 + 0.25 * k as f32, 1.0, 2.0 - 0.125 * k as f32]
}

fn input(peer: &str, format: PixelFormat) -> StageInput {
    StageInput {
        peer: peer.into(),
        layers: vec![(ILL, format)],
    }
}

fn stage_config(
    epoch: u64,
    inputs: Vec<StageInput>,
    op: (&str, String),
    out: PixelFormat,
    downstream: &str,
) -> CompositorConfig {
    CompositorConfig {
        epoch,
        width: WIDTH,
        height: HEIGHT,
        band_height: BAND,
        inputs,
        ops: if op.0.is_empty() {
            vec![]
        } else {
            let params: serde_json::Value = serde_json::from_str(&op.1).expect("JSON parameters");
            vec![lightfold_compositor::ops::spec_from_json(op.0, &params).expect("operator")]
        },
        outputs: vec![(ILL, out)],
        downstream: downstream.into(),
        input_index: 0,
        wiring: Vec::new(),
        frames_in_flight: 2,
    }
}

/// Per value, the round-trip bound of packing `values` in `format` (rgb9e5 by triple maximum).
fn link_bound(format: PixelFormat, values: &[f32]) -> Vec<f32> {
    let mut out = Vec::with_capacity(values.len());
    for px in values.chunks_exact(6) {
        for (c, &v) in px.iter().enumerate() {
            out.push(if format == PixelFormat::Rgb9e5x2 {
                let max = px[c / 3 * 3..c / 3 * 3 + 3]
                    .iter()
                    .fold(0.0f32, |m, &x| m.max(x));
                (v - clamp_to_range(format, v, 1.0)).abs() + quantisation_bound(format, c, max, 1.0)
            } else {
                channel_bound(format, c, v, 1.0)
            });
        }
    }
    out
}

/// A value in memory with the error bound it carries.
#[derive(Clone)]
struct Bounded {
    value: Vec<f32>,
    error: Vec<f32>,
}

/// One stage in memory: its operator over whole frames, the error of its inputs carried through
/// (scaled by the colour for accumulate), plus its output link's quantisation.
fn stage_in_memory(
    op: &str,
    params: &str,
    inputs: &[Bounded],
    colours: &[[f32; 3]],
    out: PixelFormat,
) -> Bounded {
    let pixels = (WIDTH * HEIGHT) as usize;
    let params: serde_json::Value = serde_json::from_str(params).expect("JSON parameters");
    let ops = vec![lightfold_compositor::ops::spec_from_json(op, &params).expect("operator")];
    let p = Pipeline::from_ops(&ops, &vec![vec![ILL]; inputs.len()]).expect("pipeline");
    let views: Vec<BandView<'_>> = inputs
        .iter()
        .map(|b| BandView::new(pixels).with(ILL, &b.value))
        .collect();
    let mut value = vec![0.0; pixels * 6];
    let mut m = BandMut::new(pixels).with(ILL, &mut value);
    p.run(&views, &mut m, &mut Default::default()).expect("run");
    // Inputs beyond the colours (an upstream sum, join inputs) carry their error at weight 1.
    let first_coloured = inputs.len() - colours.len();
    let mut error = vec![0.0f32; pixels * 6];
    for (i, b) in inputs.iter().enumerate() {
        for (k, e) in error.iter_mut().enumerate() {
            let w = if i >= first_coloured {
                colours[i - first_coloured][k % 3]
            } else {
                1.0
            };
            *e += w * b.error[k];
        }
    }
    // The packed value is at most `error` away from `value`: judge the link there, and allow
    // f32 rounding of the sums.
    let worst: Vec<f32> = value.iter().zip(&error).map(|(v, e)| v + e).collect();
    let link = if out == SINK_FMT {
        vec![0.0; worst.len()]
    } else {
        link_bound(out, &worst)
    };
    for ((e, l), v) in error.iter_mut().zip(link).zip(&value) {
        *e += l + 2.0 * f32::EPSILON * v;
    }
    Bounded { value, error }
}

fn node(img: &LayerImage) -> Bounded {
    Bounded {
        value: img.data.clone(),
        error: link_bound(NODE_FMT, &img.data),
    }
}

fn accumulate(upstream: bool, colours: &[[f32; 3]]) -> String {
    let list: Vec<String> = colours
        .iter()
        .map(|c| format!("[{}, {}, {}]", c[0], c[1], c[2]))
        .collect();
    format!(
        r#"{{"upstream": {upstream}, "colors": [{}]}}"#,
        list.join(", ")
    )
}

fn check(got: &[f32], want: &Bounded, what: &str) {
    let mut worst = 0.0f32;
    for (k, (g, (w, b))) in got
        .iter()
        .zip(want.value.iter().zip(&want.error))
        .enumerate()
    {
        let err = (g - w).abs();
        assert!(err <= *b, "{what}: value {k} is {g}, expected {w} ± {b}");
        if *b > 0.0 {
            worst = worst.max(err / b);
        }
    }
    eprintln!("{what}: worst error {worst:.2} of the bound");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn eight_processes_as_a_chain_then_a_tree_match_the_in_memory_result() {
    let mut daemons = Daemons(Vec::new());
    let mut addrs = Vec::new();
    for k in 0..STAGES {
        let (child, addr) = spawn(&format!("c{k}"));
        daemons.0.push(child);
        addrs.push(addr);
    }
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let sink_addr = listener.local_addr().unwrap().to_string();
    let mut sink = Sink::new(listener, me(Role::Coordinator, "coord"), timeouts());
    let mut ctl = Vec::new();
    for a in &addrs {
        ctl.push(
            ControlClient::connect(a, &me(Role::Coordinator, "coord"), timeouts(), WAIT)
                .await
                .unwrap(),
        );
    }
    let images: Vec<LayerImage> = (0..STAGES as u64)
        .map(|k| hdr(k + 1, if k % 3 == 0 { 8..16 } else { 0..0 }))
        .collect();
    let shape = |epoch, frame| FrameShape {
        epoch,
        frame,
        width: WIDTH,
        height: HEIGHT,
        band_height: BAND,
        scale: 1.0,
    };
    let no_params = || FrameParams {
        colors: vec![],
        scale: None,
        time: None,
        lights: Vec::new(),
        rows: None,
    };

    // Epoch 1: c0 → c1 → … → c7 → sink, node k feeding stage k.
    for k in 0..STAGES {
        let node_in = input(&format!("n{k}"), NODE_FMT);
        let (inputs, params) = if k == 0 {
            (vec![node_in], accumulate(false, &[colour(k)]))
        } else {
            (
                vec![input(&format!("c{}", k - 1), LINK_FMT), node_in],
                accumulate(true, &[colour(k)]),
            )
        };
        let (out, down) = if k + 1 < STAGES {
            (LINK_FMT, addrs[k + 1].as_str())
        } else {
            (SINK_FMT, sink_addr.as_str())
        };
        let cfg = stage_config(1, inputs, ("accumulate", params), out, down);
        ctl[k].configure(cfg, WAIT).await.unwrap();
    }
    let mut producers = Vec::new();
    for (k, a) in addrs.iter().enumerate() {
        producers.push(
            Producer::connect(a, &me(Role::Node, &format!("n{k}")), timeouts(), WAIT)
                .await
                .unwrap(),
        );
    }
    // Two frames in flight through the chain.
    for frame in 1..=2 {
        for c in ctl.iter_mut() {
            c.render(1, frame, no_params()).await.unwrap();
        }
        for (p, img) in producers.iter_mut().zip(&images) {
            p.send_frame(&shape(1, frame), std::slice::from_ref(img))
                .await
                .unwrap();
        }
    }
    let mut want = stage_in_memory(
        "accumulate",
        &accumulate(false, &[colour(0)]),
        &[node(&images[0])],
        &[colour(0)],
        LINK_FMT,
    );
    for (k, img) in images.iter().enumerate().skip(1) {
        let out = if k + 1 < STAGES { LINK_FMT } else { SINK_FMT };
        want = stage_in_memory(
            "accumulate",
            &accumulate(true, &[colour(k)]),
            &[want, node(img)],
            &[colour(k)],
            out,
        );
    }
    for frame in 1..=2 {
        let got = sink
            .recv_frame(&shape(1, frame), &[(ILL, SINK_FMT)], WAIT)
            .await
            .unwrap();
        check(&got[0].data, &want, &format!("chain frame {frame}"));
        for c in ctl.iter_mut() {
            c.frame_done(frame, WAIT).await.unwrap();
        }
    }

    // Epoch 2, same processes: leaves c0..c3 accumulate two nodes each, c4 and c5 join pairs of
    // leaves, c6 joins those, c7 relays to the sink.
    let down = |k: usize| match k {
        0 | 1 => addrs[4].clone(),
        2 | 3 => addrs[5].clone(),
        4 | 5 => addrs[6].clone(),
        6 => addrs[7].clone(),
        _ => sink_addr.clone(),
    };
    let join = ("join", r#"{"inputs": 2}"#.to_string());
    for (k, c) in ctl.iter_mut().enumerate() {
        let cfg = match k {
            0..=3 => {
                let ins = vec![
                    input(&format!("n{}", 2 * k), NODE_FMT),
                    input(&format!("n{}", 2 * k + 1), NODE_FMT),
                ];
                let params = accumulate(false, &[colour(2 * k), colour(2 * k + 1)]);
                stage_config(2, ins, ("accumulate", params), LINK_FMT, &down(k))
            }
            4..=6 => {
                let first = if k == 6 { 4 } else { 2 * (k - 4) };
                let ins = vec![
                    input(&format!("c{first}"), LINK_FMT),
                    input(&format!("c{}", first + 1), LINK_FMT),
                ];
                stage_config(2, ins, join.clone(), LINK_FMT, &down(k))
            }
            _ => stage_config(
                2,
                vec![input("c6", LINK_FMT)],
                ("", String::new()),
                SINK_FMT,
                &down(k),
            ),
        };
        c.configure(cfg, WAIT).await.unwrap();
    }
    // The chain's producers go first: a stage refuses a second link claiming a producer whose
    // link is alive (docs/cluster-protocol.md, "Hostile peers"), as a real producer closes its
    // old link before it dials again.
    drop(producers);
    let mut producers = Vec::new();
    for k in 0..STAGES {
        let a = &addrs[k / 2];
        producers.push(
            Producer::connect(a, &me(Role::Node, &format!("n{k}")), timeouts(), WAIT)
                .await
                .unwrap(),
        );
    }
    for c in ctl.iter_mut() {
        c.render(2, 3, no_params()).await.unwrap();
    }
    for (p, img) in producers.iter_mut().zip(&images) {
        p.send_frame(&shape(2, 3), std::slice::from_ref(img))
            .await
            .unwrap();
    }
    let leaves: Vec<Bounded> = (0..4)
        .map(|k| {
            let cs = [colour(2 * k), colour(2 * k + 1)];
            let ins = [node(&images[2 * k]), node(&images[2 * k + 1])];
            stage_in_memory("accumulate", &accumulate(false, &cs), &ins, &cs, LINK_FMT)
        })
        .collect();
    let j = |a: &Bounded, b: &Bounded| {
        stage_in_memory("join", &join.1, &[a.clone(), b.clone()], &[], LINK_FMT)
    };
    let left = j(&leaves[0], &leaves[1]);
    let right = j(&leaves[2], &leaves[3]);
    let tree = j(&left, &right);
    let got = sink
        .recv_frame(&shape(2, 3), &[(ILL, SINK_FMT)], WAIT)
        .await
        .unwrap();
    check(&got[0].data, &tree, "tree frame");
    for c in ctl.iter_mut() {
        c.frame_done(3, WAIT).await.unwrap();
    }

    // Clean exit on the coordinator's word, and for the last one on SIGTERM.
    for c in ctl.iter_mut().take(STAGES - 1) {
        c.shutdown().await.unwrap();
    }
    let pid = daemons.0[STAGES - 1].id().to_string();
    let killed = Command::new("kill").args(["-TERM", &pid]).status().unwrap();
    assert!(killed.success(), "kill -TERM {pid}");
    let deadline = std::time::Instant::now() + WAIT;
    for (k, child) in daemons.0.iter_mut().enumerate() {
        loop {
            if let Some(status) = child.try_wait().unwrap() {
                assert!(status.success(), "c{k} exited with {status}");
                break;
            }
            assert!(
                std::time::Instant::now() < deadline,
                "c{k} did not exit after Shutdown or SIGTERM"
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }
}
