//! Bands that do not match the configured frame — another epoch, a wrong size, a wrong format, a
//! producer that skips ahead — are rejected with an `Error { BandMismatch }` that says what was
//! wrong, no corrupt frame is emitted, and the stage serves the next frame correctly. An input
//! that never delivers is a `Timeout` within the deadline, and the stage goes on.

use crate::support;

use bytes::Bytes;
use lightfold_harness::driver::{DriverError, FrameShape, Producer, pack_band};
use lightfold_protocol::{ErrorCode, Layer, PixelFormat};
use support::*;

const ILL: Layer = Layer::Illumination;
const SIZE: (u32, u32, u32) = (19, 13, 4);
const FMT: PixelFormat = PixelFormat::Rgb9e5x2;

struct Rig {
    ctl: lightfold_harness::driver::ControlClient,
    sink: lightfold_harness::driver::Sink,
    a: Producer,
    b: Producer,
    ia: lightfold_harness::driver::LayerImage,
    ib: lightfold_harness::driver::LayerImage,
}

const OUT: [(Layer, PixelFormat); 1] = [(ILL, PixelFormat::F32x6)];
const OPS: [(&str, &str); 1] = [("join", r#"{"inputs": 2}"#)];

impl Rig {
    async fn frame_ok(&mut self, frame: u64) {
        self.ctl.render(1, frame, no_params()).await.unwrap();
        let s = shape(1, frame, SIZE);
        self.a
            .send_frame(&s, std::slice::from_ref(&self.ia))
            .await
            .unwrap();
        self.b
            .send_frame(&s, std::slice::from_ref(&self.ib))
            .await
            .unwrap();
        let got = self.sink.recv_frame(&s, &OUT, WAIT).await.unwrap();
        self.ctl.frame_done(frame, WAIT).await.unwrap();
        let (w, h, _) = SIZE;
        let want = reference(&OPS, &[&self.ia, &self.ib], w, h);
        let bound: Vec<f32> = link_bound(FMT, &self.ia.data, 1.0)
            .iter()
            .zip(link_bound(FMT, &self.ib.data, 1.0))
            .map(|(x, y)| x + y)
            .collect();
        assert_within(&got[0].data, &want[0], &bound, &format!("frame {frame}"));
    }

    /// Sends frame `frame` with band `bad_band` of input a replaced by `bad`, input b correct.
    async fn frame_with(
        &mut self,
        frame: u64,
        bad_band: u32,
        bad: impl Fn(&FrameShape) -> (lightfold_protocol::BandHeader, Bytes),
    ) {
        self.ctl.render(1, frame, no_params()).await.unwrap();
        let s = shape(1, frame, SIZE);
        for band in 0..s.bands() {
            let (h, p) = if band == bad_band {
                bad(&s)
            } else {
                pack_band(&s, band, &self.ia).unwrap()
            };
            self.a.send_band(h, p).await.unwrap();
        }
        self.b
            .send_frame(&s, std::slice::from_ref(&self.ib))
            .await
            .unwrap();
    }

    async fn expect_mismatch(&mut self, frame: u64, words: &[&str]) {
        match self.ctl.frame_done(frame, WAIT).await {
            Err(DriverError::Refused { code, message }) => {
                assert_eq!(code, ErrorCode::BandMismatch, "{message}");
                for w in words {
                    assert!(message.contains(w), "{message:?} lacks {w:?}");
                }
                eprintln!("reported: {message}");
            }
            other => panic!("frame {frame}: expected a band mismatch, got {other:?}"),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn wrong_bands_are_rejected_and_the_next_frame_is_served() {
    let (w, h, _) = SIZE;
    let stage = start_stage("c1").await;
    let (sink, sink_addr) = sink().await;
    let mut ctl = stage.control().await;
    let ins = vec![input("a", &[(ILL, FMT)]), input("b", &[(ILL, FMT)])];
    ctl.configure(config(1, SIZE, ins, &OPS, &OUT, &sink_addr), WAIT)
        .await
        .unwrap();
    let a = stage.producer("a").await;
    let b = stage.producer("b").await;
    let mut rig = Rig {
        ctl,
        sink,
        a,
        b,
        ia: image(ILL, FMT, hdr(1, w, h, ILL, 0..0)),
        ib: image(ILL, FMT, hdr(2, w, h, ILL, 0..4)),
    };
    rig.frame_ok(1).await;

    // An epoch the stage was never configured for.
    let ia = rig.ia.clone();
    rig.frame_with(2, 1, |s| {
        let (mut h, p) = pack_band(s, 1, &ia).unwrap();
        h.epoch = 2;
        (h, p)
    })
    .await;
    rig.expect_mismatch(2, &["frame 2", "input 0 (a)", "epoch 2", "epoch 1"])
        .await;
    rig.frame_ok(3).await;

    // A band of the wrong size: a self-consistent band of 18 columns where 19 are configured.
    rig.frame_with(4, 2, |s| {
        let narrow = FrameShape { width: 18, ..*s };
        let img = image(ILL, FMT, hdr(9, 18, s.height, ILL, 0..0));
        pack_band(&narrow, 2, &img).unwrap()
    })
    .await;
    rig.expect_mismatch(4, &["frame 4", "rectangle", "18x4", "19x4"])
        .await;
    rig.frame_ok(5).await;

    // The right layer in another format of the same channel count.
    let ia = rig.ia.clone();
    rig.frame_with(6, 0, |s| {
        let other = image(ILL, PixelFormat::F16x6, ia.data.clone());
        pack_band(s, 0, &other).unwrap()
    })
    .await;
    rig.expect_mismatch(6, &["frame 6", "F16x6", "Rgb9e5x2"])
        .await;
    rig.frame_ok(7).await;

    // A producer that abandons frame 8 half-way and goes on with frame 9.
    rig.ctl.render(1, 8, no_params()).await.unwrap();
    let s8 = shape(1, 8, SIZE);
    for band in 0..2 {
        let (h, p) = pack_band(&s8, band, &rig.ia).unwrap();
        rig.a.send_band(h, p).await.unwrap();
    }
    rig.b
        .send_frame(&s8, std::slice::from_ref(&rig.ib))
        .await
        .unwrap();
    rig.ctl.render(1, 9, no_params()).await.unwrap();
    let s9 = shape(1, 9, SIZE);
    rig.a
        .send_frame(&s9, std::slice::from_ref(&rig.ia))
        .await
        .unwrap();
    rig.b
        .send_frame(&s9, std::slice::from_ref(&rig.ib))
        .await
        .unwrap();
    rig.expect_mismatch(8, &["frame 8", "skipped", "frame 9"])
        .await;
    let got = rig.sink.recv_frame(&s9, &OUT, WAIT).await.unwrap();
    rig.ctl.frame_done(9, WAIT).await.unwrap();
    let want = reference(&OPS, &[&rig.ia, &rig.ib], w, h);
    let bound: Vec<f32> = link_bound(FMT, &rig.ia.data, 1.0)
        .iter()
        .zip(link_bound(FMT, &rig.ib.data, 1.0))
        .map(|(x, y)| x + y)
        .collect();
    assert_within(&got[0].data, &want[0], &bound, "frame 9");

    assert_eq!(stage.metrics.mismatches(), 4);
    assert_eq!(stage.metrics.frames_failed(), 4);
    assert_eq!(stage.metrics.frames_done(), 5);
    stage.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_missing_input_times_out_and_the_next_frame_is_served() {
    let (w, h, _) = SIZE;
    let stage = start_stage_with("c2", |o| {
        o.input_timeout = std::time::Duration::from_millis(300)
    })
    .await;
    let (mut sink, sink_addr) = sink().await;
    let mut ctl = stage.control().await;
    let out = [(ILL, PixelFormat::F32x6)];
    let ins = vec![input("a", &[(ILL, PixelFormat::F32x6)])];
    ctl.configure(config(1, SIZE, ins, &[], &out, &sink_addr), WAIT)
        .await
        .unwrap();
    // Nobody feeds frame 1.
    ctl.render(1, 1, no_params()).await.unwrap();
    match ctl.frame_done(1, WAIT).await {
        Err(DriverError::Refused { code, message }) => {
            assert_eq!(code, ErrorCode::Timeout, "{message}");
            assert!(
                message.contains("frame 1") && message.contains("no link"),
                "{message}"
            );
        }
        other => panic!("expected a timeout, got {other:?}"),
    }
    let img = image(ILL, PixelFormat::F32x6, hdr(3, w, h, ILL, 0..0));
    let mut a = stage.producer("a").await;
    ctl.render(1, 2, no_params()).await.unwrap();
    a.send_frame(&shape(1, 2, SIZE), std::slice::from_ref(&img))
        .await
        .unwrap();
    let got = sink
        .recv_frame(&shape(1, 2, SIZE), &out, WAIT)
        .await
        .unwrap();
    assert_eq!(got[0].data, img.data);
    ctl.frame_done(2, WAIT).await.unwrap();
    stage.stop().await;
}

/// A stage that a re-plan leaves out (`Message::Release`) drops the frame it waits on at once:
/// no input timeout comes 300 ms later (it used to, 30 s later under the default deadline, and a
/// coordinator that took it for a fresh failure re-planned a healthy cluster). The stage then
/// serves a new configuration.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_released_stage_drops_its_frame_without_a_timeout() {
    let (w, h, _) = SIZE;
    let timeout = std::time::Duration::from_millis(300);
    let stage = start_stage_with("c3", |o| o.input_timeout = timeout).await;
    let (_first_sink, first_addr) = sink().await;
    let mut ctl = stage.control().await;
    let out = [(ILL, PixelFormat::F32x6)];
    let ins = || vec![input("a", &[(ILL, PixelFormat::F32x6)])];
    ctl.configure(config(1, SIZE, ins(), &[], &out, &first_addr), WAIT)
        .await
        .unwrap();
    // Nobody feeds frame 1, and the plan of epoch 2 leaves the stage out.
    ctl.render(1, 1, no_params()).await.unwrap();
    ctl.release(2).await.unwrap();
    ctl.send_ping(7).await.unwrap();
    let quiet_until = tokio::time::Instant::now() + 4 * timeout;
    loop {
        let left = quiet_until.saturating_duration_since(tokio::time::Instant::now());
        match ctl.next_message(left).await {
            Ok(lightfold_protocol::Message::Pong { seq: 7 }) => {}
            Ok(m) => panic!("a released stage said {m:?}"),
            Err(DriverError::Timeout { .. }) => break, // quiet until the deadline
            Err(e) => panic!("{e}"),
        }
    }
    // Configured again (epoch 3, to another consumer), it serves frames.
    let (mut sink, sink_addr) = sink().await;
    ctl.configure(config(3, SIZE, ins(), &[], &out, &sink_addr), WAIT)
        .await
        .unwrap();
    let img = image(ILL, PixelFormat::F32x6, hdr(3, w, h, ILL, 0..0));
    let mut a = stage.producer("a").await;
    ctl.render(3, 2, no_params()).await.unwrap();
    a.send_frame(&shape(3, 2, SIZE), std::slice::from_ref(&img))
        .await
        .unwrap();
    let got = sink
        .recv_frame(&shape(3, 2, SIZE), &out, WAIT)
        .await
        .unwrap();
    assert_eq!(got[0].data, img.data);
    ctl.frame_done(2, WAIT).await.unwrap();
    stage.stop().await;
}
