//! # touchfem
//!
//! Touch and see soft objects in real time: the method of Hirota & Kaneko, *Representation of
//! Soft Objects in Virtual Environment*. A linear tetrahedral FEM object's compliance `L = K⁻¹`
//! is precomputed once for the displayed rows and touchable columns; the finger's displacement is
//! turned into an equivalent nodal force with 3×3 blocks `L_ii⁻¹` (so `L` never changes); the
//! haptic loop runs that small solve at 1 kHz on the CPU, and the visual loop computes
//! `u = L·F` over the active columns.
//!
//! Units are SI throughout (m, N, Pa, s); mesh files may declare millimetres (see [`units`]).
//!
//! Data flows one way:
//! * precompute: [`mesh`] → [`fem`] (sparse K, Cholesky) → [`compliance`] (L, L_ii⁻¹) → [`cache`]
//! * haptic path: [`contact`] (god-object) → [`force`] (eq. 9–12) → [`haptics`] (lock-free publish)
//! * visual path: [`compliance::Compliance::displace`] on the CPU (f64 reference) or the GPU pass
//!   ([`gpu`], [`render`]); [`threads`] places the two loops on their own cores.

#![warn(missing_docs)]

pub mod bench_plot;
pub mod cache;
pub mod cg;
pub mod cli;
pub mod compliance;
pub mod conditioning;
pub mod contact;
pub mod demo;
pub mod devices;
pub mod error;
pub mod fem;
pub mod force;
pub mod frontal;
pub mod gpu;
pub mod gram;
pub mod haptics;
pub mod hard;
pub mod ladder;
pub mod mesh;
pub mod near;
pub mod precompute;
pub mod render;
pub mod runtime;
pub mod scene;
pub mod threads;
pub mod tradeoff;
pub mod units;
pub mod vtu;
pub mod window;

pub use error::Error;
pub use mesh::{Mesh, MeshError, RawMesh};
pub use units::{LengthUnit, Material};
pub use wgpu;

/// The README's code runs as a doc test.
#[doc = include_str!("../README.md")]
#[cfg(doctest)]
pub struct ReadmeDoctests;
