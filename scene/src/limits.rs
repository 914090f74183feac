//! Limits on what a scene may hold and read, named once. Every place that takes a scene or a
//! size from a user checks these: the CLI (`--size`, `--samples`, `--shadow-map-size`), scene
//! files, glTF and GLB models, `Scene::from_bytes` over the network and the node's configuration
//! check. `lightfold defaults` prints them.
//!
//! Why these numbers:
//! - **Image** 8192 per side and 4096 × 4096 pixels in all: what one node renders on lavapipe
//!   (its 128 MiB storage-binding limit takes the deferred pass to 2048 × 2048; larger images
//!   fall back to the forward pass, which renders 4096 × 4096 in about 4 GB) and 16 M pixels keep
//!   the coordinator's f32 frame at 200 MB. A device with smaller limits refuses what it cannot
//!   allocate with an error naming the limit.
//! - **Shadow maps** 4096²: the planner's largest size (`plan::MAX_MAP_SIZE`) and the largest
//!   the accuracy sweep uses; a 4096² layer is 64 MiB.
//! - **Samples** 4096 per area light (a 64 × 64 grid, 16× the most any shipped scene uses) and
//!   16384 in all: a plan of 16384 samples is under 1 MB and the exact CPU reference over them
//!   stays finite; at K = 4 it is already 4096 render nodes.
//! - **Triangles** 10 M: 1.4 GB of vertices on the device (the renderer expands indices), the
//!   most a 1 GiB scene of indexed triangles holds in practice.
//! - **Model files** (OBJ, PLY): at most 3 positions per triangle of the limit (30 M), and at
//!   most 65 536 meshes and 65 536 materials from one file: every count is read from the file
//!   before anything is kept, so a few bytes that declare billions are refused, never allocated.
//! - **Bytes** 1 GiB for the files of one scene together (model, buffers, images), 1 GiB for
//!   what they decode to (accessors, textures), and 1 GiB for the wire form; 16 MiB for a TOML
//!   scene file; textures at most 8192 per side.

/// Most bytes one scene may read from its files together (glTF/GLB, buffers, images), decode
/// (accessors, textures) and take on the wire (`Scene::to_bytes`).
pub const MAX_SCENE_BYTES: u64 = 1 << 30;
/// Largest TOML scene file.
pub const MAX_SCENE_FILE_BYTES: u64 = 16 << 20;
/// Most triangles in one scene.
pub const MAX_TRIANGLES: u64 = 10_000_000;
/// Most vertices (positions, and each of texture coordinates and normals) one OBJ or PLY model
/// may declare: three per triangle of [`MAX_TRIANGLES`].
pub const MAX_VERTICES: u64 = 3 * MAX_TRIANGLES;
/// Most meshes one OBJ model makes (its groups and objects, split where the material changes).
pub const MAX_MODEL_MESHES: u64 = 65_536;
/// Most materials one OBJ model's material libraries define together.
pub const MAX_MODEL_MATERIALS: u64 = 65_536;
/// Largest side of a decoded texture.
pub const MAX_TEXTURE_SIDE: u32 = 8192;
/// Most point samples one area light may ask for (its `samples` or the scene's
/// `samples_per_area_light`).
pub const MAX_SAMPLES_PER_AREA_LIGHT: u32 = 4096;
/// Most point samples of a whole scene (every light together).
pub const MAX_LIGHT_SAMPLES: u64 = 16_384;
/// Widest soft sun: a directional light's apparent angular diameter, radians (90°; wider
/// sources are not distant lights).
pub const MAX_SUN_ANGLE: f32 = std::f32::consts::FRAC_PI_2;
/// Largest image side.
pub const MAX_IMAGE_SIDE: u32 = 8192;
/// Most pixels of one image (4096 × 4096).
pub const MAX_IMAGE_PIXELS: u64 = 4096 * 4096;
/// Largest shadow-map size (per side).
pub const MAX_SHADOW_MAP_SIZE: u32 = 4096;

