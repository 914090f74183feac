//! The one frame check: the single-device render of a scene (every sample on one GPU, paper
//! eq. 2 — the image a cluster must deliver) and the comparison of a cluster frame with it
//! within the link formats' bound. Tests assert with it; `lightfold soak` checks every frame it
//! delivers with it.

use lightfold_node::gpu::{Gpu, LayerSet, RenderOptions, Renderer};
use lightfold_scene::shading::{MaterialLayers, compose_frame};
use lightfold_scene::{Image, LightSample, Scene};

/// Final radiance of all the scene's samples rendered on one device (paper eq. 2). `walkthrough`
/// fits the shadow maps to every receiver, as walkthrough nodes must (their maps outlive camera
/// moves); otherwise to the receivers the camera sees. The two differ at shadow edges (other
/// texel grids: ≈ 0.4 % of channels of `small("balls")`, up to 0.025), so each cluster mode is
/// compared with the single-device render that fits its maps the same way.
pub fn single_device(gpu: &Gpu, scene: &Scene, walkthrough: bool) -> Image {
    single_device_filtered(gpu, scene, walkthrough, 0)
}

/// [`single_device`] with the penumbra filter of `radius` (0: none) on the summed illumination
/// before the material multiply, as a last stage planned with that radius applies it.
pub fn single_device_filtered(gpu: &Gpu, scene: &Scene, walkthrough: bool, radius: u32) -> Image {
    // Direct samples and, where the scene asks for indirect light, its VPLs (as the planner).
    let samples = lightfold_scene::vpl::frame_samples(scene);
    let mut r = Renderer::new(gpu, scene, RenderOptions::from_quality(&scene.quality)).unwrap();
    r.set_fit_to_camera(!walkthrough);
    radiance(gpu, &mut r, scene, &samples, radius).unwrap()
}

/// The final radiance of `samples` of `scene` from its camera on a renderer made for the scene
/// (reused across cameras and colours), with the penumbra filter of `radius` (0: none) on the
/// summed illumination: what a cluster's frame of that camera must equal.
pub fn radiance(
    gpu: &Gpu,
    r: &mut Renderer,
    scene: &Scene,
    samples: &[LightSample],
    radius: u32,
) -> anyhow::Result<Image> {
    r.set_camera(&scene.camera);
    // Every sample in one batch: one node frame of all of them.
    let k = samples.len().max(1);
    let ((image, _), _) =
        lightfold_quality::single::render_frame(gpu, r, scene, samples, k, None, radius)?;
    Ok(image)
}

/// The material stage on one device: paper eq. 2 (`compose_frame`), `e + m^a·c^a + m^d·I^d +
/// m^s·I^s` per pixel with the ambient `c^a` only where `covered`.
fn shade(
    scene: &Scene,
    il: &Image,
    [md, ms, ma, e]: [&Image; 4],
    covered: impl Fn(usize) -> bool,
) -> Image {
    let m = MaterialLayers {
        diffuse: md,
        specular: ms,
        ambient: ma,
        emissive: e,
    };
    compose_frame(il, [1.0; 3], m, scene.ambient, covered)
}

