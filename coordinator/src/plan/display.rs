//! The plan printed for people: in full (`lightfold plan`, `--verbose`: stages, lights per node,
//! dropped samples and why, shadow passes, and bytes per frame per link, with a key to its
//! terms), or in a few lines ([`Plan::brief`], what a run prints by default).

use super::types::{
    Downstream, DropReason, Knob, MaterialMode, MaterialPlacement, Plan, ShadowViews, Source,
};
use lightfold_protocol::{Layer, PixelFormat};
use std::fmt::{self, Display, Formatter};

fn layers(l: &[(Layer, PixelFormat)]) -> String {
    l.iter()
        .map(|(l, f)| {
            format!(
                "{} {}",
                lightfold_protocol::pipeline::layer_name(*l),
                f.name()
            )
        })
        .collect::<Vec<_>>()
        .join(", ")
}

fn rgb(c: [f32; 3]) -> String {
    format!("({}, {}, {})", c[0], c[1], c[2])
}

/// Microseconds as the plan prints them, in milliseconds.
pub(super) fn ms(us: u64) -> String {
    format!("{:.1} ms", us as f64 / 1000.0)
}

fn mb(bytes: u64) -> String {
    format!("{:.2} MB", bytes as f64 / 1e6)
}

impl Display for DropReason {
    fn fmt(&self, f: &mut Formatter<'_>) -> fmt::Result {
        match self {
            DropReason::ZeroEmission => {
                f.write_str("emits nothing (zero intensity, colour or direction)")
            }
            DropReason::NonFinite => f.write_str("non-finite parameters"),
            DropReason::NoVisibleReceiver => f.write_str("no geometry in view"),
            DropReason::Unreached {
                out_of_range,
                outside_cone,
                behind,
            } => write!(
                f,
                "reaches no visible receiver ({out_of_range} out of range, {outside_cone} outside its cone, {behind} behind its lobe)"
            ),
            DropReason::BelowEpsilon { bound } => {
                write!(f, "adds at most {bound:.2e} to any pixel (within ε)")
            }
        }
    }
}

impl Display for ShadowViews {
    fn fmt(&self, f: &mut Formatter<'_>) -> fmt::Result {
        match self {
            ShadowViews::None => f.write_str("no map"),
            ShadowViews::Frustum { count: 1, fov_deg } => {
                write!(f, "1 fitted frustum {fov_deg:.0}°")
            }
            ShadowViews::Frustum { count, fov_deg } => {
                write!(f, "{count} fitted frusta, widest {fov_deg:.0}°")
            }
            ShadowViews::Ortho => f.write_str("1 orthographic view"),
            ShadowViews::Cascaded { cascades, base } => {
                write!(f, "{cascades} near cascades, then {base} fitted views")
            }
            ShadowViews::Cube { faces } => {
                // In the sample's own frame: +z along its axis (see the key).
                let names = ["+x", "-x", "+y", "-y", "+z", "-z"];
                let on: Vec<&str> = (0..6)
                    .filter(|i| faces & (1 << i) != 0)
                    .map(|i| names[i])
                    .collect();
                write!(f, "{} cube faces {}", on.len(), on.join(" "))
            }
        }
    }
}

impl Display for Plan {
    fn fmt(&self, f: &mut Formatter<'_>) -> fmt::Result {
        self.write_samples(f)?;
        self.write_nodes_summary(f)?;
        self.write_nodes(f)?;
        self.write_material(f)?;
        self.write_stages(f)?;
        self.write_links(f)?;
        write!(f, "{KEY}")
    }
}

impl Plan {
    /// Writes the plan's heading line, then its samples: how many are active and dropped,
    /// how many are virtual point lights, and each dropped one with the reason.
    fn write_samples(&self, f: &mut Formatter<'_>) -> fmt::Result {
        let hash: String = self.scene_hash[..6]
            .iter()
            .map(|b| format!("{b:02x}"))
            .collect();
        writeln!(
            f,
            "plan epoch {} · scene {} ({hash}…) · {}×{} · {} · K = {} · bands of {} rows",
            self.epoch,
            self.scene_name,
            self.width,
            self.height,
            self.topology,
            self.k,
            self.band_height
        )?;
        writeln!(
            f,
            "samples: {} total, {} active, {} dropped · ε = {:.1e} (display units), {:.1e} of it used",
            self.samples.len(),
            self.active.len(),
            self.dropped.len(),
            self.epsilon,
            self.epsilon_used
        )?;
        let bounces = self
            .samples
            .iter()
            .filter(|s| matches!(s.kind, lightfold_scene::SampleKind::Bounce { .. }))
            .count();
        if bounces > 0 {
            writeln!(
                f,
                "indirect light: {bounces} of the samples are virtual point lights (#{} on)",
                self.samples.len() - bounces
            )?;
        }
        for (i, why) in &self.dropped {
            writeln!(
                f,
                "  dropped #{i} (light {}): {why}",
                self.samples[*i].light
            )?;
        }
        Ok(())
    }

