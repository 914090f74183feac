//! MTL material libraries → lightfold materials (`docs/scenes.md` § OBJ and MTL).
//!
//! A library is read only inside the model's folder, checked line by line (numbers that parse,
//! names that are there; `Kd 0.5` is read as `Kd 0.5 0.5 0.5`, as the format allows), and only
//! then parsed by `tobj`. The mapping:
//!
//! - `Kd` → diffuse (default 0.8 grey), `map_Kd` → its texture (sRGB, multiplying `Kd`), `Ks` →
//!   specular, `Ns` → the Blinn-Phong exponent (default 32, the scene files'), `Ka` → ambient,
//!   all linear as written;
//! - `Pr` / `Pm` (the PBR extension) make a glTF metallic-roughness material of base colour `Kd`;
//! - `Ke` → emitted radiance: the material becomes one-sided and its meshes emissive-mesh lights;
//! - transparency: `illum` 4, 6, 7 or 9 is glass (a filter of colour `Tf`, else `Kd`); else
//!   `d` < 1 (or `Tr` > 0) is coverage as glTF BLEND (alpha `d`, shadows tinted by `Tf`, else
//!   `Kd`); else a `Tf` other than white or black is a filter; `Tf 1 1 1` on an opaque material
//!   (what many exporters write) is opaque.

use crate::limits::{self, Budget};
use crate::model::{AlphaMode, Material, MetallicRoughness, Texture, Transmission};
use crate::model_file::{decode_texture, read_resolved, resolve_model_path};
use std::cell::RefCell;
use std::collections::{BTreeSet, HashMap, HashSet};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};

/// One `mtllib` statement's materials (several files when it names several), each with the folder
/// (relative to the model's) its texture paths are relative to.
#[derive(Debug)]
struct Library {
    materials: Vec<tobj::Material>,
    names: HashMap<String, usize>,
    folders: Vec<String>,
}

/// Every material library an OBJ names, read and checked before `tobj` reads the OBJ, and served
/// to it by the `mtllib` argument it passes.
#[derive(Debug, Default)]
pub(super) struct Libraries {
    by_arg: HashMap<String, Library>,
    /// Arguments already served: naming a library again adds nothing (its materials are known).
    served: RefCell<HashSet<String>>,
    /// The folder of each material in the order `tobj` merges them.
    order: RefCell<Vec<String>>,
}

impl Libraries {
    pub(super) fn load(
        mtllibs: &[(usize, String)],
        base: Option<&Path>,
        files: &Budget,
        ignored: &mut BTreeSet<String>,
    ) -> Result<Libraries, String> {
        let mut out = Libraries::default();
        let mut materials = 0u64;
        for (line, arg) in mtllibs {
            if out.by_arg.contains_key(arg) {
                continue;
            }
            let at = |m: String| format!("line {line}: mtllib {arg:?}: {m}");
            // One file name, or several separated by spaces (a name may hold spaces itself).
            let parts: Vec<&str> =
                if arg.contains(char::is_whitespace) && resolve_model_path(base, arg).is_err() {
                    arg.split_whitespace().collect()
                } else {
                    vec![arg.as_str()]
                };
            let mut lib = Library {
                materials: Vec::new(),
                names: HashMap::new(),
                folders: Vec::new(),
            };
            for part in parts {
                let path = resolve_model_path(base, part).map_err(at)?;
                let bytes = read_resolved(&path, files).map_err(at)?;
                let text =
                    check(&bytes, ignored).map_err(|m| at(format!("{}: {m}", path.display())))?;
                materials += text.1;
                limits::check_count("materials", materials, limits::MAX_MODEL_MATERIALS)
                    .map_err(|e| at(format!("{e} (see `lightfold defaults`)")))?;
                let parsed = catch_unwind(AssertUnwindSafe(|| {
                    tobj::load_mtl_buf(&mut std::io::Cursor::new(text.0.as_bytes()))
                }))
                .map_err(|_| at(format!("{}: the MTL reader panicked", path.display())))?;
                let (mats, names) = parsed
                    .map_err(|e| at(format!("{}: the MTL reader failed: {e}", path.display())))?;
                let folder = folder_of(part);
                let offset = lib.materials.len();
                lib.folders.extend(std::iter::repeat_n(folder, mats.len()));
                lib.materials.extend(mats);
                for (name, i) in names {
                    lib.names.insert(name, i + offset);
                }
            }
            out.by_arg.insert(arg.clone(), lib);
        }
        Ok(out)
    }

