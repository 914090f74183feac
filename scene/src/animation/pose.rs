//! Posing: node world matrices at a clip time, then rigged meshes (morph, skin or node transform)
//! and rigged lights (rigidly, with their samples).

use super::sample::sample;
use super::{Animation, MeshRig, Target};
use crate::model::{LightSample, LightShape, Mesh, Scene};
use crate::shading::{cross, normalize, sub};
use glam::{Mat3, Mat4, Quat, Vec3};

/// Every node's world matrix and morph weights at one clip time.
#[derive(Debug, Clone)]
pub(super) struct NodePose {
    pub world: Vec<Mat4>,
    pub weights: Vec<Vec<f32>>,
}

impl Animation {
    /// Node world matrices and weights at scene time `t`.
    pub(super) fn node_pose(&self, time: f32) -> NodePose {
        let t = self.clip_time(time);
        let n = self.nodes.len();
        let mut tr: Vec<Vec3> = self
            .nodes
            .iter()
            .map(|d| Vec3::from(d.translation))
            .collect();
        let mut rot: Vec<Quat> = self
            .nodes
            .iter()
            .map(|d| Quat::from_array(d.rotation).normalize())
            .collect();
        let mut sc: Vec<Vec3> = self.nodes.iter().map(|d| Vec3::from(d.scale)).collect();
        let mut weights: Vec<Vec<f32>> = self.nodes.iter().map(|d| d.weights.clone()).collect();
        for c in &self.channels {
            let v = sample(c, if c.repeat { c.own_time(time) } else { t });
            let i = c.node as usize;
            match c.target {
                Target::Translation => tr[i] = Vec3::new(v[0], v[1], v[2]),
                Target::Rotation => rot[i] = Quat::from_xyzw(v[0], v[1], v[2], v[3]),
                Target::Scale => sc[i] = Vec3::new(v[0], v[1], v[2]),
                Target::Weights => weights[i] = v,
            }
        }
        let root = Mat4::from_cols_array(&self.root);
        let mut world: Vec<Mat4> = Vec::with_capacity(n);
        for (i, node) in self.nodes.iter().enumerate() {
            let local = Mat4::from_scale_rotation_translation(sc[i], rot[i], tr[i]);
            // `check` guarantees parents come first.
            let parent = node
                .parent
                .and_then(|p| world.get(p as usize).copied())
                .unwrap_or(root);
            world.push(parent * local);
        }
        NodePose { world, weights }
    }

    /// Per mesh of a scene with `meshes` meshes: whether anything in this animation can move it.
    pub fn moving_meshes(&self, meshes: usize) -> Vec<bool> {
        let animated = self.animated_nodes();
        let mut out = vec![false; meshes];
        for r in &self.meshes {
            let moves = match &r.skin {
                Some(s) => s.joints.iter().any(|&j| animated[j as usize]),
                None => animated[r.node as usize],
            } || (!r.targets.is_empty() && self.weights_animated(r.node));
            if let Some(o) = out.get_mut(r.mesh as usize) {
                *o = moves;
            }
        }
        out
    }

    /// Per light of a scene with `lights` lights: whether this animation moves it.
    pub fn moving_lights(&self, lights: usize) -> Vec<bool> {
        let animated = self.animated_nodes();
        let mut out = vec![false; lights];
        for r in &self.lights {
            if let Some(o) = out.get_mut(r.light as usize) {
                *o = animated[r.node as usize];
            }
        }
        out
    }

    /// Nodes whose world transform changes over time: keyed themselves (translation, rotation
    /// or scale with more than one distinct key) or below such a node.
    fn animated_nodes(&self) -> Vec<bool> {
        let mut keyed = vec![false; self.nodes.len()];
        for c in &self.channels {
            if c.target != Target::Weights && varies(c) {
                keyed[c.node as usize] = true;
            }
        }
        let mut out = vec![false; self.nodes.len()];
        for (i, n) in self.nodes.iter().enumerate() {
            out[i] = keyed[i] || n.parent.is_some_and(|p| out[p as usize]);
        }
        out
    }

