// Deferred variant: a G-buffer pass stores each pixel's surface (position, normals, material) as
// f32 bits, then a compute pass lights every pixel with the K samples, one dispatch per chunk of
// lights (`lights_uniform.wgsl`), each adding to the last. Same maths as the forward eye pass
// (`illuminate`), no shading of hidden fragments. Needs `eye.wgsl` before it.

// Material index + 1 in `position.w`; 0 marks background. The object ID in `normal.w`; the
// shading texture coordinates (`shading_uv`, exactly) in `geometric_normal.w`.
struct GBufferOut {
    @location(0) position: vec4<u32>,
    @location(1) normal: vec4<u32>,
    @location(2) geometric_normal: vec4<u32>,
    @location(3) depth: u32,
}

fn gbuffer(in: VsOut, front: bool) -> GBufferOut {
    let sf = surface(in, front);
    var out: GBufferOut;
    out.position = vec4<u32>(bitcast<vec3<u32>>(sf.p), sf.material + 1u);
    out.normal = vec4<u32>(bitcast<vec3<u32>>(sf.n), sf.object);
    out.geometric_normal = vec4<u32>(bitcast<vec3<u32>>(sf.ng), pack2x16unorm(sf.uv));
    out.depth = bitcast<u32>(eye_depth(in.world));
    return out;
}

@fragment
fn fs_gbuffer(in: VsOut, @builtin(front_facing) front: bool) -> GBufferOut {
    if rejected(in, front) {
        discard;
    }
    return gbuffer(in, front);
}

struct GBufferLayersOut {
    @location(0) position: vec4<u32>,
    @location(1) normal: vec4<u32>,
    @location(2) geometric_normal: vec4<u32>,
    @location(3) depth: u32,
    @location(4) m_diffuse: vec4f,
    @location(5) m_specular: vec4f,
    @location(6) m_ambient: vec4f,
    @location(7) emissive: vec4f,
}

@fragment
fn fs_gbuffer_layers(in: VsOut, @builtin(front_facing) front: bool) -> GBufferLayersOut {
    if rejected(in, front) {
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

@group(2) @binding(0) var gb_position: texture_2d<u32>;
@group(2) @binding(1) var gb_normal: texture_2d<u32>;
@group(2) @binding(2) var gb_geometric_normal: texture_2d<u32>;
// Two entries per pixel, row-major: diffuse RGB (w unused), then specular RGB.
@group(2) @binding(3) var<storage, read_write> illumination: array<vec4f>;

@compute @workgroup_size(8, 8)
fn cs_lights(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= frame.width || id.y >= frame.height {
        return;
    }
    let px = vec2<i32>(id.xy);
    let i = 2u * (id.y * frame.width + id.x);
    var s = Shaded(vec3f(0.0), vec3f(0.0));
    if frame.accumulate != 0u {
        s = Shaded(illumination[i].xyz, illumination[i + 1u].xyz);
    }
    let g = textureLoad(gb_position, px, 0);
    if g.w != 0u {
        let n = textureLoad(gb_normal, px, 0);
        let ng = textureLoad(gb_geometric_normal, px, 0);
        s = illuminate(Surface(
            bitcast<vec3f>(g.xyz),
            bitcast<vec3f>(n.xyz),
            bitcast<vec3f>(ng.xyz),
            g.w - 1u,
            n.w,
            unpack2x16unorm(ng.w),
        ), s);
    }
    illumination[i] = vec4f(s.diffuse, 0.0);
    illumination[i + 1u] = vec4f(s.specular, 0.0);
}
