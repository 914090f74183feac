//! The integration tests of `protocol`, one binary (each file of this folder a module).

mod common;

mod floats;
mod formats;
mod frames;
mod halfs;
mod handshake;
mod mutation;
mod ops;
mod split_frames;