    /// What `tobj` gets for a `mtllib` statement.
    pub(super) fn get(&self, p: &Path) -> tobj::MTLLoadResult {
        let key = p.to_string_lossy().into_owned();
        let empty = || Ok((Vec::new(), HashMap::new()));
        if !self.served.borrow_mut().insert(key.clone()) {
            return empty();
        }
        match self.by_arg.get(&key) {
            Some(lib) => {
                self.order.borrow_mut().extend(lib.folders.iter().cloned());
                Ok((lib.materials.clone(), lib.names.clone()))
            }
            None => empty(),
        }
    }

    /// The folder material `i` (of the list `tobj` returns) reads its textures in.
    pub(super) fn folder_of(&self, i: usize) -> String {
        self.order.borrow().get(i).cloned().unwrap_or_default()
    }
}

/// The folder part of a relative path as written (`mats/a.mtl` → `mats/`; backslashes read as
/// separators).
fn folder_of(relative: &str) -> String {
    let rel = relative.replace('\\', "/");
    match rel.rfind('/') {
        Some(k) => rel[..=k].to_string(),
        None => String::new(),
    }
}

/// Checks an MTL's text line by line and returns what `tobj` may read of it (one-number colours
/// written out as three, spectral colours and halo dissolves dropped) and its material count.
fn check(bytes: &[u8], ignored: &mut BTreeSet<String>) -> Result<(String, u64), String> {
    let mut out = String::with_capacity(bytes.len());
    let mut materials = 0u64;
    let mut unknown = 0usize;
    for (k, raw) in bytes.split(|&b| b == b'\n').enumerate() {
        let line_no = k + 1;
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        let line =
            std::str::from_utf8(raw).map_err(|_| format!("line {line_no}: not UTF-8 text"))?;
        let bad = |m: String| format!("line {line_no}: {m}");
        let mut words = line.split_whitespace();
        let Some(keyword) = words.next() else {
            continue;
        };
        let args: Vec<&str> = words.collect();
        let number = |w: &str| {
            w.parse::<f32>()
                .map_err(|_| bad(format!("{w:?} in `{keyword}` is not a number")))
        };
        match keyword {
            "newmtl" => {
                if args.is_empty() {
                    return Err(bad("`newmtl` without a name".into()));
                }
                materials += 1;
            }
            "Ka" | "Kd" | "Ks" | "Ke" | "Tf" => {
                if matches!(args.first(), Some(&"spectral" | &"xyz")) {
                    ignored.insert("spectral and CIEXYZ colours".into());
                    continue;
                }
                let values = args
                    .iter()
                    .map(|w| number(w))
                    .collect::<Result<Vec<_>, _>>()?;
                match values[..] {
                    [v] => {
                        out.push_str(&format!("{keyword} {v} {v} {v}\n"));
                        continue;
                    }
                    [_, _, _] => {}
                    _ => {
                        return Err(bad(format!(
                            "`{keyword}` has {} numbers (1 or 3 expected)",
                            values.len()
                        )));
                    }
                }
            }
            "Ns" | "Ni" | "d" | "Tr" | "Pr" | "Pm" | "sharpness" => {
                if keyword == "d" && args.first() == Some(&"-halo") {
                    ignored.insert("halo dissolve (d -halo)".into());
                    continue;
                }
                match args[..] {
                    [w] => {
                        number(w)?;
                    }
                    _ => return Err(bad(format!("`{keyword}` needs one number"))),
                }
            }
            "illum" => match args[..] {
                [w] if w.parse::<u8>().is_ok() => {}
                _ => return Err(bad("`illum` needs a model number 0 to 10".into())),
            },
            k if k.starts_with("map_")
                || matches!(k, "bump" | "disp" | "decal" | "refl" | "norm") =>
            {
                if args.is_empty() {
                    return Err(bad(format!("`{keyword}` without a file name")));
                }
            }
            k if k.starts_with('#') => continue,
            "Ps" | "Pc" | "Pcr" | "aniso" | "anisor" => {}
            _ => {
                unknown += 1;
                if unknown <= 8 {
                    let name: String = keyword.chars().take(32).collect();
                    ignored.insert(format!("unknown material statement {name:?}"));
                } else {
                    ignored.insert("further unknown material statements".into());
                }
                continue;
            }
        }
        out.push_str(line);
        out.push('\n');
    }
    Ok((out, materials))
}

/// Converts the materials an OBJ's meshes use and decodes the textures they name (each file
/// once).
pub(super) struct Converter<'a> {
    base: Option<&'a Path>,
    files: &'a Budget,
    decoded: &'a Budget,
    ignored: &'a mut BTreeSet<String>,
    textures: Vec<Texture>,
    cache: HashMap<PathBuf, usize>,
}

