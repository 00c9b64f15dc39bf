//! Haptic devices behind one trait, in the manner of CHAI3D's `cGenericHapticDevice`: each
//! device drives one finger, reporting where it is and rendering the force it is sent.
//!
//! * [`ScriptedDevice`] / [`KeyframePath`]: a scripted path (demo, tests, benchmarks);
//! * [`pointer::PointerDevice`]: the `view` window's mouse pointer;
//! * [`ReplayDevice`]: the positions of a recorded session.
//!
//! Every method is called from the haptic loop once per tick: implementations must not block
//! or allocate.

pub mod pointer;
mod replay;
mod script;

use glam::DVec3;

pub use replay::ReplayDevice;
pub use script::{KeyframePath, ScriptedDevice};

/// A force-feedback device: where the finger is, and the force to push it with.
pub trait HapticDevice: Send {
    /// The finger position in metres, in the scene's frame, at `t` seconds since start. A
    /// non-finite position means "no valid reading": the finger gets zero force.
    fn position(&mut self, t: f64) -> DVec3;
    /// Sends the force (newtons) the device should render.
    fn set_force(&mut self, f: DVec3);
}

impl<D: HapticDevice + ?Sized> HapticDevice for Box<D> {
    fn position(&mut self, t: f64) -> DVec3 {
        (**self).position(t)
    }
    fn set_force(&mut self, f: DVec3) {
        (**self).set_force(f)
    }
}
