// Peeled eye layers (`NodeConfig::peel`, `docs/translucency.md`): appended to the forward module.
//
// Peel 0, the opaque layer: `fs_peel_opaque_illumination` / `fs_peel_opaque_layers` are the
// forward pass's entry points with every translucent material rejected (filters and coverage)
// besides single-sided back faces and masked-out texels; no filters' pass follows.
//
// Peel d ≥ 1, the d-th nearest translucent surface in front of the opaque one, by depth peeling:
// per peel pass k = 1..=d a depth-only raster of the opaque surfaces (`fs_peel_opaque`), then
// the translucent fragments depth-tested and written against it, each kept only where its eye
// depth lies beyond pass k−1's (`peel_prev`, none for k = 1) by more than `PEEL_EPSILON`
// relative. Passes k < d write their eye depth (`fs_peel_depth`); pass d writes the layer
// (`fs_peel_layers`): its illumination, eye depth, material layers times its eye coverage a, and
// its eye transmittance T.

// The previous peel pass's eye depth (f32 bits; 0 where it found no layer).
@group(2) @binding(0) var peel_prev: texture_2d<u32>;

struct PeelParams {
    // Nonzero in pass 1 (no previous depth to lie beyond).
    first: u32,
    epsilon: f32,
    pad0: u32,
    pad1: u32,
}

@group(2) @binding(1) var<uniform> peel: PeelParams;

// Whether a fragment is not part of peel 0 (the opaque layer): the forward pass's rejection plus
// every translucent material.
fn peel_opaque_rejected(in: VsOut, front: bool) -> bool {
    return rejected(in, front) || materials[in.material & ~NO_UV_BIT].transmits != TRANSMITS_NONE;
}

@fragment
fn fs_peel_opaque_illumination(in: VsOut, @builtin(front_facing) front: bool) -> IlluminationOut {
    if peel_opaque_rejected(in, front) {
        discard;
    }
    let s = illuminate(surface(in, front), Shaded(vec3f(0.0), vec3f(0.0)));
    var out: IlluminationOut;
    out.diffuse = bitcast<vec4<u32>>(vec4f(s.diffuse, 1.0));
    out.specular = bitcast<vec4<u32>>(vec4f(s.specular, 1.0));
    out.depth = bitcast<u32>(eye_depth(in.world));
    return out;
}

@fragment
fn fs_peel_opaque_layers(in: VsOut, @builtin(front_facing) front: bool) -> LayersOut {
    if peel_opaque_rejected(in, front) {
        discard;
    }
    let s = illuminate(surface(in, front), Shaded(vec3f(0.0), vec3f(0.0)));
    let m = material_layers(in);
    var out: LayersOut;
    out.diffuse = bitcast<vec4<u32>>(vec4f(s.diffuse, 1.0));
    out.specular = bitcast<vec4<u32>>(vec4f(s.specular, 1.0));
    out.depth = bitcast<u32>(eye_depth(in.world));
    out.m_diffuse = m.diffuse;
    out.m_specular = m.specular;
    out.m_ambient = m.ambient;
    out.emissive = m.emissive;
    return out;
}

// The opaque surfaces' depth in each peel pass: only the depth buffer is written.
@fragment
fn fs_peel_opaque(in: VsOut, @builtin(front_facing) front: bool) {
    if peel_opaque_rejected(in, front) {
        discard;
    }
}

// Whether a translucent fragment is a candidate of this peel pass: a translucent material, not a
// single-sided back face, not a filter's masked-out texel (a coverage material is never masked
// out here: it blends), and beyond the previous pass's layer (where that pass found one).
fn peel_candidate(in: VsOut, front: bool) -> bool {
    let m = materials[in.material & ~NO_UV_BIT];
    if m.transmits == TRANSMITS_NONE || (!front && m.double_sided == 0u) {
        return false;
    }
    if m.transmits == TRANSMITS_FILTER && masked_out(m, in.uv, (in.material & NO_UV_BIT) == 0u) {
        return false;
    }
    if peel.first == 0u {
        let prev = bitcast<f32>(textureLoad(peel_prev, vec2i(in.clip.xy), 0).r);
        if !(prev > 0.0) || eye_depth(in.world) <= prev * (1.0 + peel.epsilon) {
            return false;
        }
    }
    return true;
}

@fragment
fn fs_peel_depth(in: VsOut, @builtin(front_facing) front: bool) -> @location(0) u32 {
    if !peel_candidate(in, front) {
        discard;
    }
    return bitcast<u32>(eye_depth(in.world));
}

// A translucent texel's eye coverage a (w) and eye transmittance T (rgb): under coverage
// a = α · texture alpha (clamped) and T = 1 − a; a filter covers wholly (a = 1) and lets its
// texel transmittance through.
fn peel_cover(in: VsOut) -> vec4f {
    let m = materials[in.material & ~NO_UV_BIT];
    let has_uv = (in.material & NO_UV_BIT) == 0u;
    if m.transmits == TRANSMITS_COVERAGE {
        var texel_alpha = 1.0;
        if m.diffuse_texture != NO_TEXTURE && has_uv {
            texel_alpha = sample_texture(m.diffuse_texture, in.uv).a;
        }
        let a = clamp(m.alpha * texel_alpha, 0.0, 1.0);
        return vec4f(vec3f(1.0 - a), a);
    }
    return vec4f(texel_transmittance(m, in.uv, has_uv), 1.0);
}

struct PeelOut {
    @location(0) diffuse: vec4<u32>,
    @location(1) specular: vec4<u32>,
    @location(2) depth: u32,
    @location(3) m_diffuse: vec4f,
    @location(4) m_specular: vec4f,
    @location(5) m_ambient: vec4f,
    @location(6) emissive: vec4f,
    @location(7) transmittance: vec4f,
}

@fragment
fn fs_peel_layers(in: VsOut, @builtin(front_facing) front: bool) -> PeelOut {
    if !peel_candidate(in, front) {
        discard;
    }
    let s = illuminate(surface(in, front), Shaded(vec3f(0.0), vec3f(0.0)));
    let m = material_layers(in);
    let cover = peel_cover(in);
    let a = vec4f(vec3f(cover.w), 1.0);
    var out: PeelOut;
    out.diffuse = bitcast<vec4<u32>>(vec4f(s.diffuse, 1.0));
    out.specular = bitcast<vec4<u32>>(vec4f(s.specular, 1.0));
    out.depth = bitcast<u32>(eye_depth(in.world));
    out.m_diffuse = m.diffuse * a;
    out.m_specular = m.specular * a;
    out.m_ambient = m.ambient * a;
    out.emissive = m.emissive * a;
    out.transmittance = vec4f(cover.rgb, 1.0);
    return out;
}
