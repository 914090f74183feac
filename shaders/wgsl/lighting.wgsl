// Lighting of a visible surface point by the node's K samples with their shadow lookups: shared
// by the forward eye pass (`forward.wgsl`) and the deferred light pass (`deferred.wgsl`). Lights
// and views come from `light_at` / `view_at`, which each variant binds its own way
// (`lights_storage.wgsl`, `lights_uniform.wgsl`).

const FILTER_NEAREST: u32 = 0u;
const FILTER_PCF2X2: u32 = 1u;
const FILTER_GRID: u32 = 2u;
// Each sample's shadow filtered over its cell of the light (`Light::cell`): percentage-closer
// soft shadows per sample, the kernel from the blockers' and the receiver's distances.
const FILTER_CELL: u32 = 3u;
// The cell filter's largest kernel half-width and blocker-search reach, texels.
const MAX_CELL_RADIUS: f32 = 8.0;

// The shadow filter and its taps per axis are fixed per pipeline, so only the chosen filter's
// lookups are in the code (a CPU rasteriser would run the others' too).
override SHADOW_FILTER: u32 = FILTER_PCF2X2;
override SHADOW_TAPS: u32 = 1u;

struct Frame {
    view_proj: mat4x4f,
    camera: vec3f,
    light_count: u32,
    forward: vec3f,
    // Side of the shadow-map array's layers, texels.
    map_size: f32,
    // Constant bias in metres along the light ray, and the slope factor.
    depth_bias: f32,
    slope_bias: f32,
    // Deferred light pass: nonzero when this dispatch adds to what an earlier one lit.
    accumulate: u32,
    // Index in the frame's views of this chunk's view 0 (lookups read each view's own layer).
    view_base: u32,
    // Half-width of the filter footprint in texels (the slope bias scales with it).
    kernel_radius: f32,
    // Image size (the deferred variant's compute pass needs it).
    width: u32,
    height: u32,
    // FLAG_OBJECT_IDS, FLAG_CONVENTIONAL_Z.
    flags: u32,
}

// The object-ID test (on by default): each texel of a map also holds the object (mesh index + 1)
// whose depth it stores.
const FLAG_OBJECT_IDS: u32 = 1u;
// Maps store conventional Z (near 0, far 1): a depth negative control.
const FLAG_CONVENTIONAL_Z: u32 = 2u;
// Other objects' texels are compared with the receiver's plane at their centre (`texel_lit`),
// not with the symmetric bound alone.
const FLAG_RECEIVER_PLANE: u32 = 4u;

// One shadow map: a square of a layer of `shadow_maps` and how world points land in it. The projection keeps
// its eight non-zero entries: clip = (a.x·x + a.y·z + a.z, a.w·y + b.x·z + b.y, b.z·z + b.w, w)
// with w = 1 (orthographic) or −z (perspective).
struct View {
    view: mat4x4f,
    proj_a: vec4f,
    proj_b: vec4f,
    // Width of a texel: in tangent units (perspective) or metres (orthographic).
    texel: f32,
    ortho: u32,
    layer: u32,
    // A cascade's end: the eye depth where the light's next view takes over (MODE_CASCADE).
    cascade_to: f32,
    // The map's square in its layer, in texels: (x, y, side, transmit). Maps of several sizes
    // share the array's layers (node/src/gpu/atlas.rs); every lookup stays inside its square.
    // transmit = 1 where the view also has transmittance maps, 2 where they have two
    // translucent layers (peeling renderers).
    rect: vec4f,
}

@group(1) @binding(0) var<uniform> frame: Frame;
@group(1) @binding(3) var shadow_maps: texture_depth_2d_array;
// One linear comparison sampler (GL cannot pair one texture with two samplers); the nearest
// filter reads it at texel centres, where the bilinear weights select a single texel.
@group(1) @binding(4) var shadow_linear: sampler_comparison;
@group(1) @binding(5) var shadow_ids: texture_2d_array<u32>;
// Translucent casters (`docs/translucency.md`), layer for layer with `shadow_maps`: the product of
// the transmittance of the translucent casters in front of the nearest opaque one, and the
// nearest translucent caster's depth. Read only by pipelines compiled with TRANSLUCENT, only for
// views whose light has such maps (`View::rect.w` = 1).
@group(1) @binding(6) var transmit_maps: texture_2d_array<f32>;
@group(1) @binding(7) var translucent_depth: texture_depth_2d_array;
override TRANSLUCENT: bool = false;

// How lights pick their view (`Light::cube`), one bit per mode in VIEW_MODES: the light pass is
// compiled for the modes its lights use, like LIGHT_KINDS.
const MODE_SINGLE: u32 = 0u;
const MODE_CUBE: u32 = 1u;
const MODE_SPLIT: u32 = 2u;
// Not a value of Light::cube: the bit of lights with near cascades (Light::cascades).
const MODE_CASCADE: u32 = 3u;
override VIEW_MODES: u32 = 15u;
// Most cascades of one light (`scene::shadow_views::MAX_CASCADES`).
const MAX_CASCADES: u32 = 4u;

fn uses_mode(mode: u32) -> bool {
    return (VIEW_MODES & (1u << mode)) != 0u;
}

// Whether s picks its view by `mode`; when the pipeline has that mode only, without reading s.
fn is_mode(s: Light, mode: u32) -> bool {
    return uses_mode(mode) && (VIEW_MODES == (1u << mode) || s.cube == mode);
}

// A vector in cube face `face`'s view frame (right, up, −forward) from its coordinates c in the
// light's cube frame (`scene::shadow_views::cube_frame`, left-handed: r × u = −axis). Rounding
// aside this is the face's view matrix, without reading it (`lights.rs` tests the two agree).
fn cube_face_coords(face: u32, c: vec3f) -> vec3f {
    var q = vec3f(-c.x, c.y, c.z);
    q = select(q, vec3f(c.x, c.y, -c.z), face == 4u);
    q = select(q, vec3f(-c.z, c.x, c.y), face == 3u);
    q = select(q, vec3f(-c.z, -c.x, -c.y), face == 2u);
    q = select(q, vec3f(c.z, c.y, c.x), face == 1u);
    q = select(q, vec3f(-c.z, c.y, -c.x), face == 0u);
    return q;
}

