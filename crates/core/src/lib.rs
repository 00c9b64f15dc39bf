//! # touchfem-core
//!
//! The engine of touchfem: Hirota & Kaneko's method, *Representation of Soft Objects in Virtual
//! Environment*, without a GPU, a window or a command line. A linear tetrahedral FEM object's
//! compliance `L = K⁻¹` is precomputed once for the displayed rows and touchable columns; the
//! finger's displacement is turned into an equivalent nodal force with 3×3 blocks `L_ii⁻¹`; the
//! haptic loop runs that small solve at 1 kHz and publishes the force boundary condition
//! lock-free for the visual path.
//!
//! Units are SI throughout (m, N, Pa, s); mesh and scene files may declare millimetres.
//!
//! Data flows one way:
//! * precompute: [`mesh`] → [`fem`] (sparse K, Cholesky) → [`compliance`] (L, L_ii⁻¹) →
//!   [`cache`] (the file);
//! * haptic path: [`devices`] → [`runtime::HapticWorld`] ([`contact`] god-objects,
//!   [`contact::force`] eq. 9–12, the [`runtime::bound`]) → devices, and the
//!   [`runtime::WorldSample`] published;
//! * visual path: [`compliance::Compliance::displace`] on the CPU here; the GPU pass is the
//!   `touchfem-gpu` crate's.

//!
//! ## Features
//!
//! `native` (default): threads, files written or mapped in place, sockets, the clock, the
//! environment, METIS and faer's rayon. Without it the engine is the pure, single-threaded
//! core that builds for `wasm32-unknown-unknown`: mesh, FEM, compliance, contact, cut,
//! hierarchical `L`, caches read from bytes and the haptic step (docs/guide/wasm.md).
//!
//! ## Rooms
//!
//! The root holds only the rooms of the engine, and every `use crate::…` points down this
//! order (bottom first; `scripts/check-rooms.py` checks it in CI):
//!
//! 1. [`limits`]: the fixed capacities (fingers, objects, patch nodes);
//! 2. [`options`]: the environment variables, the only reader of the environment;
//! 3. [`threads`]: CPU placement and priorities of the native threads, the parallel solves
//!    fan-out and the phase stopwatch (sequential and zero without `native`);
//! 4. [`mesh`]: the tetrahedral mesh, its readers and [`mesh::units`] (materials, lengths);
//! 5. [`fem`]: the stiffness `K`, its one factorisation, the frontal factor, the Gram
//!    products and the locking-free formulation;
//! 6. [`compliance`]: `L` and its solve plan, near blocks, the low-rank correction,
//!    precision, conditioning and the hierarchical [`compliance::hmatrix`];
//! 7. [`cache`]: the compliance files, read from bytes or files;
//! 8. [`contact`]: god-objects, the point force, the finger, the sphere, friction, the tool;
//! 9. [`devices`]: the haptic devices (pointer, script, replay, UDP) and their limits;
//! 10. [`error`]: the crate-level [`Error`](enum@Error) wrapping the rooms' typed errors;
//! 11. [`precompute`]: the one precompute call;
//! 12. [`cut`]: the blade, the removal of tets and the cut body's correction;
//! 13. [`scene`]: scene files and the [`scene::World`];
//! 14. [`haptic`]: the pure haptic step ([`haptic::HapticWorld`], the bound, the coupling,
//!     the sample) and the cutter's work, without threads or clocks;
//! 15. [`runtime`]: the native side: the haptic and cutter threads, the pacer, sessions and
//!     the UDP server.

pub mod cache;
pub mod compliance;
pub mod contact;
pub mod cut;
pub mod devices;
pub mod error;
pub mod fem;
pub mod haptic;
pub mod limits;
pub mod mesh;
pub mod options;
pub mod precompute;
pub mod runtime;
pub mod scene;
#[cfg(feature = "self-check")]
#[doc(hidden)]
pub mod self_check;
pub mod threads;

pub use error::Error;
pub use mesh::units::{Formulation, LengthUnit, Material};
pub use mesh::{Mesh, MeshError, RawMesh};
