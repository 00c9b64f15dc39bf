//! The GPU side of the visual loop: a wgpu compute pass that evaluates `u = L·F` over the active
//! columns straight into a vertex buffer, and recomputes the deformed surface's vertex normals.
//!
//! * [`Deformer`] is the embeddable piece (in the style of glyphon or egui-wgpu): it borrows the
//!   caller's [`wgpu::Device`] and [`wgpu::Queue`], uploads `L` once, takes a force boundary
//!   condition per frame with [`Deformer::set_forces`] and records its passes into the caller's
//!   encoder with [`Deformer::encode`].
//! * [`Gpu`] is a small headless context (instance, adapter, device, queue) for tools, tests and
//!   the offscreen [`crate::render`]er; it honours `WGPU_BACKEND`, `WGPU_ADAPTER_NAME` and
//!   `WGPU_POWER_PREF`.
//!
//! Use the re-exported [`crate::wgpu`] so that your wgpu version matches ours.

mod bind;
mod buffer_path;
mod deform;
mod texture_path;

pub use buffer_path::{deform_f16_wgsl, pack_f16};
pub use deform::{
    Deformer, DeformerInput, DeformerOptions, LData, LStorage, OutputTarget, Vertex, MAX_ACTIVE,
    NO_NORMALS, VERTEX_STRIDE,
};

use thiserror::Error;

/// The WGSL source of the deformation and normal passes, storage-buffer layout
/// (`shaders/deform.wgsl`).
pub const DEFORM_WGSL: &str = include_str!("../../shaders/deform.wgsl");

/// The WGSL body of the deformation and normal passes, texture layout
/// (`shaders/deform_texture.wgsl`); complete it with [`deform_texture_source`].
pub const DEFORM_TEXTURE_WGSL: &str = include_str!("../../shaders/deform_texture.wgsl");

/// Prelude of [`DEFORM_TEXTURE_WGSL`]: the active list in a uniform buffer
/// (`shaders/active_uniform.wgsl`).
pub const ACTIVE_UNIFORM_WGSL: &str = include_str!("../../shaders/active_uniform.wgsl");

/// Prelude of [`DEFORM_TEXTURE_WGSL`]: the active list's length, and short lists, as immediates
/// (`shaders/active_immediate.wgsl`; needs [`wgpu::Features::IMMEDIATES`]).
pub const ACTIVE_IMMEDIATE_WGSL: &str = include_str!("../../shaders/active_immediate.wgsl");

/// Prelude of [`DEFORM_TEXTURE_WGSL`]: vertices written word by word at any offset and stride
/// (`shaders/output_words.wgsl`).
pub const OUTPUT_WORDS_WGSL: &str = include_str!("../../shaders/output_words.wgsl");

/// Prelude of [`DEFORM_TEXTURE_WGSL`]: vertices written as [`Vertex`]es, one `vec4` store each
/// (`shaders/output_vertex.wgsl`).
pub const OUTPUT_VERTEX_WGSL: &str = include_str!("../../shaders/output_vertex.wgsl");

/// Bytes of immediates the texture layout's deformation pass uses when the device has
/// [`wgpu::Features::IMMEDIATES`] and at least this `max_immediate_size`.
pub const IMMEDIATE_BYTES: u32 = 128;

/// Most active entries that travel inline in the immediates (a 16-byte header and 16 bytes an
/// entry fill [`IMMEDIATE_BYTES`]); longer lists are uploaded to the uniform buffer.
pub const INLINE_ACTIVE: usize = 7;

