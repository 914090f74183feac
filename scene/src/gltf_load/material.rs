//! glTF materials and their textures → lightfold materials.
//!
//! Metallic-roughness is shaded as the glTF 2.0 specification's reference BRDF
//! (`Material::pbr`, `docs/shading.md`): base colour, metallic-roughness, normal, occlusion and
//! emissive textures, `KHR_materials_emissive_strength` and `KHR_materials_transmission`'s factor.

use super::accessor::Buffers;
use crate::limits::Budget;
use crate::model::{AlphaMode, Material, MetallicRoughness, Texture, Transmission};
use std::collections::{BTreeSet, HashMap};
use std::path::Path;

use crate::shading::shininess_from_roughness;

/// Converts materials and decodes the textures they use (each image once per colour space).
pub(super) struct MaterialLoader<'a> {
    pub bufs: &'a Buffers,
    pub base: Option<&'a Path>,
    pub ignored: &'a mut BTreeSet<String>,
    pub textures: Vec<Texture>,
    /// (image index, sRGB) → texture index.
    cache: HashMap<(usize, bool), usize>,
}

impl<'a> MaterialLoader<'a> {
    pub(super) fn new(
        bufs: &'a Buffers,
        base: Option<&'a Path>,
        ignored: &'a mut BTreeSet<String>,
    ) -> Self {
        MaterialLoader {
            bufs,
            base,
            ignored,
            textures: Vec::new(),
            cache: HashMap::new(),
        }
    }

    pub(super) fn convert(&mut self, m: &gltf::Material) -> Result<Material, String> {
        let pbr = m.pbr_metallic_roughness();
        let base = pbr.base_color_factor();
        let rgb = [base[0], base[1], base[2]];
        let metallic = pbr.metallic_factor().clamp(0.0, 1.0);
        // KHR_materials_transmission: the dielectric's diffuse share goes through instead,
        // tinted by the base colour (thin-walled; no refraction).
        let tau = m
            .transmission()
            .map_or(0.0, |t| t.transmission_factor().clamp(0.0, 1.0));
        if m.transmission()
            .is_some_and(|t| t.transmission_texture().is_some())
        {
            self.ignored
                .insert("transmission textures (transmission factor used alone)".into());
        }
        let diffuse_texture = match pbr.base_color_texture() {
            Some(info) => Some(self.info(info.tex_coord(), &info.texture(), true)?),
            None => None,
        };
        let metallic_roughness_texture = match pbr.metallic_roughness_texture() {
            Some(info) => Some(self.info(info.tex_coord(), &info.texture(), false)?),
            None => None,
        };
        let (normal_texture, normal_scale) = match m.normal_texture() {
            Some(info) => (
                Some(self.info(info.tex_coord(), &info.texture(), false)?),
                info.scale(),
            ),
            None => (None, 1.0),
        };
        let (occlusion_texture, occlusion_strength) = match m.occlusion_texture() {
            Some(info) => (
                Some(self.info(info.tex_coord(), &info.texture(), false)?),
                info.strength(),
            ),
            None => (None, 1.0),
        };
        let emissive_texture = match m.emissive_texture() {
            Some(info) => Some(self.info(info.tex_coord(), &info.texture(), true)?),
            None => None,
        };
        let model = MetallicRoughness {
            base_color: rgb,
            metallic,
            roughness: pbr.roughness_factor(),
            metallic_roughness_texture,
            normal_texture,
            normal_scale,
            occlusion_texture,
            occlusion_strength,
            emissive_texture,
            transmission: tau,
        };
        let alpha_mode = match m.alpha_mode() {
            gltf::material::AlphaMode::Opaque => AlphaMode::Opaque,
            gltf::material::AlphaMode::Mask => AlphaMode::Mask {
                cutoff: m.alpha_cutoff().unwrap_or(0.5),
            },
            gltf::material::AlphaMode::Blend => AlphaMode::Mask { cutoff: 0.5 },
        };
        // Shadows: a BLEND surface filters by its base colour where it covers and lets the
        // uncovered 1 − α through; a transmissive one lets τ of the light through, tinted.
        let blend = m.alpha_mode() == gltf::material::AlphaMode::Blend;
        let transmission = (blend || tau > 0.0).then(|| Transmission {
            color: if tau > 0.0 {
                rgb.map(|c| c * (1.0 - metallic) * tau)
            } else {
                rgb
            },
            coverage: blend,
        });
        let strength = m.emissive_strength().unwrap_or(1.0);
        let (diffuse, specular, ambient) = model.summary();
        Ok(Material {
            name: m.name().unwrap_or("material").to_string(),
            diffuse,
            diffuse_texture,
            specular,
            shininess: shininess_from_roughness(model.roughness),
            ambient,
            emissive: m.emissive_factor().map(|c| c * strength),
            alpha: base[3],
            alpha_mode,
            double_sided: m.double_sided(),
            transmission,
            pbr: Some(model),
        })
    }

