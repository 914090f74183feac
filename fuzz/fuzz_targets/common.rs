//! Shared by the scene targets: a model folder with one buffer and one image (so relative URIs
//! have something inside the folder to find), and the checks every scene that loads must pass.

use lightfold_scene::Scene;
use lightfold_scene::limits::MAX_LIGHT_SAMPLES;
use lightfold_scene::sampling::direct_samples;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// A folder holding `tri.bin` (three positions and three u16 indices), `tex.png` (2×2),
/// `tri.gltf` (a triangle using both), `tri.mtl` (a material textured with `tex.png`), `tri.usda`
/// (a USD triangle, material and light) and, beside it, `../outside.bin`, `../outside.mtl` and
/// `../outside.usda`.
#[allow(dead_code)]
pub fn folder() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let root = std::env::temp_dir().join(format!("lightfold-fuzz-{}", std::process::id()));
        let dir = root.join("model");
        std::fs::create_dir_all(&dir).unwrap();
        let mut bin = Vec::new();
        for p in [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
            for c in p {
                bin.extend_from_slice(&c.to_le_bytes());
            }
        }
        for i in [0u16, 1, 2, 0] {
            bin.extend_from_slice(&i.to_le_bytes());
        }
        std::fs::write(dir.join("tri.bin"), &bin).unwrap();
        std::fs::write(root.join("outside.bin"), &bin).unwrap();
        image::RgbaImage::from_pixel(2, 2, image::Rgba([200, 100, 50, 255]))
            .save(dir.join("tex.png"))
            .unwrap();
        std::fs::write(dir.join("tri.gltf"), TRI_GLTF).unwrap();
        std::fs::write(dir.join("tri.mtl"), TRI_MTL).unwrap();
        std::fs::write(root.join("outside.mtl"), TRI_MTL).unwrap();
        std::fs::write(dir.join("tri.usda"), TRI_USDA).unwrap();
        std::fs::write(root.join("outside.usda"), TRI_USDA).unwrap();
        dir
    })
}

#[allow(dead_code)]
pub const TRI_GLTF: &str = r#"{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],
"nodes":[{"mesh":0}],"meshes":[{"primitives":[{"attributes":{"POSITION":0},"indices":1,"material":0}]}],
"materials":[{"pbrMetallicRoughness":{"baseColorTexture":{"index":0}}}],
"textures":[{"source":0}],"images":[{"uri":"tex.png"}],
"buffers":[{"uri":"tri.bin","byteLength":44}],
"bufferViews":[{"buffer":0,"byteOffset":0,"byteLength":36},{"buffer":0,"byteOffset":36,"byteLength":6}],
"accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]},
{"bufferView":1,"componentType":5123,"count":3,"type":"SCALAR"}]}"#;

#[allow(dead_code)]
pub const TRI_MTL: &str = "newmtl tri\nKd 0.8 0.4 0.2\nKs 0.5 0.5 0.5\nNs 40\nmap_Kd tex.png\n\
newmtl glow\nKe 2 2 1\nnewmtl glass\nTf 0.9 0.1 0.1\nillum 4\n";

#[allow(dead_code)]
pub const TRI_USDA: &str = r#"#usda 1.0
(
    defaultPrim = "Tri"
)
def Xform "Tri"
{
    def Mesh "Mesh" (prepend apiSchemas = ["MaterialBindingAPI"])
    {
        int[] faceVertexCounts = [3]
        int[] faceVertexIndices = [0, 1, 2]
        point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (0, 1)] (interpolation = "faceVarying")
        uniform token subdivisionScheme = "none"
        rel material:binding = </Tri/Look>
    }
    def Material "Look"
    {
        token outputs:surface.connect = </Tri/Look/Surface.outputs:surface>
        def Shader "Surface"
        {
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor = (0.8, 0.4, 0.2)
            color3f inputs:emissiveColor = (1, 1, 0)
            float inputs:roughness = 0.3
            token outputs:surface
        }
    }
    def RectLight "Key"
    {
        float inputs:intensity = 5
        bool inputs:normalize = 1
        double3 xformOp:translate = (0, 2, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
}
"#;

/// What every loaded scene must satisfy: it validates clean, is within the limits, samples
/// without panicking into at most the limit's samples, and survives the wire form unchanged.
pub fn check_scene(scene: &Scene) {
    assert!(
        scene.validate().is_clean(),
        "loaded but not clean: {}",
        scene.validate()
    );
    if let Err(e) = scene.check_limits() {
        panic!("loaded beyond the limits: {e}");
    }
    let samples = direct_samples(scene);
    assert!(
        samples.len() as u64 <= MAX_LIGHT_SAMPLES,
        "{} samples",
        samples.len()
    );
    let bytes = scene.to_bytes().expect("a loaded scene encodes");
    let back =
        Scene::from_bytes(&bytes).unwrap_or_else(|e| panic!("its wire form is refused: {e}"));
    assert_eq!(
        back.content_hash(),
        scene.content_hash(),
        "the wire form changed it"
    );
}
