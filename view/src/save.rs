//! The session saved as a scene file (`GET /scene.toml`): the scene the session started from as
//! its `[base]`, with the camera, exposure and lights as the viewers left them
//! (`lightfold_scene::file::save`), so that `lightfold render --scene` of it renders the frame
//! the view shows.

use crate::camera::Steer;
use lightfold_scene::file::save::session_file;
use lightfold_scene::{Scene, builtin::is_builtin};
use std::path::Path;

/// What a saved session names as its base, given how the session's scene was named (a
/// built-in, or a file's path): a built-in's name, or the file's name — the saved file is read
/// beside it. A saved session (a file over a base, with nothing of its own but camera, lights
/// and settings) names its own base, so saving again does not nest. `Err`: why it cannot be
/// saved.
pub(crate) fn base_of(source: Option<&str>) -> Result<String, String> {
    let source = source.ok_or("the view was not told how its scene was named")?;
    if is_builtin(source) {
        return Ok(source.to_string());
    }
    let path = Path::new(source);
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .ok_or_else(|| format!("{source:?} names no file"))?;
    let toml = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("toml"));
    if !toml {
        return Ok(name);
    }
    let file = lightfold_scene::file::read_scene_file(path).map_err(|e| e.to_string())?;
    match file.base {
        None => Ok(name),
        Some(b)
            if file.objects.is_empty()
                && file.materials.is_empty()
                && file.motions.is_empty()
                && file.moves.is_empty() =>
        {
            Ok(b.scene)
        }
        Some(_) => Err(format!(
            "{source} builds on a base and adds objects of its own; a saved session over it \
             would be a base two levels deep"
        )),
    }
}

/// The scene without its geometry, textures or animation: names, materials and settings (what a
/// saved session's lights and settings are written from; mesh names name mesh lights' objects).
pub(crate) fn skeleton(scene: &Scene) -> Scene {
    Scene {
        name: scene.name.clone(),
        meshes: scene
            .meshes
            .iter()
            .map(|m| lightfold_scene::Mesh {
                name: m.name.clone(),
                positions: Vec::new(),
                normals: Vec::new(),
                uvs: Vec::new(),
                tangents: Vec::new(),
                indices: Vec::new(),
                material: m.material,
            })
            .collect(),
        materials: scene.materials.clone(),
        textures: Vec::new(),
        lights: Vec::new(),
        camera: scene.camera,
        ambient: scene.ambient,
        exposure: scene.exposure,
        quality: scene.quality,
        animation: None,
    }
}

/// The saved session's TOML: `skeleton`'s settings, with the steering's camera and lights (each
/// light's colour and power as the viewers set them) and the view's exposure (`stops`).
pub(crate) fn session_toml(
    skeleton: &Scene,
    steer: &Steer,
    stops: f32,
    base: &str,
) -> Result<String, String> {
    let mut s = skeleton.clone();
    s.camera = steer.camera;
    s.exposure = 2f32.powf(stops);
    s.lights = steer
        .scene_lights
        .iter()
        .zip(&steer.lights)
        .map(|(l, set)| lightfold_scene::Light {
            color: set.color,
            power: l.power * set.intensity,
            ..l.clone()
        })
        .collect();
    let mut file = session_file(&s, base)?;
    file.moves = steer.moves.to_vec();
    lightfold_scene::file::to_toml(&file).map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_saved_session_names_a_base_one_level_deep() {
        assert_eq!(base_of(Some("balls")).unwrap(), "balls");
        assert_eq!(base_of(Some("/data/models/fox.glb")).unwrap(), "fox.glb");
        assert!(base_of(None).is_err());
        let dir = tempfile::tempdir().unwrap();
        let write = |name: &str, text: &str| {
            let p = dir.path().join(name);
            std::fs::write(&p, text).unwrap();
            p.display().to_string()
        };
        let plain = write("room.toml", "version = 1\n");
        assert_eq!(base_of(Some(&plain)).unwrap(), "room.toml");
        // A saved session names its own base, so saving it again does not nest.
        let session = write(
            "session.toml",
            "version = 1\n[base]\nscene = \"room.toml\"\n[[light]]\ntype = \"point\"\n\
             position = [0.0, 1.0, 0.0]\nintensity = 1.0\n",
        );
        assert_eq!(base_of(Some(&session)).unwrap(), "room.toml");
        // A file over a base with objects of its own cannot be a base itself.
        let built = write(
            "built.toml",
            "version = 1\n[base]\nscene = \"room.toml\"\n[[object]]\ntype = \"box\"\n\
             center = [0.0, 0.5, 0.0]\nsize = [1.0, 1.0, 1.0]\n",
        );
        let e = base_of(Some(&built)).unwrap_err();
        assert!(e.contains("two levels deep"), "{e}");
    }

    #[test]
    fn the_session_file_folds_the_viewers_settings_into_its_lights() {
        let scene = lightfold_scene::builtin("balls").unwrap();
        let mut steer = Steer::new(&scene);
        steer.set_light(0, [0.2, 0.4, 0.8], 2.0).unwrap();
        let text = session_toml(&skeleton(&scene), &steer, 1.0, "balls").unwrap();
        let saved = lightfold_scene::parse_scene_file(&text, "session.toml", None).unwrap();
        assert_eq!(saved.lights[0].color, [0.2, 0.4, 0.8]);
        assert_eq!(saved.lights[0].power, scene.lights[0].power * 2.0);
        assert_eq!(saved.lights[1], scene.lights[1]);
        assert_eq!(saved.exposure, 2.0, "one stop up");
        assert_eq!(saved.meshes, scene.meshes, "the base's geometry");
    }
}
