//! The WGSL sources of the passes (`shaders/` at the workspace root) and the limits they are
//! written for. `deform.wgsl`, `deform_hier.wgsl` and `correct.wgsl` share one `Frame` uniform
//! struct, written once in `frame.wgsl` and put before each of them here ([`with_frame`]).

/// The `Frame` uniform struct (`shaders/frame.wgsl`; the Rust side is
/// [`FrameGpu`](crate::input::FrameGpu)).
pub(crate) const FRAME_WGSL: &str = include_str!("../../../shaders/frame.wgsl");

/// `body` with [`FRAME_WGSL`] before it.
pub(crate) fn with_frame(body: &str) -> String {
    format!("{FRAME_WGSL}\n{body}")
}

/// The complete storage-buffer layout shader: [`DEFORM_WGSL`] after [`FRAME_WGSL`].
pub(crate) fn deform_source() -> String {
    with_frame(DEFORM_WGSL)
}

/// The WGSL body of the deformation and normal passes, storage-buffer layout
/// (`shaders/deform.wgsl`); complete it with [`deform_source`].
pub(crate) const DEFORM_WGSL: &str = include_str!("../../../shaders/deform.wgsl");

/// The WGSL body of the deformation pass from a hierarchical `L`
/// (`shaders/deform_hier.wgsl`); completed by `hier_path::deform_hier_wgsl`.
pub(crate) const DEFORM_HIER_WGSL: &str = include_str!("../../../shaders/deform_hier.wgsl");

/// The WGSL body of the deformation and normal passes, texture layout
/// (`shaders/deform_texture.wgsl`); complete it with [`deform_texture_source`].
pub(crate) const DEFORM_TEXTURE_WGSL: &str = include_str!("../../../shaders/deform_texture.wgsl");

/// Prelude of [`DEFORM_TEXTURE_WGSL`]: the active list in a uniform buffer
/// (`shaders/active_uniform.wgsl`).
pub(crate) const ACTIVE_UNIFORM_WGSL: &str = include_str!("../../../shaders/active_uniform.wgsl");

/// Prelude of [`DEFORM_TEXTURE_WGSL`]: the active list's length, and short lists, as immediates
/// (`shaders/active_immediate.wgsl`; needs [`wgpu::Features::IMMEDIATES`]).
pub(crate) const ACTIVE_IMMEDIATE_WGSL: &str =
    include_str!("../../../shaders/active_immediate.wgsl");

/// Prelude of [`DEFORM_TEXTURE_WGSL`]: vertices written word by word at any offset and stride
/// (`shaders/output_words.wgsl`).
pub(crate) const OUTPUT_WORDS_WGSL: &str = include_str!("../../../shaders/output_words.wgsl");

/// Prelude of [`DEFORM_TEXTURE_WGSL`]: vertices written as `Vertex`es, one `vec4` store each
/// (`shaders/output_vertex.wgsl`).
pub(crate) const OUTPUT_VERTEX_WGSL: &str = include_str!("../../../shaders/output_vertex.wgsl");

/// Bytes of immediates the texture layout's deformation pass uses when the device has
/// [`wgpu::Features::IMMEDIATES`] and at least this `max_immediate_size`.
pub(crate) const IMMEDIATE_BYTES: u32 = 128;

/// Most active entries that travel inline in the immediates (a 16-byte header and 16 bytes an
/// entry fill `IMMEDIATE_BYTES`); longer lists are uploaded to the uniform buffer.
pub const INLINE_ACTIVE: usize = 7;

/// The complete texture-layout shader: [`DEFORM_TEXTURE_WGSL`] with the prelude that reads
/// the active list from immediates (`immediates`) or from the uniform buffer, and the one that
/// writes `Vertex`es (`vertex_layout`) or words at any offset and stride; with `half`, `L`
/// is read from an `rgba16float` texture (`LStorage::TextureF16`).
pub(crate) fn deform_texture_source(immediates: bool, vertex_layout: bool, half: bool) -> String {
    let active = if immediates {
        ACTIVE_IMMEDIATE_WGSL
    } else {
        ACTIVE_UNIFORM_WGSL
    };
    let output = if vertex_layout {
        OUTPUT_VERTEX_WGSL
    } else {
        OUTPUT_WORDS_WGSL
    };
    let body = if half {
        DEFORM_TEXTURE_WGSL.replace(
            "var l_tex: texture_storage_2d_array<rgba32float, read>",
            "var l_tex: texture_storage_2d_array<rgba16float, read>",
        )
    } else {
        DEFORM_TEXTURE_WGSL.to_string()
    };
    format!("{body}\n{active}\n{output}")
}

/// The WGSL body of the cut correction pass (`shaders/correct.wgsl`); complete it with
/// [`correct_source`].
pub(crate) const CORRECT_WGSL: &str = include_str!("../../../shaders/correct.wgsl");

/// The complete correction shader: [`CORRECT_WGSL`] after [`FRAME_WGSL`], with `store_texture` storing each corrected
/// position into the texture layout's deformed-position texture (`positions`, binding 8, read by
/// its normal pass) or doing nothing (the storage-buffer layout's normals read `out`).
pub(crate) fn correct_source(positions: bool) -> String {
    let store = if positions {
        "@group(0) @binding(8) var pos_out: texture_storage_2d<rgba32float, write>;\n\n\
         fn store_texture(r: u32, p: vec3<f32>) {\n\
         \x20   textureStore(pos_out, vec2<u32>(r & 1023u, r >> 10u), vec4<f32>(p, 1.0));\n\
         }\n"
    } else {
        "fn store_texture(r: u32, p: vec3<f32>) {}\n"
    };
    with_frame(&format!("{CORRECT_WGSL}\n{store}"))
}
