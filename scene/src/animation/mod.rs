//! Scene time: what moves and how a scene is posed at time `t`.
//!
//! An [`Animation`] is a node hierarchy (rest translation, rotation, scale per node), keyframed
//! channels on those nodes (translation, rotation, scale, morph weights; step, linear or cubic
//! spline, rotations by slerp — glTF 2.0's animation model), and rigs that attach the scene's
//! meshes and lights to nodes. `Scene::meshes` and `Scene::lights` stay the rest pose; a rig keeps
//! what posing needs: a mesh's vertices in its node's space (skinned meshes: their joints, inverse
//! bind matrices and up to four weights per vertex; morph targets: per-vertex deltas) and a light's
//! rest world matrix. glTF animations, scene-file motions (`[object.motion]`, `[light.motion]`)
//! and USD's time-sampled transforms all become this one model, and every part poses a scene through [`Scene::pose`] and
//! [`Scene::samples_at`]: the GPU node, the CPU reference and the planner see the same pose.
//!
//! Lights move rigidly: a light attached to a node moves by `W(t)·W(rest)⁻¹` (its samples too, so
//! nodes never resample); a scale on a light's node moves its position but does not change its
//! size or intensity.

mod motion;
mod pose;
mod sample;

pub use motion::{MotionSpec, PathSpec, SpinSpec, apply_motions};

/// Most nodes, channels and rigs an animation may hold (untrusted input is checked against it).
pub const MAX_NODES: usize = 1 << 16;
/// Most keyframes of one channel.
pub const MAX_KEYS: usize = 1 << 20;
/// Most morph targets of one mesh.
pub const MAX_TARGETS: usize = 64;

pub use crate::model::keyframes::{
    AnimNode, Animation, Channel, Interpolation, LightRig, MeshRig, MorphTarget, SkinRig, Target,
};

/// The identity as a column-major array.
pub const IDENTITY: [f32; 16] = [
    1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0,
];

impl Animation {
    /// The last key time over the clip's channels (0 when nothing is keyed; channels that
    /// [`Channel::repeat`] have periods of their own and do not count).
    pub fn duration(&self) -> f32 {
        self.channels
            .iter()
            .filter(|c| !c.repeat)
            .filter_map(|c| c.times.last().copied())
            .fold(0.0f32, f32::max)
    }

    /// The longest period of anything in it: the clip's duration, or the longest repeating
    /// channel's (what a time slider spans).
    pub fn span(&self) -> f32 {
        self.channels
            .iter()
            .filter_map(|c| c.times.last().copied())
            .fold(0.0f32, f32::max)
    }

    /// Scene time `t` mapped into the clip: wrapped when looping, clamped otherwise; a
    /// non-finite `t` is 0.
    pub fn clip_time(&self, t: f32) -> f32 {
        let d = self.duration();
        if !t.is_finite() || d <= 0.0 {
            return 0.0;
        }
        if self.looping {
            t.rem_euclid(d)
        } else {
            t.clamp(0.0, d)
        }
    }

    /// Key times in the clip (every channel's), sorted and deduplicated: where motion can change
    /// character.
    pub fn key_times(&self) -> Vec<f32> {
        let mut t: Vec<f32> = self
            .channels
            .iter()
            .flat_map(|c| c.times.iter().copied())
            .filter(|t| t.is_finite())
            .collect();
        t.sort_by(f32::total_cmp);
        t.dedup();
        t
    }

    /// Checks every index and length against the scene it animates (`meshes[i]` vertex counts,
    /// `lights` count) and every value for finiteness: a scene from the network or a file is
    /// posed without further checks.
    pub fn check(&self, mesh_vertices: &[usize], lights: usize) -> Result<(), String> {
        let n = self.nodes.len();
        if n > MAX_NODES || self.channels.len() > MAX_NODES {
            return Err(format!(
                "{} nodes and {} channels (at most {MAX_NODES})",
                n,
                self.channels.len()
            ));
        }
        if !self.root.iter().all(|v| v.is_finite()) {
            return Err("the root matrix is not finite".into());
        }
        for (i, node) in self.nodes.iter().enumerate() {
            if let Some(p) = node.parent
                && p as usize >= i
            {
                return Err(format!(
                    "node {i} has parent {p}, which does not come before it"
                ));
            }
            let finite = node
                .translation
                .iter()
                .chain(&node.rotation)
                .chain(&node.scale)
                .chain(&node.weights)
                .all(|v| v.is_finite());
            if !finite {
                return Err(format!("node {i} has a non-finite rest transform"));
            }
            if node.weights.len() > MAX_TARGETS {
                return Err(format!("node {i} has {} morph weights", node.weights.len()));
            }
        }
        for (i, c) in self.channels.iter().enumerate() {
            check_channel(c, n).map_err(|e| format!("channel {i}: {e}"))?;
        }
        let mut rigged = vec![false; mesh_vertices.len()];
        for (i, r) in self.meshes.iter().enumerate() {
            let Some(&count) = mesh_vertices.get(r.mesh as usize) else {
                return Err(format!(
                    "mesh rig {i} names mesh {} of {}",
                    r.mesh,
                    mesh_vertices.len()
                ));
            };
            if std::mem::replace(&mut rigged[r.mesh as usize], true) {
                return Err(format!("mesh {} has two rigs", r.mesh));
            }
            check_mesh_rig(r, count, n).map_err(|e| format!("mesh rig {i}: {e}"))?;
        }
        let mut lit = vec![false; lights];
        for (i, r) in self.lights.iter().enumerate() {
            if r.light as usize >= lights || std::mem::replace(&mut lit[r.light as usize], true) {
                return Err(format!(
                    "light rig {i} names light {} (of {lights}) twice or out of range",
                    r.light
                ));
            }
            if r.node as usize >= n {
                return Err(format!("light rig {i} names node {} of {n}", r.node));
            }
            if !r.rest.iter().all(|v| v.is_finite()) {
                return Err(format!("light rig {i} has a non-finite rest matrix"));
            }
        }
        Ok(())
    }

