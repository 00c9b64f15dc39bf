// Prelude of deform_texture.wgsl: the active list's length, and the list itself when it has at
// most 7 entries (a contact triangle is 3, two fingers 6), travel as immediates (Vulkan push
// constants) recorded in the command buffer: such a frame uploads nothing, which saves a
// staging copy and a command buffer per submit. Longer lists stay in the uniform `forces`.
// Needs wgpu::Features::IMMEDIATES and 128 bytes of immediates (touchfem::gpu::IMMEDIATE_BYTES).

struct Immediates {
    // Entries this frame.
    n_active: u32,
    // 1: the entries are in `entries`; 0: they are in `forces`.
    is_inline: u32,
    _pad0: u32,
    _pad1: u32,
    // 7 = touchfem::gpu's INLINE_ACTIVE.
    entries: array<Active, 7>,
}

var<immediate> imm: Immediates;

// u at row r: Σ over the active entries of L[r, c]·F_c. Two loops, so that neither tests
// where the entries are on every iteration.
fn displacement(r: u32, nr: u32) -> vec3<f32> {
    let n = imm.n_active;
    var u = vec3<f32>(0.0);
    if imm.is_inline != 0u {
        for (var k = 0u; k < n; k += 1u) {
            u += column_term(imm.entries[min(k, 6u)], r, nr);
        }
    } else {
        for (var k = 0u; k < n; k += 1u) {
            u += column_term(forces[k], r, nr);
        }
    }
    return u;
}
