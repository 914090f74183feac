//! The tie mask (`masks::ties`, issue 46): pixel centres on a boundary between two surfaces, which
//! a rasteriser and a ray tracer may give to either side. Judged against the junctions' own
//! geometry: where an eye ray meets the Cornell box's floor plane, computed here from the camera
//! and the plane, not by the tracer.

use lightfold_reference::masks::ties;
use lightfold_scene::Scene;

fn cornell(width: u32, height: u32) -> Scene {
    let mut s = lightfold_scene::load("cornell").expect("built-in");
    s.camera.width = width;
    s.camera.height = height;
    s
}

/// How far from the floor–wall junctions (x = ±1 on the floor y = 0, inside the room) pixel
/// `(x, y)`'s centre ray meets the floor plane, in metres; `None` where it meets it outside the
/// room's depth or not at all.
fn junction_distance(s: &Scene, x: u32, y: u32) -> Option<f32> {
    let d = s.camera.ray_dir(x as f32 + 0.5, y as f32 + 0.5);
    let o = s.camera.position;
    if d[1] >= 0.0 {
        return None;
    }
    let t = -o[1] / d[1];
    let (px, pz) = (o[0] + t * d[0], o[2] + t * d[2]);
    (pz > -0.99 && pz < 0.99).then(|| (px.abs() - 1.0).abs())
}

#[test]
fn junctions_through_pixel_centres_are_ties() {
    // Even sides: the image centre is a pixel corner, and the junctions, which run to it at 45°
    // in pixels, pass through a pixel centre in every row they cross.
    let s = cornell(64, 48);
    let mask = ties(&s);
    let mut on_junction = 0;
    for y in 0..48 {
        for x in 0..64 {
            if junction_distance(&s, x, y).is_some_and(|d| d < 1e-4) {
                on_junction += 1;
                assert!(mask[(y * 64 + x) as usize], "pixel ({x}, {y}) is a tie");
            }
        }
    }
    assert!(on_junction >= 8, "{on_junction} centres on the junctions");
}

#[test]
fn pixels_clearly_on_one_side_are_not_ties() {
    // Control: an odd width moves every centre half a pixel off the junctions' diagonal.
    let s = cornell(65, 48);
    let mask = ties(&s);
    let mut near = 0;
    for y in 0..48 {
        for x in 0..65 {
            let Some(d) = junction_distance(&s, x, y) else {
                continue;
            };
            if d < 0.05 {
                near += 1;
                assert!(
                    d < 1e-3 || !mask[(y * 65 + x) as usize],
                    "pixel ({x}, {y}), {d} m off the junction, is no tie"
                );
            }
        }
    }
    assert!(near >= 8, "{near} pixels near the junctions");
}

#[test]
fn smooth_surfaces_make_no_ties_between_their_triangles() {
    // `balls`: tessellated spheres on a ground, smoothly shaded: only the few pixels at their
    // contacts with the ground may be ties, never the edges between a sphere's triangles.
    let mut s = lightfold_scene::load("balls").expect("built-in");
    s.camera.width = 160;
    s.camera.height = 120;
    let n = ties(&s).iter().filter(|&&t| t).count();
    assert!(n * 200 < 160 * 120, "{n} ties of {} pixels", 160 * 120);
}
