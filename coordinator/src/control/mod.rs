//! The coordinator's runtime: a session of connected daemons (`session`), the sink that
//! assembles final images (`sink`), and the event loop that plans, configures and drives frames
//! over them and survives lost daemons (`live`).

mod live;
mod session;
mod sink;

pub use live::{
    EpochRecord, FrameSpec, Incident, IncidentKind, Live, LiveState, LiveStatus, LiveSummary,
    OpenScene, Refine, SEED64_HEADROOM, seed64_scale,
};
pub use session::{
    ControlError, ControlOptions, Daemon, DaemonAddr, FrameResult, SCENE_CHUNK, Session,
};
pub use sink::{SinkEvent, SinkFrame, SinkGeometry};
