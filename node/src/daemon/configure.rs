//! A `NodeConfig` from the coordinator checked and resolved into what the render thread and the
//! band packer need: scene light samples, per-light caster lists, the camera, and the layers in
//! link order. Pure, so a bad configuration is refused with a typed error (and its wire code)
//! before the device sees it.

use lightfold_protocol::{
    BAND_HEADER_LEN, ErrorCode, Layer, NodeConfig, PixelFormat, WireCamera, WireShadow,
};
use lightfold_scene::wire::{WireError, camera_from_wire, light_from_wire};
use lightfold_scene::{Camera, LightSample, Scene, ShadowFilter};

/// Most taps per axis of the cell filter a configuration may ask for (its search and its
/// kernel each read taps² footprints).
pub const MAX_CELL_TAPS: u32 = 8;

/// Layers a render node produces (radiance is made by the material stage, never by a node;
/// transmittance only by a node peeling a translucent layer, `NodeConfig::peel` ≥ 1).
pub const NODE_LAYERS: [Layer; 8] = [
    Layer::Illumination,
    Layer::Diffuse,
    Layer::Specular,
    Layer::Ambient,
    Layer::Emissive,
    Layer::Depth,
    Layer::AmbientMask,
    Layer::Transmittance,
];

/// The deepest peel a configuration may ask for (`NodeConfig::peel`; each translucent layer
/// costs its node two rasters of the scene per peel).
pub const MAX_PEEL: u32 = crate::gpu::MAX_PEEL;

/// Formats a node can pack, by layer kind.
pub fn supported_formats() -> Vec<PixelFormat> {
    PixelFormat::ALL
        .into_iter()
        .filter(|f| *f != PixelFormat::F32x3)
        .collect()
}

/// Whether a node emits `layer` in `format`.
pub fn supports(layer: Layer, format: PixelFormat) -> bool {
    if !NODE_LAYERS.contains(&layer) || format.channels() != layer.channels() {
        return false;
    }
    match layer {
        Layer::Illumination => matches!(
            format,
            PixelFormat::Seed64 | PixelFormat::Rgb9e5x2 | PixelFormat::F16x6 | PixelFormat::F32x6
        ),
        Layer::Depth => format == PixelFormat::DepthF32,
        // A transmittance is linear in [0, 1]: never sRGB-encoded.
        Layer::Transmittance => matches!(format, PixelFormat::Rgba8Linear | PixelFormat::F16x4),
        _ => matches!(
            format,
            PixelFormat::Rgba8Linear | PixelFormat::Rgba8Srgb | PixelFormat::F16x4
        ),
    }
}

/// Why a configuration is refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConfigError {
    #[error("layer {layer:?} in format {format:?} is not something a node can emit")]
    UnsupportedFormat { layer: Layer, format: PixelFormat },
    #[error("the configuration lists no layer")]
    NoLayers,
    #[error("layer {0:?} is listed twice")]
    DuplicateLayer(Layer),
    #[error("{count} lights exceed this device's limit of {max} at {map_size}² shadow maps")]
    TooManyLights {
        count: usize,
        max: u32,
        map_size: u32,
    },
    #[error("light {index}: {source}")]
    Light { index: usize, source: WireError },
    #[error("camera: {0}")]
    Camera(WireError),
    #[error("node colour {0:?} must be finite and non-negative in every channel")]
    BadColor([f32; 3]),
    #[error("scale {0} must be finite and non-negative, and positive for seed64")]
    BadScale(f32),
    #[error("band height must be at least 1")]
    BadBandHeight,
    #[error("{what} {value} is not finite")]
    NonFinite { what: &'static str, value: f32 },
    #[error("shadow entry {entry} names light {light}, but the node has {lights} lights")]
    ShadowLight {
        entry: usize,
        light: u32,
        lights: usize,
    },
    #[error("light {0} has more than one shadow entry")]
    DuplicateShadow(u32),
    #[error("light {0} has no shadow entry (give every light one, or none at all)")]
    MissingShadow(usize),
    #[error("shadow map size {size} is outside 1..={max}")]
    BadMapSize { size: u32, max: u32 },
    #[error("light {light} lists caster mesh {mesh}, but the scene has {meshes} meshes")]
    BadCaster {
        light: usize,
        mesh: u32,
        meshes: usize,
    },
    #[error("the eye pass lists mesh {mesh}, but the scene has {meshes} meshes")]
    BadEyeMesh { mesh: u32, meshes: usize },
    #[error(
        "move {index} is not one this node can make (mesh {mesh} of {meshes}, a finite transform \
         that keeps facing, each mesh once, no animated scene)"
    )]
    BadMove {
        index: usize,
        mesh: u32,
        meshes: usize,
    },
    #[error("a band of {bytes} bytes does not fit the link's maximum frame of {max} bytes")]
    BandTooLarge { bytes: u64, max: usize },
    #[error("downstream address is empty")]
    NoDownstream,
    #[error(
        "filter {0} is not 0 (none), 1 (PCF 2×2), 3 or 5 (a grid) or 258..=264 (the cell filter \
         with 2..=8 taps)"
    )]
    BadFilter(u32),
    #[error(
        "frame light {index} (sample {sample}) does not replace one of this node's lights with one \
         of the same kind, once"
    )]
    BadFrameLight { index: usize, sample: u32 },
    #[error(
        "rows {y0}..{y1} are not a tile of the {height}-row image (a sort-first tile needs \
         y0 < y1 <= {height})"
    )]
    BadRows { y0: u32, y1: u32, height: u32 },
    #[error(
        "the transmittance layer is a translucent eye layer's: it needs peel >= 1 (peel is {0:?})"
    )]
    TransmittanceWithoutPeel(Option<u32>),
    #[error("peel {peel} is deeper than a node renders (at most {max})")]
    PeelTooDeep { peel: u32, max: u32 },
    #[error("a peeled eye layer (peel {0}) cannot be a sort-last part (eye_meshes)")]
    PeelWithEyeMeshes(u32),
}

