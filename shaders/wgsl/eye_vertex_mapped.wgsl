// The eye rasters' vertex stage where some mesh is normal-mapped: as `eye_vertex.wgsl`, plus
// each vertex's tangent from a second vertex buffer (the mesh's glTF `TANGENT`, or its
// triangle's own at all three vertices), interpolated like the normal.

struct VsIn {
    @location(0) position: vec3f,
    @location(1) normal: vec3f,
    @location(2) geometric_normal: vec3f,
    @location(3) uv: vec2f,
    @location(4) material: u32,
    @location(5) object: u32,
    @location(6) tangent: vec4f,
}

struct VsOut {
    @builtin(position) clip: vec4f,
    @location(0) world: vec3f,
    @location(1) normal: vec3f,
    @location(2) geometric_normal: vec3f,
    @location(3) uv: vec2f,
    @location(4) @interpolate(flat) material: u32,
    @location(5) @interpolate(flat) object: u32,
    @location(6) tangent: vec4f,
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
    out.tangent = in.tangent;
    return out;
}

// The normal-map tangent at a fragment.
fn vertex_tangent(in: VsOut) -> vec4f {
    return in.tangent;
}