// A point and a normal in the frame of the light's view that holds the point.
struct Placed {
    // The view, NO_VIEW where the light has none there.
    index: u32,
    q: vec3f,
    n: vec3f,
    // The cube face whose own axes make q's frame, NO_FACE where the view's matrix does.
    face: u32,
}

const NO_FACE: u32 = 6u;

// The linear map from placed's view frame back to the world (rotation only): a world point is
// p + to_world·(its view-frame point − q). Only the receiver-plane test needs it, so it is
// built there, not for every placed point.
fn placed_to_world(s: Light, placed: Placed) -> mat3x3f {
    if placed.face < NO_FACE {
        // The face's frame is P·B (B: rows cube_x, cube_y, cube_z; P: the face's signed
        // permutation), so back to the world is Bᵀ·Pᵀ.
        let perm = mat3x3f(
            cube_face_coords(placed.face, vec3f(1.0, 0.0, 0.0)),
            cube_face_coords(placed.face, vec3f(0.0, 1.0, 0.0)),
            cube_face_coords(placed.face, vec3f(0.0, 0.0, 1.0)),
        );
        return mat3x3f(s.cube_x, cross(s.cube_x, s.cube_z), s.cube_z) * transpose(perm);
    }
    // A view matrix is rigid: its rotation's inverse is its transpose.
    let m = view_at(placed.index).view;
    return transpose(mat3x3f(m[0].xyz, m[1].xyz, m[2].xyz));
}

// The view of light s that holds p (its only one, the side of its split plane, or the cube face
// of p's direction), with p and the geometric normal ng in that view's frame.
fn place(s: Light, p: vec3f, ng: vec3f) -> Placed {
    var out = Placed(NO_VIEW, vec3f(0.0), vec3f(0.0), NO_FACE);
    let d = p - s.position;
    if uses_mode(MODE_SINGLE) || uses_mode(MODE_SPLIT) || uses_mode(MODE_CASCADE) {
        var index = s.first_view;
        if uses_mode(MODE_SPLIT) {
            let side = select(face_view(s, 1u), face_view(s, 0u), dot(d, s.cube_x) >= 0.0);
            index = select(index, side, is_mode(s, MODE_SPLIT));
        }
        if uses_mode(MODE_CASCADE) && s.cascades > 0u && !is_mode(s, MODE_SPLIT) {
            // A single base view comes after the near cascades.
            index += s.cascades;
        }
        let v = view_at(index);
        out = Placed(index, (v.view * vec4f(p, 1.0)).xyz, (v.view * vec4f(ng, 0.0)).xyz, NO_FACE);
    }
    if is_mode(s, MODE_CUBE) {
        let cube_y = cross(s.cube_x, s.cube_z);
        let c = vec3f(dot(d, s.cube_x), dot(d, cube_y), dot(d, s.cube_z));
        let cn = vec3f(dot(ng, s.cube_x), dot(ng, cube_y), dot(ng, s.cube_z));
        // The dominant axis, ties to x before y before z; its sign picks +/−.
        let a = abs(c);
        let on_x = a.x >= a.y && a.x >= a.z;
        let on_y = !on_x && a.y >= a.z;
        let positive = select(select(c.z >= 0.0, c.y >= 0.0, on_y), c.x >= 0.0, on_x);
        let face = select(select(4u, 2u, on_y), 0u, on_x) + select(1u, 0u, positive);
        out = Placed(face_view(s, face), cube_face_coords(face, c), cube_face_coords(face, cn), face);
    }
    // Near cascades first: the first whose end lies beyond p's eye depth, if any does.
    if uses_mode(MODE_CASCADE) && s.cascades > 0u {
        let z = dot(p - frame.camera, frame.forward);
        var k = 0u;
        for (var i = 0u; i < min(s.cascades, MAX_CASCADES); i++) {
            k += select(0u, 1u, z >= view_at(s.first_view + i).cascade_to);
        }
        if k < s.cascades {
            let v = view_at(s.first_view + k);
            out = Placed(s.first_view + k, (v.view * vec4f(p, 1.0)).xyz, (v.view * vec4f(ng, 0.0)).xyz, NO_FACE);
        }
    }
    // Cube-mode lights always have a view; others may have none.
    if VIEW_MODES != (1u << MODE_CUBE) && s.view_count == 0u {
        out.index = NO_VIEW;
    }
    return out;
}

// Only directional samples have orthographic views.
fn is_ortho(v: View) -> bool {
    return handles(KIND_DIRECTIONAL) && v.ortho != 0u;
}

fn project(v: View, q: vec3f) -> vec4f {
    var x = v.proj_a.x * q.x + v.proj_a.y * q.z;
    var y = v.proj_a.w * q.y + v.proj_b.x * q.z;
    // Only orthographic views have offsets here (a perspective view's are 0: not read).
    if handles(KIND_DIRECTIONAL) {
        x += v.proj_a.z;
        y += v.proj_b.y;
    }
    return vec4f(x, y, v.proj_b.z * q.z + v.proj_b.w, select(-q.z, 1.0, is_ortho(v)));
}

// The depth a receiver at q (view frame) is compared with, moved `bias` metres towards the light
// along the map's axis.
fn reference_depth(v: View, q: vec3f, bias: f32) -> f32 {
    let cb = project(v, vec3f(q.xy, q.z + bias));
    return select(1.0, clamp(cb.z / cb.w, 0.0, 1.0), cb.w > 0.0);
}

