//! One-bounce indirect light from virtual point lights (issue 25, `docs/indirect.md`).
//!
//! - **Closed form.** Inside a diffuse sphere of albedo ρ and radius R lit by an isotropic point
//!   light of intensity I at its centre, the one-bounce radiance of the wall is `ρ²·I/(π·R²)`
//!   everywhere (the direct light is uniform, and a sphere's `cos·cos/r²` is `1/(4R²)` for every
//!   pair of points); a falloff clamp `c` removes the fraction `c²/(8R²)` of it (the points within
//!   chord `c` of a point cover a cap of area `π·c²`, where the clamped term falls as `r²/c²`). The
//!   exact VPL sum, the path-traced truth and the GPU render each meet it.
//! - **No leak.** A point light in one of two closed rooms: the other room stays black through
//!   the GPU's shadow-mapped VPLs, while the same VPLs without visibility (seed 003's method) light
//!   it: the negative control.
//! - **Cluster.** The Cornell box with VPLs through the in-process cluster equals the single-device
//!   render within the link formats' bound, and that equals the CPU's exact VPL sum within the
//!   shadow maps' error.

use lightfold_coordinator::plan::MapSizing;
use lightfold_coordinator::run::RunOptions;
use lightfold_harness::{
    InProcessCluster, assert_close, gpu, render_on, single_device, test_control,
};
use lightfold_node::gpu::{Gpu, LayerSet, RenderOptions, Renderer};
use lightfold_reference::indirect::OneBounceOptions;
use lightfold_reference::{
    PointSumOptions, Tracer, compare, render_one_bounce, render_point_sum_with,
};
use lightfold_scene::vpl::{self, IndirectOptions};
use lightfold_scene::{Camera, Image, Light, LightSample, LightShape, Material, SampleKind, Scene};

const RHO: f32 = 0.5;
const R: f32 = 1.0;
const I: f32 = 1.0;

fn camera(position: [f32; 3], target: [f32; 3], w: u32, h: u32) -> Camera {
    Camera {
        position,
        target,
        up: [0.0, 1.0, 0.0],
        fov_y_deg: 50.0,
        width: w,
        height: h,
    }
}

fn point_light(position: [f32; 3], power: f32) -> Light {
    Light {
        name: "point".into(),
        shape: LightShape::Point { position },
        color: [1.0; 3],
        power,
        range: None,
        samples: 1,
    }
}

/// The furnace: a finely tessellated sphere of albedo ρ seen from near its centre, where the
/// point light is.
fn sphere_scene(vpls: u32, clamp: f32) -> Scene {
    let mut s = Scene::new("sphere furnace");
    let m = s.add_material(Material::diffuse("white", [RHO; 3]));
    s.add_mesh(lightfold_scene::primitives::sphere(
        "sphere", [0.0; 3], R, 96, 48, m,
    ));
    s.lights.push(point_light([0.0; 3], I));
    s.camera = camera([0.0, 0.0, 0.3], [0.0, -0.2, -1.0], 48, 36);
    s.quality.indirect = vpls;
    s.quality.indirect_clamp = Some(clamp);
    s.quality.shadow_map_size = 256;
    s.quality.map_sizing = lightfold_scene::MapSizing::Fixed;
    s
}

fn mean_rgb(img: &Image) -> f64 {
    img.data.iter().map(|&v| f64::from(v)).sum::<f64>() / img.data.len() as f64
}

/// Frame-to-frame flicker of a still camera's frames: the mean absolute difference between
/// consecutive frames over the earlier one's mean, averaged over the steps.
fn flicker(frames: &[Image]) -> f64 {
    let steps: Vec<f64> = frames
        .windows(2)
        .map(|w| {
            let d: f64 = w[0]
                .data
                .iter()
                .zip(&w[1].data)
                .map(|(a, b)| f64::from((a - b).abs()))
                .sum::<f64>()
                / w[0].data.len() as f64;
            d / mean_rgb(&w[0]).max(1e-12)
        })
        .collect();
    steps.iter().sum::<f64>() / steps.len() as f64
}