    /// A material's texture (read at TEXCOORD_0: another set is reported and read at 0).
    fn info(&mut self, tex_coord: u32, t: &gltf::Texture, srgb: bool) -> Result<usize, String> {
        if tex_coord != 0 {
            self.ignored
                .insert("textures on TEXCOORD_1+ (TEXCOORD_0 used)".into());
        }
        self.texture(t, srgb)
    }

    fn texture(&mut self, t: &gltf::Texture, srgb: bool) -> Result<usize, String> {
        let sampler = t.sampler();
        if sampler.wrap_s() != gltf::texture::WrappingMode::Repeat
            || sampler.wrap_t() != gltf::texture::WrappingMode::Repeat
        {
            self.ignored
                .insert("texture wrap modes other than REPEAT".into());
        }
        let image = t.source();
        if let Some(&k) = self.cache.get(&(image.index(), srgb)) {
            return Ok(k);
        }
        let (name, decoded) = self.decode(&image)?;
        self.textures.push(Texture {
            name,
            width: decoded.width(),
            height: decoded.height(),
            srgb,
            rgba8: decoded.into_raw(),
        });
        let k = self.textures.len() - 1;
        self.cache.insert((image.index(), srgb), k);
        Ok(k)
    }

    fn decode(&self, image: &gltf::Image) -> Result<(String, image::RgbaImage), String> {
        let name = image
            .name()
            .map(str::to_string)
            .unwrap_or_else(|| format!("image {}", image.index()));
        let bytes = match image.source() {
            gltf::image::Source::View { view, .. } => self.bufs.view_bytes(&view)?.to_vec(),
            gltf::image::Source::Uri { uri, .. } => read_uri(uri, self.base, &self.bufs.files)
                .map_err(|e| format!("texture {name} ({uri}): {e}"))?,
        };
        let decoded = crate::model_file::decode_texture(&bytes, &name, &self.bufs.decoded)?;
        Ok((name, decoded))
    }
}

/// The bytes behind a buffer or image URI: a base64 data URI, or a path relative to `base` that
/// stays inside it (a regular file, read within what `files` has left).
pub(super) fn read_uri(uri: &str, base: Option<&Path>, files: &Budget) -> Result<Vec<u8>, String> {
    if uri.starts_with("data:") {
        let bytes = gltf::buffer::Data::from_source(gltf::buffer::Source::Uri(uri), None)
            .map(|d| d.0)
            .map_err(|e| format!("bad data URI: {e}"))?;
        files.take(bytes.len() as u64).map_err(|e| e.to_string())?;
        return Ok(bytes);
    }
    if uri.contains(':') {
        return Err(format!("unsupported URI scheme in {uri:?}"));
    }
    let rel = percent_decode(uri)?;
    let base = base.ok_or_else(|| {
        format!("{rel:?} is an external file but the glTF was given as bytes without a folder")
    })?;
    let path = crate::input::resolve_inside(base, &rel, "the model's")?;
    let bytes = crate::input::read_bounded(&path, files.left())
        .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    files.take(bytes.len() as u64).map_err(|e| e.to_string())?;
    Ok(bytes)
}

/// RFC 3986 percent-decoding of a relative URI (the `gltf` crate's own decoder panics on bad
/// UTF-8).
fn percent_decode(uri: &str) -> Result<String, String> {
    let b = uri.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' {
            let hex = b
                .get(i + 1..i + 3)
                .and_then(|h| std::str::from_utf8(h).ok())
                .and_then(|h| u8::from_str_radix(h, 16).ok())
                .ok_or_else(|| format!("bad percent-encoding in URI {uri:?}"))?;
            out.push(hex);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).map_err(|_| format!("URI {uri:?} does not decode to UTF-8"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roughness_maps_to_a_clamped_exponent() {
        assert_eq!(shininess_from_roughness(1.0), 1.0);
        assert_eq!(shininess_from_roughness(0.0), 2048.0);
        // roughness 0.5: α = 0.25, s = 2/0.0625 − 2 = 30.
        assert!((shininess_from_roughness(0.5) - 30.0).abs() < 1e-4);
        assert_eq!(shininess_from_roughness(f32::NAN), 1.0);
    }

    #[test]
    fn percent_decoding() {
        assert_eq!(percent_decode("a%20b.png").unwrap(), "a b.png");
        assert!(percent_decode("bad%zz").is_err());
        assert!(percent_decode("bad%ff").is_err());
        assert!(percent_decode("cut%2").is_err());
    }
}
