//! A small headless wgpu context for tools, tests and the renderer, and the crate's errors.

use thiserror::Error;

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
        /// [`MAX_ACTIVE`](crate::MAX_ACTIVE).
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
    /// Reading a buffer back failed: why (waiting for the GPU, mapping the buffer, or an output
    /// buffer without `COPY_SRC`).
    #[error("GPU readback failed: {0}")]
    Readback(String),
}

/// Why reading a buffer back from the GPU failed (carried as [`GpuError::Readback`]'s text).
#[derive(Debug, Error)]
pub(crate) enum ReadbackError {
    /// Waiting for the GPU failed (device lost, timeout).
    #[error("waiting for the GPU: {0}")]
    Poll(#[from] wgpu::PollError),
    /// The map callback never ran (its sender was dropped).
    #[error("the map callback was dropped: {0}")]
    Callback(#[from] std::sync::mpsc::RecvError),
    /// The GPU refused to map the buffer.
    #[error("mapping the buffer: {0}")]
    Map(#[from] wgpu::BufferAsyncError),
    /// The mapped range could not be viewed.
    #[error("viewing the mapped range: {0}")]
    Range(#[from] wgpu::MapRangeError),
    /// The output buffer cannot be copied from.
    #[error("the output buffer's usage lacks COPY_SRC")]
    NotCopySource,
}

impl ReadbackError {
    /// As a [`GpuError::Readback`].
    pub(crate) fn into_gpu(self) -> GpuError {
        GpuError::Readback(self.to_string())
    }
}

/// `e` as a [`GpuError::Readback`].
fn readback(e: impl Into<ReadbackError>) -> GpuError {
    e.into().into_gpu()
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
            name: crate::options::var("WGPU_ADAPTER_NAME").filter(|s| !s.is_empty()),
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
    /// submit's hand-offs stay on one core. See [`touchfem_core::threads`]; with lavapipe also set
    /// `LP_NUM_THREADS=0` before the first context is created.
    ///
    /// [`VisualPlacement::enter_visual`]: touchfem_core::threads::VisualPlacement::enter_visual
    #[cfg(not(target_arch = "wasm32"))]
    pub fn new_headless_placed(
        placement: &touchfem_core::threads::VisualPlacement,
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
        .map_err(readback)?;
    rx.recv().map_err(readback)?.map_err(readback)?;
    let bytes = staging.get_mapped_range(..).map_err(readback)?.to_vec();
    staging.unmap();
    Ok(bytes)
}