    fn weights_animated(&self, node: u32) -> bool {
        self.channels
            .iter()
            .any(|c| c.node == node && c.target == Target::Weights && varies(c))
    }
}

/// Whether a channel's keys differ (a channel holding one value moves nothing).
fn varies(c: &super::Channel) -> bool {
    let w = c.width as usize;
    let per = if c.interpolation == super::Interpolation::CubicSpline {
        3 * w
    } else {
        w
    };
    c.values
        .chunks_exact(per)
        .any(|k| k != &c.values[..per.min(c.values.len())])
}

fn normal_matrix(m: &Mat4) -> Mat3 {
    let m3 = Mat3::from_mat4(*m);
    if m3.determinant().abs() > 1e-30 {
        m3.inverse().transpose()
    } else {
        m3
    }
}

/// Poses one mesh in place.
fn pose_mesh(mesh: &mut Mesh, rig: &MeshRig, pose: &NodePose) {
    // Rigs carry no tangents: a posed mesh's normal map uses each triangle's own
    // (`shading::triangle_tangent`) rather than rest-pose tangents pointing elsewhere.
    mesh.tangents.clear();
    let weights = &pose.weights[rig.node as usize];
    let n = rig.positions.len();
    let mut positions = rig.positions.clone();
    let mut normals = rig.normals.clone();
    for (k, target) in rig.targets.iter().enumerate() {
        let w = weights.get(k).copied().unwrap_or(0.0);
        if w == 0.0 {
            continue;
        }
        for (p, d) in positions.iter_mut().zip(&target.positions) {
            for c in 0..3 {
                p[c] += w * d[c];
            }
        }
        if !normals.is_empty() {
            for (p, d) in normals.iter_mut().zip(&target.normals) {
                for c in 0..3 {
                    p[c] += w * d[c];
                }
            }
        }
    }
    let rigid = pose.world[rig.node as usize];
    let rigid_normal = normal_matrix(&rigid);
    let joint_mats: Vec<Mat4> = rig.skin.as_ref().map_or_else(Vec::new, |s| {
        s.joints
            .iter()
            .zip(&s.inverse_bind)
            .map(|(&j, ib)| pose.world[j as usize] * Mat4::from_cols_array(ib))
            .collect()
    });
    let mut world_pos = Vec::with_capacity(n);
    let mut world_nrm = Vec::with_capacity(normals.len());
    for v in 0..n {
        let m = match &rig.skin {
            None => rigid,
            Some(s) => {
                let mut m = Mat4::ZERO;
                let mut total = 0.0;
                for k in 0..4 {
                    let w = s.vertex_weights[v][k];
                    if w != 0.0 {
                        m += joint_mats[s.vertex_joints[v][k] as usize] * w;
                        total += w;
                    }
                }
                if total > 1e-6 {
                    m * (1.0 / total)
                } else {
                    joint_mats[0]
                }
            }
        };
        world_pos.push(m.transform_point3(Vec3::from(positions[v])).to_array());
        if let Some(nv) = normals.get(v) {
            let nm = if rig.skin.is_some() {
                normal_matrix(&m)
            } else {
                rigid_normal
            };
            world_nrm.push(normalize((nm * Vec3::from(*nv)).to_array()));
        }
    }
    let source = |i: usize| -> usize {
        if rig.vertex_map.is_empty() {
            i
        } else {
            rig.vertex_map[i] as usize
        }
    };
    for (i, p) in mesh.positions.iter_mut().enumerate() {
        *p = world_pos[source(i)];
    }
    if normals.is_empty() {
        // Flat-shaded: each vertex takes its triangle's posed normal.
        if mesh.normals.len() == mesh.positions.len() {
            for t in mesh.indices.chunks_exact(3) {
                let p = [0, 1, 2].map(|k| mesh.positions[t[k] as usize]);
                let nrm = normalize(cross(sub(p[1], p[0]), sub(p[2], p[0])));
                for &i in t {
                    mesh.normals[i as usize] = nrm;
                }
            }
        }
    } else if mesh.normals.len() == mesh.positions.len() {
        for (i, nrm) in mesh.normals.iter_mut().enumerate() {
            *nrm = world_nrm[source(i)];
        }
    }
}

