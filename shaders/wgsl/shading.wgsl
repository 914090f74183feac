// Lighting maths mirrored from `scene::shading` (docs/shading.md): keep the two in step.

const PI: f32 = 3.14159265358979;

const KIND_ISOTROPIC: u32 = 0u;
const KIND_COSINE_LOBE: u32 = 1u;
const KIND_TWO_SIDED_LOBE: u32 = 2u;
const KIND_SPOT: u32 = 3u;
const KIND_DIRECTIONAL: u32 = 4u;
// A virtual point light: a cosine lobe whose 1/r² is clamped to 1/max(r², clamp²), the clamp
// distance stored in `cos_outer`.
const KIND_BOUNCE: u32 = 5u;

// One point-light sample λ as the node renders it.
struct Light {
    position: vec3f,
    kind: u32,
    // Lobe / spot axis, or direction of travel for a directional light (unit).
    direction: vec3f,
    intensity: f32,
    // c_λ ⊘ c_n: the light colour relative to the node colour.
    weight: vec3f,
    // Range window; 0 means unbounded.
    range: f32,
    // Spot cone cosines; for KIND_BOUNCE `cos_outer` is the falloff clamp distance.
    cos_outer: f32,
    cos_inner: f32,
    first_view: u32,
    view_count: u32,
    // How a point picks its view: `cube` 0 = the only view; 1 = cube faces, by the dominant axis
    // of its direction in the frame (cube_x, cube_x × cube_z, cube_z)
    // (`scene::shadow_views::cube_frame`); 2 = two frusta split by the plane with normal cube_x
    // (face 0 on its positive side, else face 1).
    cube_x: vec3f,
    cube: u32,
    cube_z: vec3f,
    // Near cascades (views first_view.. first_view + cascades, nearest first) tried before `cube`
    // picks among the rest: the first whose View::cascade_to exceeds the point's eye depth.
    cascades: u32,
    // View index per face, two faces to a word (low 16 bits, high 16 bits): +x −x, +y −y, +z −z;
    // FACE_NONE where none.
    faces: vec4<u32>,
    // The area light's shape for closed-form glossy specular (`scene::ltc`): AREA_* kind, centre,
    // half axes (a sphere's radius in area_u.x).
    area_center: vec3f,
    area_kind: u32,
    area_u: vec3f,
    // Width of the sample's cell of its light (metres; radians for a soft sun's directions; 0
    // for samples that are no cell of a shape): the cell filter's kernel (FILTER_CELL).
    cell: f32,
    area_v: vec3f,
    area_pad1: u32,
}

const AREA_NONE: u32 = 0u;
const AREA_RECT: u32 = 1u;
const AREA_DISK: u32 = 2u;
const AREA_SPHERE: u32 = 3u;

const FACE_NONE: u32 = 0xffffu;

// The view of cube face `face` (0..6 as +x −x +y −y +z −z), or NO_VIEW.
fn face_view(s: Light, face: u32) -> u32 {
    let word = select(select(s.faces.z, s.faces.y, face < 4u), s.faces.x, face < 2u);
    let v = select(word & 0xffffu, word >> 16u, (face & 1u) == 1u);
    return select(v, NO_VIEW, v == FACE_NONE);
}

const NO_VIEW: u32 = 0xffffffffu;

// Unit vector, or zero for a zero or non-finite input.
fn safe_normalize(a: vec3f) -> vec3f {
    let l = length(a);
    return select(vec3f(0.0), a / l, l > 0.0 && l < 3.0e38);
}

// The sample kinds a pipeline is built for, one bit per KIND_* (all by default). A CPU rasteriser
// runs every side of every branch, so the eye pass is specialised to the kinds its lights have:
// the code of the others folds away. The maths below is branch-free for the same reason.
override LIGHT_KINDS: u32 = 0x3fu;

fn handles(kind: u32) -> bool {
    return (LIGHT_KINDS & (1u << kind)) != 0u;
}

