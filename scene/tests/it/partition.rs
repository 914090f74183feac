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

/// `chunk_for_parts`: a mesh holding more than a part's share of the triangles becomes chunks of
/// at most half a share, each a copy of the triangles (same corners, same order within it) it
/// takes; the other meshes keep their indices; the parts then balance. Nothing changes when no
/// mesh is too large, and a mesh an emissive-mesh light samples stays whole.
#[test]
fn meshes_too_large_for_a_part_are_split_into_chunks() {
    use lightfold_scene::partition::chunk_for_parts;
    // Box 0 holds 12 · 40 = 480 of 504 triangles.
    let s = scene(&[([0.0; 3], 40), ([2.0, 0.0, 0.0], 1), ([0.0, 0.0, 3.0], 1)]);
    let c = chunk_for_parts(&s, 2).expect("box 0 is over half the triangles");
    assert_eq!(c, chunk_for_parts(&s, 2).unwrap(), "deterministic");
    assert_eq!(c.meshes[1], s.meshes[1]);
    assert_eq!(c.meshes[2], s.meshes[2]);
    let share = s.triangle_count().div_ceil(2);
    // Every chunk holds at most half a share, and together the chunks hold box 0's triangles.
    let chunks: Vec<&lightfold_scene::Mesh> = std::iter::once(&c.meshes[0])
        .chain(&c.meshes[3..])
        .collect();
    assert!(chunks.iter().all(|m| m.triangle_count() <= share / 2 + 1));
    let corners = |m: &lightfold_scene::Mesh| -> Vec<[u32; 9]> {
        let mut t: Vec<[u32; 9]> = m
            .indices
            .chunks_exact(3)
            .map(|t| {
                let p = [0, 1, 2].map(|k| m.positions[t[k] as usize]);
                std::array::from_fn(|i| p[i / 3][i % 3].to_bits())
            })
            .collect();
        t.sort_unstable();
        t
    };
    let mut all: Vec<[u32; 9]> = chunks.iter().flat_map(|m| corners(m)).collect();
    all.sort_unstable();
    assert_eq!(all, corners(&s.meshes[0]));
    assert!(c.meshes[3].name.starts_with("box0#"));
    let parts = partition_meshes(&c, 2);
    let tris = |p: &Vec<u32>| -> usize {
        p.iter()
            .map(|&m| c.meshes[m as usize].triangle_count())
            .sum()
    };
    assert!(
        tris(&parts[0]).abs_diff(tris(&parts[1])) <= share / 2,
        "{parts:?}"
    );
    // Nothing to split.
    assert!(chunk_for_parts(&s, 1).is_none());
    let even = scene(&[([0.0; 3], 1), ([2.0, 0.0, 0.0], 1)]);
    assert!(chunk_for_parts(&even, 2).is_none());
    // An emissive mesh is sampled by index: it stays whole.
    let mut lit = s.clone();
    lit.lights.push(lightfold_scene::Light {
        name: "glow".into(),
        shape: lightfold_scene::LightShape::EmissiveMesh { mesh: 0 },
        color: [1.0; 3],
        power: 1.0,
        range: None,
        samples: 4,
    });
    assert!(chunk_for_parts(&lit, 2).is_none());
}