// A receiver as the object-ID lookups see it.
struct Receiver {
    v: View,
    q: vec3f,
    // Its position in the layer, in texels.
    at: vec2f,
    layer: u32,
    object: u32,
    // Its geometric normal in the view's frame.
    n: vec3f,
    // Its world position, and the view frame's map back to the world (`placed_to_world`; only
    // read by the receiver-plane test).
    p: vec3f,
    to_world: mat3x3f,
    // Reference depth against texels of its own object (under the slope bias).
    own: f32,
    // Bias against other objects' texels: metres at the receiver, plus metres per texel of the
    // texel centre's offset from it.
    base: f32,
    per_texel: f32,
}

// Where texel c's centre ray meets the receiver's plane (through q with normal n), in the view's
// frame: exact for a plane (receiver-plane depth bias). w is 0 where the ray runs (nearly) along
// the plane or meets it behind the light: no point (tested before dividing, not by NaN, which
// shader compilers may assume away).
fn plane_point(r: Receiver, c: vec2i) -> vec4f {
    let uv = (vec2f(c) + vec2f(0.5) - r.v.rect.xy) / r.v.rect.z;
    let ndc = vec2f(2.0 * uv.x - 1.0, 1.0 - 2.0 * uv.y);
    let a = r.v.proj_a;
    let b = r.v.proj_b;
    if is_ortho(r.v) {
        // x = (ndc.x − a.y·z − a.z)/a.x at the receiver's z; the plane's z there.
        let x = (ndc.x - a.y * r.q.z - a.z) / a.x;
        let y = (ndc.y - b.x * r.q.z - b.y) / a.w;
        if abs(r.n.z) < 1e-4 {
            return vec4f(0.0);
        }
        return vec4f(x, y, r.q.z - (r.n.x * (x - r.q.x) + r.n.y * (y - r.q.y)) / r.n.z, 1.0);
    }
    // Perspective: ndc = (a.x·x + a.y·z, a.w·y + b.x·z)/(−z), so the centre's tangent is
    // ((ndc.x + a.y)/a.x, (ndc.y + b.x)/a.w), and the plane's depth along it (n·q)/(n·(t, −1)).
    let d = vec3f((ndc.x + a.y) / a.x, (ndc.y + b.x) / a.w, -1.0);
    let along = dot(r.n, d);
    if abs(along) < 1e-4 * length(d) {
        return vec4f(0.0);
    }
    let depth = dot(r.n, r.q) / along;
    return vec4f(d * depth, select(0.0, 1.0, depth > 0.0));
}

struct Bounds {
    lo: vec4f,
    hi: vec4f,
    // The solid box the object fills, if it fills one (w 1): centre, and axes with their half
    // extents in w.
    center: vec4f,
    axis_x: vec4f,
    axis_y: vec4f,
    axis_z: vec4f,
}

// Each object's axis-aligned world bounds, object − 1 for object, posed with the meshes, and the
// oriented box it fills where it fills one (every triangle on a face of it: a wall, a tile, a
// turned crate), so a point in that box is in the solid (node/src/gpu/scene_data.rs,
// `GpuBounds`).
@group(0) @binding(4) var<storage, read> object_bounds: array<Bounds>;

// The world point of the receiver's view-frame point pv.
fn receiver_world(r: Receiver, pv: vec3f) -> vec3f {
    return r.p + r.to_world * (pv - r.q);
}

// The bounds of `object` (> 0: mesh index + 1).
fn bounds_of(object: u32) -> Bounds {
    return object_bounds[min(object - 1u, arrayLength(&object_bounds) - 1u)];
}

// Whether world point w lies inside `object`'s solid: in the oriented box it fills, widened by
// `margin` (a sphere's or a mesh's box holds air: never; object 0, no caster, holds nothing).
fn in_solid_box(object: u32, w: vec3f, margin: f32) -> bool {
    if object == 0u {
        return false;
    }
    let b = bounds_of(object);
    if b.center.w < 0.5 {
        return false;
    }
    let d = w - b.center.xyz;
    return abs(dot(d, b.axis_x.xyz)) <= b.axis_x.w + margin
        && abs(dot(d, b.axis_y.xyz)) <= b.axis_y.w + margin
        && abs(dot(d, b.axis_z.xyz)) <= b.axis_z.w + margin;
}

// Whether world point w lies in `object`'s box widened by `margin` metres (object 0, no caster,
// holds nothing).
fn in_object_box(object: u32, w: vec3f, margin: f32) -> bool {
    if object == 0u {
        return false;
    }
    let b = bounds_of(object);
    return all(w >= b.lo.xyz - vec3f(margin)) && all(w <= b.hi.xyz + vec3f(margin));
}