    /// Writes how many nodes are used and idle, with the shadow passes and estimated time per
    /// frame, then the one-line summaries that apply: transmittance maps, partitions, nodes
    /// sharing a device or a CPU, the error target, the penumbra filter and the quality the
    /// planner gave up to fit.
    fn write_nodes_summary(&self, f: &mut Formatter<'_>) -> fmt::Result {
        let passes: usize = self
            .nodes
            .iter()
            .flat_map(|n| &n.shadows)
            .map(|s| s.views.count())
            .sum();
        writeln!(
            f,
            "nodes: {} used, {} idle · {passes} shadow passes per frame · est. frame {}{}",
            self.nodes.len(),
            self.idle_nodes.len(),
            ms(self.est_frame_us),
            match self.frame_budget_us {
                Some(b) if self.est_frame_us <= b => format!(" (within the {} budget)", ms(b)),
                Some(b) => format!(" (over the {} budget)", ms(b)),
                None => String::new(),
            }
        )?;
        let transmitting: Vec<usize> = self
            .nodes
            .iter()
            .flat_map(|n| &n.shadows)
            .filter(|s| s.transmittance)
            .map(|s| s.views.count())
            .collect();
        if !transmitting.is_empty() {
            writeln!(
                f,
                "transmittance maps: {} light(s), {} view(s) — translucent casters tint their shadows (docs/translucency.md)",
                transmitting.len(),
                transmitting.iter().sum::<usize>()
            )?;
        }
        let lines = [
            self.peel_line(),
            self.decomposition_line(),
            self.partition_line(),
            self.shared_line(),
            self.cpu_line(),
            self.target_line(),
            self.penumbra_line(),
            gave_up(self),
        ];
        for text in lines.into_iter().flatten() {
            writeln!(f, "{text}")?;
        }
        Ok(())
    }

    /// Writes each node's line (where its output goes, its colour and lights, or the material
    /// layers it renders) with a line per light's shadow views, then the idle nodes.
    fn write_nodes(&self, f: &mut Formatter<'_>) -> fmt::Result {
        for n in &self.nodes {
            write!(
                f,
                "  {} → {} input {} · ",
                n.node, n.downstream, n.input_index
            )?;
            if let Some(p) = n.part {
                write!(f, "part {p} · ")?;
            }
            if let Some((t, r)) = n.tile.and_then(|t| Some((t, self.tiles.get(t)?))) {
                write!(f, "tile {t} (rows {}–{}) · ", r[0], r[1])?;
            }
            match n.peel {
                Some(0) => write!(f, "opaque layer · ")?,
                Some(d) => write!(f, "translucent layer {d} · ")?,
                None => {}
            }
            if n.lights.is_empty() && n.layers.iter().all(|l| l.0 != Layer::Illumination) {
                writeln!(
                    f,
                    "material layers {} · est. {}",
                    layers(&n.layers),
                    ms(n.est_cost_us)
                )?;
                continue;
            }
            let ids: Vec<String> = n.lights.iter().map(|i| format!("#{i}")).collect();
            writeln!(
                f,
                "colour {} · {} lights [{}] · est. {}",
                rgb(n.color),
                n.lights.len(),
                ids.join(" "),
                ms(n.est_cost_us)
            )?;
            for (i, s) in n.lights.iter().zip(&n.shadows) {
                writeln!(
                    f,
                    "      #{i}: {} · {}² · {} casters {:?}{}",
                    s.views,
                    s.map_size,
                    s.casters.len(),
                    s.casters,
                    if s.transmittance {
                        " · transmittance maps"
                    } else {
                        ""
                    }
                )?;
            }
        }
        if !self.idle_nodes.is_empty() {
            writeln!(f, "  idle: {}", self.idle_nodes.join(", "))?;
        }
        Ok(())
    }