impl<'a> Converter<'a> {
    pub(super) fn new(
        base: Option<&'a Path>,
        files: &'a Budget,
        decoded: &'a Budget,
        ignored: &'a mut BTreeSet<String>,
    ) -> Self {
        Converter {
            base,
            files,
            decoded,
            ignored,
            textures: Vec::new(),
            cache: HashMap::new(),
        }
    }

    pub(super) fn ignored_mut(&mut self) -> &mut BTreeSet<String> {
        self.ignored
    }

    pub(super) fn into_textures(self) -> Vec<Texture> {
        self.textures
    }

    pub(super) fn convert(
        &mut self,
        m: &tobj::Material,
        folder: String,
    ) -> Result<Material, String> {
        let at = |e: String| format!("material {:?}: {e}", m.name);
        let param = |key: &str| -> Option<Vec<f32>> {
            m.unknown_param.get(key).map(|v| {
                v.split_whitespace()
                    .filter_map(|w| w.parse::<f32>().ok())
                    .collect()
            })
        };
        let one = |key: &str| param(key).and_then(|v| v.first().copied());
        let three = |key: &str| param(key).and_then(|v| (v.len() >= 3).then(|| [v[0], v[1], v[2]]));
        for key in m.unknown_param.keys() {
            let what = match key.as_str() {
                "Tf" | "Tr" | "Pr" | "Pm" => continue,
                "Ps" | "Pc" | "Pcr" | "aniso" | "anisor" => {
                    "sheen, clearcoat and anisotropy (Ps, Pc, Pcr, aniso, anisor)".to_string()
                }
                "sharpness" => "reflection sharpness".to_string(),
                k => format!("textures other than map_Kd ({k})"),
            };
            self.ignored.insert(what);
        }
        for (texture, key) in [
            (&m.ambient_texture, "map_Ka"),
            (&m.specular_texture, "map_Ks"),
            (&m.normal_texture, "bump"),
            (&m.shininess_texture, "map_Ns"),
            (&m.dissolve_texture, "map_d"),
        ] {
            if texture.is_some() {
                self.ignored
                    .insert(format!("textures other than map_Kd ({key})"));
            }
        }
        if m.optical_density.is_some() {
            self.ignored.insert("index of refraction (Ni)".into());
        }
        let kd = m.diffuse.unwrap_or([0.8; 3]);
        let ke = m.emissive.unwrap_or([0.0; 3]);
        let tf = three("Tf");
        let d = m
            .dissolve
            .or_else(|| one("Tr").map(|t| 1.0 - t))
            .unwrap_or(1.0);
        let glass = matches!(m.illumination_model, Some(4 | 6 | 7 | 9));
        let (alpha, alpha_mode, transmission) = if glass {
            let color = tf.unwrap_or(kd).map(|c| c.clamp(0.0, 1.0));
            (
                1.0,
                AlphaMode::Opaque,
                Some(Transmission {
                    color,
                    coverage: false,
                }),
            )
        } else if d < 1.0 {
            let color = tf.unwrap_or(kd).map(|c| c.clamp(0.0, 1.0));
            (
                d.clamp(0.0, 1.0),
                AlphaMode::Mask { cutoff: 0.5 },
                Some(Transmission {
                    color,
                    coverage: true,
                }),
            )
        } else {
            match tf {
                Some(t) if t != [1.0; 3] && t.iter().any(|&c| c > 0.0) => (
                    1.0,
                    AlphaMode::Opaque,
                    Some(Transmission {
                        color: t.map(|c| c.clamp(0.0, 1.0)),
                        coverage: false,
                    }),
                ),
                _ => (1.0, AlphaMode::Opaque, None),
            }
        };
        let diffuse_texture = match &m.diffuse_texture {
            Some(spec) => Some(self.texture(spec, &folder).map_err(at)?),
            None => None,
        };
        let emissive = ke.iter().any(|&c| c > 0.0);
        let (pr, pm) = (one("Pr"), one("Pm"));
        let base = if pr.is_some() || pm.is_some() {
            // Without `Pr`, the roughness whose Beckmann-matched exponent is `Ns` (1 without).
            let roughness = pr.unwrap_or_else(|| {
                m.shininess
                    .map_or(1.0, |ns| (2.0 / (ns.max(0.0) + 2.0)).sqrt().sqrt())
            });
            let pbr = MetallicRoughness::new(kd, pm.unwrap_or(0.0).clamp(0.0, 1.0), roughness);
            Material::metallic_roughness(&m.name, pbr)
        } else {
            Material {
                specular: m.specular.unwrap_or([0.0; 3]),
                shininess: m.shininess.unwrap_or(32.0),
                ..Material::diffuse(&m.name, kd)
            }
        };
        Ok(Material {
            diffuse_texture,
            ambient: if base.pbr.is_some() {
                base.ambient
            } else {
                m.ambient.unwrap_or([0.0; 3])
            },
            emissive: ke,
            alpha,
            alpha_mode,
            double_sided: !emissive,
            transmission,
            ..base
        })
    }