// (lit, counts) for texel t: lit is 1 where the receiver is at least as near the light as t's
// caster, else 0. A texel of the receiver's own object is compared under the slope bias (a
// surface cannot shadow itself within its own depth slope); any other object's caster is
// compared with the receiver's plane where that texel's centre ray meets it, moved by the
// constant bias (a caster in front of the plane there shadows it), the plane's offset towards
// the light held within what the slope bias allows at that texel's distance (slope capped at 2).
// A caster thinner than the slope bias (a roof, a fin's foot) still shadows, and so does a wall
// standing on the receiver's own plane: its texels beside the receiver lie in front of the plane
// however near its foot (the symmetric bound alone, 1.5× the plane's slope, let a 1 cm wall's
// foot light the floor behind it). counts is 0, and the filter leaves the texel out, where that
// plane point lies outside the receiver's own object's box — the texel is past the receiver's
// edge (a wall's inside face where another wall closes the corner: the texels past that wall's
// silhouette are the ground behind the house) — or inside the caster's solid, where the caster
// fills its box: the plane there runs under the caster (the floor beneath a box standing on
// it, whose texels would otherwise darken the lit floor at its foot by the filter's width). A
// caster that does not fill its box (a sphere, a mesh) never counts as holding the plane: its
// box also holds air, where its texels shadow the plane rightly (the floor beneath a ball).
fn texel_lit(r: Receiver, t: vec2i) -> vec2f {
    let lo = vec2i(r.v.rect.xy);
    let c = clamp(t, lo, lo + vec2i(i32(r.v.rect.z) - 1));
    let stored = textureLoad(shadow_maps, c, r.layer, 0);
    var ref_depth = r.own;
    var counts = 1.0;
    let caster = textureLoad(shadow_ids, c, r.layer, 0).x;
    if caster != r.object {
        let off = abs(vec2f(c) + vec2f(0.5) - r.at);
        let bound = r.per_texel * max(off.x, off.y);
        var plane = bound;
        if (frame.flags & FLAG_RECEIVER_PLANE) != 0u {
            let pv = plane_point(r, c);
            if pv.w > 0.0 {
                plane = clamp(pv.z - r.q.z, 0.0, bound);
                let w = receiver_world(r, pv.xyz);
                if !in_object_box(r.object, w, r.base) || in_solid_box(caster, w, r.base) {
                    counts = 0.0;
                }
            }
        }
        ref_depth = reference_depth(r.v, r.q, r.base + plane);
    }
    var lit = ref_depth >= stored;
    if (frame.flags & FLAG_CONVENTIONAL_Z) != 0u {
        lit = ref_depth <= stored;
    }
    return vec2f(select(0.0, 1.0, lit), counts);
}

// a + (b − a)·w: exactly a where a = b (fully lit stays exactly 1).
fn lerp(a: f32, b: f32, w: f32) -> f32 {
    return a + (b - a) * w;
}

// The bilinear 2×2 footprint around `at` (texels), as the comparison sampler weighs it:
// (Σ w·lit over the texels that count, Σ w over them, the plain bilinear of every texel's lit).
fn texel_bilinear(r: Receiver, at: vec2f) -> vec3f {
    let p = at - vec2f(0.5);
    let b = floor(p);
    let f = p - b;
    let t = vec2i(b);
    let a = texel_lit(r, t);
    let bx = texel_lit(r, t + vec2i(1, 0));
    let cy = texel_lit(r, t + vec2i(0, 1));
    let d = texel_lit(r, t + vec2i(1, 1));
    let w = vec4f((1.0 - f.x) * (1.0 - f.y), f.x * (1.0 - f.y), (1.0 - f.x) * f.y, f.x * f.y);
    let counted = w * vec4f(a.y, bx.y, cy.y, d.y);
    let lit = dot(counted, vec4f(a.x, bx.x, cy.x, d.x));
    let all_lit = lerp(lerp(a.x, bx.x, f.x), lerp(cy.x, d.x, f.x), f.y);
    return vec3f(lit, dot(counted, vec4f(1.0)), all_lit);
}

// A weighted sum of `texel_bilinear`s as the filter's result: the counted texels' mean, or
// where none counts, the plain mean of `n` footprints. Where every counted texel is lit the
// result is exactly 1.
fn counted_mean(sum: vec3f, n: f32) -> f32 {
    if sum.y > 0.0 {
        return select(sum.x / sum.y, 1.0, sum.x == sum.y);
    }
    return sum.z / n;
}

fn uses_object_ids() -> bool {
    return (frame.flags & FLAG_OBJECT_IDS) != 0u;
}

// One bilinear 2×2 footprint `offset` texels from the receiver: per texel with the object-ID
// test, else one hardware comparison lookup (`ref` passes where it is at least the stored
// reversed-Z depth).
fn footprint(r: Receiver, offset: vec2f) -> f32 {
    // Clamped to the square's outer texel centres, so the 2×2 footprint never reads a neighbour.
    let at = clamp(r.at + offset, r.v.rect.xy + vec2f(0.5), r.v.rect.xy + vec2f(r.v.rect.z - 0.5));
    return textureSampleCompareLevel(shadow_maps, shadow_linear, at / frame.map_size, r.layer, r.own);
}

// The filter's lookups for receiver r: the texel under it, one footprint, or a taps×taps grid
// of footprints one texel apart.
fn shadow_filter(r: Receiver) -> f32 {
    if uses_object_ids() {
        return shadow_filter_ids(r);
    }
    if SHADOW_FILTER == FILTER_NEAREST {
        // The linear sampler read at a texel centre selects that texel alone.
        let t = clamp(floor(r.at), r.v.rect.xy, r.v.rect.xy + vec2f(r.v.rect.z - 1.0));
        let centre = (t + vec2f(0.5)) / frame.map_size;
        return textureSampleCompareLevel(shadow_maps, shadow_linear, centre, r.layer, r.own);
    }
    if SHADOW_FILTER == FILTER_PCF2X2 || SHADOW_FILTER == FILTER_CELL {
        return footprint(r, vec2f(0.0));
    }
    let taps = max(SHADOW_TAPS, 1u);
    let half = 0.5 * f32(taps - 1u);
    var sum = 0.0;
    for (var j = 0u; j < taps; j++) {
        for (var i = 0u; i < taps; i++) {
            sum += footprint(r, vec2f(f32(i), f32(j)) - vec2f(half));
        }
    }
    return sum / f32(taps * taps);
}

// `shadow_filter` with the object-ID test: each texel's own comparison (`texel_lit`), texels
// past the receiver's edge left out.
fn shadow_filter_ids(r: Receiver) -> f32 {
    if SHADOW_FILTER == FILTER_NEAREST {
        return texel_lit(r, vec2i(floor(r.at))).x;
    }
    if SHADOW_FILTER == FILTER_PCF2X2 || SHADOW_FILTER == FILTER_CELL {
        return counted_mean(texel_bilinear(r, r.at), 1.0);
    }
    let taps = max(SHADOW_TAPS, 1u);
    let half = 0.5 * f32(taps - 1u);
    var sum = vec3f(0.0);
    for (var j = 0u; j < taps; j++) {
        for (var i = 0u; i < taps; i++) {
            sum += texel_bilinear(r, r.at + vec2f(f32(i), f32(j)) - vec2f(half));
        }
    }
    return counted_mean(sum, f32(taps * taps));
}

