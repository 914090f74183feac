//! Sort-last partitions (`scene::partition`): every mesh in exactly one part, deterministic,
//! balanced by triangles within what unsplit meshes allow, and spatially coherent.

use lightfold_scene::partition::partition_meshes;
use lightfold_scene::primitives::{cuboid, plane};
use lightfold_scene::{Material, Scene};
use proptest::prelude::*;

/// A scene of boxes (12 triangles each, `reps` copies stacked as one mesh) at `centres`.
fn scene(meshes: &[([f32; 3], u32)]) -> Scene {
    let mut s = Scene::new("parts");
    let m = s.add_material(Material::diffuse("grey", [0.5; 3]));
    for (i, (c, reps)) in meshes.iter().enumerate() {
        let mut mesh = cuboid(&format!("box{i}"), *c, [0.1; 3], m);
        let one = mesh.clone();
        for r in 1..*reps {
            let base = mesh.positions.len() as u32;
            mesh.positions.extend(
                one.positions
                    .iter()
                    .map(|p| [p[0], p[1] + 0.01 * r as f32, p[2]]),
            );
            mesh.normals.extend(&one.normals);
            mesh.uvs.extend(&one.uvs);
            mesh.indices.extend(one.indices.iter().map(|i| i + base));
        }
        s.add_mesh(mesh);
    }
    s
}

fn triangles(s: &Scene, part: &[u32]) -> u64 {
    part.iter()
        .map(|&m| s.meshes[m as usize].triangle_count() as u64)
        .sum()
}

proptest! {
    #[test]
    fn parts_cover_every_mesh_once_deterministically_and_balanced(
        meshes in prop::collection::vec(
            ((-50.0f32..50.0, -5.0f32..5.0, -50.0f32..50.0), 1u32..40),
            1..40,
        ),
        parts in 1usize..9,
    ) {
        let meshes: Vec<([f32; 3], u32)> =
            meshes.into_iter().map(|((x, y, z), r)| ([x, y, z], r)).collect();
        let s = scene(&meshes);
        let p = partition_meshes(&s, parts);
        prop_assert_eq!(p.len(), parts);
        prop_assert_eq!(&p, &partition_meshes(&s, parts), "deterministic");
        let mut all: Vec<u32> = p.iter().flatten().copied().collect();
        all.sort_unstable();
        prop_assert_eq!(all, (0..s.meshes.len() as u32).collect::<Vec<_>>());
        if s.meshes.len() >= parts {
            prop_assert!(p.iter().all(|q| !q.is_empty()), "{:?}", p);
        }
        // Balance: a part is off its share by at most one mesh per level of bisection.
        let total = s.triangle_count() as f64;
        let largest = s.meshes.iter().map(|m| m.triangle_count()).max().unwrap_or(0) as f64;
        let levels = (parts as f64).log2().ceil().max(1.0);
        for q in &p {
            let t = triangles(&s, q) as f64;
            prop_assert!(
                t <= total / parts as f64 + levels * largest,
                "part of {} triangles, share {:.0}, largest mesh {}", t, total / parts as f64, largest
            );
        }
    }
}

#[test]
fn two_parts_split_along_the_longest_axis() {
    // A row of equal boxes along x: the two halves, left and right.
    let meshes: Vec<([f32; 3], u32)> = (0..10).map(|i| ([i as f32, 0.0, 0.0], 1)).collect();
    let s = scene(&meshes);
    let p = partition_meshes(&s, 2);
    assert_eq!(p, vec![vec![0, 1, 2, 3, 4], vec![5, 6, 7, 8, 9]]);
    // Shuffled order in the scene does not change which boxes go together.
    let mut rev = meshes.clone();
    rev.reverse();
    let p = partition_meshes(&scene(&rev), 2);
    assert_eq!(p, vec![vec![5, 6, 7, 8, 9], vec![0, 1, 2, 3, 4]]);
    // A heavy mesh is balanced against many light ones.
    let mut heavy = meshes.clone();
    heavy[9].1 = 9;
    let s = scene(&heavy);
    let p = partition_meshes(&s, 2);
    assert_eq!(p[1], vec![9], "{p:?}");
    // An empty mesh is kept, in the first part.
    let mut s = scene(&meshes);
    s.add_mesh(plane(
        "none",
        [0.0; 3],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0],
        1,
        0,
    ));
    s.meshes[10].positions.clear();
    s.meshes[10].indices.clear();
    let p = partition_meshes(&s, 3);
    assert!(p[0].contains(&10));
    assert_eq!(p.iter().map(Vec::len).sum::<usize>(), 11);
}

/// `keep_meshes`: kept meshes are unchanged, the others become one-triangle stand-ins over the
/// same triangle bounds with the same material, and the result validates clean through the
/// scene encoding (what a node decodes), with fewer bytes.
#[test]
fn stand_ins_keep_every_mesh_s_bounds_and_validate() {
    use lightfold_scene::partition::keep_meshes;
    let mut s = scene(&[([0.0; 3], 4), ([2.0, 0.0, 0.0], 2), ([0.0, 0.0, 3.0], 1)]);
    let grey = s.meshes[0].material;
    // A flat floor too: its bounds are flat in one axis, and a stand-in still spans them.
    s.add_mesh(plane(
        "floor",
        [0.0; 3],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [8.0, 6.0],
        4,
        grey,
    ));
    let keep = [true, false, false, false];
    let sub = keep_meshes(&s, &keep);
    assert_eq!(sub.meshes.len(), s.meshes.len());
    assert_eq!(sub.meshes[0], s.meshes[0]);
    let tri_bounds = |m: &lightfold_scene::Mesh| {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for &i in &m.indices {
            let p = m.positions[i as usize];
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        (lo, hi)
    };
    for i in 1..4 {
        assert_eq!(sub.meshes[i].triangle_count(), 1, "mesh {i}");
        assert_eq!(
            tri_bounds(&sub.meshes[i]),
            tri_bounds(&s.meshes[i]),
            "mesh {i}"
        );
        assert_eq!(sub.meshes[i].material, s.meshes[i].material);
    }
    let (whole, part) = (s.to_bytes().unwrap(), sub.to_bytes().unwrap());
    assert!(
        part.len() < whole.len(),
        "{} of {} bytes",
        part.len(),
        whole.len()
    );
    let decoded = Scene::from_bytes(&part).expect("a stand-in scene decodes clean");
    assert_eq!(decoded, sub);
    // Keeping everything is the scene itself.
    assert_eq!(keep_meshes(&s, &[true; 4]), s);
}
