//! Objects moved in a live session or by a scene file's `[[move]]` tables: a mesh turned,
//! scaled (uniformly) and shifted about the centre of its box as the scene gives it. The mesh's
//! world-space triangles are transformed; nothing else of the scene changes. The renderers, the
//! planner and the reference all see a moved scene the same way: [`Scene::moved`] here, or on a
//! render node the same matrix ([`MeshMove::matrix`]) applied to the meshes it holds
//! ([`apply_matrix`]).

use crate::{LightShape, Mesh, Scene};
use glam::{Mat3, Mat4, Vec3};
use serde::{Deserialize, Serialize};

/// Largest distance an object may be moved, in metres (as a light may be placed).
pub const MAX_TRANSLATE: f32 = 1e7;
/// Smallest and largest scale an object may be given.
pub const SCALE_RANGE: (f32, f32) = (1e-3, 1e3);

/// One mesh moved: about the centre of its box as the scene gives it, first scaled by `scale`,
/// then turned by `rotate` (degrees about x, then y, then z, all world axes), then shifted by
/// `translate` (metres).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshMove {
    pub mesh: u32,
    #[serde(default)]
    pub translate: [f32; 3],
    #[serde(default)]
    pub rotate: [f32; 3],
    #[serde(default = "unit")]
    pub scale: f32,
}

fn unit() -> f32 {
    1.0
}

impl MeshMove {
    /// The move that leaves mesh `mesh` where it is.
    pub fn identity(mesh: u32) -> MeshMove {
        MeshMove {
            mesh,
            translate: [0.0; 3],
            rotate: [0.0; 3],
            scale: 1.0,
        }
    }

    /// Whether the move leaves the mesh where it is.
    pub fn is_identity(&self) -> bool {
        *self == MeshMove::identity(self.mesh)
    }

    /// The world-space transform of the move of a mesh whose box (unmoved) has centre `pivot`.
    pub fn matrix(&self, pivot: [f32; 3]) -> Mat4 {
        let p = Vec3::from(pivot);
        let [x, y, z] = self.rotate.map(f32::to_radians);
        Mat4::from_translation(p + Vec3::from(self.translate))
            * Mat4::from_rotation_z(z)
            * Mat4::from_rotation_y(y)
            * Mat4::from_rotation_x(x)
            * Mat4::from_scale(Vec3::splat(self.scale))
            * Mat4::from_translation(-p)
    }
}

/// The centre of a mesh's box (the origin for a mesh with no finite position): what a move
/// turns and scales about.
pub fn pivot(mesh: &Mesh) -> [f32; 3] {
    mesh.bounds().map_or([0.0; 3], |(lo, hi)| {
        std::array::from_fn(|i| 0.5 * (lo[i] + hi[i]))
    })
}

/// Why `moves` cannot be made in `scene`, or `Ok`. A move names a mesh of the scene once, is
/// finite and within [`MAX_TRANSLATE`] and [`SCALE_RANGE`]; a mesh light's mesh cannot move (its
/// light samples lie on it), nor can anything in an animated scene (its meshes are posed from
/// their rest places over time).
pub fn check(scene: &Scene, moves: &[MeshMove]) -> Result<(), String> {
    if !moves.is_empty() && scene.animation.is_some() {
        return Err("objects of an animated scene cannot be moved".into());
    }
    if moves.len() > scene.meshes.len() {
        return Err(format!(
            "{} moves for {} objects: each object moves at most once",
            moves.len(),
            scene.meshes.len()
        ));
    }
    for (i, m) in moves.iter().enumerate() {
        let mesh = m.mesh as usize;
        if mesh >= scene.meshes.len() {
            return Err(format!(
                "no object {mesh}: the scene has {}",
                scene.meshes.len()
            ));
        }
        if moves[..i].iter().any(|o| o.mesh == m.mesh) {
            return Err(format!("object {mesh} is moved twice"));
        }
        check_numbers(m)?;
        if let Some(why) = fixed(scene, mesh) {
            return Err(format!("object {mesh}: {why}"));
        }
    }
    Ok(())
}

/// Why mesh `mesh` of `scene` cannot move (`None`: it can): an animated scene's objects move
/// with its clock, and a mesh light's samples lie on its mesh.
pub fn fixed(scene: &Scene, mesh: usize) -> Option<String> {
    if scene.animation.is_some() {
        return Some("the scene is animated: its objects move with its clock".into());
    }
    scene
        .lights
        .iter()
        .any(|l| matches!(l.shape, LightShape::EmissiveMesh { mesh: e } if e == mesh))
        .then(|| "a mesh light cannot be moved: its light samples lie on it".into())
}

/// Why move `m`'s numbers are not ones a move may have, or `Ok`: finite, a translation within
/// [`MAX_TRANSLATE`], a scale within [`SCALE_RANGE`].
pub fn check_numbers(m: &MeshMove) -> Result<(), String> {
    let numbers = m.translate.iter().chain(&m.rotate).chain([&m.scale]);
    if !numbers.into_iter().all(|v| v.is_finite()) {
        return Err(format!("object {}'s move is not finite", m.mesh));
    }
    if m.translate.iter().any(|t| t.abs() > MAX_TRANSLATE) {
        return Err(format!(
            "an object moves at most {MAX_TRANSLATE} m along an axis"
        ));
    }
    if !(SCALE_RANGE.0..=SCALE_RANGE.1).contains(&m.scale) {
        return Err(format!(
            "an object's scale is between {} and {}",
            SCALE_RANGE.0, SCALE_RANGE.1
        ));
    }
    Ok(())
}

