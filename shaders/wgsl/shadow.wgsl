// Shadow pass: depth only (reversed-Z, cleared to 0), one draw per caster mesh. Alpha-masked
// casters run `fs_masked`, which discards texels below their material's cutoff.

struct ShadowPass {
    view_proj: mat4x4f,
}

@group(1) @binding(0) var<uniform> pass_view: ShadowPass;

@vertex
fn vs_depth(@location(0) position: vec3f) -> @builtin(position) vec4f {
    return pass_view.view_proj * vec4f(position, 1.0);
}

struct MaskedOut {
    @builtin(position) clip: vec4f,
    @location(0) uv: vec2f,
    @location(1) @interpolate(flat) material: u32,
}

@vertex
fn vs_masked(
    @location(0) position: vec3f,
    @location(3) uv: vec2f,
    @location(4) material: u32,
) -> MaskedOut {
    var out: MaskedOut;
    out.clip = pass_view.view_proj * vec4f(position, 1.0);
    out.uv = uv;
    out.material = material;
    return out;
}

@fragment
fn fs_masked(in: MaskedOut) {
    let m = materials[in.material & ~NO_UV_BIT];
    if masked_out(m, in.uv, (in.material & NO_UV_BIT) == 0u) {
        discard;
    }
}
