// The eye raster's common part: the visible surface under a fragment, its material layers, and
// which fragments eye rays skip. The forward (`forward.wgsl`) and deferred (`deferred.wgsl`)
// variants build on it; needs `lighting.wgsl` and a vertex stage (`eye_vertex.wgsl`, or
// `eye_vertex_mapped.wgsl` where the scene has normal maps) before it.

// The surface under a fragment, normals turned towards the viewer on back faces; a
// metallic-roughness material's normal map bends the shading normal (on the front face, then
// turned with it).
fn surface(in: VsOut, front: bool) -> Surface {
    var ng = safe_normalize(in.geometric_normal);
    var n = safe_normalize(in.normal);
    if all(n == vec3f(0.0)) {
        n = ng;
    }
    let material = in.material & ~NO_UV_BIT;
    // Only metallic-roughness shading reads texture coordinates after the raster.
    var suv = vec2f(0.0);
    if METALLIC_ROUGHNESS {
        suv = shading_uv(in.uv);
        if materials[material].model == MODEL_METALLIC_ROUGHNESS {
            let p = pbr[material];
            if p.normal_texture != NO_TEXTURE {
                let texel = sample_texture(p.normal_texture, suv).rgb;
                n = perturb_normal(n, vertex_tangent(in), texel, p.normal_scale);
            }
        }
    }
    if !front {
        // Back face of a double-sided material: both normals face the viewer.
        ng = -ng;
        n = -n;
    }
    return Surface(in.world, n, ng, material, in.object, suv);
}

// The material layers m^d (texture applied), m^s, m^a, e at a fragment.
struct MaterialLayers {
    diffuse: vec4f,
    specular: vec4f,
    ambient: vec4f,
    emissive: vec4f,
}

// Metallic-roughness (`scene::shading::surface_point`): m^d = c_diff ⊙ (1 − F0), m^s = the
// material's specular (1, or 0 with a scene file's `specular = false`),
// m^a = m^d · occlusion, e = emissive × emissive texture, every texture at `shading_uv`.
fn material_layers(in: VsOut) -> MaterialLayers {
    let index = in.material & ~NO_UV_BIT;
    let m = materials[index];
    if METALLIC_ROUGHNESS && m.model == MODEL_METALLIC_ROUGHNESS {
        let suv = shading_uv(in.uv);
        let p = metallic_roughness_point(index, suv);
        let q = pbr[index];
        var occ = 1.0;
        if q.occlusion_texture != NO_TEXTURE {
            occ = occlusion(q.occlusion_strength, sample_texture(q.occlusion_texture, suv).r);
        }
        let e = m.emissive * read_texture(q.emissive_texture, suv).rgb;
        return MaterialLayers(
            vec4f(p.diffuse, 1.0),
            vec4f(m.specular, 1.0),
            vec4f(p.diffuse * occ, 1.0),
            vec4f(e, 1.0),
        );
    }
    var md = m.diffuse;
    if m.diffuse_texture != NO_TEXTURE {
        md = md * sample_texture(m.diffuse_texture, in.uv).rgb;
    }
    return MaterialLayers(
        vec4f(md, 1.0),
        vec4f(m.specular, 1.0),
        vec4f(m.ambient, 1.0),
        vec4f(m.emissive, 1.0),
    );
}

// Eye rays skip single-sided back faces, transparent masked texels and filters (translucent
// casters without coverage, seen through: `fs_eye_filter`) (CPU reference rules).
fn rejected(in: VsOut, front: bool) -> bool {
    let m = materials[in.material & ~NO_UV_BIT];
    return (!front && m.double_sided == 0u)
        || m.transmits == TRANSMITS_FILTER
        || masked_out(m, in.uv, (in.material & NO_UV_BIT) == 0u);
}

// The filters in front of the visible surface (`docs/translucency.md`): each multiplies its
// transmittance into the four material layers (the blend state: dst·src), behind the eye depth
// test, so the pixel becomes T ⊙ (e + m^a⊙… + m^d⊙I^d + m^s⊙I^s). Other fragments, and
// single-sided back faces, are skipped.
struct FilterOut {
    @location(0) m_diffuse: vec4f,
    @location(1) m_specular: vec4f,
    @location(2) m_ambient: vec4f,
    @location(3) emissive: vec4f,
}

@fragment
fn fs_eye_filter(in: VsOut, @builtin(front_facing) front: bool) -> FilterOut {
    let m = materials[in.material & ~NO_UV_BIT];
    if m.transmits != TRANSMITS_FILTER || (!front && m.double_sided == 0u) {
        discard;
    }
    let t = vec4f(texel_transmittance(m, in.uv, (in.material & NO_UV_BIT) == 0u), 1.0);
    return FilterOut(t, t, t, t);
}