// Distance along the view's axis of a stored map depth (its inverse projection; reversed or
// conventional Z alike).
fn stored_distance(v: View, stored: f32) -> f32 {
    if is_ortho(v) {
        return -(stored - v.proj_b.w) / v.proj_b.z;
    }
    return v.proj_b.w / (stored + v.proj_b.z);
}

// The half-width, in texels of view v, of the shadow that one cell of width `cell` (metres;
// radians for a soft sun's direction, whose views are orthographic) casts past a blocker at
// distance `blocker` onto a receiver at distance `receiver` (both along the view's axis): the
// rays from the cell's edge to the receiver cross the blocker's depth that far from the ray
// from the sample. Similar triangles: cell/2 · (receiver − blocker) / (receiver · blocker) in
// tangent units, or cell/2 · (receiver − blocker) metres for a parallel view.
fn cell_radius(v: View, cell: f32, blocker: f32, receiver: f32) -> f32 {
    let gap = max(receiver - blocker, 0.0);
    if is_ortho(v) {
        return 0.5 * cell * gap / v.texel;
    }
    return 0.5 * cell * gap / (max(receiver, 1e-6) * max(blocker, 1e-6) * v.texel);
}

// The cell filter (FILTER_CELL) for receiver r of sample s: a blocker search over the reach a
// cell can have (taps × taps texels over ±reach, other objects' texels nearer the light than the
// receiver by more than the bias another object's texel gets there), then, where it finds
// blockers, a taps × taps grid of 2×2 footprints spread over ±the radius their mean distance
// gives (`cell_radius`). Where the search finds none the receiver gets the 2×2 footprint under
// it alone (what PCF 2×2 gives), so a blocker the sparse search steps over still shadows as a
// point sample would. `own_bias(radius)` is the receiver's own bias for a footprint of that
// half-width.
fn cell_filter(r_in: Receiver, cell: f32, slope_part: f32, own_const: f32) -> f32 {
    var r = r_in;
    let receiver = max(-r.q.z, 1e-6);
    var near = 1.0;
    if (frame.flags & FLAG_CONVENTIONAL_Z) != 0u {
        near = 0.0;
    }
    let reach = clamp(cell_radius(r.v, cell, stored_distance(r.v, near), receiver), 0.5, MAX_CELL_RADIUS);
    let taps = max(SHADOW_TAPS, 2u);
    let step = 2.0 * reach / f32(taps - 1u);
    let lo = vec2i(r.v.rect.xy);
    let hi = lo + vec2i(i32(r.v.rect.z) - 1);
    var found = 0.0;
    var sum_distance = 0.0;
    for (var j = 0u; j < taps; j++) {
        for (var i = 0u; i < taps; i++) {
            let offset = vec2f(f32(i), f32(j)) * step - vec2f(reach);
            let c = clamp(vec2i(floor(r.at + offset)), lo, hi);
            if uses_object_ids() && textureLoad(shadow_ids, c, r.layer, 0).x == r.object {
                continue;
            }
            let stored = textureLoad(shadow_maps, c, r.layer, 0);
            let off = abs(vec2f(c) + vec2f(0.5) - r.at);
            let ref_depth = reference_depth(r.v, r.q, r.base + r.per_texel * max(off.x, off.y));
            var blocks = ref_depth < stored;
            if (frame.flags & FLAG_CONVENTIONAL_Z) != 0u {
                blocks = ref_depth > stored;
            }
            if blocks {
                found += 1.0;
                sum_distance += stored_distance(r.v, stored);
            }
        }
    }
    if found == 0.0 {
        if uses_object_ids() {
            return counted_mean(texel_bilinear(r, r.at), 1.0);
        }
        return footprint(r, vec2f(0.0));
    }
    let radius = clamp(cell_radius(r.v, cell, sum_distance / found, receiver), 0.5, MAX_CELL_RADIUS);
    // The receiver's own texels under the slope bias of this footprint.
    r.own = reference_depth(r.v, r.q, own_const + slope_part * (radius + 0.5));
    // Footprint centres at the middles of taps × taps equal cells of ±radius.
    let spacing = 2.0 * radius / f32(taps);
    let first = -radius + 0.5 * spacing;
    var sum = vec3f(0.0);
    var plain = 0.0;
    for (var j = 0u; j < taps; j++) {
        for (var i = 0u; i < taps; i++) {
            let offset = vec2f(first) + vec2f(f32(i), f32(j)) * spacing;
            if uses_object_ids() {
                sum += texel_bilinear(r, r.at + offset);
            } else {
                plain += footprint(r, offset);
            }
        }
    }
    if uses_object_ids() {
        return counted_mean(sum, f32(taps * taps));
    }
    return plain / f32(taps * taps);
}

// Whether a receiver at reference depth `ref_depth` lies in front of the stored depth.
fn in_front_of(ref_depth: f32, stored: f32) -> bool {
    if (frame.flags & FLAG_CONVENTIONAL_Z) != 0u {
        return ref_depth <= stored;
    }
    return ref_depth >= stored;
}

