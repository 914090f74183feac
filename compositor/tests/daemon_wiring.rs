//! A stage with explicitly wired operators (`CompositorConfig::wiring`): one node's link carries
//! its illumination and its material layers, `accumulate` reads the illumination and `material`
//! the material layers of the same input. The sink gets the in-memory pipeline's bits; wiring
//! that names a missing input or leaves one unread is refused.

mod support;

use lightfold_compositor::ops::{BandMut, BandView};
use lightfold_compositor::pipeline::Pipeline;
use lightfold_protocol::{Layer, OpSource, PixelFormat};
use support::*;

const ILL: Layer = Layer::Illumination;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_input_feeds_accumulate_and_material() {
    let size = (23, 14, 4);
    let (w, h, _) = size;
    let (dif, spe) = (Layer::Diffuse, Layer::Specular);
    let (f_up, f_ill, f_mat) = (
        PixelFormat::F16x6,
        PixelFormat::Rgb9e5x2,
        PixelFormat::Rgba8Srgb,
    );
    let ops = [
        ("accumulate", r#"{"colors": [[2.0, 1.0, 0.5]]}"#),
        ("material", r#"{"stage": "single", "specular": true}"#),
        ("output", r#"{"exposure": 1.0}"#),
    ];
    let wiring = vec![
        vec![OpSource::Input(0), OpSource::Input(1)],
        vec![OpSource::Op(0), OpSource::Input(1)],
        vec![OpSource::Op(1)],
    ];
    let node_layers = [(ILL, f_ill), (dif, f_mat), (spe, f_mat)];
    let ins = vec![input("up", &[(ILL, f_up)]), input("n", &node_layers)];
    let out = [(Layer::Radiance, PixelFormat::F32x3)];
    let mut cfg = config(1, size, ins, &ops, &out, "");
    cfg.wiring = wiring.clone();

    // Refused: wiring that reads a missing input, and wiring that leaves an input unread.
    let stage = start_stage("wired").await;
    let (mut sink, sink_addr) = sink().await;
    cfg.downstream = sink_addr;
    let mut ctl = stage.control().await;
    for bad in [
        vec![
            vec![OpSource::Input(0), OpSource::Input(2)],
            vec![OpSource::Op(0), OpSource::Input(1)],
            vec![OpSource::Op(1)],
        ],
        vec![
            vec![OpSource::Input(0), OpSource::Input(0)],
            vec![OpSource::Op(0), OpSource::Input(0)],
            vec![OpSource::Op(1)],
        ],
    ] {
        let mut c = cfg.clone();
        c.wiring = bad;
        assert!(ctl.configure(c, WAIT).await.is_err());
    }
    ctl.configure(cfg, WAIT).await.unwrap();

    let up = quantised(f_up, ILL, hdr(31, w, h, ILL, 0..4));
    let ill = quantised(f_ill, ILL, hdr(32, w, h, ILL, 8..12));
    let albedo = |seed| -> Vec<f32> {
        let v: Vec<f32> = hdr(seed, w, h, dif, 0..0)
            .iter()
            .map(|v| (v / 100.0).min(1.0))
            .collect();
        quantised(f_mat, dif, v)
    };
    let (d, s) = (albedo(33), albedo(34));
    let mut producers = [stage.producer("up").await, stage.producer("n").await];
    ctl.render(1, 1, no_params()).await.unwrap();
    producers[0]
        .send_frame(&shape(1, 1, size), &[image(ILL, f_up, up.clone())])
        .await
        .unwrap();
    let node_frame = [
        image(ILL, f_ill, ill.clone()),
        image(dif, f_mat, d.clone()),
        image(spe, f_mat, s.clone()),
    ];
    producers[1]
        .send_frame(&shape(1, 1, size), &node_frame)
        .await
        .unwrap();
    let got = sink
        .recv_frame(&shape(1, 1, size), &out, WAIT)
        .await
        .unwrap();
    ctl.frame_done(1, WAIT).await.unwrap();

    let ops: Vec<(String, String)> = ops
        .iter()
        .map(|(n, p)| (n.to_string(), p.to_string()))
        .collect();
    let layers = vec![vec![ILL], vec![ILL, dif, spe]];
    let p = Pipeline::from_wiring(&ops, &wiring, &layers).unwrap();
    let pixels = (w * h) as usize;
    let views = [
        BandView::new(pixels).with(ILL, &up),
        BandView::new(pixels)
            .with(ILL, &ill)
            .with(dif, &d)
            .with(spe, &s),
    ];
    let mut want = vec![0.0; pixels * 3];
    let mut m = BandMut::new(pixels).with(Layer::Radiance, &mut want);
    p.run(&views, &mut m, &mut Default::default()).unwrap();
    assert_eq!(
        got[0].data, want,
        "the stage gives the wired pipeline's bits"
    );
    assert!(want.iter().any(|v| *v > 0.0));
    stage.stop().await;
}
