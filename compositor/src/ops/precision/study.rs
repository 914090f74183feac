//! The precision study: a chain of `accumulate` stages over synthetic node illumination, with the
//! node links and the partial sum between stages packed and unpacked in chosen formats, compared
//! with the exact (f64) sum. Deterministic: the content comes from a seeded generator here, so the
//! tests and `cargo bench --bench precision` (which prints docs/precision.md's table) agree.

use super::{LinkFormat, chain_bound};
use crate::ops::{Accumulate, BandMut, BandView, Operator};
use lightfold_protocol::format::{self, FormatError};
use lightfold_protocol::{Layer, PixelFormat};
use serde_json::json;

/// The synthetic content. Each pixel has a brightness `T`, log-uniform over the content's range;
/// its diffuse channels are `T·u` and its specular channels `T·k·u` with `u` uniform in
/// [0.25, 1] per channel and `k` log-uniform in [0.01, 1] per pixel (coloured surfaces, highlights
/// of every strength). The final value of each channel is spread over the nodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Content {
    /// `T` over [0.01, 100]: 1e4 : 1 with highlights far above 1.
    Hdr,
    /// `T` over [1e-4, 1e-2]: a dim scene, all of it far below 1.
    Dark,
}

impl Content {
    /// log10 of the darkest and brightest pixel brightness.
    fn decades(self) -> (f64, f64) {
        match self {
            Content::Hdr => (-2.0, 2.0),
            Content::Dark => (-4.0, -2.0),
        }
    }

    /// The value shown as white: 1 for HDR (highlights clip), the brightest pixel for the dark
    /// scene (an exposure of 100).
    pub fn white(self) -> f64 {
        match self {
            Content::Hdr => 1.0,
            Content::Dark => 1e-2,
        }
    }

    /// Errors are relative to `max(exact, floor)`: one 8-bit sRGB step above black is
    /// 1/(255·12.92) ≈ 3.0e-4 of white, so smaller values are invisible and only their absolute
    /// error against this floor matters.
    pub fn floor(self) -> f64 {
        self.white() / (255.0 * 12.92)
    }
}

/// How a fixed-point link gets its scale.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Scale {
    /// A constant chosen in advance (display white, 1.0, in the study).
    Fixed(f32),
    /// The frame's true maximum value (what a coordinator measuring the previous frame aims at).
    TrueMax,
}

/// One run of the study.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Setup {
    pub content: Content,
    pub stages: usize,
    pub pixels: usize,
    /// Format of each node's link; `None` keeps node illumination exact (f32).
    pub node: Option<(PixelFormat, Scale)>,
    /// Format of the partial sum between stages (packed after every stage, the last included).
    pub chain: (PixelFormat, Scale),
    pub seed: u64,
}

/// What the run measured.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Outcome {
    /// RMS over channels of (result − exact) / max(exact, floor) (`Content::floor`).
    pub rms_rel: f64,
    /// Largest |result − exact| / max(exact, floor) over channels.
    pub max_rel: f64,
    /// (Σ result − Σ exact) / Σ exact over the frame.
    pub energy_bias: f64,
    /// Pixels the last chain hop reported saturated.
    pub saturated: u64,
    /// Node-band pixels the node links reported saturated, summed over the nodes.
    pub node_saturated: u64,
    /// Pixels whose brightness is in the darkest decade of the content.
    pub dark: u64,
    /// Of those, pixels that kept less than half their light (sum of their six channels).
    pub dark_lost: u64,
    /// Channels outside `chain_bound` (only meaningful with exact node links).
    pub over_bound: u64,
}

/// A small deterministic generator (SplitMix64), so the library needs no random-number crate.
struct Mix(u64);

impl Mix {
    fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The per-node colours and the node illumination of stage `n`: the final value of each channel
/// split into random shares (mean 1/stages) over the nodes, divided by the node's colour.
struct Nodes {
    brightness: Vec<f32>,
    finals: Vec<f32>,
    colors: Vec<[f32; 3]>,
    stages: usize,
    seed: u64,
}

impl Nodes {
    fn new(content: Content, stages: usize, pixels: usize, seed: u64) -> Nodes {
        let mut r = Mix(seed);
        let (lo, hi) = content.decades();
        let mut brightness = Vec::with_capacity(pixels);
        let mut finals = Vec::with_capacity(pixels * 6);
        for _ in 0..pixels {
            let t = 10f64.powf(lo + (hi - lo) * r.unit());
            let k = 10f64.powf(-2.0 * r.unit());
            brightness.push(t as f32);
            for ch in 0..6 {
                let u = 0.25 + 0.75 * r.unit();
                finals.push((if ch < 3 { t * u } else { t * k * u }) as f32);
            }
        }
        let colors = (0..stages)
            .map(|_| std::array::from_fn(|_| (0.6 + 0.4 * r.unit()) as f32))
            .collect();
        Nodes {
            brightness,
            finals,
            colors,
            stages,
            seed,
        }
    }