/// The complete texture-layout shader: [`DEFORM_TEXTURE_WGSL`] with the prelude that reads
/// the active list from immediates (`immediates`) or from the uniform buffer, and the one that
/// writes [`Vertex`]es (`vertex_layout`) or words at any offset and stride; with `half`, `L`
/// is read from an `rgba16float` texture ([`LStorage::TextureF16`]).
pub fn deform_texture_source(immediates: bool, vertex_layout: bool, half: bool) -> String {
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

/// Everything that can go wrong on the GPU side.
#[derive(Debug, Error)]
pub enum GpuError {
    /// No adapter matched the request.
    #[error(
        "no GPU adapter found (WGPU_BACKEND={backends}, WGPU_ADAPTER_NAME={name}): {reason}. \
         Set WGPU_BACKEND to a backend this machine has (e.g. WGPU_BACKEND=vulkan with Mesa's \
         lavapipe installed for a software GPU) or unset WGPU_ADAPTER_NAME"
    )]
    NoAdapter {
        /// The backends that were searched, as `WGPU_BACKEND` spells them.
        backends: String,
        /// The adapter name filter, or `(unset)`.
        name: String,
        /// What wgpu said.
        reason: String,
    },
    /// The adapter refused to create a device.
    #[error("cannot create a GPU device: {0}")]
    RequestDevice(#[from] wgpu::RequestDeviceError),
    /// More active columns than the shader's active-list buffer holds.
    #[error("{count} active columns in the force boundary condition; at most {max} are supported")]
    TooManyActive {
        /// Entries passed.
        count: usize,
        /// [`MAX_ACTIVE`].
        max: usize,
    },
    /// A force names a column the compliance does not have.
    #[error("force on column {col}, but the compliance has {n_cols} columns")]
    ColumnOutOfRange {
        /// The column index passed.
        col: u32,
        /// The number of columns.
        n_cols: usize,
    },
    /// A force component is NaN or infinite.
    #[error("force on column {col} is not finite: {force:?}")]
    NonFiniteForce {
        /// The column index.
        col: u32,
        /// The force passed.
        force: [f32; 3],
    },
    /// A buffer or binding would exceed the device's limits.
    #[error("{what} needs {bytes} bytes, but the device allows {limit}")]
    BufferTooLarge {
        /// Which buffer.
        what: &'static str,
        /// Bytes it needs.
        bytes: u64,
        /// The device limit it exceeds.
        limit: u64,
    },
    /// The device lacks a capability the requested option needs.
    #[error("the device does not support {0}")]
    Unsupported(String),
    /// The compliance, rest positions or triangles are inconsistent.
    #[error("invalid deformer input: {0}")]
    BadInput(String),
    /// The caller-supplied output target is unusable.
    #[error("invalid output target: {0}")]
    BadOutput(String),
    /// Reading a buffer back failed.
    #[error("GPU readback failed: {0}")]
    Readback(String),
}

/// Which adapter [`Gpu::new`] picks.
#[derive(Clone, Debug)]
pub struct AdapterSelection {
    /// Backends to search.
    pub backends: wgpu::Backends,
    /// If set, the first adapter whose name contains this (case-insensitive).
    pub name: Option<String>,
    /// Preference when no name is given.
    pub power: wgpu::PowerPreference,
}

impl AdapterSelection {
    /// From `WGPU_BACKEND` (default: all), `WGPU_ADAPTER_NAME` and `WGPU_POWER_PREF` (default:
    /// high performance).
    pub fn from_env() -> Self {
        AdapterSelection {
            backends: wgpu::Backends::from_env().unwrap_or_default(),
            name: std::env::var("WGPU_ADAPTER_NAME")
                .ok()
                .filter(|s| !s.is_empty()),
            power: wgpu::PowerPreference::from_env()
                .unwrap_or(wgpu::PowerPreference::HighPerformance),
        }
    }
}

/// A headless wgpu context: instance, adapter, device and queue.
///
/// The device is created with the adapter's own limits (not the WebGPU defaults), so that large
/// compliance matrices can use the biggest bindings the hardware offers.
#[derive(Debug)]
pub struct Gpu {
    /// The instance.
    pub instance: wgpu::Instance,
    /// The chosen adapter.
    pub adapter: wgpu::Adapter,
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
}

fn backends_name(b: wgpu::Backends) -> String {
    if b == wgpu::Backends::all() {
        return "(unset: all)".into();
    }
    let names: Vec<&str> = [
        (wgpu::Backends::VULKAN, "vulkan"),
        (wgpu::Backends::METAL, "metal"),
        (wgpu::Backends::DX12, "dx12"),
        (wgpu::Backends::GL, "gl"),
        (wgpu::Backends::BROWSER_WEBGPU, "webgpu"),
        (wgpu::Backends::NOOP, "noop"),
    ]
    .into_iter()
    .filter(|(f, _)| b.contains(*f))
    .map(|(_, n)| n)
    .collect();
    if names.is_empty() {
        "(none)".into()
    } else {
        names.join(",")
    }
}

impl Gpu {
    /// A headless context chosen by the environment (see [`AdapterSelection::from_env`]).
    /// Fails with [`GpuError::NoAdapter`] when nothing matches.
    pub fn new_headless() -> Result<Gpu, GpuError> {
        Gpu::new(&AdapterSelection::from_env())
    }

