//! Shared parts of the GPU tests: the device (found or the test fails), a small scene built to
//! stress shadows, and the comparison with the CPU reference under an edge mask.
//!
//! Edge mask: a pixel is left out of the comparison when, in the reference, its 3×3 neighbourhood
//! (itself included) mixes shadow states — the set of samples that light it and are visible from
//! it is not the same for all nine — or touches a geometric silhouette (a coverage change or a
//! depth discontinuity per `reference::masks::silhouettes`, undilated). Shadow maps and ray tracing
//! legitimately disagree there; everywhere else they must agree to 1e-3 relative + 1e-4 absolute.

use lightfold_node::gpu::NodeFrame;
use lightfold_reference::Layers;
use lightfold_scene::primitives::{cuboid, plane, sphere};
use lightfold_scene::{
    AlphaMode, Camera, Image, Light, LightSample, LightShape, Material, Scene, Texture, sampling,
};

pub(crate) const REL_TOL: f32 = 1e-3;
pub(crate) const ABS_TOL: f32 = 1e-4;
/// Node colour of the tests: light A's colour, so light B's weight is not 1.
pub(crate) const C_N: [f32; 3] = [1.0, 0.8, 0.6];

/// The device, or a failed test that says why (GPU tests never skip).
pub(crate) use lightfold_harness::gpu;

/// A checkerboard with transparent cells, for an alpha-masked caster.
fn checker(n: u32) -> Texture {
    let mut rgba8 = Vec::with_capacity((n * n * 4) as usize);
    for y in 0..n {
        for x in 0..n {
            let on = (x / 2 + y / 2) % 2 == 0;
            rgba8.extend_from_slice(&[200, 180, 60, if on { 255 } else { 0 }]);
        }
    }
    Texture {
        name: "checker".into(),
        width: n,
        height: n,
        srgb: true,
        rgba8,
    }
}

/// Floor, back wall, a glossy sphere, a box, a pillar far off to the side of a low light (outside
/// a 90° cone of its samples), an alpha-masked fence, an emissive block, a slab floating just above
/// the floor; two coloured area lights.
pub(crate) fn shadow_scene(width: u32, height: u32) -> Scene {
    let mut s = Scene::new("shadow test");
    let grey = s.add_material(Material::diffuse("grey", [0.7, 0.7, 0.7]));
    let wall = s.add_material(Material::diffuse("wall", [0.6, 0.65, 0.7]));
    let glossy = s.add_material(Material {
        specular: [0.4; 3],
        shininess: 40.0,
        ambient: [0.05, 0.05, 0.1],
        ..Material::diffuse("glossy", [0.7, 0.2, 0.1])
    });
    let red = s.add_material(Material::diffuse("box", [0.2, 0.5, 0.8]));
    s.textures.push(checker(8));
    let fence = s.add_material(Material {
        diffuse_texture: Some(0),
        alpha_mode: AlphaMode::Mask { cutoff: 0.5 },
        ..Material::diffuse("fence", [1.0, 1.0, 1.0])
    });
    let glow = s.add_material(Material {
        emissive: [2.0, 1.5, 0.5],
        ..Material::diffuse("glow", [0.1, 0.1, 0.1])
    });
    let (x, y, z) = ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]);
    s.add_mesh(plane("floor", [0.0; 3], y, x, [8.0, 8.0], 4, grey));
    s.add_mesh(plane("wall", [0.0, 1.5, -2.5], z, x, [8.0, 3.0], 2, wall));
    s.add_mesh(sphere("ball", [0.0, 0.5, 0.0], 0.5, 32, 16, glossy));
    s.add_mesh(cuboid("box", [-1.2, 0.4, 0.8], [0.3, 0.4, 0.3], red));
    s.add_mesh(cuboid("pillar", [2.2, 0.6, -0.5], [0.15, 0.6, 0.15], red));
    s.add_mesh(plane(
        "fence",
        [-2.2, 0.6, -0.6],
        x,
        z,
        [1.6, 1.2],
        1,
        fence,
    ));
    s.add_mesh(cuboid("glow", [1.3, 0.1, 1.4], [0.2, 0.1, 0.2], glow));
    // A floating slab 0.25 m above the floor: its shadow's casters are close to the receivers.
    s.add_mesh(cuboid("slab", [-0.2, 0.28, 1.9], [1.1, 0.03, 0.55], red));
    let rect = |name: &str, center, normal, u_axis, side: f32, color| Light {
        name: name.into(),
        shape: LightShape::Rect {
            center,
            normal,
            u_axis,
            size: [side, side],
        },
        color,
        power: 12.0,
        range: None,
        samples: 4,
    };
    s.lights = vec![
        rect("low", [0.3, 1.5, 0.6], [0.0, -1.0, 0.0], x, 0.6, C_N),
        rect(
            "side",
            [-1.5, 2.5, 1.5],
            lightfold_scene::shading::normalize([1.5, -2.5, -1.5]),
            lightfold_scene::shading::normalize([1.0, 0.0, -1.0]),
            0.8,
            [0.6, 0.8, 1.0],
        ),
    ];
    s.camera = Camera {
        position: [0.0, 3.2, 5.5],
        target: [0.0, 0.3, -0.3],
        up: y,
        fov_y_deg: 50.0,
        width,
        height,
    };
    s
}

pub(crate) fn samples(scene: &Scene) -> Vec<LightSample> {
    sampling::direct_samples(scene)
}