impl ConfigError {
    /// The code the coordinator sees in `Message::Error`.
    pub fn code(&self) -> ErrorCode {
        match self {
            ConfigError::UnsupportedFormat { .. } => ErrorCode::UnsupportedFormat,
            _ => ErrorCode::BadConfig,
        }
    }
}

/// Caster meshes of each light, indexed like the lights.
pub type Casters = Vec<Vec<u32>>;

/// A configuration checked against the device and the scene.
#[derive(Debug, Clone)]
pub struct Checked {
    pub config: NodeConfig,
    pub lights: Vec<LightSample>,
    /// Caster meshes per light (index = light), or `None` for "every mesh casts".
    pub casters: Option<Casters>,
    pub camera: Camera,
    /// The largest map side (the scene's `shadow_map_size` when the plan gives none).
    pub map_size: u32,
    /// The side the device's light limit counts maps at, which the renderer is built for: the
    /// largest, or under the scene's mismatch rule at most its base size (the renderer halves
    /// larger maps to fit its shadow budget, as `lightfold render` does).
    pub budget_size: u32,
    /// Each light's map side as the plan gives it (index = light); `None` when the plan gives
    /// none: the renderer sizes maps by the scene's `map_sizing`.
    pub map_sides: Option<Vec<u32>>,
}

/// Checks a fixed-point scale (from a configuration or a frame request) for these layers.
pub fn check_scale(scale: f32, layers: &[(Layer, PixelFormat)]) -> Result<(), ConfigError> {
    let seed64 = layers.iter().any(|(_, f)| *f == PixelFormat::Seed64);
    if scale.is_finite() && scale >= 0.0 && (scale > 0.0 || !seed64) {
        Ok(())
    } else {
        Err(ConfigError::BadScale(scale))
    }
}

/// Checks a frame's lights (`FrameParams::lights`: an animated scene's virtual point lights, or
/// lights a viewer moved) against the configured ones: each a valid light replacing the
/// configured light of the same sample index and kind, at most once. Gives the index of each in
/// the configuration with its sample.
pub fn check_frame_lights(
    lights: &[lightfold_protocol::WireLight],
    configured: &[lightfold_protocol::WireLight],
) -> Result<Vec<(usize, lightfold_scene::LightSample)>, ConfigError> {
    let mut out: Vec<(usize, lightfold_scene::LightSample)> = Vec::with_capacity(lights.len());
    for (index, w) in lights.iter().enumerate() {
        let bad = || ConfigError::BadFrameLight {
            index,
            sample: w.sample,
        };
        let at = configured
            .iter()
            .position(|c| c.sample == w.sample && c.kind == w.kind)
            .ok_or_else(bad)?;
        let s = light_from_wire(w).map_err(|source| ConfigError::Light { index, source })?;
        if out.iter().any(|(i, _)| *i == at) {
            return Err(bad());
        }
        out.push((at, s));
    }
    Ok(out)
}

