//! `lightfold view-probe`: measures a live view as a viewer sees it — interaction latency (an
//! input sent → the first frame showing it arrives), the frame interval, and what serving costs
//! (encoding time and bytes per frame from the view's `stats`, the coordinator's CPU per frame
//! with `--pid`). Inputs are orbit steps, or with `--light N` steps of light N (with `--object
//! M` of object M, the scene's mesh M) dragged across the view, sent as a drag (`--rate` per second, whatever the frames do) or one at a time after the
//! frame showing the previous one (`--steps`). It also counts the nodes that drew shadow maps
//! per frame (a light drag in walkthrough mode redraws only its own node's).

use anyhow::{Context, bail};
use futures::{SinkExt, StreamExt};
use lightfold_protocol::stats;
use serde_json::{Value, json};
use std::time::{Duration, Instant};
use tokio_tungstenite::tungstenite::Message;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The view's address (HOST:PORT, as `demo --serve` prints it).
    #[arg(long, default_value = lightfold_view::DEFAULT_LISTEN)]
    pub addr: String,
    /// How long to send inputs, seconds.
    #[arg(long, default_value_t = 20.0)]
    pub seconds: f64,
    /// Drag inputs per second.
    #[arg(long, default_value_t = 30.0)]
    pub rate: f64,
    /// One input at a time: send the next 100 ms after the frame showing the last arrived.
    #[arg(long)]
    pub steps: bool,
    /// Degrees each input orbits the camera by.
    #[arg(long, default_value_t = 1.0)]
    pub yaw: f32,
    /// Drag light N (by 1 % of the view's width per input, turning back every 40 inputs)
    /// instead of orbiting the camera.
    #[arg(long, conflicts_with = "object")]
    pub light: Option<u32>,
    /// Drag object M (the scene's mesh M) the same way instead of orbiting the camera.
    #[arg(long)]
    pub object: Option<u32>,
    /// The coordinator's pid, to report its CPU time per frame.
    #[arg(long)]
    pub pid: Option<u32>,
}

type Socket =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// What the probe saw.
#[derive(Default)]
struct Seen {
    /// Per input: when it was sent and the revision its ack named.
    inputs: Vec<(Instant, Option<u64>)>,
    /// Per frame: arrival, revision, message bytes.
    frames: Vec<(Instant, u64, usize)>,
    /// Per frame from the cluster (not encoded again): nodes that drew shadow maps, and nodes.
    drew: Vec<(usize, usize)>,
    stats: Option<Value>,
}

impl Seen {
    fn take(&mut self, m: Message) -> anyhow::Result<()> {
        match m {
            Message::Binary(b) => {
                if b.len() < 4 {
                    bail!("a frame message of {} bytes", b.len());
                }
                let n = u32::from_be_bytes([b[0], b[1], b[2], b[3]]) as usize;
                let header: Value = serde_json::from_slice(b.get(4..4 + n).context("header")?)?;
                let revision = header["revision"].as_u64().unwrap_or(0);
                self.frames.push((Instant::now(), revision, b.len()));
                if header["reencoded"] != Value::Bool(true) {
                    let nodes: Vec<&Value> = header["daemons"]
                        .as_array()
                        .map(|d| d.iter().filter(|d| d["role"] == "node").collect())
                        .unwrap_or_default();
                    let drew = nodes
                        .iter()
                        .filter(|d| d["shadow_passes"].as_u64().unwrap_or(0) > 0)
                        .count();
                    self.drew.push((drew, nodes.len()));
                }
            }
            Message::Text(t) => {
                let v: Value = serde_json::from_str(&t)?;
                match v["type"].as_str() {
                    Some("ack") => {
                        let id = v["id"].as_u64().unwrap_or(u64::MAX) as usize;
                        if let Some(i) = self.inputs.get_mut(id) {
                            i.1 = v["revision"].as_u64();
                        }
                    }
                    Some("stats") => self.stats = Some(v),
                    Some("error") => bail!("the view refused an input: {}", v["text"]),
                    _ => {}
                }
            }
            Message::Close(_) => bail!("the view closed the socket"),
            _ => {}
        }
        Ok(())
    }

