//! Which material layers the view needs (paper §3): no emissive material in view → no emissive
//! layer; no global ambient `c^a` or no ambient material → no ambient layer; one specular colour
//! over the visible materials → eq. 4–5 (specular pre-multiplied in `accumulate`, a single
//! material stage); eq. 6–7 folding of `c^a` into the diffuse sum when every visible material has
//! `m^a = m^d`, or eq. 7 (the folding node's per-pixel mask `I^a = m^a ⊘ m^d` instead of the
//! ambient layer) where every visible `m^a` is `m^d` or 0 per channel and the mask travels in
//! fewer bytes than the ambient layer. Each [0, 1] layer travels in the plan's material format (half floats by default,
//! exact against the node's `Rgba16Float` targets), or in 4-byte 8-bit sRGB where every value the
//! layer can take survives it exactly.

use super::cull::Receiver;
use super::types::{FormatChoice, MaterialMode};
use lightfold_protocol::{Layer, PixelFormat};
use lightfold_scene::{Material, Scene};

/// What the visible materials ask of the material stage.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Needs {
    /// The common specular colour of every visible material, if there is one.
    pub uniform_specular: Option<[f32; 3]>,
    pub emissive: bool,
    /// `c^a ≠ 0` and some visible material has `m^a ≠ 0`.
    pub ambient: bool,
    /// Every visible material has `m^a = m^d` (untextured): eq. 6–7 may fold `c^a`.
    pub foldable: bool,
    /// Every visible material's rendered `m^a` is, per pixel and channel, its rendered `m^d` or
    /// 0 ([`mask_exact`]): eq. 7's mask `I^a ∈ {0, 1}` reproduces `m^a = m^d ⊙ I^a` exactly.
    pub maskable: bool,
    /// Layers whose visible values exceed 1 (they need the HDR material format).
    pub hdr: Vec<Layer>,
    /// Layers whose every visible value 8-bit sRGB holds exactly (untextured, each channel 0, 1
    /// or another value an sRGB code decodes to once rounded to the nodes' half floats).
    pub srgb8_exact: Vec<Layer>,
    pub notes: Vec<String>,
}

/// Whether a metallic-roughness material's diffuse layer varies per texel beyond the base-colour
/// texture (its metallic-roughness texture moves `c_diff` and `F0`).
fn pbr_varies(m: &Material) -> bool {
    m.pbr
        .is_some_and(|p| p.metallic_roughness_texture.is_some())
}

/// Whether `m`'s rendered `m^a` is, at every pixel and channel, its rendered `m^d` or 0, so that
/// eq. 7's mask (`shaders/wgsl/ambient_mask.wgsl`: 1 where the two are equal, 0 where either is
/// 0) gives `m^d ⊙ I^a = m^a` exactly. Metallic-roughness renders `m^a = m^d · occlusion`
/// (`eye.wgsl`), which is `m^d` per texel without an occlusion texture, whatever else is
/// textured. Blinn-Phong renders `m^a` as the material's constant: per channel 0, or `m^d`
/// where no diffuse texture varies `m^d`. A filter in front multiplies both layers by the same
/// transmittance, which keeps equal values equal and zero zero.
pub(crate) fn mask_exact(m: &Material) -> bool {
    match &m.pbr {
        Some(p) => p.occlusion_texture.is_none(),
        None => m
            .ambient
            .iter()
            .zip(&m.diffuse)
            .all(|(&a, &d)| a == 0.0 || (a == d && m.diffuse_texture.is_none())),
    }
}