/// [`single_device`] over sort-last parts: each part's eye pass alone with its shadow maps
/// fitted to the part (as a sort-last node renders it), then per pixel every layer of the part whose surface is nearest (eye depth
/// above 0). Exact depth ties go to the lower part, or to the higher one with `ties_to_higher`
/// (a negative control of the compositor's rule).
pub fn single_device_parts(
    gpu: &Gpu,
    scene: &Scene,
    parts: &[Vec<u32>],
    ties_to_higher: bool,
) -> Image {
    let samples = lightfold_scene::vpl::frame_samples(scene);
    let mut r = Renderer::new(gpu, scene, RenderOptions::from_quality(&scene.quality)).unwrap();
    r.set_camera(&scene.camera);
    // Each part's maps fitted to the part, as a sort-last node fits them.
    r.set_fit_to_eye_meshes(true);
    let mut won: Vec<Option<(f32, usize)>> = Vec::new();
    let mut frames = Vec::new();
    for part in parts {
        r.set_eye_meshes(Some(part.clone()));
        let f = r
            .render(gpu, &samples, None, [1.0; 3], LayerSet::all())
            .unwrap();
        frames.push(f);
    }
    let depth = |p: usize| frames[p].depth.as_ref().unwrap();
    for i in 0..depth(0).pixel_count() {
        let mut best: Option<(f32, usize)> = None;
        for p in 0..parts.len() {
            let z = depth(p).data[i];
            let nearer = match best {
                None => true,
                Some((b, _)) => z < b || (ties_to_higher && z == b),
            };
            if z > 0.0 && z.is_finite() && nearer {
                best = Some((z, p));
            }
        }
        won.push(best);
    }
    let (w, h) = (scene.camera.width, scene.camera.height);
    let mut layers: Vec<Image> = (0..5)
        .map(|k| Image::new(w, h, if k == 0 { 6 } else { 3 }))
        .collect();
    for (i, winner) in won.iter().enumerate() {
        let Some((_, p)) = *winner else { continue };
        let f = &frames[p];
        let from = [
            f.illumination.as_ref(),
            f.diffuse.as_ref(),
            f.specular.as_ref(),
            f.ambient.as_ref(),
            f.emissive.as_ref(),
        ];
        for (dst, src) in layers.iter_mut().zip(from) {
            let c = dst.channels;
            dst.data[i * c..i * c + c].copy_from_slice(&src.unwrap().data[i * c..i * c + c]);
        }
    }
    shade(
        scene,
        &layers[0],
        [&layers[1], &layers[2], &layers[3], &layers[4]],
        |i| won[i].is_some(),
    )
}

/// [`single_device`] with `peels` translucent eye layers (`docs/translucency.md` § Peeled
/// layers): the opaque layer and each translucent one rendered on one device (each with every
/// sample, as one node of each layer renders it), each shaded by eq. 2 with its own material
/// layers, then laid over one another back to front as `blend` does (`R_d + T_d ⊙ behind`,
/// the nearest last): what a peeled cluster's frame must equal.
pub fn single_device_peeled(gpu: &Gpu, scene: &Scene, peels: u32) -> Image {
    let samples = lightfold_scene::vpl::frame_samples(scene);
    let mut r = Renderer::new(gpu, scene, RenderOptions::from_quality(&scene.quality)).unwrap();
    r.set_fit_to_camera(true);
    r.set_camera(&scene.camera);
    let mut out: Option<Image> = None;
    for d in std::iter::once(0).chain((1..=peels).rev()) {
        r.set_peel(Some(d));
        let layers = LayerSet {
            transmittance: d > 0,
            ..LayerSet::all()
        };
        let f = r.render(gpu, &samples, None, [1.0; 3], layers).unwrap();
        fn material(l: &Option<Image>) -> &Image {
            l.as_ref().expect("every material layer rendered")
        }
        let depth = material(&f.depth);
        let lit = shade(
            scene,
            f.illumination.as_ref().expect("illumination rendered"),
            [
                material(&f.diffuse),
                material(&f.specular),
                material(&f.ambient),
                material(&f.emissive),
            ],
            |i| depth.data[i] > 0.0,
        );
        out = Some(match (out, &f.transmittance) {
            (None, _) => lit,
            (Some(mut behind), Some(t)) => {
                for ((b, l), t) in behind.data.iter_mut().zip(&lit.data).zip(&t.data) {
                    *b = l + t.clamp(0.0, 1.0) * *b;
                }
                behind
            }
            (Some(_), None) => panic!("a translucent layer without its transmittance"),
        });
    }
    out.expect("at least the opaque layer")
}

/// [`single_device`] with `--aa factor`: rendered at `factor` × the camera's width and height,
/// the final radiance box-resolved to the camera's size (what `lightfold render --aa N` does, and
/// the cluster's sink). `factor = 1` is [`single_device`] itself.
pub fn single_device_aa(gpu: &Gpu, scene: &Scene, factor: u32) -> Image {
    let mut s = scene.clone();
    s.camera = s.camera.supersampled(factor).unwrap();
    single_device(gpu, &s, false).box_resolve(factor).unwrap()
}

