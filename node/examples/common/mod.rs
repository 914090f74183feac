//! What the node's measuring examples share: their arguments — the scene (a built-in name, by
//! `--scene NAME` or alone), `--size WxH`, `--frames N`, and the flags of each example's own
//! that take a value — and the scene at that size.

use anyhow::{Context, bail};

/// An example's arguments.
pub(crate) struct Args {
    pub(crate) scene: String,
    pub(crate) frames: u32,
    pub(crate) size: (u32, u32),
    /// The example's own flags (those named in [`parse`]'s `own`), by flag, last value kept.
    pub(crate) own: Vec<(&'static str, String)>,
}

impl Args {
    /// The value of the example's own flag `flag`, parsed, or `default`.
    #[allow(dead_code)] // not every example has flags of its own
    pub(crate) fn get<T: std::str::FromStr>(&self, flag: &str, default: T) -> anyhow::Result<T>
    where
        T::Err: std::error::Error + Send + Sync + 'static,
    {
        match self.own.iter().rev().find(|(f, _)| *f == flag) {
            Some((_, v)) => v.parse().with_context(|| format!("{flag} {v}")),
            None => Ok(default),
        }
    }

    /// The built-in scene at the size asked for.
    pub(crate) fn builtin_scene(&self) -> anyhow::Result<lightfold_scene::Scene> {
        let mut scene = lightfold_scene::builtin(&self.scene)?;
        scene.camera.width = self.size.0;
        scene.camera.height = self.size.1;
        Ok(scene)
    }
}

/// The process's arguments, with these defaults; `own` lists the example's flags that take a
/// value. An unknown flag is an error.
pub(crate) fn parse(
    scene: &str,
    size: (u32, u32),
    frames: u32,
    own: &[&'static str],
) -> anyhow::Result<Args> {
    let mut out = Args {
        scene: scene.to_string(),
        frames,
        size,
        own: Vec::new(),
    };
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().with_context(|| format!("{a} needs a value"));
        match a.as_str() {
            "--frames" => out.frames = value()?.parse().context("--frames N")?,
            "--scene" => out.scene = value()?,
            "--size" => {
                out.size = lightfold_scene::limits::parse_image_size(&value()?)
                    .map_err(|e| anyhow::anyhow!("--size WxH: {e}"))?
            }
            flag if flag.starts_with("--") => match own.iter().find(|f| **f == flag) {
                Some(f) => out.own.push((f, value()?)),
                None => bail!("unknown argument {flag}"),
            },
            name => out.scene = name.to_string(),
        }
    }
    Ok(out)
}

/// The city's street-level view (`docs/scaling.md` § Eye-pass culling, § Occlusion culling): at
/// eye height looking down one street, most of the city out of view or behind its first
/// buildings; `camera`'s image size.
#[allow(dead_code)] // not every example looks down the street
pub(crate) fn street_camera(camera: &lightfold_scene::Camera) -> lightfold_scene::Camera {
    let mut street = *camera;
    street.position = [0.5, 1.7, 0.5];
    street.target = [40.0, 1.7, 0.5];
    street.fov_y_deg = 50.0;
    street
}
