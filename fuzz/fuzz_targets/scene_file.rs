//! Arbitrary text as a TOML scene file in a folder that holds a glTF (`tri.gltf`, with its
//! buffer and image): parsing and building must never panic, and whatever loads must be clean,
//! within the limits and survive its wire form (`common::check_scene`). Files whose objects would
//! build more than 2 M triangles (or whose `[base]` is a generated city) are skipped: a few lines of TOML reach the 10 M limit, which
//! takes seconds and gigabytes under the sanitizer (the limit itself is tested in
//! `scene/tests/it/hostile.rs`). Run with `scripts/fuzz.sh scene_file`.

#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;
use lightfold_scene::file::{parse, spec::ObjectSpec};
use lightfold_scene::parse_scene_file;

/// At most how many triangles the objects of `text` build (0 when it does not parse).
fn triangles(text: &str) -> u64 {
    let Ok(file) = parse(text, "fuzz.toml") else {
        return 0;
    };
    // A generated city as the base is as heavy as its name says (up to the 10 M limit).
    if file
        .base
        .as_ref()
        .is_some_and(|b| b.scene.starts_with("city"))
    {
        return u64::MAX;
    }
    let side = |v: u32, lo: u32, hi: u32| u64::from(v.clamp(lo, hi));
    file.objects
        .iter()
        .map(|o| match o {
            ObjectSpec::Plane { divisions, .. } => 2 * side(*divisions, 1, 256).pow(2),
            ObjectSpec::Box { .. } => 12,
            ObjectSpec::Sphere {
                segments, rings, ..
            } => 2 * side(*segments, 3, 1024) * side(*rings, 2, 512),
            ObjectSpec::Cylinder { segments, .. } => 4 * side(*segments, 3, 1024),
        })
        .sum()
}

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if triangles(text) > 2_000_000 {
        return;
    }
    if let Ok(scene) = parse_scene_file(text, "fuzz.toml", Some(common::folder())) {
        common::check_scene(&scene);
    }
});