fn vpls_of(scene: &Scene) -> (Vec<LightSample>, Vec<LightSample>) {
    let all = vpl::frame_samples(scene);
    all.into_iter()
        .partition(|s| !matches!(s.kind, SampleKind::Bounce { .. }))
}

fn radiance_of(scene: &Scene, samples: &[LightSample], shadows: bool) -> Image {
    render_point_sum_with(scene, samples, [1.0; 3], PointSumOptions { shadows })
        .radiance([1.0; 3], scene.ambient)
}

/// GPU radiance of `samples` (paper eq. 2 with no ambient).
fn gpu_radiance(gpu: &Gpu, scene: &Scene, samples: &[LightSample]) -> Image {
    let mut r = Renderer::new(gpu, scene, RenderOptions::from_quality(&scene.quality)).unwrap();
    r.set_camera(&scene.camera);
    let batch = gpu.max_lights(scene.quality.shadow_map_size).clamp(1, 64) as usize;
    let mut out = Image::new(scene.camera.width, scene.camera.height, 3);
    for chunk in samples.chunks(batch) {
        let f = r
            .render(gpu, chunk, None, [1.0; 3], LayerSet::all())
            .unwrap();
        let (il, md) = (f.illumination.unwrap(), f.diffuse.unwrap());
        for i in 0..out.pixel_count() {
            for c in 0..3 {
                out.data[i * 3 + c] += md.data[i * 3 + c] * il.data[i * 6 + c];
            }
        }
    }
    out
}

fn closed_form(clamp: f32) -> f64 {
    let (rho, r, i) = (f64::from(RHO), f64::from(R), f64::from(I));
    let c = f64::from(clamp);
    rho * rho * i / (std::f64::consts::PI * r * r) * (1.0 - c * c / (8.0 * r * r))
}

#[test]
fn vpls_are_deterministic_and_carry_the_reflected_power() {
    let scene = sphere_scene(512, 0.0);
    let (direct, vpls) = vpls_of(&scene);
    assert_eq!(direct.len(), 1);
    // Inside a closed sphere every path lands: one VPL per path.
    assert_eq!(vpls.len(), 512);
    assert_eq!(
        vpls,
        vpls_of(&scene).1,
        "the same scene gives the same VPLs"
    );
    let mut other = scene.clone();
    other.quality.seed += 1;
    assert_ne!(vpls, vpls_of(&other).1, "another seed gives other VPLs");
    // Power: each VPL re-emits π·I_v; together ρ times the light's 4π·I.
    let power: f64 = vpls
        .iter()
        .map(|v| std::f64::consts::PI * f64::from(v.intensity * v.color[0]))
        .sum();
    let want = f64::from(RHO) * 4.0 * std::f64::consts::PI * f64::from(I);
    assert!(
        (power / want - 1.0).abs() < 1e-3,
        "VPL power {power}, want {want}"
    );
    for v in &vpls {
        let d = lightfold_scene::shading::length(v.position);
        assert!(d < R && d > 0.99 * R, "a VPL on the wall, inside: {d}");
        // The lobe faces the centre.
        assert!(lightfold_scene::shading::dot(v.direction, v.position) < 0.0);
    }
}

#[test]
fn furnace_exact_vpl_sum_and_truth_meet_the_closed_form() {
    let scene = sphere_scene(1024, 0.0);
    let (direct, vpls) = vpls_of(&scene);
    let want = closed_form(0.0);
    let vpl = mean_rgb(&radiance_of(&scene, &vpls, true));
    let truth = mean_rgb(
        &render_one_bounce(&scene, &direct, &OneBounceOptions { paths: 16, seed: 3 })
            .radiance([1.0; 3], [0.0; 3]),
    );
    eprintln!("furnace one bounce: closed form {want:.5}, VPL sum {vpl:.5}, truth {truth:.5}");
    assert!((vpl / want - 1.0).abs() < 0.01, "VPL sum {vpl} vs {want}");
    assert!((truth / want - 1.0).abs() < 0.01, "truth {truth} vs {want}");
}