// Whether s is of `kind`; when the pipeline handles that kind only, without reading s.kind.
fn is_kind(s: Light, kind: u32) -> bool {
    return handles(kind) && (LIGHT_KINDS == (1u << kind) || s.kind == kind);
}

// Whether any light of the pipeline has a range window (else it is 1 and `range` is not read).
override LIGHT_RANGES: bool = true;

fn range_window(r: f32, range: f32) -> f32 {
    let q = r / range;
    let w = clamp(1.0 - q * q * q * q, 0.0, 1.0);
    return select(1.0, w * w, range > 0.0);
}

// Radiant intensity towards unit direction `to_point` (light → point).
fn sample_intensity(s: Light, to_point: vec3f) -> f32 {
    let c = dot(s.direction, to_point);
    // Isotropic and directional samples radiate `intensity` every way.
    var i = s.intensity;
    if handles(KIND_COSINE_LOBE) {
        i = select(i, s.intensity * max(c, 0.0), is_kind(s, KIND_COSINE_LOBE));
    }
    if handles(KIND_TWO_SIDED_LOBE) {
        i = select(i, s.intensity * abs(c), is_kind(s, KIND_TWO_SIDED_LOBE));
    }
    if handles(KIND_BOUNCE) {
        i = select(i, s.intensity * max(c, 0.0), is_kind(s, KIND_BOUNCE));
    }
    if handles(KIND_SPOT) {
        let t = clamp((c - s.cos_outer) / max(s.cos_inner - s.cos_outer, 1e-4), 0.0, 1.0);
        i = select(i, s.intensity * t * t, is_kind(s, KIND_SPOT));
    }
    return i;
}

// Unit direction from p towards the light (xyz) and its distance (w; huge for directional).
fn to_light(s: Light, p: vec3f) -> vec4f {
    let d = s.position - p;
    var lr = vec4f(safe_normalize(d), length(d));
    if handles(KIND_DIRECTIONAL) {
        let travel = vec4f(-safe_normalize(s.direction), 3.0e38);
        lr = select(lr, travel, is_kind(s, KIND_DIRECTIONAL));
    }
    return lr;
}

// Unshadowed scalar irradiance E_λ at a point with unit normal n, given `to_light` there.
fn irradiance(s: Light, lr: vec4f, n: vec3f) -> f32 {
    let l = lr.xyz;
    let r = lr.w;
    let cos_n = dot(n, l);
    var r2 = r * r;
    if handles(KIND_BOUNCE) {
        r2 = select(r2, max(r2, s.cos_outer * s.cos_outer), is_kind(s, KIND_BOUNCE));
    }
    var e = sample_intensity(s, -l) * cos_n / r2;
    if LIGHT_RANGES {
        e *= range_window(r, s.range);
    }
    var reached = r > 0.0;
    if handles(KIND_DIRECTIONAL) {
        let directional = is_kind(s, KIND_DIRECTIONAL);
        e = select(e, s.intensity * cos_n, directional);
        reached = reached || directional;
    }
    return select(0.0, e, cos_n > 0.0 && reached && abs(e) < 3.0e38);
}

// Energy-normalised Blinn-Phong lobe (s+8)/(8π)·max(0, n·h)^s.
fn blinn_phong(n: vec3f, l: vec3f, v: vec3f, shininess: f32) -> f32 {
    let h = safe_normalize(l + v);
    let nh = max(dot(n, h), 0.0);
    // 0^0 is 1; pow(0, s) may be NaN where it is not taken.
    let p = select(select(0.0, 1.0, shininess == 0.0), pow(nh, shininess), nh > 0.0);
    return (shininess + 8.0) / (8.0 * PI) * p;
}

// Unshadowed (i^d, i^s) of one sample at a surface point.
fn coefficients(s: Light, p: vec3f, n: vec3f, v: vec3f, shininess: f32, specular: bool) -> vec2f {
    let lr = to_light(s, p);
    let e = irradiance(s, lr, n);
    let is = select(0.0, e * blinn_phong(n, lr.xyz, v, shininess), specular && e != 0.0);
    return vec2f(e / PI, is);
}