// What translucent casters let through to a receiver at texel t: the stored transmittance
// where the receiver, at reference depth `ref_depth`, lies behind the nearest translucent caster,
// else 1. Views with two translucent layers (`View::rect.w` = 2, peeling renderers) keep the
// second layer at layer + half the array's layers: a receiver behind the first layer but in
// front of the second gets the first's own transmittance only.
fn texel_transmit(r: Receiver, t: vec2i, ref_depth: f32) -> vec3f {
    let lo = vec2i(r.v.rect.xy);
    let c = clamp(t, lo, lo + vec2i(i32(r.v.rect.z) - 1));
    let stored = textureLoad(translucent_depth, c, r.layer, 0);
    if in_front_of(ref_depth, stored) {
        return vec3f(1.0);
    }
    if r.v.rect.w > 1.5 {
        let second = r.layer + textureNumLayers(translucent_depth) / 2u;
        if in_front_of(ref_depth, textureLoad(translucent_depth, c, second, 0)) {
            return textureLoad(transmit_maps, c, second, 0).rgb;
        }
    }
    return textureLoad(transmit_maps, c, r.layer, 0).rgb;
}

// The receiver's reference depth against translucent casters' texels up to `reach` texels from
// it: under the bias of another object's texel (`texel_lit`) at that offset, one projection for
// a whole footprint.
fn transmit_reference(r: Receiver, reach: f32) -> f32 {
    return reference_depth(r.v, r.q, r.base + r.per_texel * reach);
}

fn lerp3(a: vec3f, b: vec3f, w: f32) -> vec3f {
    return a + (b - a) * w;
}

// The bilinear 2×2 footprint of `texel_transmit` around `at` (texels), `offset` texels from the
// receiver (its texel centres lie within max(|offset|) + 1 of it).
fn transmit_bilinear(r: Receiver, offset: vec2f) -> vec3f {
    let reach = max(abs(offset.x), abs(offset.y)) + 1.0;
    let ref_depth = transmit_reference(r, reach);
    let p = r.at + offset - vec2f(0.5);
    let b = floor(p);
    let f = p - b;
    let t = vec2i(b);
    let top = lerp3(
        texel_transmit(r, t, ref_depth),
        texel_transmit(r, t + vec2i(1, 0), ref_depth),
        f.x,
    );
    let bottom = lerp3(
        texel_transmit(r, t + vec2i(0, 1), ref_depth),
        texel_transmit(r, t + vec2i(1, 1), ref_depth),
        f.x,
    );
    return lerp3(top, bottom, f.y);
}

// The shadow filter's footprint over the transmittance maps (`shadow_filter`).
fn transmit_filter(r: Receiver) -> vec3f {
    if SHADOW_FILTER == FILTER_NEAREST {
        return texel_transmit(r, vec2i(floor(r.at)), transmit_reference(r, 0.5));
    }
    if SHADOW_FILTER == FILTER_PCF2X2 || SHADOW_FILTER == FILTER_CELL {
        return transmit_bilinear(r, vec2f(0.0));
    }
    let taps = max(SHADOW_TAPS, 1u);
    let half = 0.5 * f32(taps - 1u);
    var sum = vec3f(0.0);
    for (var j = 0u; j < taps; j++) {
        for (var i = 0u; i < taps; i++) {
            sum += transmit_bilinear(r, vec2f(f32(i), f32(j)) - vec2f(half));
        }
    }
    return sum / f32(taps * taps);
}

// s_λ (RGB) at world point p with geometric normal ng on object `object`: the opaque casters'
// filtered visibility times, where the view has transmittance maps, what translucent casters
// let through; 1 where no view of the light holds p.
//
// Bias: the constant part is `depth_bias` metres along the light ray; the slope part follows the
// receiver's own plane: how much its view-axis depth D changes across the filter footprint in the
// map, |∂D/∂x| + |∂D/∂y| per texel (exact for a plane, also off-axis in wide frusta and cube faces).
// With the object-ID test the slope part applies to the receiver's own object only (`texel_lit`).
fn visibility(s: Light, p: vec3f, ng: vec3f, object: u32) -> vec3f {
    let placed = place(s, p, ng);
    if placed.index == NO_VIEW {
        return vec3f(1.0);
    }
    let v = view_at(placed.index);
    let q = placed.q;
    let clip = project(v, q);
    if !(clip.w > 0.0) {
        return vec3f(1.0);
    }
    let ndc = clip.xy / clip.w;
    let uv = vec2f(ndc.x * 0.5 + 0.5, 0.5 - ndc.y * 0.5);
    if any(uv < vec2f(0.0)) || any(uv > vec2f(1.0)) {
        return vec3f(1.0);
    }
    let n = placed.n;
    let depth = max(-q.z, 0.0);
    // Depth change per texel: slope · texel_m, with texel_m the texel width in metres.
    // Perspective: the plane through q with normal n has depth D = (n·q) / (n·(x, y, −1)) at
    // tangent (x, y), so |∂D/∂x| = D·|n.x| / |n·(x, y, −1)|.
    let d = vec3f(q.xy / max(depth, 1e-6), -1.0);
    var slope = (abs(n.x) + abs(n.y)) / max(abs(dot(n, d)), 1e-3);
    var texel_m = v.texel * depth;
    var along_axis = depth / max(length(q), 1e-6);
    if is_ortho(v) {
        slope = (abs(n.x) + abs(n.y)) / max(abs(n.z), 1e-3);
        texel_m = v.texel;
        along_axis = 1.0;
    }
    // Grazing receivers cannot ask for more than ten texels' worth of depth per texel.
    let slope_part = frame.slope_bias * min(slope, 10.0) * texel_m;
    let bias = frame.depth_bias * along_axis + slope_part * frame.kernel_radius;
    var to_world = mat3x3f();
    if uses_object_ids() && (frame.flags & FLAG_RECEIVER_PLANE) != 0u {
        to_world = placed_to_world(s, placed);
    }
    let r = Receiver(
        v,
        q,
        v.rect.xy + uv * v.rect.z,
        v.layer,
        object,
        n,
        p,
        to_world,
        reference_depth(v, q, bias),
        frame.depth_bias * along_axis,
        frame.slope_bias * min(slope, 2.0) * texel_m,
    );
    var lit = 0.0;
    if SHADOW_FILTER == FILTER_CELL && s.cell > 0.0 {
        lit = cell_filter(r, s.cell, slope_part, frame.depth_bias * along_axis);
    } else {
        lit = shadow_filter(r);
    }
    if TRANSLUCENT && v.rect.w != 0.0 && lit > 0.0 {
        return lit * transmit_filter(r);
    }
    return vec3f(lit);
}

