//! The planner's material-layer formats and shadow-map sizes against `lightfold render`
//! (issue 23): half floats for material layers unless 8-bit sRGB holds every value exactly, and
//! by default the scene's own map size for every map.

use crate::plan_scenes;

use lightfold_coordinator::plan::{ClusterSpec, MapSizing, PlanOptions, plan};
use lightfold_protocol::{Layer, PixelFormat};
use plan_scenes::stage;

fn formats(p: &lightfold_coordinator::plan::Plan) -> Vec<(Layer, PixelFormat)> {
    p.material.layers.clone()
}

#[test]
fn material_layers_travel_exactly() {
    let local = ClusterSpec::local(16, 16);
    // Constant colours with no exact 8-bit sRGB code (0.7, 0.8, 0.2; a 0.5 specular).
    let mut s = stage();
    s.materials[1].specular = [0.5; 3];
    let p = plan(&s, &local, &PlanOptions::default()).unwrap();
    assert_eq!(
        formats(&p),
        [
            (Layer::Diffuse, PixelFormat::F16x4),
            (Layer::Specular, PixelFormat::F16x4)
        ]
    );
    // A white-or-black specular layer is exact in 8-bit sRGB: it takes the 4-byte format.
    s.materials[1].specular = [1.0; 3];
    let p = plan(&s, &local, &PlanOptions::default()).unwrap();
    assert_eq!(
        formats(&p),
        [
            (Layer::Diffuse, PixelFormat::F16x4),
            (Layer::Specular, PixelFormat::Rgba8Srgb)
        ]
    );
    // A format chosen by the caller is kept for layers that are not exact in 8-bit sRGB.
    let mut o = PlanOptions::default();
    o.formats.material = PixelFormat::Rgba8Linear;
    let p = plan(&s, &local, &o).unwrap();
    assert_eq!(
        p.material.layers[0],
        (Layer::Diffuse, PixelFormat::Rgba8Linear)
    );
}

#[test]
fn map_sizes_follow_the_scene_like_render() {
    let local = ClusterSpec::local(16, 16);
    let mut s = stage();
    for size in [512, 1024] {
        s.quality.shadow_map_size = size;
        s.quality.map_sizing = lightfold_scene::MapSizing::Fixed;
        let p = plan(&s, &local, &PlanOptions::default()).unwrap();
        let sizes: Vec<u32> = p
            .nodes
            .iter()
            .flat_map(|n| n.shadows.iter().map(|sh| sh.map_size))
            .collect();
        assert!(!sizes.is_empty());
        assert!(sizes.iter().all(|&n| n == size), "{sizes:?} for {size}²");
        assert_eq!(MapSizing::Scene.uniform_size(&s.quality), Some(size));
    }
    // A size asked for wins over the scene's, as `--shadow-map-size` does for `render`.
    let o = PlanOptions {
        map_sizing: MapSizing::from_request(Some(256)),
        ..PlanOptions::default()
    };
    let p = plan(&s, &local, &o).unwrap();
    assert!(
        p.nodes
            .iter()
            .all(|n| n.shadows.iter().all(|sh| sh.map_size == 256))
    );
    // The mismatch rule stays available, and sizes maps per light within its bounds.
    let o = PlanOptions {
        map_sizing: MapSizing::mismatch(),
        ..PlanOptions::default()
    };
    let p = plan(&s, &local, &o).unwrap();
    assert!(p.nodes.iter().all(|n| {
        n.shadows
            .iter()
            .all(|sh| sh.map_size.is_power_of_two() && (256..=4096).contains(&sh.map_size))
    }));
}

#[test]
fn larger_maps_take_fewer_lights_per_node() {
    use lightfold_protocol::{Capabilities, Role};
    // Nodes report their limit at 512² maps (lavapipe: 85, by its 1 GiB shadow budget of depth
    // and object ID); at 4096² the same budget holds 1 light of six views, and a plan of K = 4
    // was refused.
    let mut cluster = ClusterSpec::local(16, 16);
    for n in &mut cluster.nodes {
        n.capabilities = Some(Capabilities {
            max_lights: 85,
            max_texture_size: 8192,
            threads: 1,
            ..Capabilities::unmeasured(Role::Node, &n.id)
        });
    }
    let s = stage();
    for (size, most) in [(512, 4), (2048, 4), (4096, 1)] {
        let o = PlanOptions {
            map_sizing: MapSizing::Fixed(size),
            ..PlanOptions::default()
        };
        let p = plan(&s, &cluster, &o).unwrap();
        assert!(p.k <= most, "K = {} at {size}²", p.k);
        assert!(p.nodes.iter().all(|n| n.lights.len() <= most as usize));
    }
}