/// Whether `m` is a transform a mesh may be given: finite, and keeping its triangles' facing
/// (a positive, not vanishing determinant). What a render node checks of a move it is sent.
pub fn is_valid_matrix(m: &Mat4) -> bool {
    let det = Mat3::from_mat4(*m).determinant();
    m.to_cols_array().iter().all(|v| v.is_finite()) && det.is_finite() && det > 1e-12
}

/// [`is_valid_matrix`] of a column-major matrix as the wire carries it.
pub fn is_valid_columns(cols: &[f32; 16]) -> bool {
    is_valid_matrix(&Mat4::from_cols_array(cols))
}

/// [`apply_matrix`] with a column-major matrix as the wire carries it.
pub fn apply_columns(mesh: &mut Mesh, cols: &[f32; 16]) {
    apply_matrix(mesh, &Mat4::from_cols_array(cols));
}

/// Transforms `mesh` by `m` (`Mesh::transform`: positions, normals by the inverse transpose,
/// tangents' directions); `m` is one [`is_valid_matrix`] accepts.
pub fn apply_matrix(mesh: &mut Mesh, m: &Mat4) {
    mesh.transform(&glam::Affine3A::from_mat4(*m));
}

impl Scene {
    /// The scene with `moves` made (each mesh transformed by its move's matrix about the
    /// centre of its box here). `moves` should have passed [`check`]; a move naming no mesh
    /// is skipped.
    pub fn moved(&self, moves: &[MeshMove]) -> Scene {
        let mut scene = self.clone();
        scene.apply_moves(moves);
        scene
    }

    /// Makes `moves` in place (see [`Scene::moved`]).
    pub fn apply_moves(&mut self, moves: &[MeshMove]) {
        for (index, m) in self.move_matrices(moves) {
            apply_matrix(&mut self.meshes[index as usize], &m);
        }
    }

    /// Each move that changes something, as the matrix of its mesh (what render nodes are sent).
    pub fn move_matrices(&self, moves: &[MeshMove]) -> Vec<(u32, Mat4)> {
        moves
            .iter()
            .filter(|m| !m.is_identity())
            .filter_map(|m| {
                let mesh = self.meshes.get(m.mesh as usize)?;
                Some((m.mesh, m.matrix(pivot(mesh))))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::builtin;

    #[test]
    fn a_move_turns_and_scales_about_the_box_centre_then_shifts() {
        let scene = builtin("balls").unwrap();
        let mesh = 1;
        let c = pivot(&scene.meshes[mesh]);
        let mv = MeshMove {
            mesh: mesh as u32,
            translate: [1.0, 2.0, -0.5],
            rotate: [0.0, 90.0, 0.0],
            scale: 2.0,
        };
        let m = mv.matrix(c);
        // The centre only shifts.
        let moved = m.transform_point3(Vec3::from(c));
        assert!((moved - Vec3::from(c) - Vec3::new(1.0, 2.0, -0.5)).length() < 1e-5);
        // A point 1 m along +x of the centre goes 2 m along −z (90° about y), then shifts.
        let p = m.transform_point3(Vec3::from(c) + Vec3::X);
        let want = Vec3::from(c) + Vec3::new(1.0, 2.0, -0.5) + Vec3::new(0.0, 0.0, -2.0);
        assert!((p - want).length() < 1e-5, "{p} != {want}");
        let after = scene.moved(&[mv]);
        let (lo0, hi0) = scene.meshes[mesh].bounds().unwrap();
        let (lo1, hi1) = after.meshes[mesh].bounds().unwrap();
        // A sphere scaled 2×: its box doubles, centred where it moved.
        for i in 0..3 {
            assert!(((hi1[i] - lo1[i]) - 2.0 * (hi0[i] - lo0[i])).abs() < 1e-3);
        }
        assert_eq!(after.meshes[0], scene.meshes[0], "other meshes stay");
        for n in &after.meshes[mesh].normals {
            assert!((Vec3::from(*n).length() - 1.0).abs() < 1e-5);
        }
    }

    #[test]
    fn moves_that_cannot_be_made_are_refused() {
        let scene = builtin("balls").unwrap();
        let ok = MeshMove {
            translate: [0.5, 0.0, 0.0],
            ..MeshMove::identity(1)
        };
        assert!(check(&scene, &[ok]).is_ok());
        let bad = [
            MeshMove::identity(scene.meshes.len() as u32),
            MeshMove { scale: 0.0, ..ok },
            MeshMove {
                rotate: [f32::NAN, 0.0, 0.0],
                ..ok
            },
            MeshMove {
                translate: [2e7, 0.0, 0.0],
                ..ok
            },
        ];
        for b in bad {
            assert!(check(&scene, &[b]).is_err(), "{b:?}");
        }
        assert!(check(&scene, &[ok, ok]).is_err(), "a mesh moved twice");
        let animated = builtin("carousel").unwrap();
        assert!(animated.animation.is_some());
        assert!(check(&animated, &[MeshMove::identity(0)]).is_err());
        assert!(check(&animated, &[]).is_ok());
        assert!(!is_valid_matrix(&Mat4::from_scale(Vec3::new(
            1.0, 1.0, -1.0
        ))));
        assert!(!is_valid_matrix(&Mat4::from_scale(Vec3::ZERO)));
        assert!(is_valid_matrix(&ok.matrix([0.0; 3])));
    }
}
