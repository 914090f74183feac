//! Sort-last partitions at the node (issue 24): a renderer that draws only some meshes in its
//! eye pass (`Renderer::set_eye_meshes`) gives, where its nearest surface is the scene's, exactly
//! the layers the whole scene gives there — shadows still come from every caster. Selecting per
//! pixel the partition with the nearest surface (ties to the lower index, as the `depth` operator
//! does) reproduces the whole render bit for bit, in both eye variants; the negative control:
//! a partition whose shadow casters are only its own meshes does not.

use crate::gpu_support;

use gpu_support::*;
use lightfold_node::gpu::{EyeVariant, Gpu, LayerSet, NodeFrame, RenderOptions, Renderer};
use lightfold_scene::{Image, LightSample, Scene};

const W: u32 = 160;
const H: u32 = 120;

fn frame(
    gpu: &Gpu,
    scene: &Scene,
    samples: &[LightSample],
    variant: EyeVariant,
    eye: Option<Vec<u32>>,
    casters: Option<&[Vec<u32>]>,
) -> NodeFrame {
    let mut r = Renderer::new(gpu, scene, RenderOptions::from_quality(&scene.quality)).unwrap();
    r.set_variant(variant);
    r.set_eye_meshes(eye);
    r.render(gpu, samples, casters, C_N, LayerSet::all())
        .unwrap()
}

/// Per pixel, the index of the frame with the nearest surface (eye depth > 0), the lower index on
/// a tie; `None` where no frame covers the pixel.
fn nearest(frames: &[NodeFrame]) -> Vec<Option<usize>> {
    let depth = |f: &NodeFrame| f.depth.clone().expect("depth");
    let depths: Vec<Image> = frames.iter().map(depth).collect();
    (0..(W * H) as usize)
        .map(|i| {
            depths
                .iter()
                .enumerate()
                .filter(|(_, d)| d.data[i] > 0.0)
                .min_by(|a, b| a.1.data[i].total_cmp(&b.1.data[i]))
                .map(|(k, _)| k)
        })
        .collect()
}

/// The layers of `frames` selected per pixel by `pick`, as one frame's bits.
fn composed(frames: &[NodeFrame], pick: &[Option<usize>]) -> Vec<Vec<u32>> {
    let layer = |f: &NodeFrame, l: usize| -> Image {
        match l {
            0 => f.illumination.clone(),
            1 => f.diffuse.clone(),
            2 => f.specular.clone(),
            3 => f.ambient.clone(),
            4 => f.emissive.clone(),
            _ => f.depth.clone(),
        }
        .expect("layer")
    };
    (0..6)
        .map(|l| {
            let imgs: Vec<Image> = frames.iter().map(|f| layer(f, l)).collect();
            let c = imgs[0].channels;
            let mut bits = Vec::with_capacity((W * H) as usize * c);
            for (i, p) in pick.iter().enumerate() {
                for k in 0..c {
                    bits.push(match p {
                        Some(p) => imgs[*p].data[i * c + k].to_bits(),
                        None => 0f32.to_bits(),
                    });
                }
            }
            bits
        })
        .collect()
}

/// The whole render's layers, as [`composed`] gives them (0 where nothing covers a pixel).
fn whole(f: &NodeFrame) -> Vec<Vec<u32>> {
    let d = f.depth.as_ref().expect("depth");
    let pick: Vec<Option<usize>> = d.data.iter().map(|&z| (z > 0.0).then_some(0)).collect();
    composed(std::slice::from_ref(f), &pick)
}

/// Two parts of alternate meshes.
fn interleaved(scene: &Scene) -> Vec<Vec<u32>> {
    let n = scene.meshes.len() as u32;
    vec![
        (0..n).filter(|m| m % 2 == 0).collect(),
        (0..n).filter(|m| m % 2 == 1).collect(),
    ]
}

#[test]
fn partitions_depth_selected_equal_the_whole_scene_bit_for_bit() {
    let gpu = gpu();
    let scene = shadow_scene(W, H);
    let samples = samples(&scene);
    // Two interleaved partitions: every caster of the other partition shadows this one.
    let parts = interleaved(&scene);
    for variant in [EyeVariant::Forward, EyeVariant::Deferred] {
        let all = frame(&gpu, &scene, &samples, variant, None, None);
        let frames: Vec<NodeFrame> = parts
            .iter()
            .map(|p| frame(&gpu, &scene, &samples, variant, Some(p.clone()), None))
            .collect();
        let pick = nearest(&frames);
        let covered = pick.iter().filter(|p| p.is_some()).count();
        let from_second = pick.iter().filter(|p| **p == Some(1)).count();
        assert!(
            covered > (W * H / 2) as usize && from_second > 1000,
            "{covered} {from_second}"
        );
        let (got, want) = (composed(&frames, &pick), whole(&all));
        for (l, (g, w)) in got.iter().zip(&want).enumerate() {
            let differ = g.iter().zip(w).filter(|(a, b)| a != b).count();
            assert_eq!(differ, 0, "{variant:?} layer {l}: {differ} values differ");
        }
    }
}

#[test]
fn negative_control_own_casters_only_differ() {
    // A partition that casts shadows only from its own meshes loses the other's shadows.
    let gpu = gpu();
    let scene = shadow_scene(W, H);
    let samples = samples(&scene);
    let parts = interleaved(&scene);
    let all = frame(&gpu, &scene, &samples, EyeVariant::Deferred, None, None);
    let frames: Vec<NodeFrame> = parts
        .iter()
        .map(|p| {
            let own = vec![p.clone(); samples.len()];
            frame(
                &gpu,
                &scene,
                &samples,
                EyeVariant::Deferred,
                Some(p.clone()),
                Some(&own),
            )
        })
        .collect();
    let pick = nearest(&frames);
    let (got, want) = (composed(&frames, &pick), whole(&all));
    let differ = got[0].iter().zip(&want[0]).filter(|(a, b)| a != b).count();
    assert!(differ > 1000, "only {differ} illumination values differ");
}