// The glTF metallic-roughness reference BRDF (`scene::shading::lobe_coefficients`, Lobe::Ggx).
const MIN_ALPHA: f32 = 1e-3;

fn ggx_alpha(roughness: f32) -> f32 {
    let r = clamp(roughness, 0.0, 1.0);
    return max(r * r, MIN_ALPHA);
}

// α²/(π(|n × h|² + α²(n·h)²)²): D without 1 − (n·h)²'s cancellation (`scene::shading::ggx_d`).
fn ggx_d(n: vec3f, h: vec3f, alpha: f32) -> f32 {
    let a2 = alpha * alpha;
    let c = cross(n, h);
    let facing = dot(n, h) > 0.0;
    let nh = select(0.0, dot(n, h), facing);
    let t2 = select(1.0, dot(c, c), facing);
    let d = t2 + a2 * nh * nh;
    return a2 / (PI * d * d);
}

// Height-correlated Smith visibility G/(4|n·l||n·v|).
fn smith_visibility(nl: f32, nv: f32, alpha: f32) -> f32 {
    let a2 = alpha * alpha;
    let gv = nl * sqrt(nv * nv * (1.0 - a2) + a2);
    let gl = nv * sqrt(nl * nl * (1.0 - a2) + a2);
    let sum = gv + gl;
    return select(0.0, 0.5 / sum, sum > 0.0);
}

// Schlick's weight (1 − |v·h|)⁵.
fn schlick_weight(vh: f32) -> f32 {
    let x = 1.0 - min(abs(vh), 1.0);
    let x2 = x * x;
    return x2 * x2 * x;
}

// Per unit irradiance: the diffuse weight (1 − w)/π, the specular D·V, and w.
fn ggx_terms(n: vec3f, l: vec3f, v: vec3f, alpha: f32) -> vec3f {
    let h = safe_normalize(l + v);
    let w = schlick_weight(dot(v, h));
    let nl = max(dot(n, l), 0.0);
    let nv = max(dot(n, v), 0.0);
    let dv = ggx_d(n, h, alpha) * smith_visibility(nl, nv, alpha);
    return vec3f((1.0 - w) / PI, select(0.0, dv, abs(dv) < 3.0e38), w);
}

// 1 + strength·(r − 1).
fn occlusion(strength: f32, r: f32) -> f32 {
    return 1.0 + clamp(strength, 0.0, 1.0) * (clamp(r, 0.0, 1.0) - 1.0);
}

// The normal a normal-map texel gives (`scene::shading::perturb_normal`).
fn perturb_normal(n: vec3f, tangent: vec4f, texel: vec3f, scale_xy: f32) -> vec3f {
    if tangent.w == 0.0 {
        return n;
    }
    let w = select(1.0, -1.0, tangent.w < 0.0);
    let t = safe_normalize(tangent.xyz - n * dot(n, tangent.xyz));
    if all(t == vec3f(0.0)) {
        return n;
    }
    let b = cross(n, t) * w;
    let x = (2.0 * texel.x - 1.0) * scale_xy;
    let y = (2.0 * texel.y - 1.0) * scale_xy;
    let z = 2.0 * texel.z - 1.0;
    let m = safe_normalize(t * x + b * y + n * z);
    return select(m, n, all(m == vec3f(0.0)));
}

// The texture coordinates metallic-roughness shading reads (`scene::shading::shading_uv`):
// what a G-buffer word keeps of them.
fn shading_uv(uv: vec2f) -> vec2f {
    return unpack2x16unorm(pack2x16unorm(fract(uv)));
}

fn srgb_to_linear(x: f32) -> f32 {
    if x <= 0.04045 {
        return x / 12.92;
    }
    return pow((x + 0.055) / 1.055, 2.4);
}
