//! GLB containers: the first input byte chooses raw bytes (odd) or a well-formed container
//! (even) whose JSON chunk is the next `u16` length of bytes and whose BIN chunk is the rest, so
//! the fuzzer reaches the document and its binary buffer instead of stopping at the header. The
//! checks are those of the `gltf` target. Run with `scripts/fuzz.sh glb`.

#![no_main]

#[path = "common.rs"]
mod common;

use libfuzzer_sys::fuzz_target;
use lightfold_scene::{GltfOptions, load_gltf_slice};

/// A GLB 2.0 container around `json` and `bin` (each chunk padded to 4 bytes).
fn glb(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let pad = |n: usize| n.div_ceil(4) * 4;
    let (jl, bl) = (pad(json.len()), pad(bin.len()));
    let total = 12 + 8 + jl + if bin.is_empty() { 0 } else { 8 + bl };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(jl as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(json);
    out.resize(20 + jl, b' ');
    if !bin.is_empty() {
        out.extend_from_slice(&(bl as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(bin);
        out.resize(total, 0);
    }
    out
}

fuzz_target!(|data: &[u8]| {
    let bytes = match data.split_first() {
        Some((mode, rest)) if mode % 2 == 0 && rest.len() >= 2 => {
            let n = u16::from_le_bytes([rest[0], rest[1]]) as usize;
            let rest = &rest[2..];
            let (json, bin) = rest.split_at(n.min(rest.len()));
            glb(json, bin)
        }
        Some((_, rest)) => rest.to_vec(),
        None => return,
    };
    let opts = GltfOptions::default();
    if let Ok(scene) = load_gltf_slice(&bytes, "fuzz.glb", Some(common::folder()), &opts) {
        common::check_scene(&scene);
    }
});
