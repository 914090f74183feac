//! The model is the crate's ground floor: `src/model/` names no other module of the crate
//! (doc links apart), so every loader, the sampler, the shading maths and the GPU node build on
//! it and it on nothing of theirs.

use std::path::Path;

/// The lines of `text` (a Rust source) that reach into another module of the crate: a path
/// through `crate::` or `super::` outside comments, other than `crate::model` itself.
fn upward_paths(text: &str) -> Vec<String> {
    text.lines()
        .map(|l| l.split("//").next().unwrap_or(""))
        .filter(|code| {
            let reaches = |p: &str| {
                code.match_indices(p)
                    .any(|(i, _)| !code[i..].starts_with("crate::model"))
            };
            reaches("crate::") || code.contains("super::super::")
        })
        .map(str::to_string)
        .collect()
}

#[test]
fn the_model_depends_on_no_other_module_of_the_crate() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/model");
    let mut files = 0;
    for entry in std::fs::read_dir(&dir).expect("scene/src/model") {
        let path = entry.expect("entry").path();
        if path.extension().is_some_and(|e| e == "rs") {
            let text = std::fs::read_to_string(&path).expect("model source");
            let found = upward_paths(&text);
            assert!(found.is_empty(), "{} reaches up: {found:?}", path.display());
            files += 1;
        }
    }
    assert!(files >= 2, "found {files} model files in {}", dir.display());
}

#[test]
fn the_check_finds_a_path_into_another_module() {
    // Negative control: what the model once held (its Quality default from `defaults`, a
    // shading helper in a material constructor) is found; doc links and the model's own
    // paths are not.
    let before = "impl Default for Quality {\n    fn default() -> Self {\n        crate::defaults::quality()\n    }\n}\n";
    assert_eq!(upward_paths(before).len(), 1);
    assert_eq!(
        upward_paths("    shininess: crate::shading::shininess_from_roughness(r),").len(),
        1
    );
    assert!(upward_paths("/// See [`crate::shading::transmittance`].").is_empty());
    assert!(upward_paths("use crate::model::keyframes::Animation;").is_empty());
}