/// Checks a sort-first tile's rows (`NodeConfig::rows`, `FrameParams::rows`) for an image
/// `height` rows tall: `[y0, y1)` with at least one row, none below the image.
pub fn check_rows(rows: [u32; 2], height: u32) -> Result<(), ConfigError> {
    let [y0, y1] = rows;
    crate::gpu::check_rows(rows, height).map_err(|_| ConfigError::BadRows { y0, y1, height })
}

/// Checks a configuration's peel (`NodeConfig::peel`): at most [`MAX_PEEL`], not with sort-last
/// eye meshes (the planner never combines them), and a transmittance layer only with a
/// translucent peel (≥ 1).
pub fn check_peel(config: &NodeConfig) -> Result<(), ConfigError> {
    if let Some(peel) = config.peel {
        if peel > MAX_PEEL {
            return Err(ConfigError::PeelTooDeep {
                peel,
                max: MAX_PEEL,
            });
        }
        if config.eye_meshes.is_some() {
            return Err(ConfigError::PeelWithEyeMeshes(peel));
        }
    }
    let translucent = config.peel.is_some_and(|p| p >= 1);
    if !translucent
        && config
            .layers
            .iter()
            .any(|(l, _)| *l == Layer::Transmittance)
    {
        return Err(ConfigError::TransmittanceWithoutPeel(config.peel));
    }
    Ok(())
}

/// Checks a camera from a configuration or a frame request.
pub fn check_camera(camera: &WireCamera) -> Result<Camera, ConfigError> {
    camera_from_wire(camera).map_err(ConfigError::Camera)
}

/// Checks `config` for a node whose device takes at most `max_lights(map_size)` lights, whose
/// links carry frames up to `max_frame` bytes, rendering `scene`. `default_map_size` applies when
/// the configuration carries no shadow entries.
pub fn check(
    config: NodeConfig,
    scene: &Scene,
    max_lights: impl Fn(u32) -> u32,
    max_texture: u32,
    max_frame: usize,
) -> Result<Checked, ConfigError> {
    if config.layers.is_empty() {
        return Err(ConfigError::NoLayers);
    }
    for (i, &(layer, format)) in config.layers.iter().enumerate() {
        if !supports(layer, format) {
            return Err(ConfigError::UnsupportedFormat { layer, format });
        }
        if config.layers[..i].iter().any(|(l, _)| *l == layer) {
            return Err(ConfigError::DuplicateLayer(layer));
        }
    }
    // No light is allowed: such a node (the planner's stand-in when nothing is lit) streams
    // empty illumination bands.
    let lights = config
        .lights
        .iter()
        .enumerate()
        .map(|(index, w)| light_from_wire(w).map_err(|source| ConfigError::Light { index, source }))
        .collect::<Result<Vec<_>, _>>()?;
    // A zero channel is a saturated light colour (pure red is `[1, 0, 0]`): the node's lights
    // carry nothing in it (`gpu::lights::colour_weight`) and the compositor multiplies it by 0.
    if !config.color.iter().all(|c| c.is_finite() && *c >= 0.0) {
        return Err(ConfigError::BadColor(config.color));
    }
    check_scale(config.scale, &config.layers)?;
    if config.band_height == 0 {
        return Err(ConfigError::BadBandHeight);
    }
    for (what, value) in [
        ("depth bias", config.depth_bias),
        ("slope bias", config.slope_bias),
    ] {
        if !value.is_finite() {
            return Err(ConfigError::NonFinite { what, value });
        }
    }
    let known = match lightfold_scene::wire::filter_from_wire(config.filter) {
        Some(ShadowFilter::Pcf { taps }) => matches!(taps, 3 | 5),
        Some(ShadowFilter::Cell { taps }) => (2..=MAX_CELL_TAPS).contains(&taps),
        Some(_) => true,
        None => false,
    };
    if !known {
        return Err(ConfigError::BadFilter(config.filter));
    }
    if config.downstream.trim().is_empty() {
        return Err(ConfigError::NoDownstream);
    }
    check_peel(&config)?;
    let camera = check_camera(&config.camera)?;
    if let Some(rows) = config.rows {
        check_rows(rows, camera.height)?;
    }
    let widest = config
        .layers
        .iter()
        .map(|(_, f)| f.bytes_per_pixel() as u64)
        .max()
        .unwrap_or(0);
    let bytes = u64::from(camera.width) * u64::from(config.band_height.min(camera.height)) * widest;
    if bytes + BAND_HEADER_LEN as u64 + 1 > max_frame as u64 {
        return Err(ConfigError::BandTooLarge {
            bytes,
            max: max_frame,
        });
    }
    if let Some(m) = config
        .eye_meshes
        .iter()
        .flatten()
        .find(|&&m| m as usize >= scene.meshes.len())
    {
        return Err(ConfigError::BadEyeMesh {
            mesh: *m,
            meshes: scene.meshes.len(),
        });
    }
    for (index, m) in config.moves.iter().enumerate() {
        if index >= scene.meshes.len()
            || m.mesh as usize >= scene.meshes.len()
            || config.moves[..index].iter().any(|o| o.mesh == m.mesh)
            || !lightfold_scene::moves::is_valid_columns(&m.matrix)
            || scene.animation.is_some()
        {
            return Err(ConfigError::BadMove {
                index,
                mesh: m.mesh,
                meshes: scene.meshes.len(),
            });
        }
    }
    let (map_size, map_sides, casters) = check_shadows(
        &config.shadows,
        lights.len(),
        scene,
        scene.quality.shadow_map_size,
        max_texture,
    )?;
    // Maps sized by the scene's mismatch rule above its base size share the shadow budget (the
    // renderer halves the largest to fit), so the limit counts them at that size.
    let limit_size = match scene.quality.map_sizing {
        lightfold_scene::MapSizing::Mismatch(_) => map_size.min(scene.quality.shadow_map_size),
        lightfold_scene::MapSizing::Fixed => map_size,
    };
    let max = max_lights(limit_size);
    if lights.len() > max as usize {
        return Err(ConfigError::TooManyLights {
            count: lights.len(),
            max,
            map_size: limit_size,
        });
    }
    Ok(Checked {
        config,
        lights,
        casters,
        camera,
        map_size,
        budget_size: limit_size,
        map_sides,
    })
}