/// A value beyond one of the limits above.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LimitError {
    #[error(
        "image {width}x{height} is too large: at most {MAX_IMAGE_SIDE} per side and \
         {MAX_IMAGE_PIXELS} pixels (4096x4096) in all"
    )]
    ImageSize { width: u32, height: u32 },
    #[error("image {width}x{height}: width and height must be at least 1")]
    EmptyImage { width: u32, height: u32 },
    #[error("shadow-map size {0} is outside 1..={MAX_SHADOW_MAP_SIZE}")]
    ShadowMapSize(u32),
    #[error(
        "{what} asks for {samples} samples per area light; the limit is \
         {MAX_SAMPLES_PER_AREA_LIGHT}"
    )]
    SamplesPerLight { what: String, samples: u32 },
    #[error(
        "{samples} light samples in all (virtual point lights included); a scene may have at \
         most {MAX_LIGHT_SAMPLES}"
    )]
    TotalSamples { samples: u64 },
    #[error("{triangles} triangles; a scene may have at most {MAX_TRIANGLES}")]
    Triangles { triangles: u64 },
    #[error("{count} {what}; a model may have at most {limit}")]
    Count {
        what: &'static str,
        count: u64,
        limit: u64,
    },
    #[error("{what} take {bytes} bytes; a scene may hold at most {MAX_SCENE_BYTES}")]
    Bytes { what: &'static str, bytes: u64 },
}

/// Checks an image size against [`MAX_IMAGE_SIDE`] and [`MAX_IMAGE_PIXELS`].
pub fn check_image_size(width: u32, height: u32) -> Result<(), LimitError> {
    if width == 0 || height == 0 {
        return Err(LimitError::EmptyImage { width, height });
    }
    if width > MAX_IMAGE_SIDE
        || height > MAX_IMAGE_SIDE
        || u64::from(width) * u64::from(height) > MAX_IMAGE_PIXELS
    {
        return Err(LimitError::ImageSize { width, height });
    }
    Ok(())
}

/// Checks a shadow-map size against [`MAX_SHADOW_MAP_SIZE`].
pub fn check_shadow_map_size(size: u32) -> Result<(), LimitError> {
    if size == 0 || size > MAX_SHADOW_MAP_SIZE {
        return Err(LimitError::ShadowMapSize(size));
    }
    Ok(())
}

/// Checks a per-area-light sample count (`what` names where it came from).
pub fn check_samples_per_area_light(what: &str, samples: u32) -> Result<(), LimitError> {
    if samples > MAX_SAMPLES_PER_AREA_LIGHT {
        return Err(LimitError::SamplesPerLight {
            what: what.to_string(),
            samples,
        });
    }
    Ok(())
}

/// Checks a running triangle count against [`MAX_TRIANGLES`].
pub fn check_triangles(triangles: u64) -> Result<(), LimitError> {
    if triangles > MAX_TRIANGLES {
        return Err(LimitError::Triangles { triangles });
    }
    Ok(())
}

/// Checks a count a model file declares (`what`: "vertices", "meshes", …) against `limit`.
pub fn check_count(what: &'static str, count: u64, limit: u64) -> Result<(), LimitError> {
    if count > limit {
        return Err(LimitError::Count { what, count, limit });
    }
    Ok(())
}

/// Parses `WIDTHxHEIGHT` (or `X`) and checks it against the image limits.
pub fn parse_image_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("size {s:?} is not WIDTHxHEIGHT"))?;
    let side = |v: &str| {
        v.trim()
            .parse::<u32>()
            .map_err(|e| format!("size {s:?}: {v:?} is not a whole number of pixels ({e})"))
    };
    let (w, h) = (side(w)?, side(h)?);
    check_image_size(w, h).map_err(|e| format!("size {s:?}: {e}"))?;
    Ok((w, h))
}

