//! The runtime: the two loops of the paper's prototype. The haptic loop runs every finger of a
//! scene at 1 kHz on its own core, each tick a [`HapticWorld`] step ([`crate::haptic`]); the
//! visual loop reads the latest [`WorldSample`] through a wait-free triple buffer and draws
//! asynchronously. Threads, clocks, files and sockets live here; the step itself does not.

pub mod cutting;
pub mod pacer;
mod run;
pub mod serve;
pub mod session;

pub use crate::haptic::{self, bound, coupling};
pub use crate::haptic::{
    sample_channel, FingerView, HapticWorld, LiveStatus, SampleReader, SampleWriter, WorldSample,
    MAX_OBJECTS,
};
pub use crate::threads::VisualPlacement;
pub use run::{join_haptic, run_haptic, DoneGuard, HapticRun};
