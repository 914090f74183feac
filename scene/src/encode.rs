//! A scene's identity and its wire form. `content_hash` is SHA-256 over a canonical byte
//! encoding of everything that affects rendering (names excluded; −0.0 and NaN canonicalised),
//! stable across runs and platforms; `asset_hash` covers only the heavy part nodes cache
//! (meshes, materials, textures). `to_bytes` / `from_bytes` carry a whole scene between machines
//! (there is no shared filesystem): a magic, a format version, then bincode with a size limit;
//! a decoded scene must validate clean, so receivers can index it without checks.

use crate::error::SceneError;
use crate::model::{
    AlphaMode, AreaSpecular, Camera, Light, LightShape, MapSizing, Material, Mesh,
    MetallicRoughness, Quality, SamplePattern, Scene, ShadowFilter, Texture,
};
use sha2::{Digest, Sha256};

const MAGIC: &[u8; 4] = b"LFSC";
/// Version of the byte layout of `to_bytes` (bump when `Scene` changes shape).
pub const SCENE_BYTES_VERSION: u32 = 8;
/// Largest scene `from_bytes` accepts ([`crate::limits::MAX_SCENE_BYTES`]).
pub const MAX_SCENE_BYTES: usize = crate::limits::MAX_SCENE_BYTES as usize;

/// Feeds canonical little-endian bytes into a hasher.
struct Canon(Sha256);