fn point(m: &Mat4, p: [f32; 3]) -> [f32; 3] {
    m.transform_point3(Vec3::from(p)).to_array()
}

fn vector(m: &Mat4, v: [f32; 3]) -> [f32; 3] {
    normalize(m.transform_vector3(Vec3::from(v)).to_array())
}

/// A light's shape moved by `d`.
fn move_shape(shape: &LightShape, d: &Mat4) -> LightShape {
    match *shape {
        LightShape::Point { position } => LightShape::Point {
            position: point(d, position),
        },
        LightShape::Spot {
            position,
            direction,
            inner_angle,
            outer_angle,
        } => LightShape::Spot {
            position: point(d, position),
            direction: vector(d, direction),
            inner_angle,
            outer_angle,
        },
        LightShape::Directional { direction, angle } => LightShape::Directional {
            direction: vector(d, direction),
            angle,
        },
        LightShape::Rect {
            center,
            normal,
            u_axis,
            size,
        } => LightShape::Rect {
            center: point(d, center),
            normal: vector(d, normal),
            u_axis: vector(d, u_axis),
            size,
        },
        LightShape::Disk {
            center,
            normal,
            radius,
        } => LightShape::Disk {
            center: point(d, center),
            normal: vector(d, normal),
            radius,
        },
        LightShape::Sphere { center, radius } => LightShape::Sphere {
            center: point(d, center),
            radius,
        },
        LightShape::Cylinder {
            center,
            axis,
            length,
            radius,
        } => LightShape::Cylinder {
            center: point(d, center),
            axis: vector(d, axis),
            length,
            radius,
        },
        LightShape::EmissiveMesh { mesh } => LightShape::EmissiveMesh { mesh },
    }
}

impl Scene {
    /// Whether anything in the scene moves over time.
    pub fn is_animated(&self) -> bool {
        self.animation.as_ref().is_some_and(|a| {
            a.moving_meshes(self.meshes.len()).contains(&true)
                || a.moving_lights(self.lights.len()).contains(&true)
        })
    }

    /// The scene at time `t` seconds: rigged meshes and lights posed, everything else as is.
    /// A scene without animation is returned unchanged.
    pub fn pose(&self, t: f32) -> Scene {
        let Some(anim) = &self.animation else {
            return self.clone();
        };
        let pose = anim.node_pose(t);
        let mut out = Scene {
            meshes: Vec::new(),
            ..self.clone()
        };
        out.meshes = self.posed_meshes(&pose);
        for (light, d) in self.light_deltas(&pose) {
            let l = &mut out.lights[light];
            l.shape = move_shape(&l.shape, &d);
        }
        out
    }

    /// The scene posed at `t` as a still scene (no animation left): what a single image at that
    /// time is rendered from. Its lights sample to [`Scene::samples_at`]`(t)` (rigid moves).
    pub fn still_at(&self, t: f32) -> Scene {
        let mut s = self.pose(t);
        s.animation = None;
        s
    }

    /// The meshes at time `t` (what a renderer that keeps materials and textures re-uploads).
    pub fn pose_meshes(&self, t: f32) -> Vec<Mesh> {
        match &self.animation {
            None => self.meshes.clone(),
            Some(anim) => self.posed_meshes(&anim.node_pose(t)),
        }
    }

    fn posed_meshes(&self, pose: &NodePose) -> Vec<Mesh> {
        let mut meshes = self.meshes.clone();
        if let Some(anim) = &self.animation {
            for rig in &anim.meshes {
                if let Some(mesh) = meshes.get_mut(rig.mesh as usize) {
                    pose_mesh(mesh, rig, pose);
                }
            }
        }
        meshes
    }

    /// The point samples at time `t`: the rest samples moved with their lights (nodes never
    /// resample; this is what they render and what the reference sums).
    pub fn samples_at(&self, t: f32) -> Vec<LightSample> {
        self.pose_samples(&crate::sampling::direct_samples(self), t)
    }

