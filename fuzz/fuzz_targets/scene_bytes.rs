//! `Scene::from_bytes`, the scene a node receives over the network. The first input byte picks
//! the raw input (0) or a built-in scene's wire form (1…; the small ones: `animal` carries 4 MB
//! of texture and would make each input take a second) patched by the rest of the input in
//! 5-byte records (a `u32` offset, an XOR byte) and cut to the length the last record names, so
//! the fuzzer works deep inside valid encodings. Decoding must never panic or allocate without
//! bound, and whatever decodes must be clean, within the limits and re-encode to the same scene
//! (`common::check_scene`). Run with `scripts/fuzz.sh scene_bytes`.

#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;
use lightfold_scene::{Scene, builtin};
use std::sync::OnceLock;

fn builtins() -> &'static [Vec<u8>] {
    static BYTES: OnceLock<Vec<Vec<u8>>> = OnceLock::new();
    BYTES.get_or_init(|| {
        ["box", "cornell", "plant", "balls"]
            .iter()
            .map(|n| builtin(n).unwrap().to_bytes().unwrap())
            .collect()
    })
}

fuzz_target!(|data: &[u8]| {
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    let bytes = if mode == 0 {
        rest.to_vec()
    } else {
        let all = builtins();
        let mut bytes = all[(mode as usize - 1) % all.len()].clone();
        let mut cut = bytes.len();
        for patch in rest.chunks_exact(5) {
            let at = u32::from_le_bytes([patch[0], patch[1], patch[2], patch[3]]) as usize;
            if patch[4] == 0 {
                cut = at % (bytes.len() + 1);
            } else {
                let i = at % bytes.len();
                bytes[i] ^= patch[4];
            }
        }
        bytes.truncate(cut);
        bytes
    };
    if let Ok(scene) = Scene::from_bytes(&bytes) {
        common::check_scene(&scene);
    }
});
