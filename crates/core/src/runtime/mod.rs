//! The runtime: the two loops of the paper's prototype. The haptic loop ([`haptic`]) runs every
//! finger of a scene at 1 kHz on its own core; the visual loop reads the latest [`WorldSample`]
//! through a wait-free triple buffer and draws asynchronously.

pub mod bound;
pub mod coupling;
pub mod cutting;
pub mod haptic;
pub mod pacer;
mod run;
mod sample;
pub mod serve;
pub mod session;

pub use haptic::HapticWorld;
pub use run::{join_haptic, run_haptic, DoneGuard, HapticRun};

pub use sample::{
    sample_channel, FingerView, LiveStatus, SampleReader, SampleWriter, WorldSample, MAX_OBJECTS,
};