// A visible surface point: position, unit shading and geometric normals facing the viewer, its
// material index, its object (mesh index + 1) and its shading texture coordinates.
struct Surface {
    p: vec3f,
    n: vec3f,
    ng: vec3f,
    material: u32,
    object: u32,
    uv: vec2f,
}

// `const METALLIC_ROUGHNESS: bool`, whether any material is metallic-roughness, heads the module
// (`lightfold_shaders`): a plain constant, so a Blinn-Phong scene's pipelines hold none of that
// code (an override of the same name left it in lavapipe's code: eye passes 1.2× slower).

struct Shaded {
    diffuse: vec3f,
    specular: vec3f,
}

// `start` + Σ_λ (c_λ ⊘ c_n)·(i^d_λ, i^s_λ)·s_λ at a surface point, in light order (a deferred
// pass split into dispatches adds in the same order as one dispatch). Metallic-roughness
// materials take the glTF reference BRDF's coefficients (`scene::shading::lobe_coefficients`):
// i^d = E·(1 − w)/π, i^s = E·D·V·(F0 + (1 − F0)·w), RGB.
fn illuminate(sf: Surface, start: Shaded) -> Shaded {
    let m = materials[sf.material];
    if METALLIC_ROUGHNESS && m.model == MODEL_METALLIC_ROUGHNESS {
        return illuminate_metallic_roughness(sf, start);
    }
    let v = safe_normalize(frame.camera - sf.p);
    let specular = m.has_specular != 0u;
    var out = start;
    for (var i = 0u; i < frame.light_count; i++) {
        let s = light_at(i);
        let c = coefficients(s, sf.p, sf.n, v, m.shininess, specular);
        if c.x == 0.0 && c.y == 0.0 {
            continue;
        }
        let vis = visibility(s, sf.p, sf.ng, sf.object);
        out.diffuse += s.weight * (c.x * vis);
        out.specular += s.weight * (c.y * vis);
    }
    return out;
}

// Closed-form glossy specular of area lights (`scene::ltc`, docs/shading.md): keep the two in
// step. The fitted table, two vec4 a cell: M⁻¹'s (a, b, c, d), then the lobe's norm and Fresnel
// integral.
@group(0) @binding(5) var<storage, read> ltc_table: array<vec4f>;

const LTC_SIZE: u32 = 64u;
const LTC_MAX_VERTICES: u32 = 8u;
// Circumradius of the regular octagon with the unit disk's area.
const OCTAGON_RADIUS: f32 = 1.0539074;
const MIN_COSINE_INTEGRAL: f32 = 1e-7;

fn ltc_cell(row: u32, column: u32, half: u32) -> vec4f {
    return ltc_table[(row * LTC_SIZE + column) * 2u + half];
}

// Half `half` of the table bilinearly interpolated at GGX α and view cosine `cos_v`.
fn ltc_lookup(alpha: f32, cos_v: f32, half: u32) -> vec4f {
    let last = f32(LTC_SIZE - 1u);
    let x = sqrt(clamp(alpha, 0.0, 1.0)) * last;
    let y = sqrt(1.0 - clamp(cos_v, 0.0, 1.0)) * last;
    let i = min(u32(floor(x)), LTC_SIZE - 2u);
    let j = min(u32(floor(y)), LTC_SIZE - 2u);
    let fx = x - f32(i);
    let fy = y - f32(j);
    let a = ltc_cell(i, j, half);
    let b = ltc_cell(i + 1u, j, half);
    let top = a + (ltc_cell(i, j + 1u, half) - a) * fy;
    let bottom = b + (ltc_cell(i + 1u, j + 1u, half) - b) * fy;
    return top + (bottom - top) * fx;
}

// A unit tangent of unit n (`scene::sampling::basis`'s first axis).
fn tangent_of(n: vec3f) -> vec3f {
    let helper = select(vec3f(0.0, 1.0, 0.0), vec3f(1.0, 0.0, 0.0), abs(n.x) < 0.9);
    return safe_normalize(cross(helper, n));
}

struct Polygon {
    v: array<vec3f, 8>,
    count: u32,
}

// The polygon standing for a sample's area light seen from p (`scene::ltc::polygon`); no
// vertices from inside a sphere light.
fn area_polygon(s: Light, p: vec3f) -> Polygon {
    var out: Polygon;
    out.count = 0u;
    if s.area_kind == AREA_RECT {
        out.v[0] = s.area_center - s.area_u - s.area_v;
        out.v[1] = s.area_center + s.area_u - s.area_v;
        out.v[2] = s.area_center + s.area_u + s.area_v;
        out.v[3] = s.area_center - s.area_u + s.area_v;
        out.count = 4u;
        return out;
    }
    var c = s.area_center;
    var u = s.area_u;
    var w = s.area_v;
    if s.area_kind == AREA_SPHERE {
        let radius = s.area_u.x;
        let d = s.area_center - p;
        let dist = length(d);
        if !(dist > radius * 1.0001) {
            return out;
        }
        let k = (radius / dist) * (radius / dist);
        c = p + d * (1.0 - k);
        let r = radius * sqrt(1.0 - k);
        let axis = d * (1.0 / dist);
        let t = tangent_of(axis);
        u = t * r;
        w = cross(axis, t) * r;
    }
    for (var k = 0u; k < LTC_MAX_VERTICES; k++) {
        let phi = 2.0 * PI * f32(k) / f32(LTC_MAX_VERTICES);
        out.v[k] = c + (u * (cos(phi) * OCTAGON_RADIUS) + w * (sin(phi) * OCTAGON_RADIUS));
    }
    out.count = LTC_MAX_VERTICES;
    return out;
}

