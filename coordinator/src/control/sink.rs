//! The coordinator's sink: accepts the sink compositor's data link and assembles final radiance
//! frames from bands.

use lightfold_net::{Identity, NetError, Timeouts};
use lightfold_protocol::frame::Frame;
use lightfold_protocol::{Layer, PixelFormat, format};
use lightfold_scene::Image;
use std::collections::BTreeMap;
use std::time::Instant;
use tokio::net::TcpListener;
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

/// A finished frame as received from the sink compositor (resolved to the delivered size when
/// the cluster supersamples).
#[derive(Debug)]
pub struct SinkFrame {
    pub epoch: u64,
    pub frame: u64,
    pub image: Image,
    pub bytes: u64,
    pub received_at: Instant,
}

/// Something the sink saw.
#[derive(Debug)]
pub enum SinkEvent {
    Frame(SinkFrame),
    /// A frame of the current epoch cannot complete (a band that does not fit, one missing).
    Failed {
        frame: u64,
        reason: String,
    },
    /// A connection that is not the sink compositor's (a port scan, a wrong token, a probe), or a
    /// link that ended: logged, never fatal.
    Warning(String),
}

/// The frame geometry the sink expects (set by the coordinator for each plan epoch).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SinkGeometry {
    pub epoch: u64,
    pub width: u32,
    pub height: u32,
    pub band_height: u32,
    /// `--aa N`: the frame is N × the delivered size per side; each N × N block of radiance is
    /// averaged (box filter) when the frame completes. 1: delivered as received.
    pub supersample: u32,
}

struct Partial {
    image: Image,
    bands: u32,
    bytes: u64,
}

/// Runs the sink until cancelled: every accepted link streams radiance bands; frames are sent on
/// `out` when all their bands arrived.
pub(super) async fn run_sink(
    listener: TcpListener,
    me: Identity,
    timeouts: Timeouts,
    geometry: tokio::sync::watch::Receiver<SinkGeometry>,
    out: mpsc::Sender<SinkEvent>,
    cancel: CancellationToken,
) {
    // A stray connection (a port scan, a probe) is refused and logged; it never ends the job.
    let tracker = tokio_util::task::TaskTracker::new();
    let serve_link = {
        let (out, cancel) = (out.clone(), cancel.clone());
        move |link: lightfold_net::Link| {
            let (out, geometry, cancel) = (out.clone(), geometry.clone(), cancel.clone());
            async move {
                let addr = link.addr.clone();
                if let Err(e) = receive(link, geometry, &out, cancel).await {
                    let _ = out
                        .send(SinkEvent::Warning(format!("sink link from {addr}: {e}")))
                        .await;
                }
            }
        }
    };
    lightfold_net::serve(
        &listener, &me, timeouts, &cancel, &tracker, "the sink", serve_link,
    )
    .await;
    tracker.close();
    tracker.wait().await;
}

