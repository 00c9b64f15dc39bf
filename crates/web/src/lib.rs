//! # touchfem-web
//!
//! touchfem in a browser page: the same engine ([`touchfem_core`], built without its `native`
//! feature: one thread, bytes in and out) and the same GPU pass and renderer
//! ([`touchfem_gpu`], the same WGSL) on the browser's WebGPU.
//!
//! * [`page`] is the page's engine side, plain Rust (it builds and is tested natively too): a
//!   bundled scene or mesh loaded with its compliance computed here or read from a cache
//!   file's bytes, the scripted press (the `poke` command's press, on the same engine calls),
//!   and the haptic ticks driven by the pointer and the scene's scripts.
//! * On `wasm32`, `Page` (exported with wasm-bindgen) adds the canvas: the deformation pass
//!   writing the vertex buffer, the renderer drawing it as `touchfem view` does, and the
//!   vertex read-back the tests compare with the native f64 displacement.
//!
//! `scripts/web.sh` builds it with the page in `web/` (docs/guide/web.md).

pub mod page;

#[cfg(target_arch = "wasm32")]
mod js;
