//! A stage with explicitly wired operators (`CompositorConfig::wiring`): one node's link carries
//! its illumination and its material layers, `accumulate` reads the illumination and `material`
//! the material layers of the same input. The sink gets the in-memory pipeline's bits; wiring
//! that names a missing input or leaves one unread is refused.

use crate::support;

use lightfold_compositor::ops::{BandMut, BandView};
use lightfold_compositor::pipeline::Pipeline;
use lightfold_harness::driver::{ControlClient, LayerImage, Sink};
use lightfold_protocol::{Layer, OpSource, OpSpec, PixelFormat};
use support::*;

const ILL: Layer = Layer::Illumination;

/// Frame 1 of epoch 1 from the producers "up" and "n" (their layers in `frames`), as the sink
/// receives the stage's `out`.
async fn one_frame(
    stage: &Stage,
    ctl: &mut ControlClient,
    sink: &mut Sink,
    size: (u32, u32, u32),
    frames: [&[LayerImage]; 2],
    out: &[(Layer, PixelFormat)],
) -> Vec<LayerImage> {
    let mut producers = [stage.producer("up").await, stage.producer("n").await];
    ctl.render(1, 1, no_params()).await.unwrap();
    for (p, f) in producers.iter_mut().zip(frames) {
        p.send_frame(&shape(1, 1, size), f).await.unwrap();
    }
    let got = sink
        .recv_frame(&shape(1, 1, size), out, WAIT)
        .await
        .unwrap();
    ctl.frame_done(1, WAIT).await.unwrap();
    got
}

/// The radiance of `ops` wired as `wiring` over whole-frame `inputs` (each a list of layers), in
/// memory: what the stage must give.
fn in_memory(
    ops: &[OpSpec],
    wiring: &[Vec<OpSource>],
    inputs: &[Vec<(Layer, &[f32])>],
    pixels: usize,
) -> Vec<f32> {
    let layers: Vec<Vec<Layer>> = inputs
        .iter()
        .map(|i| i.iter().map(|(l, _)| *l).collect())
        .collect();
    let p = Pipeline::from_wiring(ops, wiring, &layers).unwrap();
    let views: Vec<BandView<'_>> = inputs
        .iter()
        .map(|i| {
            i.iter()
                .fold(BandView::new(pixels), |v, (l, d)| v.with(*l, d))
        })
        .collect();
    let mut want = vec![0.0; pixels * 3];
    let mut m = BandMut::new(pixels).with(Layer::Radiance, &mut want);
    p.run(&views, &mut m, &mut Default::default()).unwrap();
    want
}

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
    let node_frame = [
        image(ILL, f_ill, ill.clone()),
        image(dif, f_mat, d.clone()),
        image(spe, f_mat, s.clone()),
    ];
    let up_frame = [image(ILL, f_up, up.clone())];
    let got = one_frame(
        &stage,
        &mut ctl,
        &mut sink,
        size,
        [&up_frame, &node_frame],
        &out,
    )
    .await;

    let ops = specs(&ops);
    let inputs = [
        vec![(ILL, &up[..])],
        vec![(ILL, &ill[..]), (dif, &d[..]), (spe, &s[..])],
    ];
    let want = in_memory(&ops, &wiring, &inputs, (w * h) as usize);
    assert_eq!(
        got[0].data, want,
        "the stage gives the wired pipeline's bits"
    );
    assert!(want.iter().any(|v| *v > 0.0));
    stage.stop().await;
}

