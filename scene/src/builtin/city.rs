//! "city": a procedural city of a chosen size, for measuring how cost grows with triangles
//! (`city` is about a million; `city:N` asks for N, with a `k` or `M` suffix allowed: `city:250k`,
//! `city:4M`). A ground plane and a square grid of blocks, each block one mesh of four buildings
//! whose walls and roofs are split into window-sized quads, so the count comes within a few
//! percent of what was asked and the meshes stay a few thousand at most. The layout, the
//! buildings' sizes and their colours come from a fixed hash of their grid place: the same name
//! gives the same scene. Lit by a large low "sun" panel and a sky panel (2 × 16 samples), seen from
//! above one corner.

use super::{camera, rect_light};
use crate::limits::MAX_TRIANGLES;
use crate::model::{Material, Mesh, Scene};
use crate::primitives;

/// Triangles of `city` without a count.
pub(super) const DEFAULT_TRIANGLES: u64 = 1_000_000;
/// The fewest triangles a city is built with (one block).
const MIN_TRIANGLES: u64 = 1_000;
/// Distance between block centres, and a building's largest half footprint.
const PITCH: f32 = 12.0;

/// The triangle count `name` asks for (`city`, `city:N`, `city:Nk`, `city:NM`), or `None` when
/// `name` is not a city.
pub(super) fn requested(name: &str) -> Option<Result<u64, String>> {
    if name == "city" {
        return Some(Ok(DEFAULT_TRIANGLES));
    }
    let n = name.strip_prefix("city:")?;
    let (digits, unit) = match n.as_bytes().last() {
        Some(b'k' | b'K') => (&n[..n.len() - 1], 1_000),
        Some(b'm' | b'M') => (&n[..n.len() - 1], 1_000_000),
        _ => (n, 1),
    };
    Some(match digits.parse::<u64>() {
        Ok(v) if (MIN_TRIANGLES..=MAX_TRIANGLES).contains(&v.saturating_mul(unit)) => Ok(v * unit),
        _ => Err(format!(
            "{name:?}: a city of {MIN_TRIANGLES} to {MAX_TRIANGLES} triangles, e.g. city:250k or city:4M"
        )),
    })
}

/// A deterministic hash of a grid place to [0, 1).
fn hash(i: u32, j: u32, salt: u32) -> f32 {
    let mut x = i
        .wrapping_mul(0x9E37_79B1)
        .wrapping_add(j.wrapping_mul(0x85EB_CA77))
        .wrapping_add(salt.wrapping_mul(0xC2B2_AE3D));
    x ^= x >> 15;
    x = x.wrapping_mul(0x2C1B_3C6D);
    x ^= x >> 12;
    x = x.wrapping_mul(0x297A_2D39);
    x ^= x >> 15;
    (x >> 8) as f32 / (1u32 << 24) as f32
}

/// Appends `m`'s geometry to `into` (one mesh per block).
fn append(into: &mut Mesh, m: Mesh) {
    let base = into.positions.len() as u32;
    into.positions.extend(m.positions);
    into.normals.extend(m.normals);
    into.uvs.extend(m.uvs);
    into.tangents.extend(m.tangents);
    into.indices.extend(m.indices.iter().map(|i| i + base));
}

/// A building: four walls and a roof, each split into `div × div` quads (10·div² triangles).
fn building(into: &mut Mesh, center: [f32; 2], half: [f32; 2], height: f32, div: u32) {
    let [x, z] = center;
    let [hx, hz] = half;
    let y = height / 2.0;
    let m = into.material;
    for (c, n, u, size) in [
        (
            [x, y, z + hz],
            [0.0, 0.0, 1.0],
            [1.0, 0.0, 0.0],
            [2.0 * hx, height],
        ),
        (
            [x, y, z - hz],
            [0.0, 0.0, -1.0],
            [-1.0, 0.0, 0.0],
            [2.0 * hx, height],
        ),
        (
            [x + hx, y, z],
            [1.0, 0.0, 0.0],
            [0.0, 0.0, -1.0],
            [2.0 * hz, height],
        ),
        (
            [x - hx, y, z],
            [-1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0],
            [2.0 * hz, height],
        ),
        (
            [x, height, z],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            [2.0 * hx, 2.0 * hz],
        ),
    ] {
        // u × v = n: the walls' v is up; the roof's v runs along −z.
        append(into, primitives::plane("", c, n, u, size, div, m));
    }
}