    /// Latency of each input whose frame arrived, ms.
    fn latencies(&self) -> Vec<f64> {
        self.inputs
            .iter()
            .filter_map(|(sent, rev)| {
                let rev = (*rev)?;
                self.frames
                    .iter()
                    .find(|(at, r, _)| *r >= rev && at >= sent)
                    .map(|(at, _, _)| at.duration_since(*sent).as_secs_f64() * 1000.0)
            })
            .collect()
    }
}

async fn next(ws: &mut Socket, within: Duration) -> anyhow::Result<Option<Message>> {
    match tokio::time::timeout(within, ws.next()).await {
        Err(_) => Ok(None),
        Ok(None) => bail!("the view closed the socket"),
        Ok(Some(m)) => Ok(Some(m?)),
    }
}

async fn stats(ws: &mut Socket, seen: &mut Seen) -> anyhow::Result<Value> {
    seen.stats = None;
    ws.send(Message::Text(json!({"type": "stats"}).to_string().into()))
        .await?;
    let deadline = Instant::now() + Duration::from_secs(30);
    while seen.stats.is_none() {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            bail!("no stats from the view");
        }
        if let Some(m) = next(ws, left).await? {
            seen.take(m)?;
        }
    }
    seen.stats.take().context("stats")
}

/// The nearest-rank `p`-quantile of `v` (`stats`), NaN when empty (printed as "NaN").
fn percentile(v: &[f64], p: f64) -> f64 {
    stats::percentile_nearest_rank(v, p).unwrap_or(f64::NAN)
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if !(args.seconds > 0.0 && args.rate > 0.0 && args.seconds.is_finite() && args.rate < 1000.0) {
        bail!("--seconds and --rate must be positive");
    }
    let rt = tokio::runtime::Runtime::new()?;
    rt.block_on(probe(args))
}

async fn probe(args: Args) -> anyhow::Result<()> {
    let url = format!("ws://{}/ws", args.addr);
    let (mut ws, _) = tokio::time::timeout(
        Duration::from_secs(30),
        tokio_tungstenite::connect_async(&url),
    )
    .await
    .context("connecting timed out")?
    .with_context(|| format!("cannot open {url}"))?;
    let mut seen = Seen::default();
    // The welcome, then a first frame (asked for if none comes).
    let mut welcome = None;
    while welcome.is_none() {
        let m = next(&mut ws, Duration::from_secs(30))
            .await?
            .context("no welcome")?;
        if let Message::Text(t) = &m {
            let v: Value = serde_json::from_str(t)?;
            if v["type"] == "welcome" {
                welcome = Some(v);
                continue;
            }
        }
        seen.take(m)?;
    }
    let welcome = welcome.context("no welcome")?;
    if welcome["can_steer"] != true {
        bail!("this view only lets us watch: run the probe from loopback");
    }
    ws.send(Message::Text(json!({"type": "render"}).to_string().into()))
        .await?;
    while seen.frames.is_empty() {
        let m = next(&mut ws, Duration::from_secs(120))
            .await?
            .context("no frame")?;
        seen.take(m)?;
    }
    let before = stats(&mut ws, &mut seen).await?;
    let cpu_before = args.pid.map(crate::launcher::cpu_seconds);
    seen.frames.clear();
    let start = Instant::now();
    let end = start + Duration::from_secs_f64(args.seconds);
    let period = Duration::from_secs_f64(1.0 / args.rate);
    let mut tick = tokio::time::interval(period);
    let mut waiting_since: Option<Instant> = None;
    while Instant::now() < end {
        let send_now = if args.steps {
            // Next input 100 ms after the frame showing the last one.
            let shown = seen
                .inputs
                .last()
                .is_none_or(|(_, r)| r.is_some_and(|r| seen.frames.iter().any(|f| f.1 >= r)));
            if shown && waiting_since.is_none() {
                waiting_since = Some(Instant::now());
            }
            waiting_since.is_some_and(|t| t.elapsed() >= Duration::from_millis(100))
        } else {
            false
        };
        if send_now || !args.steps {
            if !args.steps {
                tick.tick().await;
            }
            waiting_since = None;
            let id = seen.inputs.len();
            let way = if (id / 40) % 2 == 0 { 1.0 } else { -1.0 };
            let m = match (args.light, args.object) {
                (Some(index), _) => {
                    json!({"type": "light_drag", "index": index, "x": 0.01 * way, "y": 0.0,
                           "id": id})
                }
                (None, Some(mesh)) => {
                    json!({"type": "object_drag", "mesh": mesh, "x": 0.01 * way, "y": 0.0,
                           "id": id})
                }
                (None, None) => {
                    json!({"type": "orbit", "yaw_deg": args.yaw, "pitch_deg": 0.0, "id": id})
                }
            };
            seen.inputs.push((Instant::now(), None));
            ws.send(Message::Text(m.to_string().into())).await?;
        }
        // Take what arrived, briefly.
        while let Some(m) = next(&mut ws, Duration::from_millis(2)).await? {
            seen.take(m)?;
        }
    }
    let sent_for = start.elapsed();
    // The last inputs' frames.
    let last = seen.inputs.iter().filter_map(|i| i.1).max().unwrap_or(0);
    let deadline = Instant::now() + Duration::from_secs(60);
    while !seen.frames.iter().any(|f| f.1 >= last) && Instant::now() < deadline {
        if let Some(m) = next(&mut ws, Duration::from_millis(200)).await? {
            seen.take(m)?;
        }
    }
    let after = stats(&mut ws, &mut seen).await?;
    let cpu = args
        .pid
        .zip(cpu_before)
        .map(|(p, b)| crate::launcher::cpu_seconds(p) - b);
    report(&args, &seen, sent_for, &before, &after, cpu);
    let _ = ws.close(None).await;
    Ok(())
}

