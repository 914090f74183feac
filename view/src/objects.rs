//! Moving the scene's objects from the page: an object (one mesh of the scene) is picked by a
//! ray cast through the pointer on the view's copy of the scene's triangles, then moved by
//! numbers (`object_set`: translation, rotation, scale) or dragged across the view
//! (`object_drag`). Every move is checked as a scene file's `[[move]]` would be
//! (`scene::moves::check_numbers`, the mesh movable); a refused move changes nothing. The
//! coordinator re-plans over the moved scene (`FrameSpec::moves`).

use crate::camera::{Steer, SteerError, check_point, finite};
use glam::{Mat4, Vec3};
use lightfold_scene::bvh::Bvh;
use lightfold_scene::moves::{self, MeshMove};
use lightfold_scene::{Camera, Scene};
use std::sync::{Arc, OnceLock};

/// The scene's objects as picking and moving need them: each mesh's name, its triangles at
/// rest (a ray-cast tree built on the first pick), the centre moves turn about, and whether it
/// may move.
#[derive(Debug)]
pub struct Objects {
    names: Vec<String>,
    pivots: Vec<[f32; 3]>,
    /// Why each mesh cannot move (`None`: it can).
    fixed: Vec<Option<String>>,
    /// Every mesh's triangles at rest, and the first triangle of each mesh in them.
    triangles: Vec<[[f32; 3]; 3]>,
    first: Vec<usize>,
    tree: OnceLock<Bvh>,
}

/// What a pick found: a mesh and its name, or nothing.
#[derive(Debug, Clone, PartialEq)]
pub struct Picked {
    pub mesh: u32,
    pub name: String,
    /// Why it cannot be moved (`None`: it can).
    pub fixed: Option<String>,
}

impl Objects {
    pub fn new(scene: &Scene) -> Objects {
        let mut triangles = Vec::with_capacity(scene.triangle_count());
        let mut first = Vec::with_capacity(scene.meshes.len());
        for mesh in &scene.meshes {
            first.push(triangles.len());
            let vertex = |i: u32| mesh.positions.get(i as usize).copied();
            for t in mesh.indices.chunks_exact(3) {
                if let (Some(a), Some(b), Some(c)) = (vertex(t[0]), vertex(t[1]), vertex(t[2])) {
                    triangles.push([a, b, c]);
                }
            }
        }
        let fixed = (0..scene.meshes.len())
            .map(|m| moves::fixed(scene, m))
            .collect();
        Objects {
            names: scene.meshes.iter().map(|m| m.name.clone()).collect(),
            pivots: scene.meshes.iter().map(moves::pivot).collect(),
            fixed,
            triangles,
            first,
            tree: OnceLock::new(),
        }
    }

