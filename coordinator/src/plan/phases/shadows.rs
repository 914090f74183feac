//! The phases up to the shadow maps: cull the light samples, fit shadow views to the scene and
//! to each sort-last part, and plan every active sample's maps.

use crate::plan::types::*;
use crate::plan::{PlanError, cull, geom, shadow};
use lightfold_scene::shading::V3;
use lightfold_scene::shadow_views::Probe;
use lightfold_scene::{LightSample, SampleKind, Scene};

/// The cull phase's output: every light sample of a frame and which of them are rendered.
pub(super) struct Culled {
    /// Direct samples, then the virtual point lights of indirect light (planned like the rest).
    pub(super) samples: Vec<LightSample>,
    /// Per mesh, its box over the whole animation (`None` where it has none).
    pub(super) bounds: Vec<Option<geom::Aabb>>,
    /// The meshes the camera may see.
    pub(super) receivers: Vec<cull::Receiver>,
    pub(super) culling: cull::Culling,
    /// Per sample, whether its light moves.
    pub(super) moving: Vec<bool>,
}

/// Culls the samples of `scene`: each is active or dropped for a reason, by the receivers it
/// reaches and the ε budget, except that a moving light's samples are kept whatever they miss at
/// rest.
pub(super) fn cull_samples(scene: &Scene, options: &PlanOptions) -> Culled {
    let samples = lightfold_scene::vpl::frame_samples(scene);
    let bounds = geom::mesh_bounds(scene);
    let receivers = cull::receivers(scene, &bounds);
    let mut culling = cull::cull(
        &samples,
        &receivers,
        scene.exposure,
        options.epsilon,
        options.force_all,
    );
    // A moving light's samples reach other receivers at other times: none is culled for what
    // it misses at rest, and every mesh may cast into its maps. In an animated scene every
    // virtual point light moves: each frame traces them again where things are
    // (`frame_samples_at`), one slot a light path, dark at rest or not.
    let animated = scene.is_animated();
    let moving: Vec<bool> = match &scene.animation {
        None => vec![false; samples.len()],
        Some(a) => {
            let moving = a.moving_lights(scene.lights.len());
            samples
                .iter()
                .map(|s| {
                    (animated && matches!(s.kind, SampleKind::Bounce { .. }))
                        || moving.get(s.light as usize).copied().unwrap_or(false)
                })
                .collect()
        }
    };
    if moving.contains(&true) {
        cull::keep_moving(&mut culling, &moving, &samples, receivers.len());
    }
    debug_assert!(
        {
            let mut seen = vec![0u8; samples.len()];
            let dropped = culling.dropped.iter().map(|d| d.0);
            culling
                .active
                .iter()
                .copied()
                .chain(dropped)
                .for_each(|i| seen[i] += 1);
            seen.iter().all(|&n| n == 1) && culling.lit.len() == samples.len()
        },
        "every sample is active or dropped, once"
    );
    Culled {
        samples,
        bounds,
        receivers,
        culling,
        moving,
    }
}

/// What a node fits its shadow views to: the boxes of the meshes it draws, and the points the
/// mismatch rule measures on them.
struct ViewFit {
    boxes: Vec<(V3, V3)>,
    probes: Vec<Probe>,
}

/// The fit phase's output: the sort-last parts and what the nodes of the whole scene, or of each
/// part, fit their shadow views to.
pub(super) struct Fit {
    whole: ViewFit,
    /// The cells of the grid (mesh indices, ascending), none without partitions or tiles:
    /// every group is rendered once per cell. Cell `c` is sort-last part `c / tiles` (the whole
    /// scene without partitions) in sort-first tile `c % tiles` (every row without tiles).
    pub(super) parts: Vec<Vec<u32>>,
    /// The sort-last parts (mesh indices, ascending), none without partitions.
    pub(super) sort_last: Vec<Vec<u32>>,
    /// Per sort-last part, whether it holds each mesh, and its own fit.
    part_fit: Vec<(Vec<bool>, ViewFit)>,
    /// Sort-first tiles (1: none). A tile's node draws its cell's meshes into its rows with the
    /// maps of its sort-last part (the whole scene's without partitions).
    pub(super) tiles: usize,
    /// Peeled translucent layers (0: none). Then the cells are the eye layers, back to front
    /// ([`peel_of`]), each of every mesh, without parts or tiles.
    pub(super) peels: u32,
}

