//! `lightfold defaults`: the project defaults of ARCHITECTURE §10, and the limits every input is
//! checked against (`lightfold_scene::limits`), as `lightfold_scene::defaults::describe` says them.

#[derive(Debug, clap::Args)]
pub(crate) struct Args {}

pub(crate) fn run(_args: Args) -> anyhow::Result<()> {
    lightfold_telemetry::out!("{}", lightfold_scene::defaults::describe());
    Ok(())
}