impl Canon {
    fn new(domain: &str) -> Self {
        let mut c = Canon(Sha256::new());
        c.bytes(domain.as_bytes());
        c
    }
    fn u8(&mut self, v: u8) {
        self.0.update([v]);
    }
    fn u32(&mut self, v: u32) {
        self.0.update(v.to_le_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.0.update(v.to_le_bytes());
    }
    fn len(&mut self, n: usize) {
        self.u64(n as u64);
    }
    fn f32(&mut self, v: f32) {
        let bits = if v.is_nan() {
            0x7fc0_0000
        } else if v == 0.0 {
            0
        } else {
            v.to_bits()
        };
        self.u32(bits);
    }
    fn f32s(&mut self, v: &[f32]) {
        for &x in v {
            self.f32(x);
        }
    }
    fn v3s(&mut self, v: &[[f32; 3]]) {
        self.len(v.len());
        for p in v {
            self.f32s(p);
        }
    }
    fn bytes(&mut self, b: &[u8]) {
        self.len(b.len());
        self.0.update(b);
    }
    fn opt_f32(&mut self, v: Option<f32>) {
        match v {
            None => self.u8(0),
            Some(x) => {
                self.u8(1);
                self.f32(x);
            }
        }
    }
    fn finish(self) -> [u8; 32] {
        self.0.finalize().into()
    }

    fn mesh(&mut self, m: &Mesh) {
        let Mesh {
            name: _,
            positions,
            normals,
            uvs,
            tangents,
            indices,
            material,
        } = m;
        self.v3s(positions);
        self.v3s(normals);
        self.len(uvs.len());
        for uv in uvs {
            self.f32s(uv);
        }
        self.len(tangents.len());
        for t in tangents {
            self.f32s(t);
        }
        self.len(indices.len());
        for &i in indices {
            self.u32(i);
        }
        self.len(*material);
    }

    fn material(&mut self, m: &Material) {
        let Material {
            name: _,
            diffuse,
            diffuse_texture,
            specular,
            shininess,
            ambient,
            emissive,
            alpha,
            alpha_mode,
            double_sided,
            transmission,
            pbr,
        } = m;
        self.f32s(diffuse);
        self.index(*diffuse_texture);
        self.f32s(specular);
        self.f32(*shininess);
        self.f32s(ambient);
        self.f32s(emissive);
        self.f32(*alpha);
        match alpha_mode {
            AlphaMode::Opaque => self.u8(0),
            AlphaMode::Mask { cutoff } => {
                self.u8(1);
                self.f32(*cutoff);
            }
        }
        self.u8(*double_sided as u8);
        match transmission {
            None => self.u8(0),
            Some(t) => {
                self.u8(1);
                self.f32s(&t.color);
                self.u8(t.coverage as u8);
            }
        }
        match pbr {
            None => self.u8(0),
            Some(p) => {
                self.u8(1);
                self.metallic_roughness(p);
            }
        }
    }

    /// An optional index: 0, or 1 and the index.
    fn index(&mut self, t: Option<usize>) {
        match t {
            None => self.u8(0),
            Some(t) => {
                self.u8(1);
                self.len(t);
            }
        }
    }

    fn metallic_roughness(&mut self, p: &MetallicRoughness) {
        let MetallicRoughness {
            base_color,
            metallic,
            roughness,
            metallic_roughness_texture,
            normal_texture,
            normal_scale,
            occlusion_texture,
            occlusion_strength,
            emissive_texture,
            transmission,
        } = p;
        self.f32s(base_color);
        self.f32(*metallic);
        self.f32(*roughness);
        for t in [
            metallic_roughness_texture,
            normal_texture,
            occlusion_texture,
            emissive_texture,
        ] {
            self.index(*t);
        }
        self.f32(*normal_scale);
        self.f32(*occlusion_strength);
        self.f32(*transmission);
    }

    fn texture(&mut self, t: &Texture) {
        let Texture {
            name: _,
            width,
            height,
            srgb,
            rgba8,
        } = t;
        self.u32(*width);
        self.u32(*height);
        self.u8(*srgb as u8);
        self.bytes(rgba8);
    }

    fn light(&mut self, l: &Light) {
        let Light {
            name: _,
            shape,
            color,
            power,
            range,
            samples,
        } = l;
        match shape {
            LightShape::Point { position } => {
                self.u8(0);
                self.f32s(position);
            }
            LightShape::Spot {
                position,
                direction,
                inner_angle,
                outer_angle,
            } => {
                self.u8(1);
                self.f32s(position);
                self.f32s(direction);
                self.f32(*inner_angle);
                self.f32(*outer_angle);
            }
            LightShape::Directional { direction, angle } => {
                self.u8(2);
                self.f32s(direction);
                self.f32(*angle);
            }
            LightShape::Rect {
                center,
                normal,
                u_axis,
                size,
            } => {
                self.u8(3);
                self.f32s(center);
                self.f32s(normal);
                self.f32s(u_axis);
                self.f32s(size);
            }
            LightShape::Disk {
                center,
                normal,
                radius,
            } => {
                self.u8(4);
                self.f32s(center);
                self.f32s(normal);
                self.f32(*radius);
            }
            LightShape::Sphere { center, radius } => {
                self.u8(5);
                self.f32s(center);
                self.f32(*radius);
            }
            LightShape::EmissiveMesh { mesh } => {
                self.u8(6);
                self.len(*mesh);
            }
            LightShape::Cylinder {
                center,
                axis,
                length,
                radius,
            } => {
                self.u8(7);
                self.f32s(center);
                self.f32s(axis);
                self.f32(*length);
                self.f32(*radius);
            }
        }
        self.f32s(color);
        self.f32(*power);
        self.opt_f32(*range);
        self.u32(*samples);
    }

    fn camera(&mut self, c: &Camera) {
        let Camera {
            position,
            target,
            up,
            fov_y_deg,
            width,
            height,
        } = c;
        self.f32s(position);
        self.f32s(target);
        self.f32s(up);
        self.f32(*fov_y_deg);
        self.u32(*width);
        self.u32(*height);
    }

    fn quality(&mut self, q: &Quality) {
        let Quality {
            samples_per_area_light,
            pattern,
            seed,
            shadow_map_size,
            map_sizing,
            filter,
            depth_bias,
            slope_bias,
            lights_per_node,
            indirect,
            indirect_clamp,
            area_specular,
        } = q;
        match samples_per_area_light {
            None => self.u8(0),
            Some(n) => {
                self.u8(1);
                self.u32(*n);
            }
        }
        self.u8(match pattern {
            SamplePattern::Grid => 0,
            SamplePattern::Jittered => 1,
            SamplePattern::Halton => 2,
        });
        self.u64(*seed);
        self.u32(*shadow_map_size);
        match map_sizing {
            MapSizing::Fixed => self.u8(0),
            MapSizing::Mismatch(m) => {
                self.u8(1);
                self.u32(m.min);
                self.u32(m.max);
                self.f32(m.target);
            }
        }
        match filter {
            ShadowFilter::None => self.u8(0),
            ShadowFilter::Pcf2x2 => self.u8(1),
            ShadowFilter::Pcf { taps } => {
                self.u8(2);
                self.u32(*taps);
            }
            ShadowFilter::Cell { taps } => {
                self.u8(3);
                self.u32(*taps);
            }
        }
        self.f32(*depth_bias);
        self.f32(*slope_bias);
        self.u32(*lights_per_node);
        // Written only when on, so a direct-light scene keeps the content hash it had before
        // indirect light existed.
        if *indirect > 0 {
            self.u8(1);
            self.u32(*indirect);
            match indirect_clamp {
                None => self.u8(0),
                Some(c) => {
                    self.u8(1);
                    self.f32(*c);
                }
            }
        }
        // Likewise only the non-default: point-sampled glossy specular.
        if *area_specular == AreaSpecular::Sampled {
            self.u8(2);
        }
    }

    fn assets(&mut self, meshes: &[Mesh], materials: &[Material], textures: &[Texture]) {
        self.len(meshes.len());
        meshes.iter().for_each(|m| self.mesh(m));
        self.len(materials.len());
        materials.iter().for_each(|m| self.material(m));
        self.len(textures.len());
        textures.iter().for_each(|t| self.texture(t));
    }
}

impl Scene {
    /// SHA-256 over everything that affects rendering: geometry, materials, textures, lights,
    /// camera, ambient, exposure and quality. Names do not count.
    pub fn content_hash(&self) -> [u8; 32] {
        let Scene {
            name: _,
            meshes,
            materials,
            textures,
            lights,
            camera,
            ambient,
            exposure,
            quality,
            animation,
        } = self;
        let mut c = Canon::new("lightfold scene content v1");
        c.assets(meshes, materials, textures);
        c.len(lights.len());
        lights.iter().for_each(|l| c.light(l));
        c.camera(camera);
        c.f32s(ambient);
        c.f32(*exposure);
        c.quality(quality);
        // A still scene hashes as it always did; an animated one adds its animation.
        match animation {
            None => {}
            Some(a) => {
                // Validated animations hold only finite values, so their bincode bytes are
                // canonical.
                c.u8(1);
                let bytes = bincode::serde::encode_to_vec(a, bincode::config::standard())
                    .unwrap_or_default();
                c.bytes(&bytes);
            }
        }
        c.finish()
    }

