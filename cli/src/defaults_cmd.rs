//! `lightfold defaults`: the project defaults of ARCHITECTURE §10.

use lightfold_scene::defaults;

#[derive(Debug, clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> anyhow::Result<()> {
    let q = defaults::quality();
    println!("scene            {}", defaults::DEFAULT_SCENE);
    println!("image            {}x{}", defaults::WIDTH, defaults::HEIGHT);
    println!("samples/area     {}", defaults::SAMPLES_PER_AREA_LIGHT);
    println!("lights per node  {}", q.lights_per_node);
    println!("shadow map       {}²", q.shadow_map_size);
    println!("filter           {:?}", q.filter);
    Ok(())
}
