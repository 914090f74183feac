// Eq. 7's per-pixel ambient mask from the eye pass's material targets: I^a = m^a ⊘ m^d per
// channel, so that m^d ⊙ I^a = m^a. Exactly 1 where m^a = m^d and exactly 0 where m^a or m^d is
// 0 (no division there, so nothing rounds); elsewhere the ratio, at most the half-float maximum.
// Filters in front of a surface multiply both targets by the same transmittance, so equal layers
// stay equal. One invocation per pixel.

@group(0) @binding(0) var m_diffuse: texture_2d<f32>;
@group(0) @binding(1) var m_ambient: texture_2d<f32>;
@group(0) @binding(2) var mask: texture_storage_2d<rgba16float, write>;

const HALF_MAX: f32 = 65504.0;

fn ambient_mask(d: vec3f, a: vec3f) -> vec3f {
    let zero = vec3f(0.0);
    let ratio = min(a / select(d, vec3f(1.0), d <= zero), vec3f(HALF_MAX));
    let one_or_ratio = select(ratio, vec3f(1.0), a == d);
    return select(one_or_ratio, zero, (a <= zero) | (d <= zero));
}

@compute @workgroup_size(8, 8)
fn cs_ambient_mask(@builtin(global_invocation_id) id: vec3<u32>) {
    let size = textureDimensions(mask);
    if id.x >= size.x || id.y >= size.y {
        return;
    }
    let p = vec2<i32>(id.xy);
    let d = textureLoad(m_diffuse, p, 0).rgb;
    let a = textureLoad(m_ambient, p, 0).rgb;
    textureStore(mask, p, vec4f(ambient_mask(d, a), 1.0));
}
