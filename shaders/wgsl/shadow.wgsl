// Shadow pass: depth (reversed-Z, cleared to 0) and the object ID of the nearest caster (mesh
// index + 1, cleared to 0), one draw per caster mesh. Alpha-masked casters run `fs_masked`, which
// discards texels below their material's cutoff. Translucent casters (`docs/translucency.md`)
// draw into their own two maps instead: `fs_translucent_depth` the nearest one's depth,
// `fs_transmit` the product of their transmittance in front of the nearest opaque caster.

struct ShadowPass {
    view_proj: mat4x4f,
}

@group(1) @binding(0) var<uniform> pass_view: ShadowPass;

struct DepthOut {
    @builtin(position) clip: vec4f,
    @location(0) @interpolate(flat) object: u32,
}

@vertex
fn vs_depth(@location(0) position: vec3f, @location(5) object: u32) -> DepthOut {
    return DepthOut(pass_view.view_proj * vec4f(position, 1.0), object);
}

@fragment
fn fs_depth(in: DepthOut) -> @location(0) u32 {
    return in.object;
}

struct MaskedOut {
    @builtin(position) clip: vec4f,
    @location(0) uv: vec2f,
    @location(1) @interpolate(flat) material: u32,
    @location(2) @interpolate(flat) object: u32,
}

@vertex
fn vs_masked(
    @location(0) position: vec3f,
    @location(3) uv: vec2f,
    @location(4) material: u32,
    @location(5) object: u32,
) -> MaskedOut {
    var out: MaskedOut;
    out.clip = pass_view.view_proj * vec4f(position, 1.0);
    out.uv = uv;
    out.material = material;
    out.object = object;
    return out;
}

@fragment
fn fs_masked(in: MaskedOut) -> @location(0) u32 {
    let m = materials[in.material & ~NO_UV_BIT];
    if masked_out(m, in.uv, (in.material & NO_UV_BIT) == 0u) {
        discard;
    }
    return in.object;
}

// The nearest translucent caster's depth: texels that let everything through do not count.
@fragment
fn fs_translucent_depth(in: MaskedOut) {
    let m = materials[in.material & ~NO_UV_BIT];
    if all(texel_transmittance(m, in.uv, (in.material & NO_UV_BIT) == 0u) >= vec3f(1.0)) {
        discard;
    }
}

// Multiplied into the transmittance map by the blend state (dst·src), behind the opaque depth
// test: only translucent casters in front of the nearest opaque one count.
@fragment
fn fs_transmit(in: MaskedOut) -> @location(0) vec4f {
    let m = materials[in.material & ~NO_UV_BIT];
    return vec4f(texel_transmittance(m, in.uv, (in.material & NO_UV_BIT) == 0u), 1.0);
}

// Two translucent layers per light view (peeling renderers, `docs/translucency.md`): the
// nearest translucent caster's depth as `fs_translucent_depth` writes it, and its own
// transmittance T1 (the depth test keeps the nearest fragment's).
@fragment
fn fs_translucent_first(in: MaskedOut) -> @location(0) vec4f {
    let m = materials[in.material & ~NO_UV_BIT];
    let t = texel_transmittance(m, in.uv, (in.material & NO_UV_BIT) == 0u);
    if all(t >= vec3f(1.0)) {
        discard;
    }
    return vec4f(t, 1.0);
}

// The nearest translucent caster's depth, read by the second peel in light space.
@group(2) @binding(0) var first_translucent: texture_depth_2d;
// Reversed-Z (near 1) or conventional (near 0) shadow depth (`ShadowDepth`).
override REVERSED_Z: bool = true;
// A step of the depth format (Depth16Unorm's 2^-16; 0 for floats).
override DEPTH_STEP: f32 = 0.0;
// How far beyond the first a second layer must lie: a relative step in near/D.
const SECOND_LAYER_EPSILON: f32 = 1e-4;

// The second-nearest translucent caster's depth: fragments not beyond the first layer's depth
// at their texel (by SECOND_LAYER_EPSILON of its near/D, or a step of the format) are
// discarded, as are those that let everything through.
@fragment
fn fs_translucent_second(in: MaskedOut) {
    let m = materials[in.material & ~NO_UV_BIT];
    if all(texel_transmittance(m, in.uv, (in.material & NO_UV_BIT) == 0u) >= vec3f(1.0)) {
        discard;
    }
    let first = textureLoad(first_translucent, vec2i(floor(in.clip.xy)), 0);
    let z = clamp(in.clip.z, 0.0, 1.0);
    var beyond = z < first - (first * SECOND_LAYER_EPSILON + DEPTH_STEP);
    if !REVERSED_Z {
        beyond = z > first + ((1.0 - first) * SECOND_LAYER_EPSILON + DEPTH_STEP);
    }
    if !beyond {
        discard;
    }
}