impl Fit {
    /// Cell `cell`'s sort-last part and sort-first tile (`None` where the grid has none).
    pub(super) fn cell(&self, cell: usize) -> (Option<usize>, Option<usize>) {
        cell_of(cell, !self.sort_last.is_empty(), self.tiles)
    }

    /// Cell `cell`'s eye layer where the plan peels translucency (`NodePlan::peel`).
    pub(super) fn peel(&self, cell: usize) -> Option<u32> {
        peel_of(cell, self.peels)
    }
}

/// The eye layer of cell `cell` of a plan peeling `peels` translucent layers (`None` for 0):
/// the cells run back to front, as `blend` takes them: the opaque layer (0), then the deepest
/// translucent layer (`peels`), …, the nearest (1).
pub(super) fn peel_of(cell: usize, peels: u32) -> Option<u32> {
    (peels > 0).then(|| match cell {
        0 => 0,
        c => peels + 1 - c as u32,
    })
}

/// Cell `cell`'s sort-last part (where the grid is `partitioned`) and tile (of `tiles`, where
/// more than one): cells run part-major, tiles within a part.
pub(super) fn cell_of(
    cell: usize,
    partitioned: bool,
    tiles: usize,
) -> (Option<usize>, Option<usize>) {
    let tiles = tiles.max(1);
    (
        partitioned.then_some(cell / tiles),
        (tiles > 1).then_some(cell % tiles),
    )
}

/// Partitions the scene's meshes when `options` asks for parts, and gives the boxes and probes
/// shadow views are fitted to; an error where a part would be empty.
pub(super) fn fit_views(
    scene: &Scene,
    bounds: &[Option<geom::Aabb>],
    options: &PlanOptions,
) -> Result<Fit, PlanError> {
    let cam = &scene.camera;
    // The boxes nodes fit shadow views to: every mesh with triangles (node/src/gpu/scene_data.rs),
    // or a sort-last node's part of them; and where the mismatch rule measures on them, as the
    // renderer does (`shadow_views::sizing`).
    let fit_where = |keep: &dyn Fn(usize) -> bool| -> ViewFit {
        let boxes: Vec<(V3, V3)> = bounds
            .iter()
            .zip(&scene.meshes)
            .enumerate()
            .filter(|(m, (_, mesh))| keep(*m) && mesh.indices.len() >= 3)
            .filter_map(|(_, (b, _))| b.map(|b| (b.lo, b.hi)))
            .collect();
        let probes = lightfold_scene::shadow_views::probes(cam, &boxes);
        ViewFit { boxes, probes }
    };
    let whole = fit_where(&|_| true);
    let peels = options.peels.layers();
    if peels > 0 {
        // `plan_with` resolved the grid: no parts, no tiles; one cell per eye layer.
        return Ok(Fit {
            whole,
            parts: vec![(0..scene.meshes.len() as u32).collect(); peels as usize + 1],
            sort_last: Vec::new(),
            part_fit: Vec::new(),
            tiles: 1,
            peels,
        });
    }
    let tiles = options.tiles.max(1) as usize;
    let sort_last = if options.partitions > 1 {
        let parts =
            lightfold_scene::partition::partition_meshes(scene, options.partitions as usize);
        if parts.iter().any(Vec::is_empty) {
            return Err(PlanError::InvalidOptions {
                reason: format!(
                    "{} partitions of a scene with {} meshes leave a part empty (`scene_for` \
                     splits meshes too large for a part, but not an animated scene's, nor one an \
                     emissive-mesh light samples): ask for at most {} partitions",
                    options.partitions,
                    scene.meshes.len(),
                    parts.iter().filter(|p| !p.is_empty()).count()
                ),
            });
        }
        parts
    } else {
        Vec::new()
    };
    let parts: Vec<Vec<u32>> = match (sort_last.is_empty(), tiles > 1) {
        (true, false) => Vec::new(),
        (true, true) => vec![(0..scene.meshes.len() as u32).collect(); tiles],
        (false, _) => sort_last
            .iter()
            .flat_map(|part| std::iter::repeat_n(part.clone(), tiles))
            .collect(),
    };
    // A part's nodes fit their maps to the part's own receivers (`Renderer::
    // set_fit_to_eye_meshes`).
    let part_fit: Vec<(Vec<bool>, ViewFit)> = sort_last
        .iter()
        .map(|part| {
            let mut mask = vec![false; scene.meshes.len()];
            for &m in part {
                mask[m as usize] = true;
            }
            let fit = fit_where(&|m| mask[m]);
            (mask, fit)
        })
        .collect();
    debug_assert!(
        sort_last.is_empty()
            || (0..scene.meshes.len())
                .all(|m| part_fit.iter().filter(|(mask, _)| mask[m]).count() == 1),
        "every mesh is in exactly one part"
    );
    Ok(Fit {
        whole,
        parts,
        sort_last,
        part_fit,
        tiles,
        peels: 0,
    })
}

