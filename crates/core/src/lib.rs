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
//! * haptic path: [`devices`] → [`runtime::HapticWorld`] ([`contact`] god-objects, [`force`]
//!   eq. 9–12, the [`runtime::bound`]) → devices, and the [`runtime::WorldSample`] published;
//! * visual path: [`compliance::Compliance::displace`] on the CPU here; the GPU pass is the
//!   `touchfem-gpu` crate's.

pub mod cache;
pub mod compliance;
pub mod conditioning;
pub mod contact;
pub mod correction;
pub mod cut;
pub mod devices;
pub mod error;
pub mod fem;
pub mod finger;
pub mod force;
pub mod frontal;
pub mod gram;
pub mod hmatrix;
pub mod mesh;
pub mod near;
pub mod options;
pub mod precision;
pub mod precompute;
pub mod runtime;
pub mod scene;
pub mod threads;
pub mod units;

pub use error::Error;
pub use mesh::{Mesh, MeshError, RawMesh};
pub use units::{Formulation, LengthUnit, Material};