    /// `samples` (of this scene's rest pose) moved with their lights to time `t`.
    pub fn pose_samples(&self, samples: &[LightSample], t: f32) -> Vec<LightSample> {
        let Some(anim) = &self.animation else {
            return samples.to_vec();
        };
        let deltas = self.light_deltas(&anim.node_pose(t));
        if deltas.is_empty() {
            return samples.to_vec();
        }
        let mut by_light: Vec<Option<Mat4>> = vec![None; self.lights.len()];
        for (l, d) in deltas {
            by_light[l] = Some(d);
        }
        samples
            .iter()
            .map(
                |s| match by_light.get(s.light as usize).copied().flatten() {
                    None => *s,
                    Some(d) => LightSample {
                        position: point(&d, s.position),
                        direction: vector(&d, s.direction),
                        ..*s
                    },
                },
            )
            .collect()
    }

    /// `(light index, W(t)·W(rest)⁻¹)` for every rigged light.
    fn light_deltas(&self, pose: &NodePose) -> Vec<(usize, Mat4)> {
        let Some(anim) = &self.animation else {
            return Vec::new();
        };
        anim.lights
            .iter()
            .filter(|r| (r.light as usize) < self.lights.len())
            .map(|r| {
                let rest = Mat4::from_cols_array(&r.rest);
                (
                    r.light as usize,
                    pose.world[r.node as usize] * rest.inverse(),
                )
            })
            .collect()
    }
}

/// Steps [`Scene::swept_bounds`] poses the scene at (besides every key time).
const SWEEP_STEPS: usize = 256;

impl Scene {
    /// Per mesh, a box that holds it whenever the scene is posed (`None`: no vertex): the bounds
    /// of its poses at every key time and at [`SWEEP_STEPS`] even steps over the animation
    /// (four spans when channels repeat on periods of their own, so their phases mix), widened
    /// by the farthest any vertex moves between neighbouring steps. A still mesh keeps its own
    /// bounds. This is what the planner culls and fits with, so culling holds over the motion.
    pub fn swept_bounds(&self) -> Vec<Option<([f32; 3], [f32; 3])>> {
        let own = |m: &Mesh| m.bounds();
        let Some(anim) = &self.animation else {
            return self.meshes.iter().map(own).collect();
        };
        let moving = anim.moving_meshes(self.meshes.len());
        if !moving.contains(&true) {
            return self.meshes.iter().map(own).collect();
        }
        let repeats = anim.channels.iter().any(|c| c.repeat);
        let span = anim.span() * if repeats { 4.0 } else { 1.0 };
        let mut times: Vec<f32> = (0..=SWEEP_STEPS)
            .map(|i| span * i as f32 / SWEEP_STEPS as f32)
            .collect();
        times.extend(anim.key_times());
        times.sort_by(f32::total_cmp);
        times.dedup();
        let mut out: Vec<Option<([f32; 3], [f32; 3])>> = self.meshes.iter().map(own).collect();
        let mut widen = vec![0.0f32; self.meshes.len()];
        let mut previous: Option<Vec<Mesh>> = None;
        for &t in &times {
            let posed = self.pose_meshes(t);
            for (i, m) in posed.iter().enumerate() {
                if !moving[i] {
                    continue;
                }
                if let Some((lo, hi)) = m.bounds() {
                    out[i] = Some(match out[i] {
                        None => (lo, hi),
                        Some((a, b)) => (
                            std::array::from_fn(|k| a[k].min(lo[k])),
                            std::array::from_fn(|k| b[k].max(hi[k])),
                        ),
                    });
                }
                if let Some(prev) = &previous {
                    let step = m
                        .positions
                        .iter()
                        .zip(&prev[i].positions)
                        .map(|(p, q)| {
                            ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2))
                                .sqrt()
                        })
                        .fold(0.0f32, f32::max);
                    widen[i] = widen[i].max(step);
                }
            }
            previous = Some(posed);
        }
        for (b, w) in out.iter_mut().zip(widen) {
            if let Some((lo, hi)) = b {
                for k in 0..3 {
                    lo[k] -= w;
                    hi[k] += w;
                }
            }
        }
        out
    }
}