    /// The texture a `map_Kd` statement names (its options, such as `-s` or `-clamp`, are
    /// reported and not applied), relative to its library's `folder`.
    fn texture(&mut self, spec: &str, folder: &str) -> Result<usize, String> {
        let (file, options) = texture_file(spec);
        if options {
            self.ignored
                .insert("texture options (-o, -s, -clamp, …)".into());
        }
        if file.is_empty() {
            return Err(format!("map_Kd {spec:?} names no file"));
        }
        let relative = format!("{folder}{file}");
        let path = resolve_model_path(self.base, &relative).map_err(|e| format!("map_Kd: {e}"))?;
        if let Some(&k) = self.cache.get(&path) {
            return Ok(k);
        }
        let bytes = read_resolved(&path, self.files).map_err(|e| format!("map_Kd: {e}"))?;
        let image = decode_texture(&bytes, file, self.decoded)?;
        self.textures.push(Texture {
            name: file.to_string(),
            width: image.width(),
            height: image.height(),
            srgb: true,
            rgba8: image.into_raw(),
        });
        let k = self.textures.len() - 1;
        self.cache.insert(path, k);
        Ok(k)
    }
}

/// The file name of a texture statement's argument and whether options came before it. Options
/// take a fixed number of arguments, except `-o`, `-s` and `-t` which take one to three numbers.
fn texture_file(spec: &str) -> (&str, bool) {
    let mut rest = spec.trim();
    let mut options = false;
    while rest.starts_with('-') {
        let (option, after) = split_word(rest);
        let args = match option {
            "-blendu" | "-blendv" | "-bm" | "-boost" | "-cc" | "-clamp" | "-imfchan"
            | "-texres" | "-type" => 1,
            "-mm" => 2,
            "-o" | "-s" | "-t" => 3,
            _ => break,
        };
        options = true;
        rest = after;
        for k in 0..args {
            let (word, after) = split_word(rest);
            // -o, -s and -t take one to three numbers: stop at the first that is not one.
            if k > 0 && matches!(option, "-o" | "-s" | "-t") && word.parse::<f32>().is_err() {
                break;
            }
            rest = after;
        }
    }
    (rest.trim(), options)
}

fn split_word(s: &str) -> (&str, &str) {
    let s = s.trim_start();
    match s.find(char::is_whitespace) {
        Some(k) => (&s[..k], s[k..].trim_start()),
        None => (s, ""),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texture_options_are_skipped() {
        assert_eq!(texture_file("wood.png"), ("wood.png", false));
        assert_eq!(texture_file("my wood.png"), ("my wood.png", false));
        assert_eq!(
            texture_file("-s 2 2 1 -clamp on wood.png"),
            ("wood.png", true)
        );
        assert_eq!(texture_file("-o 0.5 wood.png"), ("wood.png", true));
        assert_eq!(texture_file("-mm 0 1 a b.png"), ("a b.png", true));
        assert_eq!(texture_file("-s 1 1"), ("", true));
    }

    #[test]
    fn libraries_are_checked_line_by_line() {
        let mut ignored = BTreeSet::new();
        let (text, n) = check(
            b"newmtl a\nKd 0.5\nKs spectral x.rfl\nTf 1 0 0\n",
            &mut ignored,
        )
        .unwrap();
        assert_eq!(n, 1);
        assert!(text.contains("Kd 0.5 0.5 0.5"), "{text}");
        assert!(!text.contains("spectral"), "{text}");
        assert!(ignored.contains("spectral and CIEXYZ colours"));
        let e = check(b"newmtl a\nKd 1 2\n", &mut ignored).unwrap_err();
        assert!(e.contains("line 2") && e.contains("1 or 3 expected"), "{e}");
        let e = check(b"newmtl a\nNs\n", &mut ignored).unwrap_err();
        assert!(e.contains("`Ns` needs one number"), "{e}");
        let e = check(b"newmtl\n", &mut ignored).unwrap_err();
        assert!(e.contains("without a name"), "{e}");
        let e = check(b"newmtl a\nmap_Kd\n", &mut ignored).unwrap_err();
        assert!(e.contains("without a file name"), "{e}");
        let e = check(b"newmtl a\nKd x 1 1\n", &mut ignored).unwrap_err();
        assert!(e.contains("not a number"), "{e}");
    }
}
