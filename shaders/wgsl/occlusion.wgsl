// Occlusion culling for the eye pass (`node::gpu::occlusion`, docs/scaling.md § Occlusion
// culling). A hierarchical depth (HZB) of an eye depth buffer, its levels one after the other in
// a storage buffer: level 0 has a texel per 2×2 pixels, each level halves the one below (rounding
// up, so texel x of level l covers pixels [x·2^(l+1), (x+1)·2^(l+1)) exactly), and every texel
// holds the FARTHEST depth of the pixels it covers (reversed-Z: the least; 0 where it covers
// none). Then one test per candidate box: the
// box is hidden where its nearest depth is farther than the farthest depth over every pixel its
// projection could cover. Every fragment of a triangle inside the box is then behind a surface
// the eye pass draws too, so leaving the box out changes no pixel.

// One level of the HZB in the pyramid buffer: where it starts and its size in texels.
struct Level {
    offset: u32,
    width: u32,
    height: u32,
    _pad: u32,
}

struct Reduce {
    // The level read (unused for level 0, read from the depth buffer of `dst`'s pixels × 2).
    src: Level,
    // The level written.
    dst: Level,
    // The depth buffer's size in pixels.
    pixels: vec2u,
}

@group(0) @binding(0) var<uniform> reduce: Reduce;
@group(0) @binding(1) var src_depth: texture_depth_2d;
@group(0) @binding(2) var<storage, read_write> pyramid: array<f32>;

// No pixel nearer than this was found yet (reversed-Z depths are at most 1).
const NONE_YET: f32 = 3.0;

fn farthest_of(found: f32) -> f32 {
    // A texel over no pixel of the source hides nothing.
    return select(found, 0.0, found == NONE_YET);
}

@compute @workgroup_size(8, 8)
fn cs_reduce_depth(@builtin(global_invocation_id) id: vec3u) {
    let dst = reduce.dst;
    if id.x >= dst.width || id.y >= dst.height {
        return;
    }
    var far = NONE_YET;
    for (var j = 0u; j < 2u; j++) {
        for (var i = 0u; i < 2u; i++) {
            let p = id.xy * 2u + vec2u(i, j);
            if all(p < reduce.pixels) {
                far = min(far, textureLoad(src_depth, p, 0));
            }
        }
    }
    pyramid[dst.offset + id.y * dst.width + id.x] = farthest_of(far);
}

@compute @workgroup_size(8, 8)
fn cs_reduce(@builtin(global_invocation_id) id: vec3u) {
    let src = reduce.src;
    let dst = reduce.dst;
    if id.x >= dst.width || id.y >= dst.height {
        return;
    }
    var far = NONE_YET;
    for (var j = 0u; j < 2u; j++) {
        for (var i = 0u; i < 2u; i++) {
            let p = id.xy * 2u + vec2u(i, j);
            if p.x < src.width && p.y < src.height {
                far = min(far, pyramid[src.offset + p.y * src.width + p.x]);
            }
        }
    }
    pyramid[dst.offset + id.y * dst.width + id.x] = farthest_of(far);
}

// Levels the test reads at most (level 0 at 2 pixels a texel: images up to 2^16 pixels a side).
const MAX_LEVELS: u32 = 16u;

struct Test {
    view_proj: mat4x4f,
    // The image in pixels.
    size: vec2f,
    count: u32,
    // Levels of the HZB.
    levels: u32,
    // Nonzero: test the box's farthest corner instead of its nearest (`Fault::OcclusionFarCorner`,
    // a negative control that hides boxes only partly behind the occluders).
    far_corner: u32,
    // A box is hidden only where its nearest depth is below the farthest occluder depth by more
    // than this share: the occluders and the eye pass compute a vertex's depth in different
    // pipelines.
    margin: f32,
    // The rows [y0, y1) the eye pass rasterises (a sort-first tile): no fragment lands outside.
    rows: vec2u,
    level: array<Level, MAX_LEVELS>,
}

struct Bounds {
    lo: vec4f,
    hi: vec4f,
}

// Bindings of their own: one module, each pipeline's layout made from what its entry point uses.
@group(0) @binding(4) var<uniform> test: Test;
@group(0) @binding(5) var<storage, read> hzb: array<f32>;
@group(0) @binding(6) var<storage, read> boxes: array<Bounds>;
@group(0) @binding(7) var<storage, read_write> visible: array<u32>;

fn box_visible(b: Bounds) -> bool {
    var lo = vec2f(3.0e38);
    var hi = vec2f(-3.0e38);
    var nearest = 0.0;
    var farthest = 3.0e38;
    for (var c = 0u; c < 8u; c++) {
        let p = vec3f(
            select(b.lo.x, b.hi.x, (c & 1u) != 0u),
            select(b.lo.y, b.hi.y, (c & 2u) != 0u),
            select(b.lo.z, b.hi.z, (c & 4u) != 0u),
        );
        let clip = test.view_proj * vec4f(p, 1.0);
        // A corner behind the camera or in front of the near plane: the box reaches the near
        // plane, where nothing is hidden.
        if clip.w <= 0.0 || clip.z >= clip.w {
            return true;
        }
        let ndc = clip.xyz / clip.w;
        let px = vec2f((ndc.x * 0.5 + 0.5) * test.size.x, (0.5 - ndc.y * 0.5) * test.size.y);
        lo = min(lo, px);
        hi = max(hi, px);
        nearest = max(nearest, ndc.z);
        farthest = min(farthest, ndc.z);
    }
    // Every pixel whose centre the projection can cover, a pixel wider each side for the
    // rasteriser's fixed-point snapping.
    // (Clamped as floats: a corner near the camera's plane projects far beyond what an integer
    // holds, and converting such a float is undefined on some drivers.)
    let last = test.size - vec2f(1.0);
    if any(hi < vec2f(0.0)) || any(lo > test.size) {
        return true;
    }
    var p0 = vec2i(clamp(floor(lo) - vec2f(1.0), vec2f(0.0), last));
    var p1 = vec2i(clamp(floor(hi) + vec2f(1.0), vec2f(0.0), last));
    p0.y = max(p0.y, i32(test.rows.x));
    p1.y = min(p1.y, i32(test.rows.y) - 1);
    if p0.y > p1.y {
        // Wholly outside the tile's rows: the scissor keeps every fragment out.
        return false;
    }
    // The finest level where the pixels span at most two texels each way (level 0: 2×2 pixels).
    var level = 0u;
    var t0 = vec2u(p0) >> vec2u(1u);
    var t1 = vec2u(p1) >> vec2u(1u);
    loop {
        if all(t1 - t0 <= vec2u(1u)) || level + 1u >= test.levels {
            break;
        }
        level += 1u;
        t0 = t0 >> vec2u(1u);
        t1 = t1 >> vec2u(1u);
    }
    let at = test.level[level];
    let top = vec2u(at.width, at.height) - vec2u(1u);
    var occluder = 3.0e38;
    for (var y = t0.y; y <= t1.y; y++) {
        for (var x = t0.x; x <= t1.x; x++) {
            let t = min(vec2u(x, y), top);
            occluder = min(occluder, hzb[at.offset + t.y * at.width + t.x]);
        }
    }
    let depth = select(nearest, farthest, test.far_corner != 0u);
    return !(depth * (1.0 + test.margin) < occluder);
}

@compute @workgroup_size(64)
fn cs_test(@builtin(global_invocation_id) id: vec3u) {
    if id.x >= test.count {
        return;
    }
    visible[id.x] = select(0u, 1u, box_visible(boxes[id.x]));
}