    /// SHA-256 over meshes, materials and textures only: what a node caches, while lights,
    /// camera and quality travel with every plan.
    pub fn asset_hash(&self) -> [u8; 32] {
        let mut c = Canon::new("lightfold scene assets v1");
        c.assets(&self.meshes, &self.materials, &self.textures);
        c.finish()
    }

    /// The compact wire form: `LFSC`, the format version (u32 LE), then bincode.
    pub fn to_bytes(&self) -> Result<Vec<u8>, SceneError> {
        let mut out = Vec::with_capacity(64 + self.triangle_count() * 48);
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&SCENE_BYTES_VERSION.to_le_bytes());
        let body =
            bincode::serde::encode_to_vec(self, bincode::config::standard()).map_err(|e| {
                SceneError::Encode {
                    scene: self.name.clone(),
                    message: e.to_string(),
                }
            })?;
        out.extend_from_slice(&body);
        Ok(out)
    }

    /// Decodes [`Scene::to_bytes`]; rejects other versions, trailing bytes, more than
    /// [`MAX_SCENE_BYTES`], any scene that does not validate clean and any beyond
    /// [`crate::limits`].
    pub fn from_bytes(bytes: &[u8]) -> Result<Scene, SceneError> {
        let bad = |message: String| SceneError::Decode { message };
        if bytes.len() > MAX_SCENE_BYTES {
            return Err(bad(format!(
                "{} bytes exceed the {MAX_SCENE_BYTES}-byte limit",
                bytes.len()
            )));
        }
        if bytes.len() < 8 || &bytes[..4] != MAGIC {
            return Err(bad("not a lightfold scene (bad magic)".into()));
        }
        let version = u32::from_le_bytes([bytes[4], bytes[5], bytes[6], bytes[7]]);
        if version != SCENE_BYTES_VERSION {
            return Err(bad(format!(
                "format version {version}, this build reads {SCENE_BYTES_VERSION}"
            )));
        }
        let config = bincode::config::standard().with_limit::<MAX_SCENE_BYTES>();
        let (scene, used): (Scene, usize) = bincode::serde::decode_from_slice(&bytes[8..], config)
            .map_err(|e| bad(e.to_string()))?;
        if used != bytes.len() - 8 {
            return Err(bad(format!("{} trailing bytes", bytes.len() - 8 - used)));
        }
        let report = scene.validate();
        if !report.is_clean() {
            return Err(bad(format!(
                "scene {:?} is not clean: {report}",
                scene.name
            )));
        }
        scene
            .check_limits()
            .map_err(|e| bad(format!("scene {:?}: {e}", scene.name)))?;
        Ok(scene)
    }
}
