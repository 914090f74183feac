//! Arbitrary bytes as a glTF (JSON, or GLB when they start with its magic) loaded from a folder
//! that holds a buffer and an image: loading must never panic, hang or read outside the folder,
//! and whatever loads must be clean, within the limits and survive its wire form
//! (`common::check_scene`). Run with `scripts/fuzz.sh gltf`.

#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;
use lightfold_scene::{GltfOptions, load_gltf_slice};

fuzz_target!(|data: &[u8]| {
    let opts = GltfOptions::default();
    if let Ok(scene) = load_gltf_slice(data, "fuzz.gltf", Some(common::folder()), &opts) {
        common::check_scene(&scene);
    }
});
