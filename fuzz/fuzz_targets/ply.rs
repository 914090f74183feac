//! Arbitrary bytes as a PLY (ASCII or binary by its header): loading must never panic, hang or
//! allocate what its counts ask for beyond the limits, and whatever loads must be clean, within
//! the limits and survive its wire form (`common::check_scene`). Run with `scripts/fuzz.sh ply`.

#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;
use lightfold_scene::{ModelOptions, load_ply_slice};

fuzz_target!(|data: &[u8]| {
    let opts = ModelOptions::default();
    if let Ok(scene) = load_ply_slice(data, "fuzz.ply", &opts) {
        common::check_scene(&scene);
    }
});
