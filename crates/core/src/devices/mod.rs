//! Haptic devices behind one trait, in the manner of CHAI3D's `cGenericHapticDevice`: each
//! device drives one finger, reporting where it is and rendering the force it is sent.
//!
//! * [`ScriptedDevice`] / [`KeyframePath`]: a scripted path (demo, tests, benchmarks);
//! * [`pointer::PointerDevice`]: the `view` window's mouse pointer;
//! * [`ReplayDevice`]: the positions of a recorded session;
//! * [`udp::UdpBridge`]: fingers driven over UDP (`touchfem serve --udp`);
//! * [`external::ExternalFinger`]: a finger another thread drives through memory (the Haply
//!   Inverse3's WebSocket client in `touchfem-app`), with [`workspace::Workspace`] mapping a
//!   device's workspace into the scene.
//!
//! Every method is called from the haptic loop once per tick: implementations must not block
//! or allocate.

#[cfg(feature = "native")]
pub mod external;
pub mod limits;
pub mod pointer;
mod replay;
pub(crate) mod script;
pub mod udp;
pub mod workspace;

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

/// What the haptic path says about one finger's force, for devices that report it (the UDP
/// bridge's flags).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ForceState {
    /// The finger touches an object.
    pub touching: bool,
    /// A limit changed the force (saturation, or the device's coupling).
    pub limited: bool,
}

/// Every finger's device at once: what the haptic loop reads and writes each tick. A list of
/// one-finger [`HapticDevice`]s is one; a device that serves several fingers over one channel
/// (the UDP bridge, [`udp::UdpBridge`]) is another.
pub trait FingerDevices: Send {
    /// Writes each finger's position (metres, scene frame; NaN: no valid reading) at `t`
    /// seconds since start into `out`.
    fn read(&mut self, t: f64, out: &mut [DVec3]);
    /// Sends each finger its force (newtons); `state[i]` says whether finger i touches and
    /// whether a limit shaped its force.
    fn write(&mut self, forces: &[DVec3], state: &[ForceState]);
    /// Whether the device clocks the loop (each of its readings starts a tick) instead of
    /// the loop's own deadlines. Default: no.
    fn clocked(&self) -> bool {
        false
    }
    /// For a clocked device: waits, between ticks, until its next reading arrives or
    /// `timeout` passes; returns whether one arrived. Default: returns `true` at once.
    fn wait_reading(&mut self, timeout: std::time::Duration) -> bool {
        let _ = timeout;
        true
    }
    /// The end of service: every finger's device gets zero force (and a device that can say
    /// so, that it is released). Called once when the haptic loop ends, however it ends.
    fn release(&mut self);
}

impl<D: HapticDevice> FingerDevices for [D] {
    fn read(&mut self, t: f64, out: &mut [DVec3]) {
        for (p, d) in out.iter_mut().zip(self.iter_mut()) {
            *p = d.position(t);
        }
    }
    fn write(&mut self, forces: &[DVec3], _state: &[ForceState]) {
        for (f, d) in forces.iter().zip(self.iter_mut()) {
            d.set_force(*f);
        }
    }
    fn release(&mut self) {
        for d in self.iter_mut() {
            d.set_force(DVec3::ZERO);
        }
    }
}

impl<D: HapticDevice> FingerDevices for Vec<D> {
    fn read(&mut self, t: f64, out: &mut [DVec3]) {
        self.as_mut_slice().read(t, out)
    }
    fn write(&mut self, forces: &[DVec3], state: &[ForceState]) {
        self.as_mut_slice().write(forces, state)
    }
    fn release(&mut self) {
        self.as_mut_slice().release()
    }
}

impl<D: HapticDevice + ?Sized> HapticDevice for Box<D> {
    fn position(&mut self, t: f64) -> DVec3 {
        (**self).position(t)
    }
    fn set_force(&mut self, f: DVec3) {
        (**self).set_force(f)
    }
}
