//! `lightfold compare`: image metrics of a test EXR against a reference EXR (RMSE, relative MSE,
//! PSNR, max error, energy bias, non-finite pixels, FLIP), whole image and over the penumbra when
//! the reference's unoccluded image is given.

use lightfold_reference::masks::{penumbra, penumbra_mask};
use lightfold_reference::metrics::compare;
use lightfold_reference::output::write_error_map;
use lightfold_scene::Image;
use std::path::{Path, PathBuf};

#[derive(Debug, clap::Args)]
pub struct Args {
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
}

pub fn run(args: Args) -> anyhow::Result<()> {
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
    println!("test      {}", args.test.display());
    println!("reference {}", args.reference.display());
    println!("{metrics}");
    if let Some(path) = &args.error_map {
        write_error_map(&test, &reference, args.exposure, path)?;
        println!("error map {}", path.display());
    }
    Ok(())
}

fn read(path: &Path) -> anyhow::Result<Image> {
    // The image error already names the file.
    Ok(Image::read_exr(path)?)
}
