//! Arbitrary bytes as a Wavefront OBJ loaded from a folder that holds a material library
//! (`tri.mtl`, naming the image `tex.png`), with `../outside.mtl` beside it: loading must never
//! panic, hang or read outside the folder, and whatever loads must be clean, within the limits
//! and survive its wire form (`common::check_scene`). Run with `scripts/fuzz.sh obj`.

#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;
use lightfold_scene::{ModelOptions, load_obj_slice};

fuzz_target!(|data: &[u8]| {
    let opts = ModelOptions::default();
    if let Ok(scene) = load_obj_slice(data, "fuzz.obj", Some(common::folder()), &opts) {
        common::check_scene(&scene);
    }
});