    fn node(&self, n: usize, out: &mut [f32]) {
        let mut r = Mix(self.seed ^ (n as u64 + 1).wrapping_mul(0xA24B_AED4_963E_E407));
        let c = self.colors[n];
        for (k, (o, f)) in out.iter_mut().zip(&self.finals).enumerate() {
            let share = 2.0 * r.unit() / self.stages as f64;
            *o = (f64::from(*f) * share / f64::from(c[k % 3])) as f32;
        }
    }
}

fn scale_of(s: Scale, max: f32) -> f32 {
    match s {
        Scale::Fixed(v) => v,
        Scale::TrueMax => max,
    }
}

/// Packs and unpacks `v` in place through `link`; returns the saturated pixel count.
fn round_trip(link: LinkFormat, v: &mut [f32], bytes: &mut Vec<u8>) -> Result<u64, FormatError> {
    bytes.resize(v.len() / 6 * link.format.bytes_per_pixel(), 0);
    let stats = format::pack(link.format, v, link.scale, bytes)?;
    format::unpack(link.format, bytes, link.scale, v)?;
    Ok(stats.saturated)
}

/// Runs one setup (see the module documentation).
pub fn run(setup: &Setup) -> Result<Outcome, FormatError> {
    let (pixels, stages) = (setup.pixels, setup.stages);
    let nodes = Nodes::new(setup.content, stages, pixels, setup.seed);
    // The exact sum (f64 of the f32 products the operator forms) and the largest node value.
    let mut exact = vec![0f64; pixels * 6];
    let mut local = vec![0f32; pixels * 6];
    let mut node_max = 0f32;
    for n in 0..stages {
        nodes.node(n, &mut local);
        for (k, (e, v)) in exact.iter_mut().zip(&local).enumerate() {
            *e += f64::from(nodes.colors[n][k % 3] * v);
            node_max = node_max.max(*v);
        }
    }
    let final_max = exact.iter().fold(0f64, |m, v| m.max(*v)) as f32;
    let chain = LinkFormat::new(setup.chain.0, scale_of(setup.chain.1, final_max));
    let node_link = setup
        .node
        .map(|(f, s)| LinkFormat::new(f, scale_of(s, node_max)));

    let mut partial = vec![0f32; pixels * 6];
    let mut next = vec![0f32; pixels * 6];
    let mut bytes = Vec::new();
    let (mut saturated, mut node_saturated) = (0, 0);
    for n in 0..stages {
        nodes.node(n, &mut local);
        if let Some(link) = node_link {
            node_saturated += round_trip(link, &mut local, &mut bytes)?;
        }
        let op = Accumulate::new(&json!({"upstream": n > 0, "colors": [nodes.colors[n]]}))
            .expect("study parameters are valid");
        let mut views = Vec::new();
        if n > 0 {
            views.push(BandView::new(pixels).with(Layer::Illumination, &partial));
        }
        views.push(BandView::new(pixels).with(Layer::Illumination, &local));
        let mut out = BandMut::new(pixels).with(Layer::Illumination, &mut next);
        op.apply(&views, &mut out)
            .expect("study bands are well formed");
        std::mem::swap(&mut partial, &mut next);
        saturated = round_trip(chain, &mut partial, &mut bytes)?;
    }
    let mut o = measure(setup, &nodes, &exact, &partial, saturated, chain);
    o.node_saturated = node_saturated;
    Ok(o)
}

fn measure(
    setup: &Setup,
    nodes: &Nodes,
    exact: &[f64],
    got: &[f32],
    saturated: u64,
    chain: LinkFormat,
) -> Outcome {
    let (lo, _) = setup.content.decades();
    let dark_limit = 10f64.powf(lo + 1.0);
    let floor = setup.content.floor();
    let mut o = Outcome {
        saturated,
        ..Outcome::default()
    };
    let (mut sq, mut sum_e, mut sum_g) = (0f64, 0f64, 0f64);
    let pixels = exact.chunks_exact(6).zip(got.chunks_exact(6));
    for ((e6, g6), t) in pixels.zip(&nodes.brightness) {
        for (e3, g3) in e6.chunks_exact(3).zip(g6.chunks_exact(3)) {
            let triple_max = e3.iter().fold(0f64, |m, v| m.max(*v)) as f32;
            for (e, g) in e3.iter().zip(g3) {
                let g = f64::from(*g);
                let rel = (g - e) / e.max(floor);
                sq += rel * rel;
                o.max_rel = o.max_rel.max(rel.abs());
                let value = if chain.format == PixelFormat::Rgb9e5x2 {
                    triple_max
                } else {
                    *e as f32
                };
                if setup.node.is_none()
                    && (g - e).abs() > f64::from(chain_bound(chain, setup.stages as u32, value))
                {
                    o.over_bound += 1;
                }
            }
        }
        let (e, g) = (
            e6.iter().sum::<f64>(),
            g6.iter().map(|v| f64::from(*v)).sum::<f64>(),
        );
        sum_e += e;
        sum_g += g;
        if f64::from(*t) < dark_limit {
            o.dark += 1;
            if g < 0.5 * e {
                o.dark_lost += 1;
            }
        }
    }
    o.rms_rel = (sq / exact.len() as f64).sqrt();
    o.energy_bias = (sum_g - sum_e) / sum_e;
    o
}
