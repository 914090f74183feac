//! A glTF animation → [`Animation`]: the node hierarchy with each node's rest TRS, the chosen
//! clip's channels (samplers read through the checked accessor reader), and the rigs the mesh
//! and light loaders collected, renumbered from glTF node indices to hierarchy order.

use super::accessor::{Buffers, ReadResult};
use crate::animation::{
    AnimNode, Animation, Channel, Interpolation, LightRig, MAX_TARGETS, MeshRig, Target,
};
use glam::Mat4;
use gltf::accessor::Dimensions;
use gltf::animation::Property;

/// Which clip of the document to play: by name or index, else the first.
pub(super) fn choose<'a>(
    doc: &'a gltf::Document,
    wanted: Option<&str>,
) -> Result<Option<gltf::Animation<'a>>, String> {
    let Some(w) = wanted else {
        return Ok(doc.animations().next());
    };
    let found = doc.animations().find(|a| a.name() == Some(w)).or_else(|| {
        w.parse::<usize>()
            .ok()
            .and_then(|i| doc.animations().nth(i))
    });
    match found {
        Some(a) => Ok(Some(a)),
        None => {
            let names: Vec<String> = doc
                .animations()
                .enumerate()
                .map(|(i, a)| a.name().map_or(i.to_string(), |n| format!("{n:?}")))
                .collect();
            Err(format!(
                "no animation {w:?} in the model (it has: {})",
                if names.is_empty() {
                    "none".to_string()
                } else {
                    names.join(", ")
                }
            ))
        }
    }
}

/// Builds the animation of `clip`; `meshes` and `lights` are the rigs the loaders kept, with glTF
/// node indices in `node` and their scene indices in `mesh` / `light`.
pub(super) fn build(
    doc: &gltf::Document,
    clip: &gltf::Animation,
    bufs: &Buffers,
    root: Mat4,
    meshes: Vec<MeshRig>,
    lights: Vec<(u32, usize, Mat4)>,
) -> ReadResult<Animation> {
    let n = doc.nodes().len();
    let mut parent = vec![None; n];
    for node in doc.nodes() {
        for c in node.children() {
            parent[c.index()] = Some(node.index());
        }
    }
    // Hierarchy order: parents before children (the loader already rejected cycles).
    let mut order = Vec::with_capacity(n);
    let mut placed = vec![false; n];
    let mut depth_first: Vec<usize> = (0..n).rev().filter(|&i| parent[i].is_none()).collect();
    let children: Vec<Vec<usize>> = doc
        .nodes()
        .map(|nd| nd.children().map(|c| c.index()).collect())
        .collect();
    while let Some(i) = depth_first.pop() {
        if std::mem::replace(&mut placed[i], true) {
            continue;
        }
        order.push(i);
        depth_first.extend(children[i].iter().rev().copied());
    }
    let mut index = vec![0u32; n];
    for (k, &i) in order.iter().enumerate() {
        index[i] = k as u32;
    }
    let gltf_nodes: Vec<gltf::Node> = doc.nodes().collect();
    let nodes: Vec<AnimNode> = order
        .iter()
        .map(|&i| {
            let nd = &gltf_nodes[i];
            let (t, r, s) = nd.transform().decomposed();
            let weights = nd
                .weights()
                .or_else(|| nd.mesh().and_then(|m| m.weights()))
                .map(|w| w.iter().take(MAX_TARGETS).copied().collect())
                .unwrap_or_default();
            AnimNode {
                name: nd.name().unwrap_or("node").to_string(),
                parent: parent[i].map(|p| index[p]),
                translation: t,
                rotation: r,
                scale: s,
                weights,
            }
        })
        .collect();

    let mut channels = Vec::new();
    for (c, ch) in clip.channels().enumerate() {
        let at = format!("animation {} channel {c}", clip.index());
        let node = ch.target().node().index();
        let sampler = ch.sampler();
        let (times, _) =
            bufs.read_f32(&sampler.input(), &[Dimensions::Scalar], "animation input")?;
        let (target, dims) = match ch.target().property() {
            Property::Translation => (Target::Translation, Dimensions::Vec3),
            Property::Rotation => (Target::Rotation, Dimensions::Vec4),
            Property::Scale => (Target::Scale, Dimensions::Vec3),
            Property::MorphTargetWeights => (Target::Weights, Dimensions::Scalar),
        };
        let (values, _) = bufs.read_f32(&sampler.output(), &[dims], "animation output")?;
        let interpolation = match sampler.interpolation() {
            gltf::animation::Interpolation::Step => Interpolation::Step,
            gltf::animation::Interpolation::Linear => Interpolation::Linear,
            gltf::animation::Interpolation::CubicSpline => Interpolation::CubicSpline,
        };
        let per_key = if interpolation == Interpolation::CubicSpline {
            3
        } else {
            1
        };
        let keys = times.len();
        if keys == 0 {
            return Err(format!("{at} has no keys"));
        }
        let width = match target {
            Target::Translation | Target::Scale => 3,
            Target::Rotation => 4,
            Target::Weights => values.len() / (keys * per_key),
        };
        if values.len() != keys * per_key * width || width == 0 {
            return Err(format!(
                "{at}: {} output values for {keys} keys of {width}",
                values.len()
            ));
        }
        channels.push(Channel {
            node: index[node],
            target,
            interpolation,
            times,
            values,
            width: width as u32,
            repeat: false,
        });
    }
    let meshes = meshes
        .into_iter()
        .map(|mut r| {
            r.node = index[r.node as usize];
            if let Some(s) = r.skin.as_mut() {
                for j in &mut s.joints {
                    *j = index[*j as usize];
                }
            }
            r
        })
        .collect();
    let lights = lights
        .into_iter()
        .map(|(light, node, rest)| LightRig {
            light,
            node: index[node],
            rest: rest.to_cols_array(),
        })
        .collect();
    Ok(Animation {
        name: clip
            .name()
            .map_or_else(|| format!("animation {}", clip.index()), str::to_string),
        root: root.to_cols_array(),
        nodes,
        channels,
        meshes,
        lights,
        looping: true,
    })
}
