//! # touchfem
//!
//! Touch and see soft objects in real time: the method of Hirota & Kaneko, *Representation of
//! Soft Objects in Virtual Environment*. A linear tetrahedral FEM object's compliance `L = K⁻¹`
//! is precomputed once for the displayed rows and touchable columns; the finger's displacement is
//! turned into an equivalent nodal force with 3×3 blocks `L_ii⁻¹`; the haptic loop runs that
//! small solve at 1 kHz on the CPU, and the visual loop computes `u = L·F` over the active
//! columns on the GPU, straight into a vertex buffer. `L` changes only when an object is cut,
//! by an exact low-rank correction folded in off the haptic thread.
//!
//! This crate is the one to depend on. It re-exports the engine's rooms (`touchfem-core`, no
//! GPU) by name — [`mesh`], [`fem`], [`compliance`], [`cache`], [`precompute`], [`contact`],
//! [`devices`], [`cut`], [`scene`], [`haptic`], [`runtime`], [`limits`] — and, with the default
//! `gpu` feature, the GPU pass and renderer (`touchfem-gpu`) as [`gpu`] and [`render`]. The
//! `app` feature adds the `touchfem` program and its visual loop, [`visual`].
//!
//! ```no_run
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! // A scene with the paper's cube and a scripted finger, its compliance precomputed.
//! let world = touchfem::scene::World::load_with("fig1", "script", None)?;
//! let mut haptic = touchfem::haptic::HapticWorld::new(&world);
//! let mut sample = touchfem::haptic::WorldSample::default();
//! let mut force = [glam::DVec3::ZERO; 1];
//! haptic.step(&[glam::DVec3::new(0.015, 0.015, 0.028)], &mut force, &mut sample);
//! assert!(force[0].length() <= world.haptics.max_force_n);
//! # Ok(())
//! # }
//! ```

pub use touchfem_core::{
    cache, compliance, contact, cut, devices, fem, haptic, limits, mesh, precompute, runtime, scene,
};
pub use touchfem_core::{Error, Formulation, LengthUnit, Material, Mesh, MeshError, RawMesh};

/// The visual loop's displacement update from a haptic sample (GPU, CPU fallback), and the
/// cut bodies it follows: orchestration over the runtime, part of the program (`app`).
#[cfg(feature = "app")]
pub use touchfem_app::visual;
/// The GPU pass ([`gpu::Deformer`]), its headless context ([`gpu::Gpu`]) and `wgpu` itself.
#[cfg(feature = "gpu")]
pub use touchfem_gpu as gpu;
/// The offscreen renderer.
#[cfg(feature = "gpu")]
pub use touchfem_gpu::render;
/// The wgpu this crate was built with.
#[cfg(feature = "gpu")]
pub use touchfem_gpu::wgpu;

/// The README's code runs as a doc test.
#[doc = include_str!("../README.md")]
#[cfg(doctest)]
pub struct ReadmeDoctests;

/// The embedding guide's code is compiled as a doc test.
#[doc = include_str!("../docs/guide/embedding.md")]
#[cfg(all(doctest, feature = "gpu"))]
pub struct EmbeddingGuideDoctests;