    /// [`new_headless`](Self::new_headless), created while the calling thread is pinned to
    /// `placement`'s visual core, so that a software driver's threads (lavapipe's queue
    /// thread) start on that core; the calling thread's affinity is restored afterwards. Submit
    /// from a thread pinned to the same core ([`VisualPlacement::enter_visual`]) and every
    /// submit's hand-offs stay on one core. See [`crate::threads`]; with lavapipe also set
    /// `LP_NUM_THREADS=0` before the first context is created.
    ///
    /// [`VisualPlacement::enter_visual`]: crate::threads::VisualPlacement::enter_visual
    pub fn new_headless_placed(
        placement: &crate::threads::VisualPlacement,
    ) -> Result<Gpu, GpuError> {
        placement.enter_visual();
        let g = Gpu::new_headless();
        placement.leave();
        g
    }

    /// A headless context on the adapter `sel` names.
    pub fn new(sel: &AdapterSelection) -> Result<Gpu, GpuError> {
        Gpu::with_instance(Gpu::instance(sel), sel, None)
    }

    /// An instance for the backends `sel` allows (for a caller that needs it before the
    /// context, e.g. to create a window surface).
    pub fn instance(sel: &AdapterSelection) -> wgpu::Instance {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        desc.backends = sel.backends;
        wgpu::Instance::new(desc)
    }

    /// A context on `instance`'s adapter that `sel` names and, when given, that can present to
    /// `surface`; requests `IMMEDIATES` where offered.
    pub fn with_instance(
        instance: wgpu::Instance,
        sel: &AdapterSelection,
        surface: Option<&wgpu::Surface<'_>>,
    ) -> Result<Gpu, GpuError> {
        let no_adapter = |reason: String| GpuError::NoAdapter {
            backends: backends_name(sel.backends),
            name: sel.name.clone().unwrap_or_else(|| "(unset)".into()),
            reason,
        };
        let adapter = match &sel.name {
            Some(name) => {
                let want = name.to_lowercase();
                let adapters = pollster::block_on(instance.enumerate_adapters(sel.backends));
                let seen: Vec<String> = adapters.iter().map(|a| a.get_info().name).collect();
                adapters
                    .into_iter()
                    .find(|a| {
                        a.get_info().name.to_lowercase().contains(&want)
                            && surface.is_none_or(|s| a.is_surface_supported(s))
                    })
                    .ok_or_else(|| {
                        no_adapter(format!(
                            "no adapter name contains '{name}' (found: {seen:?})"
                        ))
                    })?
            }
            None => pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
                power_preference: sel.power,
                force_fallback_adapter: false,
                compatible_surface: surface,
                apply_limit_buckets: false,
            }))
            .map_err(|e| no_adapter(e.to_string()))?,
        };
        let (device, queue) =
            pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
                label: Some("touchfem"),
                // Immediates let the texture layout skip the per-frame upload.
                required_features: adapter.features() & wgpu::Features::IMMEDIATES,
                required_limits: adapter.limits(),
                experimental_features: wgpu::ExperimentalFeatures::disabled(),
                memory_hints: wgpu::MemoryHints::Performance,
                trace: wgpu::Trace::Off,
            }))?;
        Ok(Gpu {
            instance,
            adapter,
            device,
            queue,
        })
    }
}

/// Copies `size` bytes at `offset` of `buffer` (which needs `COPY_SRC`) back to the CPU, waiting
/// for the GPU. `offset` and `size` must be multiples of 4.
pub fn read_buffer(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    buffer: &wgpu::Buffer,
    offset: u64,
    size: u64,
) -> Result<Vec<u8>, GpuError> {
    let staging = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("touchfem readback"),
        size,
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    let mut enc = device.create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
    enc.copy_buffer_to_buffer(buffer, offset, &staging, 0, size);
    queue.submit([enc.finish()]);
    map_read(device, &staging)
}