    /// Writes how the material stage runs and where its layers are rendered, the ambient
    /// colour when it is folded into the diffuse sum, and the material's notes.
    fn write_material(&self, f: &mut Formatter<'_>) -> fmt::Result {
        let m = &self.material;
        let mode = match m.mode {
            MaterialMode::UniformSpecular { specular } => {
                format!(
                    "single stage, uniform specular {} pre-multiplied (eq. 4–5)",
                    rgb(specular)
                )
            }
            MaterialMode::General => "single stage with a specular layer".to_string(),
        };
        let place = match &m.placement {
            MaterialPlacement::None => "rendered nowhere".to_string(),
            MaterialPlacement::ExtraTargets { node } => format!("extra targets of {node}"),
            MaterialPlacement::OwnNode { node } => format!("on {node}, a node of their own"),
            MaterialPlacement::PerPart { nodes } => {
                format!(
                    "extra targets of each part's first node ({})",
                    nodes.join(", ")
                )
            }
        };
        writeln!(
            f,
            "material: {mode} · layers {} · {place}",
            layers(&m.layers)
        )?;
        if m.fold_ambient {
            writeln!(
                f,
                "  ambient colour {} folded into the diffuse sum (eq. 6–7)",
                rgb(m.ambient)
            )?;
        }
        for note in &m.notes {
            writeln!(f, "  {note}")?;
        }
        Ok(())
    }

    /// Writes each compositor stage: its inputs, where its output goes, and its operators.
    fn write_stages(&self, f: &mut Formatter<'_>) -> fmt::Result {
        writeln!(f, "stages:")?;
        for s in &self.stages {
            let ins: Vec<String> = s
                .inputs
                .iter()
                .map(|i| match &i.source {
                    Source::Node(n) | Source::Stage(n) => n.clone(),
                })
                .collect();
            let to = match &s.downstream {
                Downstream::Stage(d) => format!("{d} input {}", s.input_index),
                Downstream::Sink => format!("sink {}", self.sink),
            };
            writeln!(f, "  {} ← [{}] → {to}", s.compositor, ins.join(", "))?;
            for op in &s.ops {
                writeln!(f, "      {} {}", op.name(), op_params(op))?;
            }
        }
        Ok(())
    }

    /// Writes each link with the layers it carries and its bytes per frame, then the total.
    fn write_links(&self, f: &mut Formatter<'_>) -> fmt::Result {
        writeln!(f, "links (bytes per frame):")?;
        let mut total = 0;
        for l in &self.links {
            total += l.bytes_per_frame;
            writeln!(
                f,
                "  {} → {} ({}) · {} · {}",
                l.from,
                l.to,
                l.address,
                layers(&l.layers),
                mb(l.bytes_per_frame)
            )?;
        }
        writeln!(f, "  total {} per frame", mb(total))
    }
}

/// What the full plan's terms mean.
const KEY: &str = "\
key: #N is light sample N (an area light is split into point samples); a node's colour is the \
colour its lights share (c_n in the paper: the node renders their shadowed sum divided by it, \
the compositor multiplies it back); cube faces are named in the sample's own frame, +z along its \
axis; N² is the shadow map's size in texels; casters are mesh indices; ε is the most a dropped \
sample may add to any pixel; est. is the cost model's time per frame.
";

/// The plan in a few lines: what runs where, what a frame costs and moves ([`Plan::brief`]).
#[derive(Debug, Clone, Copy)]
pub struct Brief<'a>(&'a Plan);

impl Plan {
    /// The plan in a few lines, for a run's default output (the full plan is `Display`).
    pub fn brief(&self) -> Brief<'_> {
        Brief(self)
    }
}

impl Plan {
    /// What the plan peels of the scene's translucency and why, one line, or `None` when it
    /// was not asked to peel.
    pub fn peel_line(&self) -> Option<String> {
        self.peels.as_ref().map(|p| {
            let cells = if p.layers > 0 {
                let groups = self.nodes.iter().filter(|n| n.peel == Some(0)).count();
                format!(
                    " — {} eye layers × {groups} light group(s) = {} nodes, blended back to front",
                    p.layers + 1,
                    self.nodes.len()
                )
            } else {
                String::new()
            };
            format!("peels: {}{cells}", p.why)
        })
    }

    /// How an automatic plan chose between tiles and an untiled image, one line, or `None` when
    /// the options fixed it.
    pub fn decomposition_line(&self) -> Option<String> {
        self.decomposition
            .as_ref()
            .map(|d| format!("decomposition: {}", d.why))
    }

