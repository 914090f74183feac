// The eye rasters' vertex stage where no mesh is normal-mapped: no tangent is fetched or
// interpolated (on a CPU rasteriser a varying costs every triangle). `eye_vertex_mapped.wgsl` is
// the same with the tangent.

struct VsIn {
    @location(0) position: vec3f,
    @location(1) normal: vec3f,
    @location(2) geometric_normal: vec3f,
    @location(3) uv: vec2f,
    @location(4) material: u32,
    @location(5) object: u32,
}

struct VsOut {
    @builtin(position) clip: vec4f,
    @location(0) world: vec3f,
    @location(1) normal: vec3f,
    @location(2) geometric_normal: vec3f,
    @location(3) uv: vec2f,
    @location(4) @interpolate(flat) material: u32,
    @location(5) @interpolate(flat) object: u32,
}

@vertex
fn vs_eye(in: VsIn) -> VsOut {
    var out: VsOut;
    out.clip = frame.view_proj * vec4f(in.position, 1.0);
    out.world = in.position;
    out.normal = in.normal;
    out.geometric_normal = in.geometric_normal;
    out.uv = in.uv;
    out.material = in.material;
    out.object = in.object;
    return out;
}

// The normal-map tangent at a fragment: none here.
fn vertex_tangent(in: VsOut) -> vec4f {
    return vec4f(0.0);
}