// One edge's share of 2π·∫cos/π over a spherical polygon (unit a, b).
fn ltc_edge(a: vec3f, b: vec3f) -> f32 {
    let c = cross(a, b);
    let s = length(c);
    let theta = atan2(s, dot(a, b));
    return c.z * select(1.0, theta / s, s > 1e-9);
}

// ∫ max(z, 0)/π dω over the spherical polygon of directions `poly`, clipped to z ≥ 0.
fn clipped_cosine_integral(poly: Polygon) -> f32 {
    var clipped: array<vec3f, 9>;
    var m = 0u;
    for (var k = 0u; k < poly.count; k++) {
        let a = poly.v[k];
        let b = poly.v[(k + 1u) % poly.count];
        if a.z >= 0.0 {
            clipped[m] = a;
            m++;
        }
        if (a.z >= 0.0) != (b.z >= 0.0) && m < 9u {
            let t = a.z / (a.z - b.z);
            var x = a + (b - a) * t;
            x.z = 0.0;
            clipped[m] = x;
            m++;
        }
    }
    var sum = 0.0;
    for (var k = 0u; k < m; k++) {
        sum += ltc_edge(safe_normalize(clipped[k]), safe_normalize(clipped[(k + 1u) % m]));
    }
    return abs(sum / (2.0 * PI));
}

// (S₁/E, S_w/E, 1) of a sample's area light at a surface point (`scene::ltc::ggx_area_terms`),
// or zero where the closed form does not apply.
fn ggx_area_terms(s: Light, p: vec3f, n: vec3f, v: vec3f, alpha: f32) -> vec3f {
    let world = area_polygon(s, p);
    if world.count == 0u {
        return vec3f(0.0);
    }
    let along = v - n * dot(n, v);
    let l = length(along);
    let t1 = select(tangent_of(n), along * (1.0 / l), l > 1e-6);
    let t2 = cross(n, t1);
    let m = ltc_lookup(alpha, dot(n, v), 0u);
    var local: Polygon;
    var lobe: Polygon;
    local.count = world.count;
    lobe.count = world.count;
    for (var k = 0u; k < world.count; k++) {
        let w = world.v[k] - p;
        let q = vec3f(dot(w, t1), dot(w, t2), dot(w, n));
        local.v[k] = q;
        lobe.v[k] = vec3f(m.x * q.x + m.y * q.z, q.y, m.z * q.x + m.w * q.z);
    }
    let e = clipped_cosine_integral(local);
    if !(e > MIN_COSINE_INTEGRAL) {
        return vec3f(0.0);
    }
    let k = ltc_lookup(alpha, dot(n, v), 1u);
    let ratio = clipped_cosine_integral(lobe) / (PI * e);
    let terms = vec2f(k.x * ratio, k.y * ratio);
    return select(vec3f(0.0), vec3f(terms, 1.0), all(abs(terms) < vec2f(3.0e38)));
}

// Roughness range over which glossy specular passes from the closed form to the samples' own.
const CLOSED_FORM_ROUGHNESS: vec2f = vec2f(0.4, 0.6);

// The closed form's share at GGX α (`scene::ltc::closed_form_share`).
fn closed_form_share(alpha: f32) -> f32 {
    let r = sqrt(max(alpha, 0.0));
    let t = clamp((r - CLOSED_FORM_ROUGHNESS.x) / (CLOSED_FORM_ROUGHNESS.y - CLOSED_FORM_ROUGHNESS.x), 0.0, 1.0);
    return 1.0 - t * t * (3.0 - 2.0 * t);
}

// Whether two samples belong to the same area light (consecutive samples of one light share
// its closed-form terms).
fn same_area(a: Light, b: Light) -> bool {
    return a.area_kind == b.area_kind && all(a.area_center == b.area_center)
        && all(a.area_u == b.area_u) && all(a.area_v == b.area_v);
}

fn illuminate_metallic_roughness(sf: Surface, start: Shaded) -> Shaded {
    let lobe = metallic_roughness_lobe(sf.material, sf.uv);
    let f0 = lobe.xyz;
    let v = safe_normalize(frame.camera - sf.p);
    var out = start;
    // The closed form's share of glossy specular, the last area light's terms and the sample
    // they were computed for.
    let share = closed_form_share(lobe.w);
    var area_terms = vec3f(0.0);
    var area_of: Light;
    area_of.area_kind = AREA_NONE;
    for (var i = 0u; i < frame.light_count; i++) {
        let s = light_at(i);
        let lr = to_light(s, sf.p);
        let e = irradiance(s, lr, sf.n);
        if e == 0.0 {
            continue;
        }
        let t = ggx_terms(sf.n, lr.xyz, v, lobe.w);
        var x = e * t.y * (f0 + (vec3f(1.0) - f0) * t.z);
        if s.area_kind != AREA_NONE && share > 0.0 {
            if !same_area(s, area_of) {
                area_terms = ggx_area_terms(s, sf.p, sf.n, v, lobe.w);
                area_of = s;
            }
            if area_terms.z > 0.0 {
                let closed = e * (f0 * area_terms.x + (vec3f(1.0) - f0) * area_terms.y);
                x = x + (closed - x) * share;
            }
        }
        let is = select(vec3f(0.0), x, abs(x) < vec3f(3.0e38));
        let vis = visibility(s, sf.p, sf.ng, sf.object);
        out.diffuse += s.weight * (e * t.x * vis);
        out.specular += s.weight * (is * vis);
    }
    return out;
}

// Eye depth: distance along the camera's forward axis.
fn eye_depth(p: vec3f) -> f32 {
    return dot(p - frame.camera, frame.forward);
}