pub(super) fn build(triangles: u64) -> Scene {
    let triangles = triangles.clamp(MIN_TRIANGLES, MAX_TRIANGLES);
    // Quads per wall edge grow with the count so the buildings stay at most ten thousand.
    let buildings_wanted = (triangles / 160).clamp(4, 10_000) as f64;
    let div = ((triangles as f64 / (10.0 * buildings_wanted))
        .sqrt()
        .round() as u32)
        .clamp(1, 64);
    let per_building = 10 * u64::from(div) * u64::from(div);
    // Four buildings a block, blocks on a square grid, never over the limit (ground: 2).
    let mut grid = ((triangles as f64 / (4.0 * per_building as f64))
        .sqrt()
        .round() as u32)
        .max(1);
    while u64::from(grid * grid) * 4 * per_building + 2 > MAX_TRIANGLES {
        grid -= 1;
    }
    let mut s = Scene::new(&format!(
        "city ({} triangles)",
        u64::from(grid * grid) * 4 * per_building + 2
    ));
    let extent = grid as f32 * PITCH;
    let ground = s.add_material(Material::diffuse("asphalt", [0.3, 0.3, 0.32]));
    s.add_mesh(primitives::plane(
        "ground",
        [0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 0.0, 0.0],
        [extent + 2.0 * PITCH, extent + 2.0 * PITCH],
        1,
        ground,
    ));
    let palette: Vec<usize> = [
        [0.72, 0.68, 0.6],
        [0.55, 0.58, 0.62],
        [0.7, 0.5, 0.4],
        [0.8, 0.78, 0.74],
        [0.45, 0.5, 0.48],
    ]
    .iter()
    .enumerate()
    .map(|(k, c)| s.add_material(Material::diffuse(&format!("facade {k}"), *c)))
    .collect();
    for i in 0..grid {
        for j in 0..grid {
            let cx = (i as f32 + 0.5) * PITCH - extent / 2.0;
            let cz = (j as f32 + 0.5) * PITCH - extent / 2.0;
            let material = palette[(hash(i, j, 7) * palette.len() as f32) as usize % palette.len()];
            let mut block = Mesh {
                name: format!("block {i},{j}"),
                positions: Vec::new(),
                normals: Vec::new(),
                uvs: Vec::new(),
                tangents: Vec::new(),
                indices: Vec::new(),
                material,
            };
            // Towers near the middle, low blocks at the edge.
            let centre = 1.0 - ((cx * cx + cz * cz).sqrt() / (extent / 2.0 + PITCH)).min(1.0);
            for (k, (dx, dz)) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
                .into_iter()
                .enumerate()
            {
                let salt = k as u32 * 3;
                let half = [
                    1.2 + 1.3 * hash(i, j, salt + 1),
                    1.2 + 1.3 * hash(i, j, salt + 2),
                ];
                let height = 3.0 + (6.0 + 30.0 * centre) * hash(i, j, salt + 3);
                building(
                    &mut block,
                    [cx + dx * PITCH / 4.0, cz + dz * PITCH / 4.0],
                    half,
                    height,
                    div,
                );
            }
            s.add_mesh(block);
        }
    }
    s.camera = camera(
        [-0.45 * extent, 0.35 * extent + 20.0, -0.45 * extent],
        [0.05 * extent, 0.0, 0.05 * extent],
        50.0,
    );
    let far = extent.max(60.0);
    s.lights = vec![
        rect_light(
            "sun",
            [0.6 * far, 0.5 * far, -0.3 * far],
            [0.0, 0.0, 0.0],
            0.08 * far,
            110.0,
            [1.0, 0.92, 0.8],
        ),
        rect_light(
            "sky",
            [-0.2 * far, 0.9 * far, 0.4 * far],
            [0.0, 0.0, 0.0],
            0.2 * far,
            16.0,
            [0.6, 0.7, 1.0],
        ),
    ];
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_and_the_count_is_close_to_what_was_asked() {
        assert_eq!(requested("balls"), None);
        assert_eq!(requested("city"), Some(Ok(DEFAULT_TRIANGLES)));
        assert_eq!(requested("city:250k"), Some(Ok(250_000)));
        assert_eq!(requested("city:4M"), Some(Ok(4_000_000)));
        assert_eq!(requested("city:15000"), Some(Ok(15_000)));
        for bad in [
            "city:",
            "city:0",
            "city:11M",
            "city:-5",
            "city:1.5M",
            "city:999",
        ] {
            assert!(matches!(requested(bad), Some(Err(_))), "{bad}");
        }
        for n in [15_000u64, 250_000, 1_000_000] {
            let s = build(n);
            let t = s.triangle_count() as f64;
            assert!((t / n as f64 - 1.0).abs() < 0.15, "{n}: {t}");
            assert!(s.meshes.len() <= 2_600, "{n}: {} meshes", s.meshes.len());
            let report = s.validate();
            assert!(report.is_clean(), "{n}: {report}");
        }
        // The limit holds at the top.
        assert!(build(MAX_TRIANGLES).triangle_count() as u64 <= MAX_TRIANGLES);
        // Deterministic, and loaded by name like the other built-ins.
        assert_eq!(build(20_000).content_hash(), build(20_000).content_hash());
        let loaded = crate::load("city:20k").unwrap();
        assert_eq!(loaded.content_hash(), build(20_000).content_hash());
        let e = crate::load("city:0").unwrap_err();
        assert!(e.to_string().contains("city:250k"), "{e}");
        assert!(crate::is_builtin("city") && !crate::builtin_names().contains(&"city"));
    }
}