/// The shadow phase's output: every active sample's shadow maps, for the whole scene and for
/// each part's receivers.
pub(super) struct Shadows {
    /// Per sample, its maps for the whole scene (`None`: not rendered).
    pub(super) whole: Vec<Option<ShadowPlan>>,
    /// Per part and sample, its maps fitted to the part's receivers.
    pub(super) parts: Vec<Vec<Option<ShadowPlan>>>,
}

impl Shadows {
    /// The maps of `lights` (sample indices) that part `part`'s nodes render, or a node of the
    /// whole scene for `None`.
    pub(super) fn of(&self, part: Option<usize>, lights: &[usize]) -> Vec<&ShadowPlan> {
        let maps = part.map_or(&self.whole, |p| &self.parts[p]);
        lights.iter().filter_map(|&i| maps[i].as_ref()).collect()
    }
}

/// Plans the casters, views and map size of every active sample's maps, once for the whole
/// scene and once per part.
pub(super) fn plan_shadows(
    scene: &Scene,
    options: &PlanOptions,
    culled: &Culled,
    fit: &Fit,
) -> Shadows {
    let cam = &scene.camera;
    let Culled {
        samples,
        bounds,
        receivers,
        culling,
        moving,
    } = culled;
    // Like the node's renderer: moving-light maps are fitted to what the camera sees (cascades
    // where that spans a deep range); walkthrough maps outlive camera moves, so they cover every
    // receiver.
    let fit_camera = (!options.walkthrough).then_some(cam);
    // Sample i's shadow plan for the whole scene, or for part `p`'s receivers only.
    let shadow_in = |i: usize, p: Option<usize>| {
        let in_part = |m: usize| p.is_none_or(|p| fit.part_fit[p].0[m]);
        let lit: Vec<&cull::Receiver> = culling.lit[i]
            .iter()
            .map(|&r| &receivers[r])
            .filter(|r| in_part(r.mesh))
            .collect();
        let view_fit = p.map_or(&fit.whole, |p| &fit.part_fit[p].1);
        let mut plan = shadow::shadow_plan(
            &samples[i],
            &lit,
            bounds,
            &view_fit.boxes,
            fit_camera,
            &view_fit.probes,
            cam,
            options.map_sizing.resolve(&scene.quality),
            scene.quality.shadow_map_size,
            options.force_all || moving[i],
        );
        // Model only what the scene needs: transmittance maps where a caster lets light through.
        plan.transmittance = plan
            .casters
            .iter()
            .any(|&m| scene.is_translucent_mesh(m as usize));
        plan
    };
    let shadows_of = |p: Option<usize>| -> Vec<Option<ShadowPlan>> {
        let mut v = vec![None; samples.len()];
        for &i in &culling.active {
            v[i] = Some(shadow_in(i, p));
        }
        v
    };
    let whole = shadows_of(None);
    // Per sort-last part once; a cell takes its part's maps (the whole scene's for tiles alone).
    let by_part: Vec<Vec<Option<ShadowPlan>>> = (0..fit.sort_last.len())
        .map(|p| shadows_of(Some(p)))
        .collect();
    let parts = (0..fit.parts.len())
        .map(|c| match fit.cell(c).0 {
            Some(p) => by_part[p].clone(),
            None => whole.clone(),
        })
        .collect();
    let shadows = Shadows { whole, parts };
    debug_assert!(
        std::iter::once(&shadows.whole)
            .chain(&shadows.parts)
            .all(|maps| (0..samples.len())
                .all(|i| maps[i].is_some() == culling.active.binary_search(&i).is_ok())),
        "exactly the active samples have maps, in every part"
    );
    shadows
}
