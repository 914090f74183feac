//! Encodes delivered frames for the view off the event loop: a thread takes the newest frame
//! (skipping those it had no time for), converts it to 8-bit sRGB at the scene's exposure,
//! compresses it to JPEG and publishes it with its header to every viewer.

use crate::hub::{Hub, ViewFrame};
use bytes::{BufMut, Bytes, BytesMut};
use lightfold_coordinator::control::FrameResult;
use lightfold_scene::Image;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::sync::mpsc;
use std::time::Instant;

struct Job {
    frame: u64,
    header: serde_json::Value,
    image: Image,
}

#[derive(Debug)]
pub struct Encoder {
    tx: Option<mpsc::Sender<Job>>,
    thread: Option<std::thread::JoinHandle<()>>,
    hub: Arc<Hub>,
    last_received: Option<Instant>,
}

impl Encoder {
    pub fn start(hub: Arc<Hub>, exposure: f32) -> Encoder {
        let (tx, rx) = mpsc::channel::<Job>();
        let h = Arc::clone(&hub);
        let thread = std::thread::Builder::new()
            .name("view-encoder".into())
            .spawn(move || encode_loop(&h, &rx, exposure))
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
    pub fn send(&mut self, f: &FrameResult) {
        let interval = self
            .last_received
            .map(|t| f.received_at.saturating_duration_since(t).as_secs_f64() * 1000.0);
        self.last_received = Some(f.received_at);
        let revision = self.hub.revision_of(f.frame);
        let plan = self.hub.plan();
        let header = crate::json::frame_header(f, revision, interval, plan.as_deref());
        if let Some(tx) = &self.tx {
            let _ = tx.send(Job {
                frame: f.frame,
                header,
                image: f.image.clone(),
            });
        }
    }

    /// Encodes what is queued, then stops the thread.
    pub fn finish(mut self) {
        drop(self.tx.take());
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn encode_loop(hub: &Hub, rx: &mpsc::Receiver<Job>, exposure: f32) {
    while let Ok(mut job) = rx.recv() {
        // Only the newest frame is worth encoding.
        while let Ok(next) = rx.try_recv() {
            job = next;
        }
        let started = Instant::now();
        let cpu_before = thread_cpu_ns();
        match encode(&job, exposure, hub.jpeg_quality) {
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
                *hub.image.lock().unwrap_or_else(|e| e.into_inner()) = Some(Arc::new(job.image));
                hub.frames.send_replace(Some(Arc::new(frame)));
            }
            Err(e) => tracing::warn!(
                frame = job.frame,
                "cannot encode the frame for the view: {e}"
            ),
        }
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

fn encode(job: &Job, exposure: f32, quality: u8) -> anyhow::Result<ViewFrame> {
    let (w, h) = (job.image.width, job.image.height);
    let rgb = job.image.to_srgb8(exposure)?;
    let mut jpeg = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, quality).encode(
        &rgb,
        w,
        h,
        image::ExtendedColorType::Rgb8,
    )?;
    let mut header = job.header.clone();
    header["jpeg_bytes"] = jpeg.len().into();
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
