//! lightfold's render node: device setup, shadow maps, the illumination eye pass and material
//! layers on a wgpu device owned by one render thread, and the daemon that streams packed bands to
//! a compositor.
//!
//! Must not depend on the coordinator or compositor crates: it speaks to them only through
//! `lightfold-protocol`.

pub mod daemon;
pub mod gpu;