/// Maps a `MAP_READ` buffer that the GPU has been asked to fill and returns its bytes.
pub(crate) fn map_read(device: &wgpu::Device, staging: &wgpu::Buffer) -> Result<Vec<u8>, GpuError> {
    let (tx, rx) = std::sync::mpsc::channel();
    staging.map_async(wgpu::MapMode::Read, .., move |r| {
        let _ = tx.send(r);
    });
    device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| GpuError::Readback(e.to_string()))?;
    rx.recv()
        .map_err(|e| GpuError::Readback(e.to_string()))?
        .map_err(|e| GpuError::Readback(e.to_string()))?;
    let bytes = staging
        .get_mapped_range(..)
        .map_err(|e| GpuError::Readback(e.to_string()))?
        .to_vec();
    staging.unmap();
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    fn validate(name: &str, src: &str, caps: naga::valid::Capabilities) {
        let module = naga::front::wgsl::parse_str(src)
            .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(src)));
        naga::valid::Validator::new(naga::valid::ValidationFlags::all(), caps)
            .validate(&module)
            .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(src)));
    }

    /// The half-float variant of `deform.wgsl` validates, and packing keeps the low half first.
    #[test]
    fn f16_shader_validates_and_packs_low_half_first() {
        validate(
            "deform.wgsl (f16)",
            &super::deform_f16_wgsl(),
            naga::valid::Capabilities::SHADER_FLOAT16_IN_FLOAT32,
        );
        let w = super::pack_f16(&[1.0, -2.0, 0.5]);
        assert_eq!(w, [0x3c00 | (0xc000 << 16), 0x3800]);
    }

    /// Every shader in `shaders/` parses and validates with naga (no GPU needed): the
    /// stand-alone ones as they are, the texture layout's body with each of its preludes.
    #[test]
    fn shaders_validate_with_naga() {
        use naga::valid::Capabilities;
        let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/shaders");
        let parts = [
            "deform_texture.wgsl",
            "active_uniform.wgsl",
            "active_immediate.wgsl",
            "output_words.wgsl",
            "output_vertex.wgsl",
        ];
        let mut n = 0;
        for entry in std::fs::read_dir(dir).expect("shaders/ exists") {
            let path = entry.unwrap().path();
            if path.extension().and_then(|e| e.to_str()) != Some("wgsl") {
                continue;
            }
            n += 1;
            let name = path.file_name().unwrap().to_str().unwrap().to_string();
            if parts.contains(&name.as_str()) {
                continue;
            }
            let src = std::fs::read_to_string(&path).unwrap();
            validate(&name, &src, Capabilities::empty());
        }
        assert!(
            n >= 7,
            "expected deform.wgsl, render.wgsl and the texture layout's five parts, found {n}"
        );
        for immediates in [false, true] {
            for vertex in [false, true] {
                for half in [false, true] {
                    let caps = if immediates {
                        Capabilities::IMMEDIATES
                    } else {
                        Capabilities::empty()
                    };
                    let src = super::deform_texture_source(immediates, vertex, half);
                    assert_eq!(src.contains("rgba16float"), half);
                    validate(
                        &format!(
                            "deform_texture (immediates {immediates}, vertex layout {vertex}, half {half})"
                        ),
                        &src,
                        caps,
                    );
                }
            }
        }
    }

    /// The shaders' fixed-size active lists hold exactly `MAX_ACTIVE` entries.
    #[test]
    fn shaders_active_lists_match_max_active() {
        let decl = format!("array<Active, {}>", super::MAX_ACTIVE);
        for src in [super::DEFORM_WGSL, super::DEFORM_TEXTURE_WGSL] {
            assert!(src.contains(&decl), "{decl} not found");
        }
        let inline = super::INLINE_ACTIVE;
        assert_eq!(16 + 16 * inline as u32, super::IMMEDIATE_BYTES);
        for decl in [
            format!("array<Active, {inline}>"),
            format!("imm.entries[{}]", inline - 1),
            format!("ACTIVE_INLINE > {}u", inline - 1),
        ] {
            assert!(
                super::ACTIVE_IMMEDIATE_WGSL.contains(&decl),
                "{decl} not found"
            );
        }
    }

    #[test]
    fn embedded_shaders_are_the_files() {
        for (name, embedded) in [
            ("deform.wgsl", super::DEFORM_WGSL),
            ("deform_texture.wgsl", super::DEFORM_TEXTURE_WGSL),
            ("active_uniform.wgsl", super::ACTIVE_UNIFORM_WGSL),
            ("active_immediate.wgsl", super::ACTIVE_IMMEDIATE_WGSL),
            ("output_words.wgsl", super::OUTPUT_WORDS_WGSL),
            ("output_vertex.wgsl", super::OUTPUT_VERTEX_WGSL),
        ] {
            let path = format!("{}/shaders/{name}", env!("CARGO_MANIFEST_DIR"));
            assert_eq!(std::fs::read_to_string(path).unwrap(), embedded, "{name}");
        }
    }
}
