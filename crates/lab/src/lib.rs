//! # touchfem-lab
//!
//! The laboratory: studies that measure touchfem rather than run it. Speed against error
//! ([`tradeoff`], plotted by [`bench_plot`]), the mesh-refinement ladder ([`ladder`]), the hard
//! cases ([`hard`]: nearly incompressible material, slivers, stiff contrasts, f16 storage), the
//! conjugate-gradient baseline ([`cg`]), the locking-free
//! stiffness against the standard one ([`locking_free`]), and what every report says of its machine
//! ([`report`]). The criterion benchmarks live in the workspace's `benches/`.

pub mod bench_plot;
pub mod cg;
pub mod cutting;
pub mod error;
pub mod hard;
pub mod hertz;
pub mod hmatrix_study;
pub mod ladder;
pub mod locking_free;
pub mod report;
pub mod tradeoff;

pub use error::Error;