    /// Number of objects (the scene's meshes).
    pub fn len(&self) -> usize {
        self.names.len()
    }

    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }

    /// Mesh `mesh`'s name ("" past the last).
    pub fn name(&self, mesh: u32) -> &str {
        self.names.get(mesh as usize).map_or("", String::as_str)
    }

    /// The mesh whose triangle `id` is.
    fn mesh_of(&self, id: u32) -> u32 {
        (self.first.partition_point(|&f| f <= id as usize) - 1) as u32
    }

    /// The object seen through `(x, y)` (fractions of the view from its left and top) with the
    /// objects where `moves` put them, or `None` where the ray meets nothing.
    pub fn pick(&self, camera: &Camera, moved: &[MeshMove], x: f32, y: f32) -> Option<Picked> {
        let tree = self.tree.get_or_init(|| Bvh::build(&self.triangles));
        let o = Vec3::from(camera.position);
        let d = Vec3::from(camera.ray_dir(x * camera.width as f32, y * camera.height as f32));
        let wide = |v: Vec3| v.to_array().map(f64::from);
        let matrices: Vec<(u32, Mat4)> = moved
            .iter()
            .filter(|m| !m.is_identity())
            .filter_map(|m| Some((m.mesh, m.matrix(*self.pivots.get(m.mesh as usize)?))))
            .collect();
        let is_moved = |mesh: u32| matrices.iter().any(|(m, _)| *m == mesh);
        // Meshes at rest, then each moved one with the ray taken back to where its mesh rests
        // (the same `t`: the direction is mapped by the same linear part).
        let mut best = tree
            .closest(wide(o), wide(d), 0.0, f64::INFINITY, |id, _, _| {
                !is_moved(self.mesh_of(id))
            })
            .map(|h| (h.t, self.mesh_of(h.id)));
        for (mesh, m) in &matrices {
            let back = m.inverse();
            let (ro, rd) = (back.transform_point3(o), back.transform_vector3(d));
            let tmax = best.map_or(f64::INFINITY, |b| b.0);
            if let Some(h) = tree.closest(wide(ro), wide(rd), 0.0, tmax, |id, _, _| {
                self.mesh_of(id) == *mesh
            }) {
                best = Some((h.t, *mesh));
            }
        }
        best.map(|(_, mesh)| Picked {
            mesh,
            name: self.name(mesh).to_string(),
            fixed: self.fixed[mesh as usize].clone(),
        })
    }

    /// Checks a move a viewer made: a mesh of the scene that may move, and numbers a scene
    /// file's `[[move]]` would pass.
    fn check(&self, m: &MeshMove) -> Result<(), SteerError> {
        let fixed = self.fixed.get(m.mesh as usize).ok_or_else(|| {
            bad(format!(
                "no object {}: the scene has {}",
                m.mesh,
                self.len()
            ))
        })?;
        if let Some(why) = fixed {
            return Err(bad(why.clone()));
        }
        moves::check_numbers(m).map_err(bad)
    }
}

fn bad(m: impl Into<String>) -> SteerError {
    SteerError::BadMove(m.into())
}

impl Steer {
    /// Object `m.mesh` moved as `m` says (from where the scene has it); the identity takes it
    /// back.
    pub fn move_object(&mut self, objects: &Objects, m: MeshMove) -> Result<(), SteerError> {
        objects.check(&m)?;
        let mut list: Vec<MeshMove> = self
            .moves
            .iter()
            .filter(|o| o.mesh != m.mesh)
            .copied()
            .collect();
        if !m.is_identity() {
            list.push(m);
            list.sort_by_key(|o| o.mesh);
        }
        self.moves = Arc::new(list);
        self.moves_edited = true;
        Ok(())
    }

    /// Moves object `mesh` by `x` view widths right and `y` view heights up, at the depth of
    /// the centre it turns about (an object behind the camera moves at the target's distance).
    pub fn drag_object(
        &mut self,
        objects: &Objects,
        mesh: u32,
        x: f32,
        y: f32,
    ) -> Result<(), SteerError> {
        finite(&[x, y], "drag")?;
        if x.abs() > 100.0 || y.abs() > 100.0 {
            return Err(SteerError::OutOfRange(
                "a drag moves at most 100 views at a time".into(),
            ));
        }
        let now = self.object_move(mesh);
        let pivot = objects
            .pivots
            .get(mesh as usize)
            .ok_or_else(|| bad(format!("no object {mesh}: the scene has {}", objects.len())))?;
        let centre = Vec3::from(*pivot) + Vec3::from(now.translate);
        let shift = self.view_shift(centre, x, y)?;
        let translate = Vec3::from(now.translate) + shift;
        check_point(centre + shift)?;
        self.move_object(
            objects,
            MeshMove {
                translate: translate.to_array(),
                ..now
            },
        )
    }

    /// Object `mesh`'s move now (the identity where it was not moved).
    pub fn object_move(&self, mesh: u32) -> MeshMove {
        self.moves
            .iter()
            .find(|m| m.mesh == mesh)
            .copied()
            .unwrap_or(MeshMove::identity(mesh))
    }

