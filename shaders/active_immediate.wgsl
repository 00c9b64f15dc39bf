// Prelude of deform_texture.wgsl: the active list's length, and the list itself when it has at
// most 7 entries (a contact triangle is 3, two fingers 6), travel as immediates (Vulkan push
// constants) recorded in the command buffer: such a frame uploads nothing, which saves a
// staging copy and a command buffer per submit. Longer lists stay in the uniform `forces`.
// Needs wgpu::Features::IMMEDIATES and 128 bytes of immediates (touchfem::gpu::IMMEDIATE_BYTES).

struct Immediates {
    // Entries this frame.
    n_active: u32,
    // 1: the entries are in `entries`; 0: they are in `forces` (informative: the pipeline's
    // ACTIVE_INLINE decides).
    is_inline: u32,
    _pad0: u32,
    _pad1: u32,
    // 7 = touchfem::gpu's INLINE_ACTIVE.
    entries: array<Active, 7>,
}

var<immediate> imm: Immediates;

// The pipeline's specialisation: 0..=7 entries inline, or 8 for a list in `forces`. One
// pipeline per value (touchfem::gpu picks it per frame from the list's length), so an inline
// frame runs straight-line code that reads its entries at constant indices: llvmpipe (lavapipe)
// loads such an entry once per SIMD batch, but lane by lane at a loop index (measured: 9 µs of a
// 1178-row, 3-entry frame).
override ACTIVE_INLINE: u32 = 8u;

// u at row r: Σ over the active entries of L[r, c]·F_c.
fn displacement(r: u32, nr: u32) -> vec3<f32> {
    var u = vec3<f32>(0.0);
    if ACTIVE_INLINE > 7u {
        for (var k = 0u; k < imm.n_active; k += 1u) {
            u += column_term(forces[k], r, nr);
        }
        return u;
    }
    if ACTIVE_INLINE > 0u {
        u += column_term(imm.entries[0], r, nr);
    }
    if ACTIVE_INLINE > 1u {
        u += column_term(imm.entries[1], r, nr);
    }
    if ACTIVE_INLINE > 2u {
        u += column_term(imm.entries[2], r, nr);
    }
    if ACTIVE_INLINE > 3u {
        u += column_term(imm.entries[3], r, nr);
    }
    if ACTIVE_INLINE > 4u {
        u += column_term(imm.entries[4], r, nr);
    }
    if ACTIVE_INLINE > 5u {
        u += column_term(imm.entries[5], r, nr);
    }
    if ACTIVE_INLINE > 6u {
        u += column_term(imm.entries[6], r, nr);
    }
    return u;
}
