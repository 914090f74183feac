// Materials and textures, shared by the shadow and eye passes (group 0, bindings 0–2).

const ALPHA_OPAQUE: u32 = 0u;
const ALPHA_MASK: u32 = 1u;
const NO_TEXTURE: u32 = 0xffffffffu;
// Per-vertex material word: the material index, with this bit set when the mesh has no UVs.
const NO_UV_BIT: u32 = 0x80000000u;

struct Material {
    diffuse: vec3f,
    diffuse_texture: u32,
    specular: vec3f,
    shininess: f32,
    ambient: vec3f,
    alpha: f32,
    emissive: vec3f,
    alpha_mode: u32,
    cutoff: f32,
    double_sided: u32,
    has_specular: u32,
    _pad: u32,
}

struct TextureInfo {
    // First texel in `texels`, size, and whether colour channels are sRGB-encoded.
    offset: u32,
    width: u32,
    height: u32,
    srgb: u32,
}

@group(0) @binding(0) var<storage, read> materials: array<Material>;
@group(0) @binding(1) var<storage, read> textures: array<TextureInfo>;
// RGBA8 texels packed little-endian into u32 (R in the low byte).
@group(0) @binding(2) var<storage, read> texels: array<u32>;

fn texel(t: TextureInfo, x: i32, y: i32) -> vec4f {
    let w = i32(t.width);
    let h = i32(t.height);
    let xx = ((x % w) + w) % w;
    let yy = ((y % h) + h) % h;
    let c = unpack4x8unorm(texels[t.offset + u32(yy * w + xx)]);
    if t.srgb != 0u {
        return vec4f(srgb_to_linear(c.r), srgb_to_linear(c.g), srgb_to_linear(c.b), c.a);
    }
    return c;
}

// Bilinear lookup with repeat wrapping, texel centres at +0.5 (`scene::shading::sample_texture`).
fn sample_texture(index: u32, uv: vec2f) -> vec4f {
    let t = textures[index];
    if t.width == 0u || t.height == 0u {
        return vec4f(1.0);
    }
    let fu = uv.x * f32(t.width) - 0.5;
    let fv = uv.y * f32(t.height) - 0.5;
    let x0 = floor(fu);
    let y0 = floor(fv);
    let tx = fu - x0;
    let ty = fv - y0;
    let xi = i32(x0);
    let yi = i32(y0);
    let a = texel(t, xi, yi);
    let b = texel(t, xi + 1, yi);
    let c = texel(t, xi, yi + 1);
    let d = texel(t, xi + 1, yi + 1);
    let top = a + (b - a) * tx;
    let bot = c + (d - c) * tx;
    return top + (bot - top) * ty;
}

// Material alpha times texture alpha.
fn material_alpha(m: Material, uv: vec2f, has_uv: bool) -> f32 {
    var alpha = m.alpha;
    if m.diffuse_texture != NO_TEXTURE && has_uv {
        alpha = alpha * sample_texture(m.diffuse_texture, uv).a;
    }
    return alpha;
}

// Whether an alpha-masked texel is transparent (to eye and shadow rays alike); without UVs only
// the material alpha counts, as in the CPU reference.
fn masked_out(m: Material, uv: vec2f, has_uv: bool) -> bool {
    return m.alpha_mode == ALPHA_MASK && material_alpha(m, uv, has_uv) < m.cutoff;
}