#[test]
fn furnace_clamp_bias_is_the_documented_one() {
    let clamp = 0.5 * R;
    let scene = sphere_scene(2048, clamp);
    let (_, vpls) = vpls_of(&scene);
    assert!(vpls.iter().all(|v| v.kind == SampleKind::Bounce { clamp }));
    let got = mean_rgb(&radiance_of(&scene, &vpls, true));
    let want = closed_form(clamp);
    let unclamped = closed_form(0.0);
    eprintln!("furnace clamp {clamp}: {got:.5}, want {want:.5} (unclamped {unclamped:.5})");
    assert!(
        (got / want - 1.0).abs() < 0.01,
        "clamped sum {got} vs {want}"
    );
    // Negative control: the bias is larger than the tolerance, so the test sees it.
    assert!((got / unclamped - 1.0).abs() > 0.02);
}

#[test]
fn furnace_on_the_gpu() {
    let gpu = gpu();
    let scene = sphere_scene(256, 0.0);
    let (_, vpls) = vpls_of(&scene);
    let got = mean_rgb(&gpu_radiance(&gpu, &scene, &vpls));
    let want = closed_form(0.0);
    eprintln!("furnace on the GPU: {got:.5}, want {want:.5}");
    assert!(
        (got / want - 1.0).abs() < 0.02,
        "GPU VPL sum {got} vs {want}"
    );
}

/// Two closed rooms side by side, x < 0 and x > 0, a 0.2 m wall between; the light in the first,
/// the camera in the second.
fn two_rooms(vpls: u32) -> Scene {
    let mut s = Scene::new("two rooms");
    let m = s.add_material(Material::diffuse("white", [0.8; 3]));
    let cuboid = lightfold_scene::primitives::cuboid;
    let t = 0.1;
    // Floor, ceiling, outer walls (enclosing x ∈ [-3, 3], y ∈ [0, 2], z ∈ [-1.5, 1.5]), middle.
    s.add_mesh(cuboid(
        "floor",
        [0.0, -t, 0.0],
        [3.0 + 2.0 * t, t, 1.5 + 2.0 * t],
        m,
    ));
    s.add_mesh(cuboid(
        "ceiling",
        [0.0, 2.0 + t, 0.0],
        [3.0 + 2.0 * t, t, 1.5 + 2.0 * t],
        m,
    ));
    s.add_mesh(cuboid(
        "west",
        [-3.0 - t, 1.0, 0.0],
        [t, 1.0 + 2.0 * t, 1.5 + 2.0 * t],
        m,
    ));
    s.add_mesh(cuboid(
        "east",
        [3.0 + t, 1.0, 0.0],
        [t, 1.0 + 2.0 * t, 1.5 + 2.0 * t],
        m,
    ));
    s.add_mesh(cuboid(
        "north",
        [0.0, 1.0, -1.5 - t],
        [3.0 + 2.0 * t, 1.0 + 2.0 * t, t],
        m,
    ));
    s.add_mesh(cuboid(
        "south",
        [0.0, 1.0, 1.5 + t],
        [3.0 + 2.0 * t, 1.0 + 2.0 * t, t],
        m,
    ));
    s.add_mesh(cuboid(
        "middle",
        [0.0, 1.0, 0.0],
        [t, 1.0 + 2.0 * t, 1.5 + 2.0 * t],
        m,
    ));
    // A box in the lit room, so its light bounces off more than walls.
    s.add_mesh(cuboid("box", [-1.5, 0.4, 0.3], [0.4, 0.4, 0.4], m));
    s.lights.push(point_light([-2.0, 1.5, -0.5], 10.0));
    s.camera = camera([2.8, 1.6, 1.3], [0.2, 0.3, -0.5], 48, 36);
    s.quality.indirect = vpls;
    s.quality.shadow_map_size = 512;
    s.quality.map_sizing = lightfold_scene::MapSizing::Fixed;
    s
}

