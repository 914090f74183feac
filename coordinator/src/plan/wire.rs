//! Scene ↔ wire conversions the plan uses. The conversions themselves live in
//! `lightfold_scene::wire` (both directions, validated on the way in) so nodes and the coordinator
//! share one definition; this module re-exports them next to the plan.

pub use lightfold_scene::wire::{
    WireError, camera_from_wire, camera_to_wire, light_from_wire, light_to_wire,
};
