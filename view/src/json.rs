//! The JSON the page reads (`docs/live-view.md`): the scene, the cluster status and plan, the
//! camera and lights, and frame headers.

use crate::camera::Steer;
use crate::clock::Clock;
use crate::hub::Requested;
use lightfold_coordinator::control::{FrameResult, IncidentKind, LiveState, LiveStatus};
use lightfold_coordinator::plan::{Downstream, Plan};
use lightfold_scene::moves::MeshMove;
use lightfold_scene::{Camera, LightShape, Scene};
use serde_json::{Value, json};
use std::time::Instant;

pub(crate) fn scene(s: &Scene) -> Value {
    let lights: Vec<Value> = s.lights.iter().enumerate().map(light).collect();
    json!({
        "name": s.name,
        "width": s.camera.width,
        "height": s.camera.height,
        "exposure": s.exposure,
        "lights": lights,
    })
}

/// A light as the page lists it: index, name, kind, colour, power and samples.
fn light((i, l): (usize, &lightfold_scene::Light)) -> Value {
    json!({
        "index": i,
        "name": l.name,
        "kind": shape_name(&l.shape),
        "color": l.color,
        "power": l.power,
        "samples": if l.is_area() { l.samples } else { 1 },
    })
}

fn shape_name(s: &LightShape) -> &'static str {
    match s {
        LightShape::Point { .. } => "point",
        LightShape::Spot { .. } => "spot",
        LightShape::Directional { .. } => "directional",
        LightShape::Rect { .. } => "rect",
        LightShape::Disk { .. } => "disk",
        LightShape::Sphere { .. } => "sphere",
        LightShape::Cylinder { .. } => "cylinder",
        LightShape::EmissiveMesh { .. } => "emissive mesh",
    }
}

pub(crate) fn camera(c: &Camera) -> Value {
    json!({
        "position": c.position,
        "target": c.target,
        "up": c.up,
        "fov_y_deg": c.fov_y_deg,
    })
}

pub(crate) fn camera_message(s: &Steer) -> Value {
    json!({"type": "camera", "camera": camera(&s.camera), "revision": s.revision})
}

/// The scene's clock as the page shows it: the clip's span, its time now, and how it plays.
pub(crate) fn animation(c: &Clock) -> Value {
    json!({
        "span": c.span,
        "time": c.now(),
        "playing": c.playing(),
        "loop": c.looping,
        "speed": c.speed,
    })
}

pub(crate) fn animation_message(s: &Steer) -> Value {
    json!({"type": "animation", "animation": animation(&s.clock), "revision": s.revision})
}

pub(crate) fn exposure_message(stops: f32) -> Value {
    json!({"type": "exposure", "stops": stops})
}

/// Every light as the viewers set it: colour and power multiplier, and the light itself — its
/// kind, name, samples, where it is (`position`, for the page's markers; `null`: directional or
/// a mesh light) and its `[[light]]` table (`spec`; `null` for a mesh light, which the page
/// cannot edit).
pub(crate) fn lights_message(s: &Steer) -> Value {
    let lights: Vec<Value> = s
        .lights
        .iter()
        .zip(s.scene_lights.iter())
        .enumerate()
        .map(|(i, (set, l))| {
            let spec = match l.shape {
                LightShape::EmissiveMesh { .. } => Value::Null,
                _ => lightfold_scene::file::save::light_spec(l, &Scene::new(""))
                    .ok()
                    .and_then(|spec| serde_json::to_value(spec).ok())
                    .unwrap_or(Value::Null),
            };
            let mut v = light((i, l));
            v["color"] = json!(set.color);
            v["intensity"] = json!(set.intensity);
            v["position"] = json!(crate::edit::light_position(&l.shape));
            v["spec"] = spec;
            v
        })
        .collect();
    json!({"type": "lights", "lights": lights, "revision": s.revision})
}

/// The objects viewers moved, each with its name and move (`crate::objects`).
pub(crate) fn moves_message(s: &Steer, objects: &crate::objects::Objects) -> Value {
    let moves: Vec<Value> = s
        .moves
        .iter()
        .map(|m| object(m, objects.name(m.mesh), None))
        .collect();
    json!({"type": "moves", "moves": moves, "revision": s.revision})
}

