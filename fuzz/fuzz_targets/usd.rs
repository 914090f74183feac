//! Arbitrary bytes as a USD text layer loaded from a folder that holds a layer to reference (`tri.usda`: a triangle
//! with a UsdPreviewSurface material and a rect light), with `../outside.usda` beside it: loading
//! must never panic, hang or read outside the folder, and whatever loads must be clean, within
//! the limits and survive its wire form (`common::check_scene`). Run with `scripts/fuzz.sh usd`.
//!
//! libFuzzer's panic hook aborts on every panic. A panic inside the `openusd` crate is its bug,
//! which the loader's `catch_unwind` turns into an error ("the USD reader panicked"); such panics
//! are let through to it, so that fuzzing goes on past the crate's known bugs (docs/fuzzing.md
//! lists them), while any other panic still aborts.
//!
//! Binary crate layers (`PXR-USDC`) and packages (`PK`) are skipped: `openusd` 0.6 allocates
//! what the counts in a binary layer say before reading them, so a few bytes abort the process
//! (the second run's find, kept in `fuzz/crashes/usd/`; `docs/scenes.md` § USD), and every run
//! would stop there.

#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;
use lightfold_scene::{ModelOptions, load_usd_slice};
use std::sync::Once;

fn let_openusd_panics_unwind() {
    static HOOK: Once = Once::new();
    HOOK.call_once(|| {
        let abort = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let in_openusd = info
                .location()
                .is_some_and(|l| l.file().contains("/openusd-"));
            if !in_openusd {
                abort(info);
            }
        }));
    });
}

fuzz_target!(|data: &[u8]| {
    if data.starts_with(b"PXR-USDC") || data.starts_with(b"PK") {
        return;
    }
    let_openusd_panics_unwind();
    let opts = ModelOptions::default();
    if let Ok(scene) = load_usd_slice(data, "fuzz.usda", Some(common::folder()), &opts) {
        common::check_scene(&scene);
    }
});