    /// The moves as the loop put them back after a move it could not plan or make.
    pub(crate) fn put_back_moves(&mut self, moves: &Arc<Vec<MeshMove>>) {
        self.moves = Arc::clone(moves);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfold_scene::builtin;

    /// Where mesh `m`'s box centre shows in `camera`'s view, as fractions of the view.
    fn seen_at(camera: &Camera, p: [f32; 3]) -> (f32, f32) {
        let f = camera.frame();
        let v = Vec3::from(p) - Vec3::from(camera.position);
        let (r, u, fw) = (
            v.dot(Vec3::from(f.right)),
            v.dot(Vec3::from(f.up)),
            v.dot(Vec3::from(f.forward)),
        );
        let t = (camera.fov_y_deg.to_radians() * 0.5).tan();
        let sx = r / fw / (t * camera.aspect());
        let sy = u / fw / t;
        (0.5 * (sx + 1.0), 0.5 * (1.0 - sy))
    }

    #[test]
    fn a_pick_finds_the_object_under_the_pointer_where_it_was_moved() {
        let scene = builtin("balls").unwrap();
        let objects = Objects::new(&scene);
        let cam = scene.camera;
        // Each ball's centre picks that ball (the floor is mesh 0 in balls).
        let ball = (1..scene.meshes.len() as u32)
            .find(|&m| {
                let (x, y) = seen_at(&cam, objects.pivots[m as usize]);
                objects.pick(&cam, &[], x, y).map(|p| p.mesh) == Some(m)
            })
            .expect("some ball is picked at its centre");
        let (x, y) = seen_at(&cam, objects.pivots[ball as usize]);
        // Moved 3 m away along x: its old place shows something else, its new one shows it.
        let mv = MeshMove {
            translate: [3.0, 0.0, 0.0],
            ..MeshMove::identity(ball)
        };
        assert_ne!(objects.pick(&cam, &[mv], x, y).map(|p| p.mesh), Some(ball));
        // Moved halfway to the camera along the same ray: in front of everything there, and
        // smaller (the ray meets it where it is now, not where it was).
        let c = Vec3::from(objects.pivots[ball as usize]);
        let toward = MeshMove {
            translate: ((Vec3::from(cam.position) - c) * 0.5).to_array(),
            scale: 0.5,
            ..MeshMove::identity(ball)
        };
        assert_eq!(
            objects.pick(&cam, &[toward], x, y).map(|p| p.mesh),
            Some(ball)
        );
        // Far off the scene: nothing.
        let up = Camera {
            target: [
                cam.position[0],
                cam.position[1] + 10.0,
                cam.position[2] + 0.1,
            ],
            ..cam
        };
        assert_eq!(objects.pick(&up, &[], 0.5, 0.5), None);
    }

    #[test]
    fn moves_are_checked_and_an_identity_takes_an_object_back() {
        let scene = builtin("balls").unwrap();
        let objects = Objects::new(&scene);
        let mut steer = Steer::new(&scene);
        let mv = MeshMove {
            translate: [0.5, 0.0, 0.0],
            rotate: [0.0, 45.0, 0.0],
            scale: 1.5,
            ..MeshMove::identity(1)
        };
        steer.move_object(&objects, mv).unwrap();
        assert_eq!(*steer.moves, vec![mv]);
        assert!(steer.spec().moves.is_some());
        for bad in [
            MeshMove::identity(99),
            MeshMove { scale: -1.0, ..mv },
            MeshMove {
                translate: [f32::INFINITY, 0.0, 0.0],
                ..mv
            },
        ] {
            assert!(steer.move_object(&objects, bad).is_err(), "{bad:?}");
        }
        assert_eq!(*steer.moves, vec![mv], "a refused move changes nothing");
        steer.drag_object(&objects, 1, 0.1, 0.0).unwrap();
        let dragged = steer.object_move(1);
        assert!((dragged.translate[0] - 0.5).abs() > 1e-3 || dragged.translate[2].abs() > 1e-3);
        assert_eq!((dragged.rotate, dragged.scale), (mv.rotate, mv.scale));
        steer.move_object(&objects, MeshMove::identity(1)).unwrap();
        assert!(steer.moves.is_empty());
        // A mesh light and an animated scene's objects stay.
        let carousel = builtin("carousel").unwrap();
        let fixed = Objects::new(&carousel);
        let mut s = Steer::new(&carousel);
        assert!(s.move_object(&fixed, MeshMove { ..mv }).is_err());
    }
}