#[test]
fn indirect_light_does_not_leak_through_walls() {
    let gpu = gpu();
    let scene = two_rooms(256);
    let (direct, vpls) = vpls_of(&scene);
    assert!(vpls.len() > 200, "{} VPLs", vpls.len());
    assert!(
        vpls.iter().all(|v| v.position[0] < 0.0),
        "every VPL is in the lit room"
    );
    // How bright the lit room's bounce is, for scale: its wall seen from inside.
    let mut lit = scene.clone();
    lit.camera = camera([-0.3, 1.0, 1.2], [-2.5, 0.8, -1.0], 48, 36);
    let lit_level = mean_rgb(&radiance_of(&lit, &vpls, true));
    assert!(lit_level > 1e-3, "the lit room is lit: {lit_level}");

    let gpu_dark = gpu_radiance(&gpu, &scene, &[direct.clone(), vpls.clone()].concat());
    let peak = gpu_dark.data.iter().copied().fold(0.0f32, f32::max);
    let cpu_dark = radiance_of(&scene, &vpls, true);
    let cpu_peak = cpu_dark.data.iter().copied().fold(0.0f32, f32::max);
    // Negative control: the same VPLs without visibility light the dark room.
    let leak = radiance_of(&scene, &vpls, false);
    let leak_mean = mean_rgb(&leak);
    eprintln!(
        "dark room: GPU peak {peak:.2e}, CPU peak {cpu_peak:.2e}; without visibility mean \
         {leak_mean:.2e}; lit room mean {lit_level:.2e}"
    );
    assert_eq!(
        cpu_peak, 0.0,
        "the exact VPL sum leaves the dark room black"
    );
    assert!(
        f64::from(peak) < 1e-3 * lit_level,
        "light leaked into the dark room through the GPU's VPLs: peak {peak}"
    );
    // And the GPU does light the lit room with those VPLs.
    let gpu_lit = mean_rgb(&gpu_radiance(&gpu, &lit, &vpls));
    eprintln!("lit room through the GPU's VPLs: {gpu_lit:.3e}");
    assert!(
        (gpu_lit / lit_level - 1.0).abs() < 0.05,
        "{gpu_lit} vs {lit_level}"
    );
    assert!(
        leak_mean > 0.02 * lit_level,
        "without visibility the VPLs must leak (seed 003's method): {leak_mean}"
    );
}

fn cornell(vpls: u32) -> Scene {
    let mut s = lightfold_scene::builtin("cornell").unwrap();
    s.quality.samples_per_area_light = Some(4);
    s.quality.indirect = vpls;
    s.camera.width = 64;
    s.camera.height = 48;
    s
}

#[test]
fn cornell_vpls_on_the_gpu_match_the_exact_vpl_sum() {
    let gpu = gpu();
    let scene = cornell(64);
    let samples = vpl::frame_samples(&scene);
    let got = single_device(&gpu, &scene, false);
    let want = radiance_of(&scene, &samples, true);
    let m = compare(&got, &want, scene.exposure, None).unwrap();
    let (direct, _) = vpls_of(&scene);
    let direct_only = radiance_of(&scene, &direct, true);
    let gain = mean_rgb(&want) / mean_rgb(&direct_only) - 1.0;
    eprintln!(
        "cornell, 64 VPLs: GPU vs exact VPL sum PSNR {:.2} dB, energy bias {:+.4}; indirect adds \
         {:+.1} % energy",
        m.whole.psnr,
        m.whole.energy_bias,
        gain * 100.0
    );
    assert!(gain > 0.05, "indirect light adds energy: {gain}");
    assert!(m.whole.psnr > 40.0, "PSNR {}", m.whole.psnr);
    assert!(m.whole.energy_bias.abs() < 0.01);
    // The ceiling, black with direct light only, is lit.
    let ceiling = |img: &Image| img.rgb(32, 1)[0];
    assert_eq!(ceiling(&direct_only), 0.0);
    assert!(ceiling(&got) > 0.0);
}

