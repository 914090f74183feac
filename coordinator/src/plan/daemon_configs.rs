//! The plan as daemon configurations: what the control loop sends in `ConfigureNode` and
//! `ConfigureCompositor`.

use super::types::{Downstream, Plan, Source};
use super::wire::{camera_to_wire, light_to_wire};
use lightfold_protocol::{CompositorConfig, NodeConfig, StageInput, WireShadow};

impl Plan {
    /// The configuration of render node `node_id`, or `None` when the plan leaves it idle.
    pub fn node_config(&self, node_id: &str) -> Option<NodeConfig> {
        let n = self.nodes.iter().find(|n| n.node == node_id)?;
        Some(NodeConfig {
            epoch: self.epoch,
            scene: n.scene.unwrap_or(self.scene_hash),
            lights: n
                .lights
                .iter()
                .map(|&i| light_to_wire(&self.samples[i], i as u32))
                .collect(),
            shadows: n
                .shadows
                .iter()
                .enumerate()
                .map(|(j, s)| WireShadow {
                    light: j as u32,
                    map_size: s.map_size,
                    casters: s.casters.clone(),
                })
                .collect(),
            color: n.color,
            layers: n.layers.clone(),
            scale: 1.0,
            band_height: self.band_height,
            camera: camera_to_wire(&self.camera),
            walkthrough: self.walkthrough,
            downstream: self.address(&n.downstream),
            input_index: n.input_index,
            filter: lightfold_scene::wire::filter_to_wire(self.filter),
            depth_bias: self.depth_bias,
            slope_bias: self.slope_bias,
            eye_meshes: n.part.and_then(|p| self.partitions.get(p).cloned()),
            rows: n.tile.and_then(|t| self.tiles.get(t).copied()),
            moves: Vec::new(),
            peel: n.peel,
        })
    }

    /// The configuration of compositor `compositor_id`, or `None` when the plan does not use it.
    pub fn compositor_config(&self, compositor_id: &str) -> Option<CompositorConfig> {
        let s = self.stages.iter().find(|s| s.compositor == compositor_id)?;
        Some(CompositorConfig {
            epoch: self.epoch,
            width: self.width,
            height: self.height,
            band_height: self.band_height,
            inputs: s
                .inputs
                .iter()
                .map(|i| StageInput {
                    peer: match &i.source {
                        Source::Node(id) | Source::Stage(id) => id.clone(),
                    },
                    layers: i.layers.clone(),
                })
                .collect(),
            ops: s.ops.clone(),
            wiring: s.wiring.clone(),
            outputs: s.outputs.clone(),
            downstream: match &s.downstream {
                Downstream::Stage(id) => self.address(id),
                Downstream::Sink => self.sink.clone(),
            },
            input_index: s.input_index,
            frames_in_flight: self.frames_in_flight,
        })
    }

    /// Data address of a daemon the plan uses (empty if unknown).
    pub fn address(&self, id: &str) -> String {
        self.addresses
            .iter()
            .find(|(d, _)| d == id)
            .map_or_else(String::new, |(_, a)| a.clone())
    }

    /// Which compositor input carries node `node_id`'s colour, for `FrameParams::colors` when a
    /// light colour changes without re-rendering: `(compositor id, input index)`.
    pub fn color_input(&self, node_id: &str) -> Option<(String, u32)> {
        let n = self.nodes.iter().find(|n| n.node == node_id)?;
        Some((n.downstream.clone(), n.input_index))
    }
}
