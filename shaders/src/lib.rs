//! lightfold's WGSL shaders, as source strings, validated by a naga unit test so a broken shader
//! fails `cargo test` without a GPU.
//!
//! Depends on nothing; the node crate builds its pipelines from these sources.
