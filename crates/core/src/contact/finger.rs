//! One finger on one object, on its own: the god-object and the force solve of the paper, with
//! the force saturated. What the speed-against-error study and the benchmarks time; a scene's
//! fingers run [`crate::runtime::HapticWorld`].

use glam::DVec3;

use crate::compliance::Compliance;
use crate::contact::force::{finger_force, saturate, ForceBc, ForceModel};
use crate::contact::{ContactPoint, GodObject, Surface};

/// The per-finger state of the haptic path: god-object plus the last outputs.
#[derive(Clone, Debug)]
pub struct Finger {
    god: GodObject,
    /// The last contact, if touching.
    pub contact: Option<ContactPoint>,
    /// The last force boundary condition (what the visual path needs).
    pub bc: ForceBc,
}

impl Finger {
    /// A finger starting free at `x` (outside the object).
    pub fn new(x: DVec3) -> Finger {
        Finger {
            god: GodObject::new(x),
            contact: None,
            bc: ForceBc::default(),
        }
    }

    /// One haptic tick: god-object update and force solve. Returns the bounded force for the
    /// device. Allocates nothing.
    #[inline]
    pub fn step(
        &mut self,
        surface: &Surface,
        compliance: &Compliance,
        x: DVec3,
        model: ForceModel,
        max_force_n: f64,
    ) -> DVec3 {
        self.bc.clear();
        if !x.is_finite() {
            // A glitching device: keep the god-object, send nothing.
            self.contact = None;
            return DVec3::ZERO;
        }
        self.contact = self.god.update(surface, x);
        match &self.contact {
            Some(c) => {
                let f = finger_force(compliance, c, model, &mut self.bc).feedback;
                let out = saturate(f, max_force_n);
                if out != f {
                    // Scale the boundary condition with the force actually rendered.
                    let s = if f.length() > 0.0 && out.length() > 0.0 {
                        out.length() / f.length()
                    } else {
                        0.0
                    };
                    let mut scaled = ForceBc::default();
                    for &(col, v) in self.bc.entries() {
                        scaled.add(col, v * s);
                    }
                    self.bc = scaled;
                }
                out
            }
            None => DVec3::ZERO,
        }
    }
}