    /// Renumbers mesh rigs after meshes were dropped (`new_index[old]`), dropping the rigs of
    /// dropped meshes; the same for lights. Rigs naming meshes or lights that never existed are
    /// kept, for [`Animation::check`] to refuse.
    pub fn renumber(&mut self, meshes: &[Option<usize>], lights: &[Option<usize>]) {
        fn keep(index: &mut u32, map: &[Option<usize>]) -> bool {
            match map.get(*index as usize) {
                None => true,
                Some(None) => false,
                Some(Some(i)) => {
                    *index = *i as u32;
                    true
                }
            }
        }
        self.meshes.retain_mut(|r| keep(&mut r.mesh, meshes));
        self.lights.retain_mut(|r| keep(&mut r.light, lights));
    }
}

impl Channel {
    /// Scene time `t` on this channel's own period (for [`Channel::repeat`]).
    pub fn own_time(&self, t: f32) -> f32 {
        let period = self.times.last().copied().unwrap_or(0.0);
        if !t.is_finite() || period <= 0.0 {
            0.0
        } else {
            t.rem_euclid(period)
        }
    }
}

fn check_channel(c: &Channel, nodes: usize) -> Result<(), String> {
    if c.node as usize >= nodes {
        return Err(format!("targets node {} of {nodes}", c.node));
    }
    let width = c.width as usize;
    let expected = match c.target {
        Target::Translation | Target::Scale => 3,
        Target::Rotation => 4,
        Target::Weights => width,
    };
    if width != expected || width == 0 || width > MAX_TARGETS {
        return Err(format!("{:?} with {width} components per key", c.target));
    }
    if c.times.is_empty() || c.times.len() > MAX_KEYS {
        return Err(format!("{} keys", c.times.len()));
    }
    if !c.times.iter().all(|t| t.is_finite() && *t >= 0.0) {
        return Err("a key time is negative or not finite".into());
    }
    if c.times.windows(2).any(|w| w[1] < w[0]) {
        return Err("key times decrease".into());
    }
    let per_key = if c.interpolation == Interpolation::CubicSpline {
        3 * width
    } else {
        width
    };
    if c.values.len() != c.times.len() * per_key {
        return Err(format!(
            "{} values for {} keys of {per_key}",
            c.values.len(),
            c.times.len()
        ));
    }
    if !c.values.iter().all(|v| v.is_finite()) {
        return Err("a value is not finite".into());
    }
    Ok(())
}

fn check_mesh_rig(r: &MeshRig, vertices: usize, nodes: usize) -> Result<(), String> {
    if r.node as usize >= nodes {
        return Err(format!("names node {} of {nodes}", r.node));
    }
    let sources = r.positions.len();
    if r.vertex_map.is_empty() {
        if sources != vertices {
            return Err(format!(
                "{sources} source vertices for a mesh of {vertices}"
            ));
        }
    } else if r.vertex_map.len() != vertices || r.vertex_map.iter().any(|&v| v as usize >= sources)
    {
        return Err("its vertex map does not fit the mesh".into());
    }
    if !r.normals.is_empty() && r.normals.len() != sources {
        return Err("normal count differs from position count".into());
    }
    let finite = |v: &[[f32; 3]]| v.iter().flatten().all(|x| x.is_finite());
    if !finite(&r.positions) || !finite(&r.normals) {
        return Err("a vertex is not finite".into());
    }
    if r.targets.len() > MAX_TARGETS {
        return Err(format!("{} morph targets", r.targets.len()));
    }
    for t in &r.targets {
        if t.positions.len() != sources || (!t.normals.is_empty() && t.normals.len() != sources) {
            return Err("a morph target's size differs from the mesh's".into());
        }
        if !finite(&t.positions) || !finite(&t.normals) {
            return Err("a morph target is not finite".into());
        }
    }
    if let Some(s) = &r.skin {
        if s.joints.is_empty()
            || s.joints.len() > MAX_NODES
            || s.inverse_bind.len() != s.joints.len()
        {
            return Err(format!(
                "skin of {} joints with {} inverse bind matrices",
                s.joints.len(),
                s.inverse_bind.len()
            ));
        }
        if s.joints.iter().any(|&j| j as usize >= nodes) {
            return Err("a joint is out of range".into());
        }
        if s.vertex_joints.len() != sources || s.vertex_weights.len() != sources {
            return Err("skin influences do not match the vertices".into());
        }
        if s.vertex_joints
            .iter()
            .flatten()
            .any(|&j| j as usize >= s.joints.len())
        {
            return Err("a vertex names a joint the skin lacks".into());
        }
        let ok = s.vertex_weights.iter().flatten().all(|w| w.is_finite())
            && s.inverse_bind.iter().flatten().all(|w| w.is_finite());
        if !ok {
            return Err("a weight or bind matrix is not finite".into());
        }
    }
    Ok(())
}
