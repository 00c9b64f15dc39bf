// Prelude of deform_texture.wgsl: vertices go to the deformer's own buffer in its documented
// layout (touchfem::gpu::Vertex: position (x, y, z, |u|) then normal (x, y, z, 0), 32 bytes; |u| is
// the displacement's magnitude in metres, for the renderer's colour map), one vec4 store each — llvmpipe (lavapipe) stores a storage-buffer word lane by lane, so three
// scalar stores cost about three times one vector store.

@group(0) @binding(2) var<storage, read_write> out: array<vec4<f32>>;

fn store_position(r: u32, p: vec3<f32>, u: vec3<f32>) {
    out[2u * r] = vec4<f32>(p, length(u));
}

fn store_normal(v: u32, n: vec3<f32>) {
    out[2u * v + 1u] = vec4<f32>(n, 0.0);
}
