//! The runtime: the two loops of the paper's prototype. The haptic loop runs every finger of a
//! scene at 1 kHz on its own core, each tick a [`HapticWorld`] step ([`crate::haptic`]); the
//! visual loop reads the latest [`WorldSample`] through a wait-free triple buffer and draws
//! asynchronously. Threads, clocks, files and sockets live here; the step itself does not.
//! Without the `native` feature only the re-exports of the pure step and the cutter's
//! rings ([`cutting::CutLink`]) remain.

pub mod cutting;
#[cfg(feature = "native")]
pub mod pacer;
#[cfg(feature = "native")]
mod run;
#[cfg(feature = "native")]
pub mod serve;
#[cfg(feature = "native")]
pub mod session;

pub use crate::haptic::{self, bound, coupling};
pub use crate::haptic::{
    sample_channel, FingerView, HapticWorld, LiveStatus, SampleReader, SampleWriter, WorldSample,
    MAX_OBJECTS,
};
pub use crate::threads::VisualPlacement;
#[cfg(feature = "native")]
pub use run::{join_haptic, run_haptic, DoneGuard, HapticRun};
