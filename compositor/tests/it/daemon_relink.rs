//! A consumer that lets a stage's output link go (a re-plan that leaves the stage out of its
//! inputs for an epoch, then takes it back) gets a fresh link before the stage's next band: no
//! frame fails writing into the closed connection.

use crate::support;

use lightfold_protocol::{Layer, PixelFormat};
use std::time::Duration;
use support::*;

const ILL: Layer = Layer::Illumination;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_output_link_the_consumer_let_go_is_dialled_again() {
    let size = (64, 48, 8);
    let (w, h, _) = size;
    let stage = start_stage("relink").await;
    let (mut sink, sink_addr) = sink().await;
    let mut ctl = stage.control().await;
    let layers = [(ILL, PixelFormat::F32x6)];
    let cfg = config(
        1,
        size,
        vec![input("up", &layers)],
        &[],
        &layers,
        &sink_addr,
    );
    ctl.configure(cfg, WAIT).await.unwrap();
    let mut up = stage.producer("up").await;
    let img = image(ILL, PixelFormat::F32x6, hdr(3, w, h, ILL, 0..0));
    for frame in 1..=3u64 {
        ctl.render(1, frame, no_params()).await.unwrap();
        up.send_frame(&shape(1, frame, size), std::slice::from_ref(&img))
            .await
            .unwrap();
        let got = sink
            .recv_frame(&shape(1, frame, size), &layers, WAIT)
            .await
            .unwrap();
        assert_eq!(got[0].data, img.data, "frame {frame} relayed bit for bit");
        let stats = ctl.frame_done(frame, WAIT).await;
        assert!(stats.is_ok(), "frame {frame}: {stats:?}");
        sink.let_go();
        // The close reaches the stage well before the next frame is asked for.
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    assert_eq!(stage.metrics.frames_done(), 3);
    assert_eq!(stage.metrics.frames_failed(), 0);
    stage.stop().await;
}
