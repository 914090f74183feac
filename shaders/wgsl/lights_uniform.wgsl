// Deferred light pass: one chunk of at most CHUNK_LIGHTS lights and CHUNK_VIEWS views per
// dispatch, in uniform buffers (view indices relative to the chunk). lavapipe reads a storage
// buffer one lane and one word at a time, behind a branch each; a uniform read is one gather,
// which made the per-light cost a third lower.

const CHUNK_LIGHTS: u32 = 64u;
// Six views per light at most (a full cube).
const CHUNK_VIEWS: u32 = 384u;

@group(1) @binding(1) var<uniform> lights: array<Light, CHUNK_LIGHTS>;
@group(1) @binding(2) var<uniform> views: array<View, CHUNK_VIEWS>;

fn light_at(i: u32) -> Light {
    return lights[i];
}

fn view_at(i: u32) -> View {
    return views[i];
}