pub(crate) fn needs(scene: &Scene, receivers: &[Receiver], force_all: bool) -> Needs {
    let mut ids: Vec<usize> = receivers
        .iter()
        .map(|r| scene.meshes[r.mesh].material)
        .collect();
    ids.sort_unstable();
    ids.dedup();
    let mats: Vec<&Material> = ids.iter().filter_map(|&i| scene.materials.get(i)).collect();
    let nonzero = |c: [f32; 3]| c.iter().any(|&v| v != 0.0);
    let over_one = |c: [f32; 3]| c.iter().any(|&v| v > 1.0);
    let mut hdr = Vec::new();
    let mut srgb8_exact = Vec::new();
    for (layer, get) in [
        (
            Layer::Diffuse,
            (|m: &Material| m.diffuse) as fn(&Material) -> [f32; 3],
        ),
        (Layer::Specular, |m: &Material| m.specular),
        (Layer::Ambient, |m: &Material| m.ambient),
    ] {
        if mats.iter().any(|m| over_one(get(m))) {
            hdr.push(layer);
        }
        // Blinn-Phong textures only the diffuse layer (`material_layers` in `eye.wgsl`);
        // metallic-roughness's base-colour and metallic-roughness textures vary the diffuse
        // and ambient layers, its occlusion the ambient (`scene::shading::surface_point`).
        let textured = |m: &Material| match (&m.pbr, layer) {
            (_, Layer::Diffuse) => m.diffuse_texture.is_some() || pbr_varies(m),
            (Some(p), Layer::Ambient) => {
                m.diffuse_texture.is_some() || pbr_varies(m) || p.occlusion_texture.is_some()
            }
            _ => false,
        };
        if mats.iter().all(|m| !textured(m) && srgb8_holds(get(m))) {
            srgb8_exact.push(layer);
        }
    }
    let mut notes = Vec::new();
    if force_all {
        notes.push("forced: every material layer, no folding".to_string());
        return Needs {
            uniform_specular: None,
            emissive: true,
            ambient: true,
            foldable: false,
            maskable: false,
            hdr,
            srgb8_exact,
            notes,
        };
    }
    let emissive = mats.iter().any(|m| nonzero(m.emissive));
    let ambient_light = nonzero(scene.ambient);
    let ambient = ambient_light && mats.iter().any(|m| nonzero(m.ambient));
    let foldable = ambient
        && mats.iter().all(|m| {
            m.ambient == m.diffuse
                && m.diffuse_texture.is_none()
                && m.pbr.is_none_or(|p| p.occlusion_texture.is_none())
        });
    let maskable = ambient && mats.iter().all(|m| mask_exact(m));
    let first_spec = mats.first().map(|m| m.specular);
    let uniform_specular = match first_spec {
        Some(s) if mats.iter().all(|m| m.specular == s) => Some(s),
        None => Some([0.0; 3]),
        _ => None,
    };
    // Filters seen through (`docs/translucency.md`) multiply every layer of what lies behind
    // them by their transmittance: no layer keeps values 8-bit sRGB holds exactly, and a common
    // specular colour is no longer common per pixel (but zero stays zero).
    let filters = mats.iter().any(|m| m.is_filter());
    let (srgb8_exact, uniform_specular) = if filters {
        notes.push(
            "filters: a visible glass tints the layers behind it → half-float layers, the specular layer unless no material has one"
                .to_string(),
        );
        (Vec::new(), uniform_specular.filter(|s| *s == [0.0; 3]))
    } else {
        (srgb8_exact, uniform_specular)
    };
    notes.push(if emissive {
        "emissive: a visible material emits → emissive layer".to_string()
    } else {
        "emissive: no visible material emits → no emissive layer".to_string()
    });
    notes.push(match (ambient_light, ambient, foldable, maskable) {
        (false, ..) => "ambient: c^a = 0 → no ambient layer".to_string(),
        (true, false, ..) => "ambient: no visible material has m^a → no ambient layer".to_string(),
        (true, true, true, _) => {
            "ambient: every visible material has m^a = m^d → c^a folded into the diffuse sum (eq. 6–7) if a node can carry c_n = c^a"
                .to_string()
        }
        (true, true, false, true) => {
            "ambient: every visible m^a is m^d or 0 per pixel and channel → eq. 7's mask I^a ∈ {0, 1} reproduces it exactly"
                .to_string()
        }
        (true, true, false, false) => {
            "ambient: m^a differs from m^d (neither m^d nor 0, or under a texture) → ambient layer"
                .to_string()
        }
    });
    notes.push(match uniform_specular {
        Some(s) => format!(
            "specular: one colour {s:?} over the visible materials → pre-multiplied in accumulate, single material stage (eq. 4–5)"
        ),
        None => "specular: colours differ → specular layer".to_string(),
    });
    Needs {
        uniform_specular,
        emissive,
        ambient,
        foldable,
        maskable,
        hdr,
        srgb8_exact,
        notes,
    }
}

