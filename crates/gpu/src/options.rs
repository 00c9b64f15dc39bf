//! The GPU crate's settings from the environment, read in this one place: `TOUCHFEM_GPU_L` (the
//! storage of `L` a live session asks for) and `WGPU_ADAPTER_NAME` (wgpu's own `WGPU_BACKEND`
//! and `WGPU_POWER_PREF` are read by wgpu).

/// The value of environment variable `name`, if set and UTF-8.
pub(crate) fn var(name: &str) -> Option<String> {
    std::env::var(name).ok()
}
