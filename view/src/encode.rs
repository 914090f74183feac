//! Encodes delivered frames for the view off the event loop: a thread takes the newest frame
//! (skipping those it had no time for), converts it to 8-bit sRGB at the view's exposure,
//! compresses it to JPEG and publishes it with its header to every viewer. The exposure is the
//! viewers' to set (stops, `Hub::set_exposure`): it is applied here, after the cluster, so a
//! change needs no render; the thread keeps the last frame, linear, and encodes it again at the
//! new exposure.

use crate::hub::{Hub, ViewFrame};
use bytes::{BufMut, Bytes, BytesMut};
use lightfold_coordinator::control::FrameResult;
use lightfold_scene::Image;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::sync::mpsc;
use std::time::Instant;

/// Exposures a viewer may set, stops (the multiplier is 2^stops); beyond them a value is clamped.
pub const MIN_STOPS: f32 = -16.0;
pub const MAX_STOPS: f32 = 16.0;

/// An exposure in stops as the view applies it: finite (else an error), clamped to
/// `MIN_STOPS..=MAX_STOPS`.
pub(crate) fn check_stops(stops: f32) -> Result<f32, crate::SteerError> {
    if !stops.is_finite() {
        return Err(crate::SteerError::NotFinite("exposure stops"));
    }
    Ok(stops.clamp(MIN_STOPS, MAX_STOPS))
}

/// A scene's exposure multiplier in stops (clamped; 0 for one that is not positive).
pub(crate) fn stops_of(multiplier: f32) -> f32 {
    if multiplier.is_finite() && multiplier > 0.0 {
        multiplier.log2().clamp(MIN_STOPS, MAX_STOPS)
    } else {
        0.0
    }
}

/// The multiplier `to_srgb8` takes for an exposure in stops.
pub(crate) fn multiplier(stops: f32) -> f32 {
    stops.exp2()
}

/// A delivered frame to encode, and its header.
pub(crate) struct Job {
    frame: u64,
    header: serde_json::Value,
    image: Arc<Image>,
}

/// What the encoding thread is sent: a delivered frame, or word that the exposure changed.
pub(crate) enum Work {
    Frame(Job),
    Exposure,
}

#[derive(Debug)]
pub(crate) struct Encoder {
    tx: Option<mpsc::Sender<Work>>,
    thread: Option<std::thread::JoinHandle<()>>,
    hub: Arc<Hub>,
    last_received: Option<Instant>,
}

impl Encoder {
    pub(crate) fn start(hub: Arc<Hub>) -> Encoder {
        let (tx, rx) = mpsc::channel::<Work>();
        *hub.encoder.lock().unwrap_or_else(|e| e.into_inner()) = Some(tx.clone());
        let h = Arc::clone(&hub);
        let thread = std::thread::Builder::new()
            .name("view-encoder".into())
            .spawn(move || encode_loop(&h, &rx))
            .map_err(|e| tracing::error!("cannot start the view's encoder: {e}"))
            .ok();
        Encoder {
            tx: Some(tx),
            thread,
            hub,
            last_received: None,
        }
    }

    /// Queues a delivered frame (called on the event loop: builds the header, copies the image).
    pub(crate) fn send(&mut self, f: &FrameResult) {
        let interval = self
            .last_received
            .map(|t| f.received_at.saturating_duration_since(t).as_secs_f64() * 1000.0);
        self.last_received = Some(f.received_at);
        let requested = self.hub.requested(f.frame);
        let plan = self.hub.plan();
        let header = crate::json::frame_header(f, requested, interval, plan.as_deref());
        if let Some(tx) = &self.tx {
            let _ = tx.send(Work::Frame(Job {
                frame: f.frame,
                header,
                image: Arc::new(f.image.clone()),
            }));
        }
    }