/// How a frame compares with its single-device render: channels outside the link formats'
/// bound (2.5 % relative + 1e-3 absolute), the worst difference, the mean energy's ratio.
#[derive(Debug, Clone)]
pub struct Check {
    pub frame: u64,
    /// Within the bound: finite, at most one channel in `per` outside, energy within 1 %.
    pub ok: bool,
    pub outside: usize,
    pub channels: usize,
    pub energy_ratio: f64,
    pub worst: f32,
    /// Why the frame could not be compared (size, non-finite pixels, a failed render).
    pub error: Option<String>,
}

impl Check {
    /// A frame that could not be checked: `error` says why.
    pub fn failed(frame: u64, channels: usize, error: String) -> Check {
        Check {
            frame,
            ok: false,
            outside: 0,
            channels,
            energy_ratio: f64::NAN,
            worst: f32::NAN,
            error: Some(error),
        }
    }
}

/// Per-pixel agreement of `test` with `want` within the link formats' bound: rgb9e5x2 from nodes
/// (2⁻⁹ relative), f16 between stages (2⁻¹¹ per hop), material colours as planned (`f16x4` is
/// exact; `rgba8srgb`, when asked for, is ≤ 1.3 % relative at the dark end), so 2.5 % relative +
/// 1e-3 absolute per channel, at most one channel in `per` outside; and mean energy within 1 %.
pub fn compare(frame: u64, test: &Image, want: &Image, per: usize) -> Check {
    let mut check = Check {
        frame,
        ok: false,
        outside: 0,
        channels: test.data.len(),
        energy_ratio: f64::NAN,
        worst: 0.0,
        error: None,
    };
    if (test.width, test.height, test.channels) != (want.width, want.height, want.channels) {
        check.error = Some(format!(
            "size {}x{}x{}, expected {}x{}x{}",
            test.width, test.height, test.channels, want.width, want.height, want.channels
        ));
        return check;
    }
    let mut finite = true;
    for (a, b) in test.data.iter().zip(&want.data) {
        finite &= a.is_finite();
        let d = (a - b).abs();
        // NaN differences count as outside.
        if d.is_nan() || d > 0.025 * b.abs() + 1e-3 {
            check.outside += 1;
        }
        if d > check.worst || d.is_nan() {
            check.worst = d;
        }
    }
    let ea: f64 = test.data.iter().map(|&v| f64::from(v)).sum();
    let eb: f64 = want.data.iter().map(|&v| f64::from(v)).sum();
    check.energy_ratio = ea / eb;
    check.ok = finite
        && eb > 0.0
        && check.outside * per <= check.channels
        && (check.energy_ratio - 1.0).abs() < 0.01;
    if !finite {
        check.error = Some("non-finite pixel".into());
    } else if eb <= 0.0 {
        check.error = Some("the reference is black".into());
    }
    check
}

/// Asserts [`compare`] with at most one channel in 1000 outside.
pub fn assert_close(test: &Image, want: &Image, what: &str) {
    assert_close_within(test, want, what, 1000);
}

/// Asserts [`compare`] with at most one channel in `per` outside, saying where it failed.
pub fn assert_close_within(test: &Image, want: &Image, what: &str, per: usize) {
    let c = compare(0, test, want, per);
    if c.outside > 0 {
        eprintln!(
            "{what}: {} channels outside; worst |diff| {}",
            c.outside, c.worst
        );
    }
    assert!(c.error.is_none(), "{what}: {}", c.error.unwrap_or_default());
    assert!(
        c.outside * per <= c.channels,
        "{what}: {} of {} channels outside the bound",
        c.outside,
        c.channels
    );
    assert!(
        (c.energy_ratio - 1.0).abs() < 0.01,
        "{what}: energy ratio {}",
        c.energy_ratio
    );
}