/// The penumbra filter at the last stage, band by band: each band is combined with `halo` rows
/// of its neighbours, so the sink gets the bits of the in-memory pipeline run on the whole frame
/// at once (bands of 4 rows and a short last band of 2, radius 3). A band height below the halo,
/// and a filter told another width, are refused.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn penumbra_filters_across_band_edges() {
    let size = (23, 14, 4);
    let (w, h, _) = size;
    let (dif, dep) = (Layer::Diffuse, Layer::Depth);
    let (f_up, f_ill, f_mat, f_dep) = (
        PixelFormat::F16x6,
        PixelFormat::Rgb9e5x2,
        PixelFormat::F16x4,
        PixelFormat::DepthF32,
    );
    let filter = format!(r#"{{"width": {w}, "radius": 3, "specular": true}}"#);
    let ops = [
        ("accumulate", r#"{"colors": [[2.0, 1.0, 0.5]]}"#),
        ("penumbra", filter.as_str()),
        ("material", r#"{"stage": "single", "specular": false}"#),
        ("output", r#"{"exposure": 1.0}"#),
    ];
    let wiring = vec![
        vec![OpSource::Input(0), OpSource::Input(1)],
        vec![OpSource::Op(0), OpSource::Input(1)],
        vec![OpSource::Op(1), OpSource::Input(1)],
        vec![OpSource::Op(2)],
    ];
    let node_layers = [(ILL, f_ill), (dif, f_mat), (dep, f_dep)];
    let ins = vec![input("up", &[(ILL, f_up)]), input("n", &node_layers)];
    let out = [(Layer::Radiance, PixelFormat::F32x3)];
    let mut cfg = config(1, size, ins, &ops, &out, "");
    cfg.wiring = wiring.clone();

    let stage = start_stage("filtered").await;
    let (mut sink, sink_addr) = sink().await;
    cfg.downstream = sink_addr;
    let mut ctl = stage.control().await;
    let mut short = cfg.clone();
    short.band_height = 2;
    let e = ctl.configure(short, WAIT).await.unwrap_err();
    assert!(e.to_string().contains("needs 3 rows"), "{e}");
    let mut narrow = cfg.clone();
    narrow.ops[1] = specs(&[("penumbra", r#"{"width": 22}"#)]).remove(0);
    let e = ctl.configure(narrow, WAIT).await.unwrap_err();
    assert!(e.to_string().contains("22 pixels wide"), "{e}");
    ctl.configure(cfg, WAIT).await.unwrap();

    // The upstream sum has a block of empty rows (an empty band inside the halo of others).
    let up = quantised(f_up, ILL, hdr(41, w, h, ILL, 4..8));
    let ill = quantised(f_ill, ILL, hdr(42, w, h, ILL, 0..0));
    let d: Vec<f32> = hdr(43, w, h, dif, 0..0)
        .iter()
        .map(|v| (v / 100.0).min(1.0))
        .collect();
    let d = quantised(f_mat, dif, d);
    // Depth: a slanted plane with a nearer box over part of it and a background corner.
    let depth: Vec<f32> = (0..w * h)
        .map(|p| {
            let (x, y) = (p % w, p / w);
            if x + y < 3 {
                0.0
            } else if (8..15).contains(&x) && (3..11).contains(&y) {
                2.0
            } else {
                1.0 / (0.2 + 0.004 * y as f32)
            }
        })
        .collect();
    let node_frame = [
        image(ILL, f_ill, ill.clone()),
        image(dif, f_mat, d.clone()),
        image(dep, f_dep, depth.clone()),
    ];
    let up_frame = [image(ILL, f_up, up.clone())];
    let got = one_frame(
        &stage,
        &mut ctl,
        &mut sink,
        size,
        [&up_frame, &node_frame],
        &out,
    )
    .await;

    let ops = specs(&ops);
    let inputs = [
        vec![(ILL, &up[..])],
        vec![(ILL, &ill[..]), (dif, &d[..]), (dep, &depth[..])],
    ];
    let pixels = (w * h) as usize;
    let want = in_memory(&ops, &wiring, &inputs, pixels);
    assert_eq!(
        got[0].data, want,
        "band by band with halos gives the whole frame's bits"
    );
    // And the filter did something: without it the frame differs.
    let plain = vec![ops[0].clone(), ops[2].clone(), ops[3].clone()];
    let plain_wiring = vec![
        vec![OpSource::Input(0), OpSource::Input(1)],
        vec![OpSource::Op(0), OpSource::Input(1)],
        vec![OpSource::Op(1)],
    ];
    assert_ne!(in_memory(&plain, &plain_wiring, &inputs, pixels), want);
    stage.stop().await;
}