fn report(
    args: &Args,
    seen: &Seen,
    sent_for: Duration,
    before: &Value,
    after: &Value,
    cpu: Option<f64>,
) {
    let lat = seen.latencies();
    let intervals: Vec<f64> = seen
        .frames
        .windows(2)
        .map(|w| w[1].0.duration_since(w[0].0).as_secs_f64() * 1000.0)
        .collect();
    let d = |k: &str| after[k].as_f64().unwrap_or(0.0) - before[k].as_f64().unwrap_or(0.0);
    let (encoded, sent) = (d("frames_encoded").max(1.0), d("frames_sent").max(1.0));
    let delivered = d("frames_delivered");
    println!(
        "view-probe: {} inputs ({}) over {:.1} s, {} frames received, {} delivered by the cluster",
        seen.inputs.len(),
        {
            let what = match (args.light, args.object) {
                (Some(l), _) => format!("light {l} dragged"),
                (None, Some(m)) => format!("object {m} dragged"),
                (None, None) => "a drag".to_string(),
            };
            if args.steps && args.light.is_none() && args.object.is_none() {
                "one at a time".to_string()
            } else if args.steps {
                format!("{what}, one at a time")
            } else {
                format!("{what} at {} /s", args.rate)
            }
        },
        sent_for.as_secs_f64(),
        seen.frames.len(),
        delivered
    );
    println!(
        "  interaction latency (input -> first frame showing it): p50 {:.1} ms, p95 {:.1} ms, max {:.1} ms ({} inputs shown)",
        percentile(&lat, 0.5),
        percentile(&lat, 0.95),
        percentile(&lat, 1.0),
        lat.len()
    );
    println!(
        "  frame interval at the viewer: p50 {:.1} ms, p95 {:.1} ms; latency p50 = {:.2} frame intervals",
        percentile(&intervals, 0.5),
        percentile(&intervals, 0.95),
        percentile(&lat, 0.5) / percentile(&intervals, 0.5)
    );
    println!(
        "  serving: {:.2} ms encoding per frame ({:.2} ms of CPU), {:.0} JPEG bytes per frame, {:.0} bytes sent per frame per viewer, {} frames skipped by viewers",
        d("encode_us") / encoded / 1000.0,
        d("encode_cpu_us") / encoded / 1000.0,
        d("jpeg_bytes") / encoded,
        d("bytes_sent") / sent,
        d("frames_skipped")
    );
    let (drew, nodes): (usize, usize) = seen
        .drew
        .iter()
        .fold((0, 0), |(a, b), (d, n)| (a + d, b + n));
    let frames = seen.drew.len().max(1) as f64;
    println!(
        "  shadow maps: {:.2} of {:.2} nodes drew maps per frame ({} frames)",
        drew as f64 / frames,
        nodes as f64 / frames,
        seen.drew.len()
    );
    if let Some(c) = cpu {
        println!(
            "  coordinator CPU: {:.2} ms per frame delivered ({:.2} s in all)",
            c * 1000.0 / delivered.max(1.0),
            c
        );
    }
}