impl crate::model::Scene {
    /// Checks the scene against every limit of this module: image size, shadow-map size,
    /// samples per area light and in all, triangles, and the bytes of its meshes and textures.
    pub fn check_limits(&self) -> Result<(), LimitError> {
        check_image_size(self.camera.width, self.camera.height)?;
        check_shadow_map_size(self.quality.shadow_map_size)?;
        if let crate::model::MapSizing::Mismatch(m) = self.quality.map_sizing {
            check_shadow_map_size(m.min)?;
            check_shadow_map_size(m.max)?;
        }
        match self.quality.samples_per_area_light {
            Some(n) => check_samples_per_area_light("quality.samples_per_area_light", n)?,
            None => {
                for l in self.lights.iter().filter(|l| l.is_area()) {
                    check_samples_per_area_light(&format!("light {:?}", l.name), l.samples)?;
                }
            }
        }
        let samples = self.sample_count() as u64 + u64::from(self.quality.indirect);
        if samples > MAX_LIGHT_SAMPLES {
            return Err(LimitError::TotalSamples { samples });
        }
        check_triangles(self.triangle_count() as u64)?;
        let mesh_bytes: u64 = self
            .meshes
            .iter()
            .map(|m| {
                (m.positions.len() as u64 + m.normals.len() as u64) * 12
                    + m.uvs.len() as u64 * 8
                    + m.tangents.len() as u64 * 16
                    + m.indices.len() as u64 * 4
            })
            .sum();
        let texture_bytes: u64 = self.textures.iter().map(|t| t.rgba8.len() as u64).sum();
        let bytes = mesh_bytes + texture_bytes;
        if bytes > MAX_SCENE_BYTES {
            return Err(LimitError::Bytes {
                what: "meshes and textures",
                bytes,
            });
        }
        Ok(())
    }
}

/// A running budget of bytes (files read, or data decoded) for one scene load.
#[derive(Debug)]
pub(crate) struct Budget {
    what: &'static str,
    left: std::cell::Cell<u64>,
}

impl Budget {
    pub(crate) fn new(what: &'static str) -> Budget {
        Budget {
            what,
            left: std::cell::Cell::new(MAX_SCENE_BYTES),
        }
    }

    /// Bytes still allowed.
    pub(crate) fn left(&self) -> u64 {
        self.left.get()
    }

    /// Takes `bytes` from the budget, or says which limit they break.
    pub(crate) fn take(&self, bytes: u64) -> Result<(), LimitError> {
        let left = self.left.get();
        if bytes > left {
            return Err(LimitError::Bytes {
                what: self.what,
                bytes: MAX_SCENE_BYTES - left + bytes,
            });
        }
        self.left.set(left - bytes);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_sizes() {
        assert!(check_image_size(800, 600).is_ok());
        assert!(check_image_size(4096, 4096).is_ok());
        assert!(check_image_size(8192, 2048).is_ok());
        assert_eq!(
            check_image_size(8192, 2049),
            Err(LimitError::ImageSize {
                width: 8192,
                height: 2049
            })
        );
        assert!(check_image_size(8193, 1).is_err());
        assert!(check_image_size(0, 1).is_err());
        assert!(
            parse_image_size("16384x16384")
                .unwrap_err()
                .contains("too large")
        );
        assert!(
            parse_image_size("100000x100000")
                .unwrap_err()
                .contains("at most 8192")
        );
        assert_eq!(parse_image_size("640X480"), Ok((640, 480)));
        assert!(
            parse_image_size("640")
                .unwrap_err()
                .contains("WIDTHxHEIGHT")
        );
        assert!(parse_image_size("99999999999x1").is_err());
    }

    #[test]
    fn budgets() {
        let b = Budget::new("files");
        b.take(MAX_SCENE_BYTES - 10).unwrap();
        assert_eq!(b.left(), 10);
        let e = b.take(11).unwrap_err();
        assert_eq!(
            e.to_string(),
            format!(
                "files take {} bytes; a scene may hold at most {MAX_SCENE_BYTES}",
                MAX_SCENE_BYTES + 1
            )
        );
        b.take(10).unwrap();
    }
}