async fn receive(
    link: lightfold_net::Link,
    geometry: tokio::sync::watch::Receiver<SinkGeometry>,
    out: &mpsc::Sender<SinkEvent>,
    cancel: CancellationToken,
) -> Result<(), NetError> {
    let (mut reader, _writer) = link.split();
    // By (epoch, frame): a frame re-requested under a new epoch keeps its id.
    let mut partial: BTreeMap<(u64, u64), Partial> = BTreeMap::new();
    loop {
        let next = tokio::select! {
            _ = cancel.cancelled() => return Ok(()),
            n = reader.next() => n,
        };
        let frame = match next {
            None => return Ok(()),
            Some(f) => f?,
        };
        let (h, payload) = match frame {
            Frame::Band(h, p) => (h, p),
            other => {
                let _ = out
                    .send(SinkEvent::Warning(format!(
                        "sink got {} instead of a band",
                        lightfold_net::describe(&other)
                    )))
                    .await;
                continue;
            }
        };
        let g = *geometry.borrow();
        if h.epoch != g.epoch {
            continue; // a band of an old plan
        }
        // Frames of older epochs will never complete.
        partial.retain(|k, _| k.0 == g.epoch);
        let bands = g.height.div_ceil(g.band_height.max(1));
        let expect_y0 = h.y0;
        let ok = h.layer == Layer::Radiance
            && h.x0 == 0
            && h.width == g.width
            && expect_y0 % g.band_height.max(1) == 0
            && h.height == g.band_height.min(g.height.saturating_sub(h.y0))
            && h.height > 0;
        if !ok {
            let _ = out
                .send(SinkEvent::Failed {
                    frame: h.frame,
                    reason: format!(
                        "sink rejected band of frame {} (layer {:?}, rect {}x{}+{}+{}): does not match {}x{} bands of {}",
                        h.frame, h.layer, h.width, h.height, h.x0, h.y0, g.width, g.height, g.band_height
                    ),
                })
                .await;
            partial.remove(&(h.epoch, h.frame));
            continue;
        }
        let p = partial
            .entry((h.epoch, h.frame))
            .or_insert_with(|| Partial {
                image: Image::new(g.width, g.height, 3),
                bands: 0,
                bytes: 0,
            });
        if !h.empty {
            let start = h.y0 as usize * g.width as usize * 3;
            let len = h.height as usize * g.width as usize * 3;
            let dst = &mut p.image.data[start..start + len];
            if let Err(e) = unpack_into(h.format, &payload, h.scale, dst) {
                let _ = out
                    .send(SinkEvent::Failed {
                        frame: h.frame,
                        reason: format!("sink cannot unpack frame {}: {e}", h.frame),
                    })
                    .await;
                partial.remove(&(h.epoch, h.frame));
                continue;
            }
        }
        p.bands += 1;
        p.bytes += payload.len() as u64;
        if p.bands == bands {
            let Some(done) = partial.remove(&(h.epoch, h.frame)) else {
                continue;
            };
            // Older incomplete frames will never complete once a newer one has.
            let stale: Vec<u64> = partial
                .range((h.epoch, 0)..(h.epoch, h.frame))
                .map(|(k, _)| k.1)
                .collect();
            for k in stale {
                partial.remove(&(h.epoch, k));
                let _ = out
                    .send(SinkEvent::Failed {
                        frame: k,
                        reason: format!("frame {k} incomplete at the sink"),
                    })
                    .await;
            }
            // The resolve of `--aa N`: after the material stage, on final radiance (on a
            // blocking thread: one pass over N² × the delivered pixels).
            let image = match resolve(done.image, g.supersample.max(1)).await {
                Ok(image) => image,
                Err(e) => {
                    let _ = out
                        .send(SinkEvent::Failed {
                            frame: h.frame,
                            reason: format!("sink cannot resolve frame {}: {e}", h.frame),
                        })
                        .await;
                    continue;
                }
            };
            let _ = out
                .send(SinkEvent::Frame(SinkFrame {
                    epoch: h.epoch,
                    frame: h.frame,
                    image,
                    bytes: done.bytes,
                    received_at: Instant::now(),
                }))
                .await;
        }
    }
}

/// The frame at its delivered size: `image` box-resolved by `factor` (itself when 1).
async fn resolve(image: Image, factor: u32) -> Result<Image, String> {
    if factor == 1 {
        return Ok(image);
    }
    match tokio::task::spawn_blocking(move || image.box_resolve(factor)).await {
        Ok(r) => r.map_err(|e| e.to_string()),
        Err(e) => Err(format!("the resolve task failed: {e}")),
    }
}

fn unpack_into(
    fmt: PixelFormat,
    payload: &[u8],
    scale: f32,
    dst: &mut [f32],
) -> Result<(), String> {
    if fmt.channels() != 3 {
        return Err(format!("format {} is not a radiance format", fmt.name()));
    }
    format::unpack(fmt, payload, scale, dst).map_err(|e| e.to_string())
}