/// One object and its move; `fixed`: why it cannot move.
pub(crate) fn object(m: &MeshMove, name: &str, fixed: Option<&str>) -> Value {
    json!({
        "mesh": m.mesh,
        "name": name,
        "translate": m.translate,
        "rotate": m.rotate,
        "scale": m.scale,
        "fixed": fixed,
    })
}

pub(crate) fn status(s: &LiveStatus, started: Instant) -> Value {
    let at =
        |t: Instant| (t.saturating_duration_since(started).as_secs_f64() * 1000.0).round() / 1000.0;
    let state = match s.state {
        LiveState::Starting => "starting",
        LiveState::Running => "running",
        LiveState::Replanning => "replanning",
        LiveState::Degraded => "degraded",
    };
    let incidents: Vec<Value> = s
        .incidents
        .iter()
        .map(|i| {
            let text = match &i.kind {
                IncidentKind::Lost { reason } => format!("lost: {reason}"),
                IncidentKind::Slow { frame, waited } => {
                    format!("slow: frame {frame} waited {} ms", waited.as_millis())
                }
                IncidentKind::Rejoined => "rejoined".to_string(),
            };
            json!({"at_s": at(i.at), "daemon": i.daemon, "text": text})
        })
        .collect();
    let epochs: Vec<Value> = s
        .epochs
        .iter()
        .map(|e| {
            json!({
                "epoch": e.epoch.to_string(), "at_s": at(e.at), "reason": e.reason, "nodes": e.nodes,
                "stages": e.stages, "k": e.k, "lights_moved": e.lights_moved,
                "configure_ms": e.configure.as_millis() as u64,
            })
        })
        .collect();
    let lost: Vec<Value> = s
        .lost
        .iter()
        .map(|(id, why)| json!({"id": id, "reason": why}))
        .collect();
    json!({
        "type": "status",
        "state": state,
        "epoch": s.plan.as_ref().map(|p| p.epoch.to_string()),
        "plan": s.plan.as_deref().map(plan),
        "lost": lost,
        "incidents": incidents,
        "epochs": epochs,
    })
}

pub(crate) fn plan(p: &Plan) -> Value {
    let downstream = |d: &Downstream| match d {
        Downstream::Stage(s) => s.clone(),
        Downstream::Sink => "sink".to_string(),
    };
    let nodes: Vec<Value> = p
        .nodes
        .iter()
        .map(|n| {
            json!({
                "id": n.node, "lights": n.lights.len(), "color": n.color,
                "downstream": n.downstream, "est_ms": n.est_cost_us as f64 / 1000.0,
                "part": n.part,
                "tile": n.tile,
                "peel": n.peel,
            })
        })
        .collect();
    let stages: Vec<Value> = p
        .stages
        .iter()
        .map(|s| {
            let ops: Vec<&str> = s.ops.iter().map(|op| op.name()).collect();
            json!({"id": s.compositor, "ops": ops, "downstream": downstream(&s.downstream)})
        })
        .collect();
    let links: Vec<Value> = p
        .links
        .iter()
        .map(|l| {
            let layers: Vec<String> = l
                .layers
                .iter()
                .map(|(layer, f)| format!("{layer:?}:{f:?}"))
                .collect();
            json!({"from": l.from, "to": l.to, "layers": layers, "bytes_per_frame": l.bytes_per_frame})
        })
        .collect();
    json!({
        "nodes": nodes, "stages": stages, "links": links, "sink": p.sink, "k": p.k,
        "idle": p.idle_nodes, "est_frame_ms": p.est_frame_us as f64 / 1000.0,
        "walkthrough": p.walkthrough,
        "frame_budget_ms": p.frame_budget_us.map(|b| b as f64 / 1000.0),
        "samples": p.samples.len(), "gave_up": p.gave_up(),
        "penumbra_radius": p.penumbra_radius, "penumbra": p.penumbra_line(),
        "partitions": p.partitions.len(), "partition": p.partition_line(),
        "tiles": p.tiles, "decomposition": p.decomposition_line(),
        "peels": p.peel_line(),
    })
}

