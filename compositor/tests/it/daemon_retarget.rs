//! A stage whose downstream is dead (a closed port, dialled with retry until `dial_timeout`) is
//! reconfigured to a live downstream while a frame is stuck behind the dial: `Configured` comes
//! at once (the engine never waits for the writer), the stuck frame is dropped unreported, and
//! the next frame reaches the new downstream promptly.

use crate::support;

use lightfold_protocol::{Layer, PixelFormat};
use std::time::{Duration, Instant};
use support::*;
use tokio::net::TcpListener;

const ILL: Layer = Layer::Illumination;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_new_configuration_frees_a_writer_stuck_on_a_dead_downstream() {
    // 12 bands: more than the engine → writer queue holds, so the engine blocks behind the writer.
    let size = (16, 48, 4);
    let (w, h, _) = size;
    let stage = start_stage_with("retarget", |o| o.dial_timeout = Duration::from_secs(60)).await;
    let dead = {
        let l = TcpListener::bind("127.0.0.1:0").await.unwrap();
        l.local_addr().unwrap().to_string()
    };
    let (mut sink, sink_addr) = sink().await;
    let mut ctl = stage.control().await;
    let layers = [(ILL, PixelFormat::F32x6)];
    let cfg = |epoch, downstream: &str| {
        config(
            epoch,
            size,
            vec![input("up", &layers)],
            &[],
            &layers,
            downstream,
        )
    };
    ctl.configure(cfg(1, &dead), WAIT).await.unwrap();
    let mut up = stage.producer("up").await;
    let img = image(ILL, PixelFormat::F32x6, hdr(5, w, h, ILL, 0..0));
    ctl.render(1, 1, no_params()).await.unwrap();
    up.send_frame(&shape(1, 1, size), std::slice::from_ref(&img))
        .await
        .unwrap();
    // Let the stage combine what fits in its queues; the writer is still dialling.
    tokio::time::sleep(Duration::from_millis(300)).await;

    let t = Instant::now();
    ctl.configure(cfg(2, &sink_addr), WAIT).await.unwrap();
    let took = t.elapsed();
    assert!(took < Duration::from_secs(3), "Configured after {took:?}");

    ctl.render(2, 2, no_params()).await.unwrap();
    up.send_frame(&shape(2, 2, size), std::slice::from_ref(&img))
        .await
        .unwrap();
    let got = sink
        .recv_frame(&shape(2, 2, size), &layers, Duration::from_secs(5))
        .await
        .unwrap();
    assert_eq!(got[0].data, img.data, "frame 2 relayed bit for bit");
    // The first report after `Configured` is frame 2's: frame 1 was dropped unreported, and the
    // abandoned dial reported nothing.
    let stats = ctl.frame_done(2, Duration::from_secs(5)).await.unwrap();
    assert_eq!((stats.epoch, stats.frame), (2, 2));
    let took = t.elapsed();
    assert!(took < Duration::from_secs(8), "frame 2 done after {took:?}");
    assert_eq!(stage.metrics.frames_failed(), 0);
    stage.stop().await;
}
