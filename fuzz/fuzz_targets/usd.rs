//! Arbitrary bytes as a USD layer (text, binary crate or `.usdz` package, told apart by their
//! first bytes) loaded from a folder that holds a layer to reference (`tri.usda`: a triangle
//! with a UsdPreviewSurface material and a rect light), with `../outside.usda` beside it: loading
//! must never panic, hang or read outside the folder, and whatever loads must be clean, within
//! the limits and survive its wire form (`common::check_scene`). Run with `scripts/fuzz.sh usd`.

#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;
use lightfold_scene::{ModelOptions, load_usd_slice};

fuzz_target!(|data: &[u8]| {
    let opts = ModelOptions::default();
    if let Ok(scene) = load_usd_slice(data, "fuzz.usda", Some(common::folder()), &opts) {
        common::check_scene(&scene);
    }
});
