//! Peeled translucency planned (`PlanOptions::peels`, `docs/translucency.md` § Peeled layers):
//! how many translucent eye layers, and the grid they take. Each layer is a cell of light
//! groups like a sort-last part, so a peeled plan takes no parts and no tiles of its own; the
//! stages blend the layers back to front (`topology::peeled_stages`).

use super::types::{MAX_PEELS, PeelChoice, Peels, PenumbraFilter, PlanOptions};
use super::{ClusterSpec, PlanError, partitions_for};
use lightfold_scene::Scene;
use lightfold_scene::trace::Tracer;

/// Most eye rays the depth complexity is measured with (a grid over the image).
const GRID_RAYS: u32 = 128 * 96;

impl Peels {
    /// The layers a resolved choice peels (0 for `Off`, and for `Auto` before it is resolved).
    pub fn layers(self) -> u32 {
        match self {
            Peels::Layers(d) => d,
            Peels::Off | Peels::Auto => 0,
        }
    }
}

/// The most translucent surfaces in front of an opaque one (or of nothing) along the eye rays
/// of a grid over the image, counted up to `cap` (`Tracer::translucent_count`); 0 without a
/// translucent material.
pub fn depth_complexity(scene: &Scene, cap: u32) -> u32 {
    if !scene.materials.iter().any(|m| m.is_translucent()) {
        return 0;
    }
    let cam = &scene.camera;
    let (w, h) = (cam.width.max(1), cam.height.max(1));
    // Square cells of `step` pixels, at most `GRID_RAYS` of them.
    let step = ((u64::from(w) * u64::from(h)) as f64 / f64::from(GRID_RAYS))
        .sqrt()
        .ceil()
        .max(1.0) as u32;
    let tracer = Tracer::new(scene);
    let mut most = 0;
    for y in (0..h).step_by(step as usize) {
        for x in (0..w).step_by(step as usize) {
            let n = tracer.translucent_count(x as f32 + 0.5, y as f32 + 0.5, cap as usize) as u32;
            most = most.max(n);
            if most >= cap {
                return cap;
            }
        }
    }
    most
}

/// The options a peeled plan is made with, and what it peels, for options that ask for peeling
/// (`None` where `options.peels` is off). Refused where the options ask for what a peeled plan
/// does not take: sort-first tiles, sort-last partitions (asked, or needed for the scene's
/// memory), the material layers on a node of their own, the penumbra filter asked for.
pub(super) fn resolve(
    scene: &Scene,
    cluster: &ClusterSpec,
    options: &PlanOptions,
) -> Result<Option<(PlanOptions, PeelChoice)>, PlanError> {
    let bad = |reason: String| Err(PlanError::InvalidOptions { reason });
    // Every layer needs a node per light group: the opaque one and each translucent one.
    let nodes = cluster.nodes.len() as u32;
    let (layers, depth_complexity, why) = match options.peels {
        Peels::Off => return Ok(None),
        Peels::Layers(d) => {
            if !(1..=MAX_PEELS).contains(&d) {
                return bad(format!(
                    "peels must be off, auto or 1 to {MAX_PEELS} translucent layers, got {d}"
                ));
            }
            // Layers take the nodes there are, as tiles do (a lost node leaves fewer).
            let fit = d.min(nodes.saturating_sub(1));
            let why = if fit < d {
                format!(
                    "{fit} translucent layer(s) of the {d} asked: each layer and the opaque one \
                     need a render node per light group, and there are {nodes} nodes"
                )
            } else {
                format!("{d} translucent layer(s), as asked")
            };
            (fit, None, why)
        }
        Peels::Auto => {
            let n = depth_complexity(scene, MAX_PEELS + 1);
            let d = n.min(MAX_PEELS).min(nodes.saturating_sub(1));
            let why = match n {
                n if n > 0 && d < n.min(MAX_PEELS) => format!(
                    "{d} translucent layer(s) of the {} in view: each layer and the opaque one \
                     need a render node per light group, and there are {nodes} nodes",
                    n.min(MAX_PEELS)
                ),
                0 => "none: no translucent surface in view (glass and blended surfaces only \
                      ever tint)"
                    .to_string(),
                n if n > MAX_PEELS => format!(
                    "{d} translucent layers: depth complexity above {MAX_PEELS}, capped (what \
                     lies behind the {d}th translucent surface is not seen)"
                ),
                n => {
                    format!("{d} translucent layer(s): the scene's depth complexity in view is {n}")
                }
            };
            (d, Some(n.min(MAX_PEELS + 1)), why)
        }
    };
    let choice = PeelChoice {
        layers,
        depth_complexity,
        why,
    };
    if layers == 0 {
        let options = PlanOptions {
            peels: Peels::Off,
            ..options.clone()
        };
        return Ok(Some((options, choice)));
    }
    if options.tiles > 1 {
        return bad(
            "peeled translucency takes no sort-first tiles (each eye layer is a cell of its \
             own): ask for --tiles auto or 1"
                .to_string(),
        );
    }
    if options.partitions > 1 {
        return bad(
            "peeled translucency takes no sort-last partitions (a part's translucent surfaces \
             would not be peeled against the others')"
                .to_string(),
        );
    }
    if options.material_own_node {
        return bad(
            "with peeled translucency each layer's first node renders its material layers: drop \
             the material node of its own"
                .to_string(),
        );
    }
    if matches!(
        options.penumbra_filter,
        PenumbraFilter::Auto | PenumbraFilter::Radius(_)
    ) {
        return bad(
            "the penumbra filter is not planned with peeled translucency (it filters one \
             surface's illumination)"
                .to_string(),
        );
    }
    if options.partitions == 0
        && let needed = partitions_for(scene, cluster, options)
        && needed > 1
    {
        return bad(format!(
            "the scene's geometry needs {needed} sort-last partitions on these nodes, which \
             peeled translucency does not take: turn peeling off"
        ));
    }
    let options = PlanOptions {
        peels: Peels::Layers(layers),
        tiles: 1,
        partitions: 1,
        penumbra_filter: PenumbraFilter::Off,
        ..options.clone()
    };
    Ok(Some((options, choice)))
}
