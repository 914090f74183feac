//! lightfold's transport: authenticated, framed TCP links over the pure `lightfold-protocol` core,
//! with a deadline on every wait. Shared by every daemon and the coordinator.
//!
//! Must not depend on wgpu, the scene, or any daemon crate.

pub mod claim;
mod codec;
mod downstream;
mod frame_io;
pub mod gate;
mod link;
mod serve;
mod token;

pub use codec::LinkCodec;
pub use downstream::Downstream;
pub use link::{
    Identity, Link, LinkReader, LinkWriter, NetError, PRE_AUTH_MAX_FRAME, Timeouts, accept,
    describe, dial, dial_retry,
};
pub use serve::serve;
pub use token::{TokenError, load_token};