/// Eq. 7's choice where the visible materials allow the mask (`Needs::maskable`, not eq. 6's
/// uniform fold): the format the folding node sends `I^a` in when it takes fewer bytes a pixel
/// than the ambient layer would (`None` otherwise), and the note saying which and why.
pub(crate) fn eq7_mask(
    needs: &Needs,
    formats: &FormatChoice,
) -> (Option<PixelFormat>, Option<String>) {
    if !needs.ambient || needs.foldable || !needs.maskable {
        return (None, None);
    }
    // I^a is 0 or 1, which every material format holds exactly; 8-bit sRGB is the narrowest.
    let mask = if formats.material.bytes_per_pixel() > PixelFormat::Rgba8Srgb.bytes_per_pixel() {
        PixelFormat::Rgba8Srgb
    } else {
        formats.material
    };
    let ambient = layer_format(needs, formats, Layer::Ambient);
    let (m, a) = (mask.bytes_per_pixel(), ambient.bytes_per_pixel());
    if m < a {
        (
            Some(mask),
            Some(format!(
                "ambient: eq. 7 → c^a folded into the diffuse sum at a node of c_n = c^a, masked by the I^a that node renders ({} B/px in {mask:?}) instead of the ambient layer ({a} B/px in {ambient:?}); the material stage multiplies one layer fewer",
                m
            )),
        )
    } else {
        (
            None,
            Some(format!(
                "ambient: eq. 7's mask would take {m} B/px ({mask:?}), no fewer than the ambient layer's {a} ({ambient:?}) → ambient layer"
            )),
        )
    }
}

/// Whether 8-bit sRGB carries colour `c` exactly as a node renders it: rounded to the half
/// floats of its material targets, every channel is a value an sRGB code decodes to.
fn srgb8_holds(c: [f32; 3]) -> bool {
    use lightfold_protocol::format::{pack, unpack};
    let (mut h, mut b) = ([0u8; 8], [0u8; 4]);
    let (mut rendered, mut back) = ([0f32; 3], [0f32; 3]);
    let round_trips = pack(PixelFormat::F16x4, &c, 1.0, &mut h).is_ok()
        && unpack(PixelFormat::F16x4, &h, 1.0, &mut rendered).is_ok()
        && pack(PixelFormat::Rgba8Srgb, &rendered, 1.0, &mut b).is_ok()
        && unpack(PixelFormat::Rgba8Srgb, &b, 1.0, &mut back).is_ok();
    round_trips && rendered.map(f32::to_bits) == back.map(f32::to_bits)
}

/// The format material layer `l` travels in: the HDR material format for emission and layers
/// above 1, 8-bit sRGB where it holds every visible value exactly and is narrower, otherwise
/// the material format.
fn layer_format(needs: &Needs, formats: &FormatChoice, l: Layer) -> PixelFormat {
    if l == Layer::Emissive || needs.hdr.contains(&l) {
        formats.material_hdr
    } else if needs.srgb8_exact.contains(&l)
        && formats.material.bytes_per_pixel() > PixelFormat::Rgba8Srgb.bytes_per_pixel()
    {
        // As exact as the wider format, in fewer bytes.
        PixelFormat::Rgba8Srgb
    } else {
        formats.material
    }
}

/// The material mode and the layers the material node renders, given whether `c^a` is folded.
pub(crate) fn layers(
    needs: &Needs,
    fold: bool,
    formats: &FormatChoice,
) -> (MaterialMode, Vec<(Layer, PixelFormat)>) {
    let format = |l: Layer| layer_format(needs, formats, l);
    let mut layers = vec![Layer::Diffuse];
    let mode = match needs.uniform_specular {
        Some(specular) => MaterialMode::UniformSpecular { specular },
        None => {
            layers.push(Layer::Specular);
            MaterialMode::General
        }
    };
    if needs.ambient && !fold {
        layers.push(Layer::Ambient);
    }
    if needs.emissive {
        layers.push(Layer::Emissive);
    }
    (mode, layers.into_iter().map(|l| (l, format(l))).collect())
}