    /// Encodes what is queued, then stops the thread.
    pub(crate) fn finish(mut self) {
        drop(self.tx.take());
        drop(
            self.hub
                .encoder
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .take(),
        );
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn encode_loop(hub: &Hub, rx: &mpsc::Receiver<Work>) {
    // The last frame encoded, linear, and the exposure it was encoded at.
    let mut last: Option<(Job, f32)> = None;
    while let Ok(work) = rx.recv() {
        // Only the newest frame is worth encoding.
        let mut fresh = None;
        for w in std::iter::once(work).chain(rx.try_iter()) {
            if let Work::Frame(job) = w {
                fresh = Some(job);
            }
        }
        let stops = *hub.exposure.borrow();
        let (job, again) = match fresh {
            Some(job) => (job, false),
            // A new exposure with no new frame: the last frame again, if it was another.
            None => match last.take() {
                Some((job, at)) if at != stops => (job, true),
                other => {
                    last = other;
                    continue;
                }
            },
        };
        let started = Instant::now();
        let cpu_before = thread_cpu_ns();
        match encode(&job, stops, again, hub.jpeg_quality) {
            Ok(frame) => {
                let c = &hub.counters;
                c.encode_us
                    .fetch_add(started.elapsed().as_micros() as u64, Ordering::Relaxed);
                if let (Some(a), Some(b)) = (cpu_before, thread_cpu_ns()) {
                    c.encode_cpu_us
                        .fetch_add(b.saturating_sub(a) / 1000, Ordering::Relaxed);
                }
                c.frames_encoded.fetch_add(1, Ordering::Relaxed);
                c.jpeg_bytes
                    .fetch_add(frame.jpeg.len() as u64, Ordering::Relaxed);
                *hub.image.lock().unwrap_or_else(|e| e.into_inner()) = Some(Arc::clone(&job.image));
                hub.frames.send_replace(Some(Arc::new(frame)));
            }
            Err(e) => tracing::warn!(
                frame = job.frame,
                "cannot encode the frame for the view: {e}"
            ),
        }
        last = Some((job, stops));
    }
}

/// CPU time this thread has run, nanoseconds (Linux: the first field of its schedstat).
fn thread_cpu_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// 8-bit sRGB of `image` at `stops` of exposure.
pub(crate) fn srgb8(
    img: &Image,
    stops: f32,
) -> Result<Vec<u8>, lightfold_scene::image::ImageError> {
    img.to_srgb8(multiplier(stops))
}

/// `image` as a PNG, 8-bit sRGB at `stops` of exposure (`/frame.png`).
pub(crate) fn png(img: &Image, stops: f32) -> anyhow::Result<Vec<u8>> {
    Ok(img.png_bytes(multiplier(stops))?)
}

/// The frame message: its header (with the exposure it was encoded at, and whether it is a
/// frame encoded before at another exposure), then the JPEG.
fn encode(job: &Job, stops: f32, again: bool, quality: u8) -> anyhow::Result<ViewFrame> {
    let (w, h) = (job.image.width, job.image.height);
    let rgb = srgb8(&job.image, stops)?;
    let mut jpeg = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, quality).encode(
        &rgb,
        w,
        h,
        image::ExtendedColorType::Rgb8,
    )?;
    let mut header = job.header.clone();
    header["jpeg_bytes"] = jpeg.len().into();
    header["exposure"] = stops.into();
    header["reencoded"] = again.into();
    let header = serde_json::to_vec(&header)?;
    let mut msg = BytesMut::with_capacity(4 + header.len() + jpeg.len());
    msg.put_u32(u32::try_from(header.len())?);
    msg.put_slice(&header);
    msg.put_slice(&jpeg);
    Ok(ViewFrame {
        frame: job.frame,
        message: msg.freeze(),
        jpeg: Bytes::from(jpeg),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A gradient of mid-grey radiances, none of which saturates at +1 stop.
    fn gradient() -> Image {
        let (w, h) = (16u32, 8u32);
        let data = (0..w * h)
            .flat_map(|i| {
                let v = 0.02 + 0.2 * i as f32 / (w * h) as f32;
                [v, v * 0.8, v * 0.5]
            })
            .collect();
        Image {
            width: w,
            height: h,
            channels: 3,
            data,
        }
    }

    fn mean(v: &[u8]) -> f64 {
        v.iter().map(|&x| f64::from(x)).sum::<f64>() / v.len() as f64
    }

    #[test]
    fn a_stop_more_exposure_is_brighter_and_bad_stops_are_refused_or_clamped() {
        let img = gradient();
        let base = srgb8(&img, 0.0).unwrap();
        let up = srgb8(&img, 1.0).unwrap();
        let down = srgb8(&img, -1.0).unwrap();
        // Every channel of every pixel is at least as bright, and the picture is brighter.
        assert!(up.iter().zip(&base).all(|(u, b)| u >= b));
        assert!(
            mean(&up) > mean(&base) + 10.0,
            "{} vs {}",
            mean(&up),
            mean(&base)
        );
        assert!(mean(&down) < mean(&base) - 10.0);
        // +1 stop is the same as twice the radiance at 0 stops.
        let doubled = Image {
            data: img.data.iter().map(|v| v * 2.0).collect(),
            ..img.clone()
        };
        assert_eq!(up, srgb8(&doubled, 0.0).unwrap());
        // Negative control: the same exposure encodes the same bytes.
        assert_eq!(base, srgb8(&img, 0.0).unwrap());

        assert!(check_stops(f32::NAN).is_err());
        assert!(check_stops(f32::INFINITY).is_err());
        assert_eq!(check_stops(1e9).unwrap(), MAX_STOPS);
        assert_eq!(check_stops(-1e9).unwrap(), MIN_STOPS);
        assert_eq!(check_stops(1.5).unwrap(), 1.5);
        assert_eq!(stops_of(2.0), 1.0);
        assert_eq!(stops_of(0.0), 0.0);
        assert_eq!(multiplier(stops_of(0.25)), 0.25);
    }

    #[test]
    fn the_png_is_the_frame_at_its_exposure() {
        let img = gradient();
        for stops in [0.0, 2.0] {
            let png = png(&img, stops).unwrap();
            let back = image::load_from_memory_with_format(&png, image::ImageFormat::Png)
                .unwrap()
                .to_rgb8();
            assert_eq!((back.width(), back.height()), (16, 8));
            assert_eq!(back.into_raw(), srgb8(&img, stops).unwrap(), "lossless");
        }
    }
}
