// Forward eye pass: per fragment the node's illumination Σ (c_λ ⊘ c_n)·(i^d_λ, i^s_λ)·s_λ over its
// K samples, with s_λ from the shadow maps, plus eye depth and (entry point `fs_layers`) the
// material layers. Needs `eye.wgsl` and `lights_storage.wgsl`.

// Illumination and depth leave as f32 bits in integer targets: exact, and renderable on GL too.
struct IlluminationOut {
    @location(0) diffuse: vec4<u32>,
    @location(1) specular: vec4<u32>,
    @location(2) depth: u32,
}

@fragment
fn fs_illumination(in: VsOut, @builtin(front_facing) front: bool) -> IlluminationOut {
    if rejected(in, front) {
        discard;
    }
    let s = illuminate(surface(in, front), Shaded(vec3f(0.0), vec3f(0.0)));
    var out: IlluminationOut;
    out.diffuse = bitcast<vec4<u32>>(vec4f(s.diffuse, 1.0));
    out.specular = bitcast<vec4<u32>>(vec4f(s.specular, 1.0));
    out.depth = bitcast<u32>(eye_depth(in.world));
    return out;
}

struct LayersOut {
    @location(0) diffuse: vec4<u32>,
    @location(1) specular: vec4<u32>,
    @location(2) depth: u32,
    @location(3) m_diffuse: vec4f,
    @location(4) m_specular: vec4f,
    @location(5) m_ambient: vec4f,
    @location(6) emissive: vec4f,
}

@fragment
fn fs_layers(in: VsOut, @builtin(front_facing) front: bool) -> LayersOut {
    if rejected(in, front) {
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

// The occluders' depth pass (`node::gpu::occlusion`): depth only, where the eye pass would write
// it (the same rejection), so the depth it leaves is never nearer than the eye pass's.
@fragment
fn fs_occluder(in: VsOut, @builtin(front_facing) front: bool) {
    if rejected(in, front) {
        discard;
    }
}