#[test]
fn tracer_light_rays_see_single_sided_backs() {
    // A single-sided quad seen from behind: eye rays pass, light rays stop (it casts shadows)
    // and report the unseen back.
    let mut s = Scene::new("quad");
    let mut mat = Material::diffuse("one-sided", [0.5; 3]);
    mat.double_sided = false;
    let m = s.add_material(mat);
    s.add_mesh(lightfold_scene::primitives::plane(
        "quad",
        [0.0; 3],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [2.0, 2.0],
        1,
        m,
    ));
    let t = Tracer::new(&s);
    let up = [0.0f32, 1.0, 0.0];
    assert!(t.eye_ray([0.0, -1.0, 0.0], up, 1.0).is_none());
    let (hit, back) = t.light_ray([0.0, -1.0, 0.0], up).unwrap();
    assert!(back);
    assert!((hit.position[1]).abs() < 1e-6);
    let (_, back) = t.light_ray([0.0, 1.0, 0.0], [0.0, -1.0, 0.0]).unwrap();
    assert!(!back);
    // No VPL on an unseen back: a light under the quad, pointing up, makes none there.
    s.lights.push(point_light([0.0, -0.5, 0.0], 1.0));
    let direct = lightfold_scene::sampling::direct_samples(&s);
    let opts = IndirectOptions {
        count: 64,
        clamp: 0.0,
        seed: 1,
    };
    assert!(vpl::vpls(&Tracer::new(&s), &direct, &opts).is_empty());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn cluster_with_vpls_matches_single_device_render() {
    let gpu = gpu();
    let scene = cornell(48);
    let want = single_device(&gpu, &scene, false);
    let cluster = InProcessCluster::start(4, 4).await.unwrap();
    let mut session = cluster.connect(test_control()).await.unwrap();
    let mut opts = RunOptions {
        control: test_control(),
        ..RunOptions::default()
    };
    opts.plan.lights_per_node = 16;
    opts.plan.map_sizing = MapSizing::Fixed(scene.quality.shadow_map_size);
    let out = render_on(&mut session, &scene, &opts).await.unwrap();
    let bounces = out
        .plan
        .samples
        .iter()
        .filter(|s| matches!(s.kind, SampleKind::Bounce { .. }))
        .count();
    assert!(bounces > 40, "the plan carries the VPLs: {bounces}");
    assert_close(
        &out.frames[0].image,
        &want,
        "cornell with VPLs through the cluster",
    );
    session.detach();
    cluster.stop().await.unwrap();
}

#[test]
fn plans_carry_vpls_and_keep_every_slot_of_an_animated_scene() {
    use lightfold_coordinator::plan::{ClusterSpec, PlanOptions, plan};
    let scene = cornell(64);
    let p = plan(&scene, &ClusterSpec::local(64, 8), &PlanOptions::default()).unwrap();
    let direct = lightfold_scene::sampling::direct_samples(&scene).len();
    let bounces: Vec<_> = p
        .samples
        .iter()
        .filter(|s| matches!(s.kind, SampleKind::Bounce { .. }))
        .collect();
    assert_eq!(p.samples.len(), direct + bounces.len());
    assert!(bounces.len() > 40);
    // Culled and shadowed like any sample: the VPLs on the box's hidden faces or facing away from
    // everything the camera sees may go, but most light something it sees.
    let active_bounces = p.active.iter().filter(|&&i| i >= direct).count();
    assert!(
        active_bounces * 2 > bounces.len(),
        "{active_bounces} active"
    );
    // Direct light only: the plan has no VPL.
    let still = plan(
        &cornell(0),
        &ClusterSpec::local(64, 8),
        &PlanOptions::default(),
    )
    .unwrap();
    assert_eq!(still.samples.len(), direct);

    // An animated scene: one slot a light path, every one kept (a VPL dark or unseen at rest
    // may light what the camera sees at another time).
    let mut moving = lightfold_scene::builtin("carousel").unwrap();
    moving.quality.indirect = 16;
    let p = plan(&moving, &ClusterSpec::local(64, 8), &PlanOptions::default()).unwrap();
    let first = lightfold_scene::sampling::direct_samples(&moving).len();
    assert_eq!(p.samples.len(), first + 16);
    assert!(
        p.samples[first..]
            .iter()
            .all(|s| matches!(s.kind, SampleKind::Bounce { .. }))
    );
    assert!(
        (first..first + 16).all(|i| p.active.contains(&i)),
        "every slot active"
    );
}

#[test]
fn scene_files_set_indirect_light() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("room.toml");
    std::fs::write(
        &path,
        r#"
version = 1
name = "room"
[camera]
position = [0.0, 1.0, 3.0]
target = [0.0, 0.5, 0.0]
fov_y_deg = 45.0
[quality]
indirect = 128
indirect_clamp = 0.05
[[object]]
type = "plane"
center = [0.0, 0.0, 0.0]
size = [4.0, 4.0]
[[light]]
type = "point"
position = [0.0, 2.0, 0.0]
intensity = 10.0
"#,
    )
    .unwrap();
    let scene = lightfold_scene::load(path.to_str().unwrap()).unwrap();
    assert_eq!(scene.quality.indirect, 128);
    assert_eq!(scene.quality.indirect_clamp, Some(0.05));
    let bounces = vpl::frame_samples(&scene)
        .iter()
        .filter(|s| s.kind == SampleKind::Bounce { clamp: 0.05 })
        .count();
    // The 4 m square 2 m below the light subtends 4·asin(1/2) = 2π/3 sr, a sixth of the sphere:
    // the other paths leave the scene (128/6 ≈ 21 VPLs).
    assert!((15..=28).contains(&bounces), "{bounces} VPLs");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_light_colour_change_recolours_its_vpls() {
    use lightfold_coordinator::run::ColorChange;
    let gpu = gpu();
    let scene = cornell(24);
    let cluster = InProcessCluster::start(3, 3).await.unwrap();
    let mut opts = RunOptions {
        control: test_control(),
        frames: 2,
        ..RunOptions::default()
    };
    opts.plan.lights_per_node = 16;
    opts.plan.map_sizing = MapSizing::Fixed(scene.quality.shadow_map_size);
    let new_color = [0.3, 0.6, 1.0];
    opts.color_changes = vec![ColorChange {
        frame: 2,
        light: 0,
        color: new_color,
    }];
    let out = cluster.render(&scene, &opts).await.unwrap();
    assert_eq!(out.frames.len(), 2);
    assert_close(
        &out.frames[0].image,
        &single_device(&gpu, &scene, false),
        "frame 1",
    );
    // The truth of frame 2: the scene with the new colour, its VPLs traced again (they carry the
    // light's colour times the albedo they bounced off).
    let mut recoloured = scene.clone();
    recoloured.lights[0].color = new_color;
    let want = single_device(&gpu, &recoloured, false);
    assert_close(&out.frames[1].image, &want, "frame 2 (new colour)");
    // Negative control: recolouring only the direct light is visibly wrong.
    let stale = {
        let (_, vpls) = vpls_of(&scene);
        let (new_direct, _) = vpls_of(&recoloured);
        let mut r =
            Renderer::new(&gpu, &scene, RenderOptions::from_quality(&scene.quality)).unwrap();
        r.set_camera(&scene.camera);
        let samples = [new_direct, vpls].concat();
        let f = r
            .render(&gpu, &samples, None, [1.0; 3], LayerSet::all())
            .unwrap();
        let il = f.illumination.clone().unwrap();
        f.radiance(&il, scene.ambient).unwrap()
    };
    let d = |a: &Image, b: &Image| {
        a.data
            .iter()
            .zip(&b.data)
            .map(|(x, y)| f64::from((x - y).abs()))
            .sum::<f64>()
            / a.data.len() as f64
    };
    let (good, bad) = (d(&out.frames[1].image, &want), d(&stale, &want));
    eprintln!("frame 2 mean |diff|: {good:.2e}; with the VPLs' old colour {bad:.2e}");
    assert!(bad > 5.0 * good, "the control must differ: {bad} vs {good}");
    cluster.stop().await.unwrap();
}

/// VPLs follow a moved object without flicker: the live loop plans a moved scene with the
/// scene's own seed (`FrameSpec::moves`), so the same light paths are traced every frame and a
/// small move changes the bounce a little, where a fresh random set of VPLs each frame (the
/// control, the scene's seed changed per frame) flickers. Flicker is the mean |difference| of
/// the bounce (the exact sum of the VPLs alone, with visibility) between consecutive frames of a
/// still camera, relative to its mean, over five 1 cm moves of Cornell's tall box. A 1 cm move
/// in a 2 m room changes the true bounce by about a per cent near the box and less elsewhere; a
/// fresh set of 64 VPLs changes every pixel by its Monte Carlo error, tens of per cent. The bound
/// (a quarter of the control's) sits between them.
#[test]
fn vpls_follow_a_moved_object_without_flicker() {
    use lightfold_scene::moves::MeshMove;
    let base = cornell(64);
    let tall = base
        .meshes
        .iter()
        .position(|m| m.name == "tall box")
        .unwrap() as u32;
    let frames = |fresh: bool| -> Vec<Image> {
        (0..6)
            .map(|k| {
                let mut s = base.moved(&[MeshMove {
                    translate: [0.01 * k as f32, 0.0, 0.0],
                    ..MeshMove::identity(tall)
                }]);
                if fresh {
                    s.quality.seed = base.quality.seed.wrapping_add(k + 1);
                }
                let (_, vpls) = vpls_of(&s);
                assert!(vpls.len() > 32, "{} VPLs", vpls.len());
                radiance_of(&s, &vpls, true)
            })
            .collect()
    };
    let coherent = flicker(&frames(false));
    let fresh = flicker(&frames(true));
    eprintln!(
        "bounce flicker over 1 cm moves: same paths {:.4}, fresh VPLs each frame {:.4} (ratio {:.3})",
        coherent,
        fresh,
        coherent / fresh
    );
    assert!(coherent > 0.0, "the moves change the bounce");
    assert!(
        coherent < 0.25 * fresh,
        "the bounce flickers: {coherent:.4} against {fresh:.4} with fresh VPLs"
    );
}

/// The carousel (a box spins, an area light travels) with 64 VPLs, a fixed clamp, 64×48.
fn carousel_indirect(vpls: u32) -> Scene {
    let mut s = lightfold_harness::small("carousel");
    s.quality.indirect = vpls;
    // A clamp of its own: the default follows the scene's bounds, which a pose changes.
    s.quality.indirect_clamp = Some(0.1);
    s
}

/// Indirect light on the built-in animated scene: every frame traces the VPLs again where the
/// box and the light are, with the same light paths, one slot each (a path that leaves nothing
/// keeps a dark slot). The bounce (VPLs alone, exact sums on the CPU) between consecutive frames
/// of a still camera 1/50 s apart changes by what moved — the travelling light's paths land
/// a little further along, the spinner's VPLs turn with it — while a fresh random set each frame
/// (the control, the seed changed per frame) changes every pixel by its Monte Carlo error; the
/// bound is a quarter of the control's, as for moved objects.
#[test]
fn vpls_follow_the_animation_without_flicker() {
    let base = carousel_indirect(64);
    assert!(base.is_animated());
    let rest = vpl::frame_samples(&base);
    let slots = rest
        .iter()
        .filter(|s| matches!(s.kind, SampleKind::Bounce { .. }))
        .count();
    assert_eq!(slots, 64, "one slot a light path");
    // What tracing a frame's VPLs costs (the coordinator does it on its event loop).
    let traced = std::cell::Cell::new(0.0f64);
    let frames = |fresh: bool| -> Vec<Image> {
        (0..6)
            .map(|k| {
                let t = 0.5 + k as f32 / 50.0;
                let mut s = base.clone();
                if fresh {
                    s.quality.seed = base.quality.seed.wrapping_add(k + 1);
                }
                let started = std::time::Instant::now();
                let all = vpl::frame_samples_at(&s, t);
                traced.set(traced.get() + started.elapsed().as_secs_f64());
                assert_eq!(all.len(), rest.len(), "t = {t}: slot for slot");
                let vpls: Vec<LightSample> = all
                    .into_iter()
                    .filter(|x| matches!(x.kind, SampleKind::Bounce { .. }))
                    .collect();
                assert!(vpls.iter().filter(|v| v.intensity > 0.0).count() > 32);
                radiance_of(&s.still_at(t), &vpls, true)
            })
            .collect()
    };
    let coherent = flicker(&frames(false));
    let fresh = flicker(&frames(true));
    eprintln!(
        "carousel bounce flicker, frames 1/50 s apart: same paths {coherent:.4}, fresh VPLs each \
         frame {fresh:.4} (ratio {:.3}); a frame's samples posed and traced in {:.1} ms",
        coherent / fresh,
        traced.get() * 1e3 / 12.0
    );
    assert!(coherent > 0.0, "the animation changes the bounce");
    assert!(
        coherent < 0.25 * fresh,
        "the bounce flickers: {coherent:.4} against {fresh:.4} with fresh VPLs"
    );
}

/// The carousel with VPLs through the in-process cluster: each frame (its VPLs traced again at
/// its time and sent with the frame, `FrameParams::lights`) equals the single-device render of
/// the scene posed at that time with its own VPLs; the rest pose's VPLs kept (the control) do
/// not.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn an_animated_scene_with_vpls_through_the_cluster_equals_each_pose() {
    let gpu = gpu();
    let scene = carousel_indirect(16);
    let cluster = InProcessCluster::start(3, 3).await.unwrap();
    let mut session = cluster.connect(test_control()).await.unwrap();
    let mut opts = RunOptions {
        control: test_control(),
        frames: 2,
        time: Some(0.5),
        fps: Some(1.5),
        ..RunOptions::default()
    };
    opts.plan.lights_per_node = 8;
    opts.plan.walkthrough = true;
    opts.plan.map_sizing = MapSizing::Fixed(scene.quality.shadow_map_size);
    let out = render_on(&mut session, &scene, &opts).await.unwrap();
    let bounce = out
        .plan
        .samples
        .iter()
        .filter(|s| matches!(s.kind, SampleKind::Bounce { .. }))
        .count();
    assert_eq!(bounce, 16, "every VPL slot planned, none culled");
    for (i, f) in out.frames.iter().enumerate() {
        let t = opts.time_of(i as u32).unwrap();
        let want = single_device(&gpu, &scene.still_at(t), true);
        assert_close(&f.image, &want, &format!("carousel with VPLs at t = {t}"));
    }
    // The control: the pose at the last time with the rest pose's VPLs.
    let t = opts.time_of(1).unwrap();
    let posed = scene.still_at(t);
    let mut kept = lightfold_scene::sampling::direct_samples(&posed);
    kept.extend(
        vpl::frame_samples(&scene)
            .into_iter()
            .filter(|s| matches!(s.kind, SampleKind::Bounce { .. })),
    );
    let stale = radiance_of(&posed, &kept, true);
    let fresh = radiance_of(&posed, &vpl::frame_samples(&posed), true);
    let d = |a: &Image, b: &Image| {
        a.data
            .iter()
            .zip(&b.data)
            .map(|(x, y)| f64::from((x - y).abs()))
            .sum::<f64>()
            / a.data.len() as f64
    };
    let (to_stale, to_fresh) = (
        d(&out.frames[1].image, &stale),
        d(&out.frames[1].image, &fresh),
    );
    eprintln!(
        "carousel at t = {t}: mean difference to its own VPLs {to_fresh:.5}, to the rest pose's {to_stale:.5}"
    );
    assert!(
        to_stale > 2.0 * to_fresh,
        "the frame kept the rest pose's VPLs"
    );
}