/// The largest map side and, when the plan gives shadow entries, each light's side and caster
/// list.
#[allow(clippy::type_complexity)]
fn check_shadows(
    shadows: &[WireShadow],
    lights: usize,
    scene: &Scene,
    default_size: u32,
    max_texture: u32,
) -> Result<(u32, Option<Vec<u32>>, Option<Casters>), ConfigError> {
    // The device's limit, and the one every input shares (`lightfold_scene::limits`).
    let max = max_texture.min(lightfold_scene::limits::MAX_SHADOW_MAP_SIZE);
    let mut sides = vec![0u32; lights];
    let mut per_light: Vec<Option<Vec<u32>>> = vec![None; lights];
    for (entry, s) in shadows.iter().enumerate() {
        let slot = per_light
            .get_mut(s.light as usize)
            .ok_or(ConfigError::ShadowLight {
                entry,
                light: s.light,
                lights,
            })?;
        if slot.is_some() {
            return Err(ConfigError::DuplicateShadow(s.light));
        }
        if let Some(m) = s
            .casters
            .iter()
            .find(|&&m| m as usize >= scene.meshes.len())
        {
            return Err(ConfigError::BadCaster {
                light: s.light as usize,
                mesh: *m,
                meshes: scene.meshes.len(),
            });
        }
        if s.map_size == 0 || s.map_size > max {
            return Err(ConfigError::BadMapSize {
                size: s.map_size,
                max,
            });
        }
        sides[s.light as usize] = s.map_size;
        *slot = Some(s.casters.clone());
    }
    if shadows.is_empty() {
        if default_size == 0 || default_size > max {
            return Err(ConfigError::BadMapSize {
                size: default_size,
                max,
            });
        }
        return Ok((default_size, None, None));
    }
    let casters = per_light
        .into_iter()
        .enumerate()
        .map(|(i, c)| c.ok_or(ConfigError::MissingShadow(i)))
        .collect::<Result<Vec<_>, _>>()?;
    let largest = sides.iter().copied().max().unwrap_or(default_size);
    Ok((largest, Some(sides), Some(casters)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfold_protocol::{WireCamera, WireLight};

    fn config(layers: Vec<(Layer, PixelFormat)>, lights: usize) -> NodeConfig {
        let light = WireLight {
            position: [0.0, 2.0, 0.0],
            direction: [0.0, -1.0, 0.0],
            kind: 1,
            cone: [0.0; 2],
            intensity: 1.0,
            color: [1.0; 3],
            range: 0.0,
            light: 0,
            sample: 0,
            area: None,
            cell: 0.0,
        };
        NodeConfig {
            epoch: 1,
            scene: [0; 32],
            lights: vec![light; lights],
            shadows: Vec::new(),
            color: [1.0; 3],
            layers,
            scale: 1.0,
            band_height: 16,
            camera: WireCamera {
                position: [0.0, 1.0, 5.0],
                target: [0.0; 3],
                up: [0.0, 1.0, 0.0],
                fov_y_deg: 45.0,
                width: 64,
                height: 48,
            },
            walkthrough: false,
            downstream: "127.0.0.1:1".into(),
            input_index: 0,
            filter: 1,
            depth_bias: 0.0,
            slope_bias: 0.0,
            eye_meshes: None,
            rows: None,
            moves: Vec::new(),
            peel: None,
        }
    }

    fn scene(meshes: usize) -> Scene {
        let mut s = Scene::new("t");
        for _ in 0..meshes {
            s.add_mesh(lightfold_scene::primitives::cuboid(
                "c", [0.0; 3], [1.0; 3], 0,
            ));
        }
        s
    }

    type Expect = fn(&ConfigError) -> bool;

    fn run(c: NodeConfig) -> Result<Checked, ConfigError> {
        check(c, &scene(2), |_| 8, 4096, 1 << 20)
    }

    #[test]
    fn a_good_configuration_passes() {
        let c = run(config(
            vec![(Layer::Illumination, PixelFormat::Rgb9e5x2)],
            2,
        ))
        .unwrap();
        assert_eq!((c.lights.len(), c.map_size, c.casters), (2, 512, None));
    }

    #[test]
    fn saturated_node_colours_pass() {
        // A pure-red light's colour group: the planner sends its colour as `c_n`. Refusing a zero
        // channel ended live sessions whose user picked #ff0000.
        for color in [[1.0, 0.0, 0.0], [3.0, 0.375, 0.0], [0.0; 3]] {
            let c = NodeConfig {
                color,
                ..config(vec![(Layer::Illumination, PixelFormat::Rgb9e5x2)], 1)
            };
            assert!(run(c).is_ok(), "{color:?}");
        }
    }

    #[test]
    fn sizes_beyond_the_shared_limits_are_refused() {
        // A device that takes 16384² textures still gets at most the limits' image and maps:
        // 16384 × 16384 used to pass here and then panic in wgpu.
        let big = |c: NodeConfig| check(c, &scene(2), |_| 8, 16384, usize::MAX);
        let mut c = config(vec![(Layer::Illumination, PixelFormat::Rgb9e5x2)], 1);
        (c.camera.width, c.camera.height) = (16384, 16384);
        let e = big(c).unwrap_err();
        assert!(
            e.to_string().contains("image 16384x16384 is too large"),
            "{e}"
        );
        let mut c = config(vec![(Layer::Illumination, PixelFormat::Rgb9e5x2)], 1);
        c.shadows = vec![WireShadow {
            light: 0,
            map_size: 8192,
            casters: Vec::new(),
        }];
        assert_eq!(
            big(c).unwrap_err(),
            ConfigError::BadMapSize {
                size: 8192,
                max: 4096
            }
        );
    }

    #[test]
    fn every_supported_pair_is_a_real_format() {
        for layer in NODE_LAYERS {
            let formats: Vec<_> = supported_formats()
                .into_iter()
                .filter(|f| supports(layer, *f))
                .collect();
            assert!(!formats.is_empty(), "{layer:?} has a format");
            assert!(formats.iter().all(|f| f.channels() == layer.channels()));
        }
        assert!(!supports(Layer::Radiance, PixelFormat::F32x3));
    }

    /// Mesh `mesh` scaled by `s` about the origin.
    fn moved(mesh: u32, s: f32) -> lightfold_protocol::WireMove {
        let mut matrix = [0.0; 16];
        (matrix[0], matrix[5], matrix[10], matrix[15]) = (s, s, s, 1.0);
        lightfold_protocol::WireMove { mesh, matrix }
    }

    #[test]
    fn shadow_filters_are_the_ones_a_node_renders_and_cells_are_checked() {
        let illum = vec![(Layer::Illumination, PixelFormat::F16x6)];
        let with = |filter| NodeConfig {
            filter,
            ..config(illum.clone(), 1)
        };
        for (code, filter) in [
            (0, ShadowFilter::None),
            (1, ShadowFilter::Pcf2x2),
            (3, ShadowFilter::Pcf { taps: 3 }),
            (5, ShadowFilter::Pcf { taps: 5 }),
            (258, ShadowFilter::Cell { taps: 2 }),
            (259, ShadowFilter::Cell { taps: 3 }),
            (264, ShadowFilter::Cell { taps: 8 }),
        ] {
            assert!(run(with(code)).is_ok(), "{code}");
            assert_eq!(lightfold_scene::wire::filter_to_wire(filter), code);
            assert_eq!(crate::daemon::render_thread::shadow_filter(code), filter);
        }
        for code in [2, 4, 6, 16, 255, 256, 257, 265, u32::MAX] {
            assert_eq!(run(with(code)).unwrap_err(), ConfigError::BadFilter(code));
        }
        // A light's cell must be a finite width.
        for (cell, negative) in [(-0.1, true), (f32::NAN, false), (f32::INFINITY, false)] {
            let mut c = config(illum.clone(), 1);
            c.lights[0].cell = cell;
            let e = run(c).unwrap_err();
            assert!(
                matches!(
                    e,
                    ConfigError::Light {
                        source: WireError::NegativeCell { .. },
                        ..
                    }
                ) == negative
                    && matches!(e, ConfigError::Light { .. }),
                "{cell}: {e}"
            );
        }
    }

    #[test]
    fn bad_configurations_are_refused_with_their_code() {
        let illum = vec![(Layer::Illumination, PixelFormat::F16x6)];
        let cases: Vec<(NodeConfig, Expect)> = vec![
            (
                config(vec![(Layer::Illumination, PixelFormat::Rgba8Linear)], 1),
                |e| matches!(e, ConfigError::UnsupportedFormat { .. }),
            ),
            (config(Vec::new(), 1), |e| *e == ConfigError::NoLayers),
            (config(vec![illum[0], illum[0]], 1), |e| {
                matches!(e, ConfigError::DuplicateLayer(Layer::Illumination))
            }),
            (
                NodeConfig {
                    scale: 0.0,
                    ..config(vec![(Layer::Illumination, PixelFormat::Seed64)], 1)
                },
                |e| *e == ConfigError::BadScale(0.0),
            ),
            (
                NodeConfig {
                    scale: f32::NAN,
                    ..config(illum.clone(), 1)
                },
                |e| matches!(e, ConfigError::BadScale(_)),
            ),
            (config(illum.clone(), 9), |e| {
                matches!(
                    e,
                    ConfigError::TooManyLights {
                        count: 9,
                        max: 8,
                        ..
                    }
                )
            }),
            (
                NodeConfig {
                    band_height: 0,
                    ..config(illum.clone(), 1)
                },
                |e| *e == ConfigError::BadBandHeight,
            ),
            (
                NodeConfig {
                    color: [1.0, -0.5, 1.0],
                    ..config(illum.clone(), 1)
                },
                |e| matches!(e, ConfigError::BadColor(_)),
            ),
            (
                NodeConfig {
                    color: [1.0, f32::NAN, 0.0],
                    ..config(illum.clone(), 1)
                },
                |e| matches!(e, ConfigError::BadColor(_)),
            ),
            (
                NodeConfig {
                    band_height: 48,
                    camera: WireCamera {
                        width: 4096,
                        ..config(illum.clone(), 1).camera
                    },
                    ..config(vec![(Layer::Illumination, PixelFormat::F32x6)], 1)
                },
                |e| matches!(e, ConfigError::BandTooLarge { .. }),
            ),
            (
                NodeConfig {
                    shadows: vec![WireShadow {
                        light: 0,
                        map_size: 256,
                        casters: vec![2],
                    }],
                    ..config(illum.clone(), 1)
                },
                |e| matches!(e, ConfigError::BadCaster { mesh: 2, .. }),
            ),
            (
                NodeConfig {
                    shadows: vec![WireShadow {
                        light: 1,
                        map_size: 256,
                        casters: vec![],
                    }],
                    ..config(illum.clone(), 2)
                },
                |e| matches!(e, ConfigError::MissingShadow(0)),
            ),
            (
                NodeConfig {
                    moves: vec![moved(2, 1.0)],
                    ..config(illum.clone(), 1)
                },
                |e| matches!(e, ConfigError::BadMove { mesh: 2, .. }),
            ),
            (
                NodeConfig {
                    moves: vec![moved(1, 1.0), moved(1, 2.0)],
                    ..config(illum.clone(), 1)
                },
                |e| matches!(e, ConfigError::BadMove { index: 1, .. }),
            ),
            (
                NodeConfig {
                    // A mirror turns the mesh's triangles inside out.
                    moves: vec![moved(0, -1.0)],
                    ..config(illum.clone(), 1)
                },
                |e| matches!(e, ConfigError::BadMove { index: 0, .. }),
            ),
            (
                NodeConfig {
                    moves: vec![moved(0, f32::NAN)],
                    ..config(illum.clone(), 1)
                },
                |e| matches!(e, ConfigError::BadMove { index: 0, .. }),
            ),
        ];
        // A move the scene can make passes.
        let good = NodeConfig {
            moves: vec![moved(1, 2.0)],
            ..config(illum.clone(), 1)
        };
        assert!(run(good).is_ok());
        for (i, (c, expected)) in cases.into_iter().enumerate() {
            let e = run(c).expect_err(&format!("case {i} is refused"));
            assert!(expected(&e), "case {i}: {e}");
            let code = if matches!(e, ConfigError::UnsupportedFormat { .. }) {
                ErrorCode::UnsupportedFormat
            } else {
                ErrorCode::BadConfig
            };
            assert_eq!(e.code(), code);
        }
    }

    #[test]
    fn tile_rows_within_the_image_pass_and_others_are_refused() {
        // The test camera is 48 rows tall.
        let illum = vec![(Layer::Illumination, PixelFormat::F16x6)];
        let with = |rows| NodeConfig {
            rows,
            ..config(illum.clone(), 1)
        };
        for rows in [
            None,
            Some([0, 48]),
            Some([0, 1]),
            Some([47, 48]),
            Some([13, 29]),
        ] {
            assert!(run(with(rows)).is_ok(), "{rows:?}");
        }
        for [y0, y1] in [
            [5, 5],
            [9, 3],
            [0, 49],
            [48, 49],
            [0, u32::MAX],
            [u32::MAX, 0],
        ] {
            let e = run(with(Some([y0, y1]))).expect_err("refused");
            assert_eq!(e, ConfigError::BadRows { y0, y1, height: 48 });
            assert_eq!(e.code(), ErrorCode::BadConfig);
            assert!(e.to_string().contains(&format!("rows {y0}..{y1}")), "{e}");
        }
        assert!(check_rows([0, 48], 48).is_ok());
        assert!(check_rows([0, 0], 0).is_err());
    }

    #[test]
    fn peels_are_checked() {
        let t = (Layer::Transmittance, PixelFormat::F16x4);
        let illum = (Layer::Illumination, PixelFormat::F16x6);
        let with = |layers: Vec<(Layer, PixelFormat)>, peel| NodeConfig {
            peel,
            ..config(layers, 1)
        };
        // Every peel up to the cap, with or without the transmittance layer where it is a
        // translucent one.
        for peel in [None, Some(0), Some(1), Some(2), Some(MAX_PEEL)] {
            assert!(run(with(vec![illum], peel)).is_ok(), "{peel:?}");
        }
        for peel in [Some(1), Some(3), Some(MAX_PEEL)] {
            assert!(run(with(vec![illum, t], peel)).is_ok(), "{peel:?}");
            let linear = (Layer::Transmittance, PixelFormat::Rgba8Linear);
            assert!(run(with(vec![illum, linear], peel)).is_ok(), "{peel:?}");
        }
        // Transmittance without a translucent peel.
        for peel in [None, Some(0)] {
            let e = run(with(vec![illum, t], peel)).unwrap_err();
            assert_eq!(e, ConfigError::TransmittanceWithoutPeel(peel));
            assert_eq!(e.code(), ErrorCode::BadConfig);
            assert!(e.to_string().contains("needs peel >= 1"), "{e}");
        }
        // Beyond the cap.
        for peel in [MAX_PEEL + 1, u32::MAX] {
            let e = run(with(vec![illum, t], Some(peel))).unwrap_err();
            assert_eq!(
                e,
                ConfigError::PeelTooDeep {
                    peel,
                    max: MAX_PEEL
                }
            );
            assert_eq!(e.code(), ErrorCode::BadConfig);
        }
        // A peel as a sort-last part; the same part without a peel passes.
        let part = |peel| NodeConfig {
            eye_meshes: Some(vec![0]),
            ..with(vec![illum], peel)
        };
        assert!(run(part(None)).is_ok());
        for peel in [0, 2] {
            let e = run(part(Some(peel))).unwrap_err();
            assert_eq!(e, ConfigError::PeelWithEyeMeshes(peel));
            assert_eq!(e.code(), ErrorCode::BadConfig);
        }
        // Transmittance in sRGB or a format of another channel count is no node's.
        for f in [
            PixelFormat::Rgba8Srgb,
            PixelFormat::F16x6,
            PixelFormat::DepthF32,
        ] {
            assert!(!supports(Layer::Transmittance, f), "{f:?}");
            let e = run(with(vec![illum, (Layer::Transmittance, f)], Some(1))).unwrap_err();
            assert!(matches!(e, ConfigError::UnsupportedFormat { .. }), "{e}");
            assert_eq!(e.code(), ErrorCode::UnsupportedFormat);
        }
    }

    #[test]
    fn caster_lists_cover_every_light() {
        let shadows = (0..2)
            .map(|light| WireShadow {
                light,
                map_size: 256,
                casters: vec![light],
            })
            .collect();
        let c = run(NodeConfig {
            shadows,
            ..config(vec![(Layer::Illumination, PixelFormat::F16x6)], 2)
        })
        .unwrap();
        assert_eq!(c.map_size, 256);
        assert_eq!(c.map_sides, Some(vec![256, 256]));
        assert_eq!(c.casters, Some(vec![vec![0], vec![1]]));
        // Each light keeps its own side; the largest bounds the device's light limit.
        let c = run(NodeConfig {
            shadows: vec![
                WireShadow {
                    light: 0,
                    map_size: 2048,
                    casters: vec![0],
                },
                WireShadow {
                    light: 1,
                    map_size: 256,
                    casters: vec![1],
                },
            ],
            ..config(vec![(Layer::Illumination, PixelFormat::F16x6)], 2)
        })
        .unwrap();
        assert_eq!((c.map_size, c.map_sides), (2048, Some(vec![2048, 256])));
    }

    /// A frame's lights replace configured ones of the same sample and kind, once each; anything
    /// else is refused.
    #[test]
    fn frame_lights_replace_configured_lights_of_their_kind_once() {
        const BOUNCE_KIND: u8 = 5;
        let mut lights = config(vec![(Layer::Illumination, PixelFormat::F16x4)], 3).lights;
        for (i, l) in lights.iter_mut().enumerate() {
            l.sample = 10 + i as u32;
        }
        lights[1].kind = BOUNCE_KIND;
        lights[1].cone = [0.1, 0.0];
        lights[2].kind = BOUNCE_KIND;
        let moved = |sample: u32| WireLight {
            position: [0.5, 1.0, 0.0],
            sample,
            ..lights[1]
        };
        let got = check_frame_lights(&[moved(12), moved(11)], &lights).unwrap();
        assert_eq!(got.iter().map(|(i, _)| *i).collect::<Vec<_>>(), [2, 1]);
        assert_eq!(got[0].1.position, [0.5, 1.0, 0.0]);
        let nan = WireLight {
            intensity: f32::NAN,
            ..moved(11)
        };
        let not_bounce = WireLight {
            kind: 1,
            ..moved(11)
        };
        // A moved cosine-lobe sample (kind 1) replaces light 0.
        let lobe = WireLight {
            position: [0.0, 3.0, 0.0],
            ..lights[0]
        };
        assert_eq!(check_frame_lights(&[lobe], &lights).unwrap()[0].0, 0);
        for (what, bad) in [
            ("another kind than the configured light", vec![moved(10)]),
            ("no such sample", vec![moved(99)]),
            ("twice", vec![moved(11), moved(11)]),
            ("a lobe for a bounce light", vec![not_bounce]),
            ("not finite", vec![nan]),
        ] {
            assert!(
                check_frame_lights(&bad, &lights).is_err(),
                "{what} was taken"
            );
        }
    }
}
