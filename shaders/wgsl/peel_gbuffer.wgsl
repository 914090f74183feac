// Peel 0 (the opaque layer, `NodeConfig::peel`) in the deferred variant: appended to the deferred
// module, the G-buffer rasters with every translucent material rejected besides what the classic
// pass rejects; the light pass (`cs_lights`) is the classic one, and no filters' pass follows.

fn peel_gbuffer_rejected(in: VsOut, front: bool) -> bool {
    return rejected(in, front) || materials[in.material & ~NO_UV_BIT].transmits != TRANSMITS_NONE;
}

@fragment
fn fs_gbuffer_peel(in: VsOut, @builtin(front_facing) front: bool) -> GBufferOut {
    if peel_gbuffer_rejected(in, front) {
        discard;
    }
    return gbuffer(in, front);
}

@fragment
fn fs_gbuffer_layers_peel(in: VsOut, @builtin(front_facing) front: bool) -> GBufferLayersOut {
    if peel_gbuffer_rejected(in, front) {
        discard;
    }
    let g = gbuffer(in, front);
    let m = material_layers(in);
    return GBufferLayersOut(
        g.position,
        g.normal,
        g.geometric_normal,
        g.depth,
        m.diffuse,
        m.specular,
        m.ambient,
        m.emissive,
    );
}