pub(crate) use lightfold_reference::masks::ShadowStates;

/// The reference's shadow states; these tests judge at most 64 samples, each with its own bit.
pub(crate) fn shadow_states(scene: &Scene, samples: &[LightSample]) -> ShadowStates {
    assert!(samples.len() <= 64, "shadow states hold 64 samples");
    lightfold_reference::masks::shadow_states(scene, samples)
}

/// Outcome of comparing a GPU layer with the reference.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Comparison {
    pub compared: usize,
    pub agree: f64,
    pub energy_ratio: f64,
}

impl Comparison {
    /// The bar: ≥ 99 % of compared pixels agree and mean energy within 1 %.
    pub(crate) fn passes(&self) -> bool {
        self.agree >= 0.99 && (self.energy_ratio - 1.0).abs() <= 0.01
    }
}

/// Compares images channel by channel on `mask`; energy is compared over every pixel.
pub(crate) fn compare(gpu: &Image, reference: &Image, mask: &[bool]) -> Comparison {
    assert_eq!(
        (gpu.width, gpu.height, gpu.channels),
        (reference.width, reference.height, reference.channels)
    );
    let c = gpu.channels;
    let (mut compared, mut agree) = (0usize, 0usize);
    for (i, &m) in mask.iter().enumerate() {
        if !m {
            continue;
        }
        compared += 1;
        let a = &gpu.data[i * c..i * c + c];
        let b = &reference.data[i * c..i * c + c];
        if a.iter()
            .zip(b)
            .all(|(x, y)| (x - y).abs() <= REL_TOL * y.abs() + ABS_TOL)
        {
            agree += 1;
        }
    }
    let sum = |img: &Image| img.data.iter().map(|&v| f64::from(v)).sum::<f64>();
    let (eg, er) = (sum(gpu), sum(reference));
    Comparison {
        compared,
        agree: agree as f64 / compared.max(1) as f64,
        energy_ratio: if er > 0.0 {
            eg / er
        } else {
            f64::from(u8::from(eg == 0.0))
        },
    }
}

/// Writes GPU, reference and ×10 difference PNGs when `LIGHTFOLD_TEST_IMAGES` names a folder.
pub(crate) fn dump(name: &str, frame: &NodeFrame, reference: &Layers) {
    let Ok(dir) = std::env::var("LIGHTFOLD_TEST_IMAGES") else {
        return;
    };
    let dir = std::path::Path::new(&dir);
    let Some(g) = &frame.illumination else { return };
    let r = &reference.illumination;
    let mut diff = Image::new(g.width, g.height, 3);
    for i in 0..g.pixel_count() {
        for k in 0..3 {
            let d = (g.data[i * 6 + k] - r.data[i * 6 + k]).abs();
            diff.data[i * 3 + k] = d * 10.0;
        }
    }
    let _ = g.write_png(&dir.join(format!("{name}-actual.png")), 1.0);
    let _ = r.write_png(&dir.join(format!("{name}-expected.png")), 1.0);
    let _ = diff.write_png(&dir.join(format!("{name}-diff.png")), 1.0);
}

/// Pixels compared: not on a shadow edge or a silhouette (see the module docs).
pub(crate) fn comparable(reference: &Layers, states: &[u64]) -> Vec<bool> {
    lightfold_reference::masks::comparable(&reference.depth, &reference.coverage, states)
}

/// The scene with every translucent material made opaque (`None`) or removed from shadows.
pub(crate) fn without_transmission(scene: &Scene) -> Scene {
    let mut s = scene.clone();
    for m in &mut s.materials {
        m.transmission = None;
    }
    s
}

/// The edge mask of `gpu_support`, on the scene as it is and with its panes opaque, less the
/// pixels whose 3×3 neighbourhood sees the transmittance of some sample change by more than
/// 1 % (a texture's edge seen through a map of a few texels per edge, as shadow edges are).
pub(crate) fn edge_free(scene: &Scene, samples: &[LightSample], reference: &Layers) -> Vec<bool> {
    use lightfold_reference::Tracer;
    let states = shadow_states(scene, samples);
    let opaque_states = shadow_states(&without_transmission(scene), samples);
    let a = comparable(reference, &states.visible);
    let b = comparable(reference, &opaque_states.visible);
    let tracer = Tracer::new(scene);
    let (w, h) = (scene.camera.width as i64, scene.camera.height as i64);
    let tint: Vec<Vec<[f32; 3]>> = (0..w * h)
        .map(|i| match tracer.primary((i % w) as u32, (i / w) as u32) {
            Some(hit) => samples
                .iter()
                .map(|s| tracer.transmittance(&hit, s))
                .collect(),
            None => vec![[1.0; 3]; samples.len()],
        })
        .collect();
    let steady = |i: i64| {
        let (x, y) = (i % w, i / w);
        let mine = &tint[i as usize];
        (-1..=1).all(|dy| {
            (-1..=1).all(|dx| {
                let (nx, ny) = (x + dx, y + dy);
                if nx < 0 || ny < 0 || nx >= w || ny >= h {
                    return true;
                }
                tint[(ny * w + nx) as usize]
                    .iter()
                    .zip(mine)
                    .all(|(p, q)| (0..3).all(|k| (p[k] - q[k]).abs() <= 0.01))
            })
        })
    };
    (0..w * h)
        .map(|i| a[i as usize] && b[i as usize] && steady(i))
        .collect()
}
