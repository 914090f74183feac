//! The coordinator's runtime: connect daemons, apply plans, drive frames, receive final images.

mod session;
mod sink;

pub use session::{
    ControlError, ControlOptions, Daemon, DaemonAddr, FrameRequest, FrameResult, Participants,
    SCENE_CHUNK, Session,
};
pub use sink::{SinkEvent, SinkFrame, SinkGeometry};