    /// The sort-last grid in one line (`None` without partitions): parts × light groups, the
    /// meshes of each part; or the sort-first tiles': tiles × light groups, the rows of each.
    pub fn partition_line(&self) -> Option<String> {
        let put_together = match self.topology {
            super::types::Topology::Tree => "in a tree",
            _ => "along the chain",
        };
        // Light groups: the nodes of the first cell (part 0 and tile 0, where the grid has them).
        let groups = self
            .nodes
            .iter()
            .filter(|n| n.part.unwrap_or(0) == 0 && n.tile.unwrap_or(0) == 0)
            .count();
        if !self.tiles.is_empty() {
            let rows: Vec<String> = self
                .tiles
                .iter()
                .map(|r| format!("{}–{}", r[0], r[1]))
                .collect();
            let parts = match self.partitions.len() {
                0 => String::new(),
                p => format!(" × {p} sort-last parts"),
            };
            return Some(format!(
                "tiles: {} sort-first tiles{parts} × {groups} light group(s) = {} nodes, put \
                 together {put_together}; rows {} to start, balanced each frame from the nodes' \
                 eye passes",
                self.tiles.len(),
                self.nodes.len(),
                rows.join(", ")
            ));
        }
        if self.partitions.is_empty() {
            return None;
        }
        let meshes: Vec<String> = self
            .partitions
            .iter()
            .enumerate()
            .map(|(i, m)| format!("part {i}: {} mesh(es)", m.len()))
            .collect();
        Some(format!(
            "partitions: {} parts × {groups} light group(s) = {} nodes, depth-composed {} ({})",
            self.partitions.len(),
            self.nodes.len(),
            put_together,
            meshes.join(", ")
        ))
    }
}

impl Display for Brief<'_> {
    fn fmt(&self, f: &mut Formatter<'_>) -> fmt::Result {
        let p = self.0;
        let passes: usize = p
            .nodes
            .iter()
            .flat_map(|n| &n.shadows)
            .map(|s| s.views.count())
            .sum();
        let bytes: u64 = p.links.iter().map(|l| l.bytes_per_frame).sum();
        writeln!(
            f,
            "plan: scene {} at {}×{}, K = {} lights per render node, {} of {} compositor stage(s)",
            p.scene_name,
            p.width,
            p.height,
            p.k,
            p.topology,
            p.stages.len()
        )?;
        writeln!(
            f,
            "  {} light sample(s): {} rendered on {} render node(s){}, {}",
            p.samples.len(),
            p.active.len(),
            p.nodes.len(),
            if p.idle_nodes.is_empty() {
                String::new()
            } else {
                format!(" ({} idle)", p.idle_nodes.len())
            },
            match p.dropped.len() {
                0 => "none dropped".to_string(),
                n => format!("{n} dropped (culled: the full plan says why)"),
            }
        )?;
        write!(
            f,
            "  {passes} shadow-map pass(es) per frame · estimated {} per frame{} · links carry {} \
             per frame\n  (the full plan: --verbose, or `lightfold plan`)",
            ms(p.est_frame_us),
            match p.frame_budget_us {
                Some(b) if p.est_frame_us <= b => format!(" (within the {} budget)", ms(b)),
                Some(b) => format!(" (over the {} budget)", ms(b)),
                None => String::new(),
            },
            mb(bytes)
        )?;
        if let Some(text) = p.target_line() {
            write!(f, "\n  {text}")?;
        }
        if let Some(text) = gave_up(p) {
            write!(f, "\n  {text}")?;
        }
        if let Some(text) = p.penumbra_line() {
            write!(f, "\n  {text}")?;
        }
        if let Some(text) = p.peel_line() {
            write!(f, "\n  {text}")?;
        }
        if let Some(text) = p.decomposition_line() {
            write!(f, "\n  {text}")?;
        }
        if let Some(text) = p.partition_line() {
            write!(f, "\n  {text}")?;
        }
        if let Some(text) = p.shared_line() {
            write!(f, "\n  {text}")?;
        }
        if let Some(text) = p.cpu_line() {
            write!(f, "\n  {text}")?;
        }
        Ok(())
    }
}

impl Plan {
    /// Nodes sharing devices planned as one node per device, one line, or `None`.
    pub fn shared_line(&self) -> Option<String> {
        self.shared_devices.map(|s| {
            format!(
                "shared GPUs: {} node(s) report {} device(s) between them; one node per device                  renders the lights of the {} its nodes would have (K = {} instead of {};                  estimated {} per frame against {} with a device's nodes one after another)",
                s.nodes,
                s.devices,
                s.stacked,
                self.k,
                s.k_separate,
                ms(self.est_frame_us),
                ms(s.est_separate_us)
            )
        })
    }

    /// Nodes sharing a machine's CPU, estimated one after another, one line, or `None`.
    pub fn cpu_line(&self) -> Option<String> {
        self.cpu_shared.map(|s| {
            format!(
                "shared CPU: {} node(s) render on the cores of {} machine(s) (software \
                 rasterisers), so their frames are estimated one after another: {} per frame \
                 where the slowest node alone takes {}",
                s.nodes,
                s.machines,
                ms(self.est_frame_us),
                ms(s.est_slowest_node_us)
            )
        })
    }

