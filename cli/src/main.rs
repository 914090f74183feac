//! The one `lightfold` binary: every daemon role and every tool (render, plan, demo, bench,
//! accuracy) as a subcommand.

use clap::{Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(
    name = "lightfold",
    version,
    about = "Distributed many-light soft-shadow renderer"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Print the built-in defaults (image size, samples, K, shadow-map size).
    Defaults,
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Defaults => {
            let q = lightfold_scene::defaults::quality();
            println!(
                "scene {} {}x{} samples/area light {} K {} shadow map {}",
                lightfold_scene::defaults::DEFAULT_SCENE,
                lightfold_scene::defaults::WIDTH,
                lightfold_scene::defaults::HEIGHT,
                lightfold_scene::defaults::SAMPLES_PER_AREA_LIGHT,
                q.lights_per_node,
                q.shadow_map_size
            );
        }
    }
    Ok(())
}
