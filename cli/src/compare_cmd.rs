//! `lightfold compare`: image metrics of a test EXR against a reference EXR (RMSE, relative MSE,
//! PSNR, max error, energy bias, non-finite pixels, FLIP), whole image and over the penumbra when
//! the reference's unoccluded image is given. `--min-psnr` and `--max-flip` turn it into a gate:
//! the command fails (status 1) when the whole-image figures miss them.

use lightfold_reference::masks::{penumbra, penumbra_mask};
use lightfold_reference::metrics::compare;
use lightfold_reference::output::write_error_map;
use lightfold_scene::Image;
use lightfold_telemetry::outln;
use std::path::{Path, PathBuf};

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// The image under test (EXR, linear radiance).
    pub test: PathBuf,
    /// The reference image (EXR, linear radiance).
    pub reference: PathBuf,
    /// Exposure applied before comparing (PSNR peak and FLIP white are 1.0 after it).
    #[arg(long, default_value_t = 1.0)]
    pub exposure: f32,
    /// Write the FLIP error map (magma colours) as PNG.
    #[arg(long)]
    pub error_map: Option<PathBuf>,
    /// The reference rendered without shadows: enables the penumbra figures.
    #[arg(long)]
    pub unoccluded: Option<PathBuf>,
    /// The reference's eye depth (EXR, 0 = background): removes silhouettes from the penumbra.
    #[arg(long, requires = "unoccluded")]
    pub depth: Option<PathBuf>,
    /// Fail (exit status 1) when the whole image's PSNR is below DB decibels.
    #[arg(long, value_name = "DB", allow_negative_numbers = true)]
    pub min_psnr: Option<f64>,
    /// Fail (exit status 1) when the whole image's mean FLIP error is above X (0 = identical,
    /// 1 = as different as can be).
    #[arg(long, value_name = "X")]
    pub max_flip: Option<f64>,
}

pub(crate) fn run(args: Args) -> anyhow::Result<()> {
    let test = read(&args.test)?;
    let reference = read(&args.reference)?;
    let mask = match &args.unoccluded {
        None => None,
        Some(path) => {
            let unoccluded = read(path)?;
            anyhow::ensure!(
                unoccluded.width == reference.width && unoccluded.height == reference.height,
                "{} is {}x{}, the reference {}x{}",
                path.display(),
                unoccluded.width,
                unoccluded.height,
                reference.width,
                reference.height
            );
            Some(match &args.depth {
                Some(d) => {
                    let depth = read(d)?;
                    anyhow::ensure!(
                        depth.width == reference.width && depth.height == reference.height,
                        "{} does not match the reference size",
                        d.display()
                    );
                    let coverage: Vec<bool> = depth.data.chunks(3).map(|p| p[0] > 0.0).collect();
                    penumbra_mask(&reference, &unoccluded, &depth, &coverage)
                }
                None => penumbra(&reference, &unoccluded),
            })
        }
    };
    let metrics = compare(&test, &reference, args.exposure, mask.as_deref())?;
    outln!("test      {}", args.test.display());
    outln!("reference {}", args.reference.display());
    outln!("{metrics}");
    if let Some(path) = &args.error_map {
        write_error_map(&test, &reference, args.exposure, path)?;
        outln!("error map {}", path.display());
    }
    let failed = gate(&args, metrics.whole.psnr, metrics.flip);
    anyhow::ensure!(failed.is_empty(), "{}", failed.join("; "));
    Ok(())
}

/// What the whole-image figures miss of `--min-psnr` and `--max-flip`; empty when they pass.
fn gate(args: &Args, psnr: f64, flip: f64) -> Vec<String> {
    let mut failed = Vec::new();
    if let Some(min) = args.min_psnr
        && (psnr < min || psnr.is_nan())
    {
        failed.push(format!("PSNR {psnr:.2} dB is below --min-psnr {min}"));
    }
    if let Some(max) = args.max_flip
        && (flip > max || flip.is_nan())
    {
        failed.push(format!("FLIP {flip:.4} is above --max-flip {max}"));
    }
    failed
}

fn read(path: &Path) -> anyhow::Result<Image> {
    let mut magic = [0u8; 8];
    let head = std::fs::File::open(path)
        .and_then(|mut f| std::io::Read::read(&mut f, &mut magic))
        .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", path.display()))?;
    let magic = &magic[..head];
    let kind = if magic.starts_with(b"\x89PNG") {
        "a PNG"
    } else if magic.starts_with(&[0xff, 0xd8, 0xff]) {
        "a JPEG"
    } else if !magic.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
        anyhow::bail!("compare reads EXR; {} is not one", path.display());
    } else {
        // The image error already names the file.
        return Ok(Image::read_exr(path)?);
    };
    // `render` and `coordinator` write the EXR (linear radiance) next to their PNG.
    let exr = path.with_extension("exr");
    let hint = if exr != path && exr.is_file() {
        format!("; compare {} instead", exr.display())
    } else {
        " (8-bit sRGB; `render` and `coordinator` write the linear EXR next to their PNG)"
            .to_string()
    };
    anyhow::bail!("compare reads EXR; got {kind}: {}{hint}", path.display())
}