    /// What the plan gave up to meet its frame budget, one line, or `None` when nothing was.
    pub fn gave_up(&self) -> Option<String> {
        gave_up(self)
    }

    /// The penumbra filter at the last stage, one line, or `None` without one.
    pub fn penumbra_line(&self) -> Option<String> {
        let r = self.penumbra_radius;
        (r > 0).then(|| {
            let us = super::budget::filter_cost_us(r, self.width, self.height, self.band_height, 1);
            format!(
                "penumbra filter: radius {r} ({0}×{0} tent on the illumination sum, on each \
                 pixel's own surface, before the material multiply; about {1} a frame on one core \
                 of the last stage)",
                2 * r + 1,
                ms(us.round() as u64)
            )
        })
    }

    /// How an error target chose the samples, one line, or `None` without a target.
    pub fn target_line(&self) -> Option<String> {
        let t = self.target.as_ref()?;
        let filter = match (t.penumbra_radius, t.cell_filter) {
            (_, true) => " + cell filter (each sample's shadow over its cell)".to_string(),
            (0, false) => String::new(),
            (r, false) => format!(" + penumbra filter r{r}"),
        };
        let maps = match t.map_floor {
            0 => String::new(),
            f => format!(", shadow maps from {f}²"),
        };
        let (model, check) = if t.calibrated {
            (
                "this scene's calibration",
                "`lightfold accuracy --planned` measures it",
            )
        } else {
            (
                "the default scene's error model",
                "`lightfold accuracy --knobs samples,penumbra --target-db` measures it; \
                 `lightfold calibrate` fits this scene's own",
            )
        };
        let gloss: String = t
            .gloss
            .iter()
            .map(|g| {
                format!(
                    "; highlights: {:?} {} → {} for {:?} (GGX α {:.2} at {:.2} m{})",
                    g.name,
                    g.from,
                    g.to,
                    g.material,
                    g.alpha,
                    g.distance,
                    if g.reached {
                        ""
                    } else {
                        ", capped: its highlight stays spotted"
                    }
                )
            })
            .collect();
        Some(format!(
            "error target {:.1} dB penumbra PSNR: samples per area light {} → {}{filter}{maps} \
             (expected {:.1} dB by {model}{}; {check}){gloss}",
            t.target_db,
            t.from,
            t.to,
            t.expected_db,
            if t.reachable {
                ""
            } else {
                ", the most it measured: the target is out of reach"
            }
        ))
    }
}

fn gave_up(p: &Plan) -> Option<String> {
    if p.concessions.is_empty() {
        return None;
    }
    let mut steps: Vec<String> = Vec::new();
    for c in &p.concessions {
        let name = match c.knob {
            Knob::ShadowMaps => "shadow maps",
            Knob::SamplesPerAreaLight => "samples per area light",
            Knob::Epsilon => "ε",
        };
        // Consecutive steps of one knob read as one change.
        match steps.last_mut() {
            Some(last) if last.starts_with(name) => {
                if let Some(at) = last.rfind(" → ") {
                    last.replace_range(at.., &format!(" → {}", c.to));
                }
            }
            _ => steps.push(format!("{name} {} → {}", c.from, c.to)),
        }
    }
    let db: f32 = p.concessions.iter().filter_map(|c| c.expected_db).sum();
    let bound = if p.concessions.iter().any(|c| c.knob == Knob::Epsilon) {
        format!(
            "; dropped samples add at most {:.1e} to a pixel",
            p.epsilon_used
        )
    } else {
        String::new()
    };
    Some(format!(
        "gave up for the budget: {} (expected penumbra PSNR {db:+.1} dB by the error model{bound})",
        steps.join(", ")
    ))
}

/// An operator's parameters as one line of JSON: keys sorted, unset options left out, each f32
/// in its shortest decimal form (0.85, not 0.8500000238418579).
fn op_params(op: &lightfold_protocol::OpSpec) -> serde_json::Value {
    // Through text: serde_json writes an f32 in its shortest form, and reads that back as the
    // f64 of the same digits.
    let text = serde_json::to_string(op).unwrap_or_default();
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap_or_default();
    let mut params = v
        .as_object_mut()
        .and_then(|m| m.remove(op.name()))
        .unwrap_or_default();
    if let Some(m) = params.as_object_mut() {
        m.retain(|_, x| !x.is_null());
    }
    params
}
