// Forward eye pass: the frame's lights and views in storage buffers, any number of them.

@group(1) @binding(1) var<storage, read> lights: array<Light>;
@group(1) @binding(2) var<storage, read> views: array<View>;

fn light_at(i: u32) -> Light {
    return lights[i];
}

fn view_at(i: u32) -> View {
    return views[i];
}
