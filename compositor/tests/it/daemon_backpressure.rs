//! A stalled consumer blocks the producer through the stage: the stage stops reading its input
//! once its bounded queues are full, TCP pushes back, and the producer's sends stop completing.
//! Meanwhile the bytes the stage holds stay under the bound its configuration implies; once the
//! consumer reads again every frame arrives, complete and in order.

use crate::support;

use lightfold_compositor::daemon::BAND_OVERHEAD;
use lightfold_protocol::{Layer, PixelFormat};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;
use support::*;
use tokio::time::Instant;

const ILL: Layer = Layer::Illumination;
const SIZE: (u32, u32, u32) = (256, 256, 32);
const FRAMES: u64 = 40;
/// Bands the engine → writer queue holds (`output::OUT_QUEUE`) plus the one being written and
/// the one being queued.
const OUT_BANDS_IN_FLIGHT: u64 = 4 + 2;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stalled_consumer_blocks_the_producer_and_memory_stays_bounded() {
    let (w, h, bh) = SIZE;
    let stage = start_stage("c").await;
    let (mut sink, sink_addr) = sink().await;
    let mut ctl = stage.control().await;
    let fmt = PixelFormat::F32x6;
    let ops = [(
        "accumulate",
        r#"{"upstream": false, "colors": [[1, 1, 1]]}"#,
    )];
    let cfg = config(
        1,
        SIZE,
        vec![input("n", &[(ILL, fmt)])],
        &ops,
        &[(ILL, fmt)],
        &sink_addr,
    );
    let frames_in_flight = u64::from(cfg.frames_in_flight);
    ctl.configure(cfg, WAIT).await.unwrap();
    for frame in 1..=FRAMES {
        ctl.render(1, frame, no_params()).await.unwrap();
    }

    let frame_bytes = u64::from(w * h) * fmt.bytes_per_pixel() as u64;
    let bands = u64::from(h.div_ceil(bh));
    let band_bytes = frame_bytes / bands;
    let bound =
        frames_in_flight * (frame_bytes + bands * BAND_OVERHEAD) + OUT_BANDS_IN_FLIGHT * band_bytes;

    let img = image(ILL, fmt, hdr(1, w, h, ILL, 0..0));
    let sent = Arc::new(AtomicU64::new(0));
    let mut producer = stage.producer("n").await;
    let counter = Arc::clone(&sent);
    let source = img.clone();
    let produce = tokio::spawn(async move {
        for frame in 1..=FRAMES {
            producer
                .send_frame(&shape(1, frame, SIZE), std::slice::from_ref(&source))
                .await
                .unwrap();
            counter.fetch_add(1, Ordering::Relaxed);
        }
    });

    // The consumer takes one band (so the link is up), then stalls.
    sink.next_band(Instant::now() + WAIT).await.unwrap();
    let mut last = u64::MAX;
    let start = Instant::now();
    loop {
        tokio::time::sleep(Duration::from_millis(400)).await;
        let now = sent.load(Ordering::Relaxed);
        if now == last {
            break;
        }
        last = now;
        assert!(
            start.elapsed() < WAIT,
            "the producer never blocked ({now} frames sent)"
        );
    }
    assert!(
        last < FRAMES,
        "the producer should block, it sent all {FRAMES} frames"
    );
    let peak = stage.metrics.peak_buffered_bytes();
    eprintln!(
        "producer blocked after {last} frames of {} KiB; stage peak {} KiB, bound {} KiB",
        frame_bytes / 1024,
        peak / 1024,
        bound / 1024
    );
    assert!(peak <= bound, "stage held {peak} bytes, bound {bound}");
    assert!(
        peak >= frame_bytes,
        "the stage should have queued at least a frame ({peak})"
    );

    // The consumer resumes: the rest of frame 1 and every later frame arrive complete.
    let rest = (bands - 1) as usize;
    for _ in 0..rest {
        sink.next_band(Instant::now() + WAIT).await.unwrap();
    }
    for frame in 2..=FRAMES {
        let got = sink
            .recv_frame(&shape(1, frame, SIZE), &[(ILL, fmt)], WAIT)
            .await
            .unwrap();
        assert!(got[0].data == img.data, "frame {frame} differs");
    }
    tokio::time::timeout(WAIT, produce).await.unwrap().unwrap();
    for frame in 1..=FRAMES {
        ctl.frame_done(frame, WAIT).await.unwrap();
    }
    assert!(stage.metrics.peak_buffered_bytes() <= bound);
    stage.stop().await;
}