/// A refinement step as frame headers carry it (`null`: the session's quality).
pub(crate) fn refine_step(s: Option<crate::refine::Step>) -> Value {
    s.map_or(Value::Null, |s| {
        json!({
            "level": s.level,
            "of": s.of,
            "samples": s.refine.samples_per_area_light,
            "aa": s.refine.supersample,
        })
    })
}

/// How the view refines while idle, for the welcome (`null`: it does not).
pub(crate) fn refine(l: Option<&crate::refine::Ladder>) -> Value {
    l.map_or(Value::Null, |l| {
        let steps: Vec<Value> = (1..=l.top()).map(|i| refine_step(l.step(i))).collect();
        json!({"after_ms": l.after.as_millis() as u64, "steps": steps})
    })
}

/// The header of a frame message (the encoder adds the exposure it was encoded at).
pub(crate) fn frame_header(
    f: &FrameResult,
    requested: Requested,
    interval_ms: Option<f64>,
    plan: Option<&Plan>,
) -> Value {
    let is_node = |id: &str| plan.is_some_and(|p| p.nodes.iter().any(|n| n.node == id));
    let daemons: Vec<Value> = f
        .stats
        .iter()
        .map(|s| {
            json!({
                "id": s.daemon_id,
                "role": if is_node(&s.daemon_id) { "node" } else { "compositor" },
                "shadow_us": s.shadow_us, "eye_us": s.eye_us, "readback_us": s.readback_us,
                "pack_us": s.pack_us, "send_us": s.send_us, "composite_us": s.composite_us,
                "total_us": s.total_us, "bytes_out": s.bytes_out,
                "lights_rendered": s.lights_rendered.len(),
                "shadow_passes": s.shadow_passes, "maps_kept": s.maps_kept,
            })
        })
        .collect();
    let latency = f.received_at.saturating_duration_since(f.requested_at);
    json!({
        "frame": f.frame,
        "epoch": f.epoch.to_string(),
        "revision": requested.revision,
        "time": requested.time,
        "refine": refine_step(requested.refine),
        "width": f.image.width,
        "height": f.image.height,
        "interval_ms": interval_ms,
        "latency_ms": latency.as_secs_f64() * 1000.0,
        "sink_bytes": f.sink_bytes,
        "daemons": daemons,
    })
}

#[cfg(test)]
mod tests {
    use lightfold_coordinator::plan::{ClusterSpec, PlanOptions, plan};

    #[test]
    fn the_plan_graph_names_each_node_s_part() {
        let scene = lightfold_scene::builtin("balls").unwrap();
        let options = PlanOptions {
            partitions: 2,
            // Parts alone (the automatic choice adds tiles on these synthetic nodes).
            tiles: 1,
            ..PlanOptions::default()
        };
        let p = plan(&scene, &ClusterSpec::local(32, 8), &options).unwrap();
        let v = super::plan(&p);
        assert_eq!(v["partitions"], 2);
        assert!(
            v["partition"]
                .as_str()
                .unwrap()
                .starts_with("partitions: 2 parts")
        );
        let parts: Vec<u64> = v["nodes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|n| n["part"].as_u64().unwrap())
            .collect();
        assert!(parts.contains(&0) && parts.contains(&1), "{parts:?}");
        // The automatic choice's reason travels with the plan.
        let auto = PlanOptions {
            partitions: 2,
            ..PlanOptions::default()
        };
        let chosen = super::plan(&plan(&scene, &ClusterSpec::local(32, 8), &auto).unwrap());
        assert!(
            chosen["decomposition"]
                .as_str()
                .unwrap()
                .starts_with("decomposition: sort-last, 2 partitions"),
            "{chosen}"
        );
        // Without partitions or tiles there is no part.
        let untiled = PlanOptions {
            tiles: 1,
            ..PlanOptions::default()
        };
        let whole = super::plan(&plan(&scene, &ClusterSpec::local(32, 8), &untiled).unwrap());
        assert!(whole["nodes"][0]["part"].is_null() && whole["partition"].is_null());
        assert!(whole["decomposition"].is_null(), "the options fixed it");
    }
}
