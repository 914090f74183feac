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
    // MODEL_*: a metallic-roughness material's parameters are `pbr` at the same index.
    model: u32,
    // Translucent casters (`scene::Transmission`): RGB transmittance where the surface covers,
    // and `transmits` = TRANSMITS_* (none: an opaque caster).
    transmission: vec3f,
    transmits: u32,
}

// glTF metallic-roughness (`scene::MetallicRoughness`), read where the material's model is
// MODEL_METALLIC_ROUGHNESS; the base-colour texture is the material's `diffuse_texture`. In its own
// array (binding 3), index for index with `materials`.
struct Pbr {
    base_color: vec3f,
    metallic: f32,
    roughness: f32,
    metallic_roughness_texture: u32,
    normal_texture: u32,
    normal_scale: f32,
    occlusion_texture: u32,
    occlusion_strength: f32,
    emissive_texture: u32,
    transmission: f32,
}

const MODEL_BLINN_PHONG: u32 = 0u;
const MODEL_METALLIC_ROUGHNESS: u32 = 1u;

const TRANSMITS_NONE: u32 = 0u;
const TRANSMITS_FILTER: u32 = 1u;
// Alpha is coverage (glTF BLEND): the uncovered 1 − α passes untinted.
const TRANSMITS_COVERAGE: u32 = 2u;

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
@group(0) @binding(3) var<storage, read> pbr: array<Pbr>;

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

// Transmittance of one texel of a translucent caster (`scene::shading::transmittance`):
// (1 − a) + a·c⊙x under coverage, else c⊙x; x the diffuse texture's colour (with UVs only).
// A masked-out texel of a filter lets everything through.
fn texel_transmittance(m: Material, uv: vec2f, has_uv: bool) -> vec3f {
    var texel = vec4f(1.0);
    if m.diffuse_texture != NO_TEXTURE && has_uv {
        texel = sample_texture(m.diffuse_texture, uv);
    }
    let covered = clamp(m.transmission, vec3f(0.0), vec3f(1.0)) * clamp(texel.rgb, vec3f(0.0), vec3f(1.0));
    if m.transmits == TRANSMITS_COVERAGE {
        let a = clamp(m.alpha * texel.a, 0.0, 1.0);
        return vec3f(1.0 - a) + a * covered;
    }
    if m.alpha_mode == ALPHA_MASK && m.alpha * texel.a < m.cutoff {
        return vec3f(1.0);
    }
    return covered;
}

// A texture's texel at uv, white where there is none.
fn read_texture(index: u32, uv: vec2f) -> vec4f {
    if index == NO_TEXTURE {
        return vec4f(1.0);
    }
    return sample_texture(index, uv);
}

// A metallic-roughness surface at shading coordinates suv (`shading_uv`):
// m^d = c_diff ⊙ (1 − F0), F0 and α (`scene::shading::metallic_roughness_point`).
struct MrPoint {
    diffuse: vec3f,
    f0: vec3f,
    alpha: f32,
}

fn metallic_roughness_point(material: u32, suv: vec2f) -> MrPoint {
    let p = pbr[material];
    let base_texel = read_texture(materials[material].diffuse_texture, suv);
    let mr = read_texture(p.metallic_roughness_texture, suv);
    let metallic = clamp(p.metallic * mr.b, 0.0, 1.0);
    let roughness = p.roughness * mr.g;
    let keep = (1.0 - metallic) * (1.0 - clamp(p.transmission, 0.0, 1.0));
    let base = max(p.base_color * base_texel.rgb, vec3f(0.0));
    let f0 = vec3f(0.04) + (base - vec3f(0.04)) * metallic;
    return MrPoint(base * keep * (vec3f(1.0) - f0), f0, ggx_alpha(roughness));
}

// F0 (xyz) and α (w) of a metallic-roughness surface, all its lights need
// (`metallic_roughness_point` without m^d): a dielectric's F0 is 0.04 whatever its base colour,
// so the base-colour texture is read only where the surface is metallic (exactly the same F0).
fn metallic_roughness_lobe(material: u32, suv: vec2f) -> vec4f {
    let p = pbr[material];
    let mr = read_texture(p.metallic_roughness_texture, suv);
    let metallic = clamp(p.metallic * mr.b, 0.0, 1.0);
    var base = max(p.base_color, vec3f(0.0));
    if metallic > 0.0 {
        base = max(p.base_color * read_texture(materials[material].diffuse_texture, suv).rgb, vec3f(0.0));
    }
    let f0 = vec3f(0.04) + (base - vec3f(0.04)) * metallic;
    return vec4f(f0, ggx_alpha(p.roughness * mr.g));
}
