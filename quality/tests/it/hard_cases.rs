//! The hard cases of issue 12, small versions: each within its bound, free of NaN and Inf, and
//! its negative control outside the bound. GPU cases fail (never skip) without an adapter.

use lightfold_quality::hard::shadow_maps::{Fixes, run_with};
use lightfold_quality::hard::{CaseReport, case_names, run_case};

fn check(name: &str) -> CaseReport {
    let r = run_case(name, false).unwrap_or_else(|e| panic!("{name}: {e}"));
    eprintln!("{r}");
    assert_eq!(r.non_finite, 0, "{r}");
    assert!(r.within_bound(), "{r}");
    assert!(r.control_fails(), "negative control within the bound: {r}");
    r
}

/// Case `name` rendered without one of the fixes (`fixes`): it must break its bound, which
/// shows that fix is what holds it.
fn fails_without(name: &str, fixes: Fixes, what: &str) {
    let r = run_with(name, false, fixes)
        .expect("a shadow-map case")
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    eprintln!("{r}");
    assert!(!r.within_bound(), "{name} passes {what}: {r}");
}

#[test]
fn chain64() {
    check("chain64");
}

#[test]
fn hdr_mix() {
    check("hdr-mix");
}

#[test]
fn many_lights() {
    check("many-lights");
}

#[test]
fn grazing() {
    check("grazing");
}

#[test]
fn thin_wall() {
    check("thin-wall");
}

#[test]
fn near_light() {
    check("near-light");
}

#[test]
fn degenerate() {
    check("degenerate");
}

#[test]
fn contact() {
    check("contact");
}

#[test]
fn terminator() {
    check("terminator");
}

#[test]
fn depth_range() {
    check("depth-range");
}

#[test]
fn banding() {
    check("banding");
}

#[test]
fn subtexel_leaves() {
    check("subtexel-leaves");
}

#[test]
fn subtexel_fence() {
    check("subtexel-fence");
}

#[test]
fn corner_leak() {
    check("corner-leak");
}

/// The object-ID test is what closes the corners: without it (the cascades alone) the same room
/// leaks again.
#[test]
fn corner_leak_leaks_without_object_ids() {
    let fixes = Fixes {
        object_ids: false,
        ..Fixes::ALL
    };
    fails_without("corner-leak", fixes, "without object IDs");
}

#[test]
fn grazing_fin() {
    check("grazing-fin");
}

#[test]
fn deep_near() {
    check("deep-near");
}

#[test]
fn thin_poles() {
    check("thin-poles");
}

/// Issue 46: a closed house of 1 cm walls lit through a window from outside keeps every junction
/// dark (case 18).
#[test]
fn thin_house() {
    check("thin-house");
}

/// The receiver's plane at each other object's texel (and texels past the receiver's own box
/// left out) is what keeps the junctions dark: with the symmetric slope bound alone, as before
/// issue 46, the floor along the lit wall's foot and the side wall along the corner light up.
#[test]
fn thin_house_leaks_without_the_receiver_plane() {
    let fixes = Fixes {
        receiver_plane: false,
        ..Fixes::ALL
    };
    fails_without("thin-house", fixes, "without the receiver plane");
}

/// Issue 46: a room of separate planes lit from inside (the Cornell box) keeps its junctions as
/// the exact point sum has them (case 20).
#[test]
fn cornell_junction() {
    check("cornell-junction");
}

/// Issue 46: glossy highlights of an area light equal the lobe's integral over the light (case
/// 19); each sample's own point highlight, as before, is the control that fails.
#[test]
fn glossy_area() {
    check("glossy-area");
}

/// Per-light map sizes are what pass the fin, the deep scene and the poles: with every map at
/// 512² (the size every map had before; cascades and object IDs still on) each fails again.
#[test]
fn one_map_size_for_every_light_fails_cases_15_to_17() {
    let fixes = Fixes {
        map_size: Some(512),
        ..Fixes::ALL
    };
    for name in ["grazing-fin", "deep-near", "thin-poles"] {
        fails_without(name, fixes, "with 512² maps");
    }
}

#[test]
fn every_case_is_tested_and_unknown_names_fail() {
    let names = case_names();
    assert_eq!(names.len(), 20, "{names:?}: add a test per case");
    assert!(run_case("no-such-case", false).is_err());
}
