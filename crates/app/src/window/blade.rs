//! The `view` window's blade mode (`B`): the pointer drives either the scene's pointer finger
//! or its *blade twin* ([`touchfem_core::scene::pointer`], which says what the twin is and how
//! deep it cuts). The window writes the pointer's position into exactly one of the two; the
//! other one is lifted.

use glam::DVec3;
use std::sync::Arc;

use touchfem_core::devices::pointer::PointerShared;
pub use touchfem_core::scene::pointer::{blade_twin, twin_depth_m, BladeTwin, DEFAULT_BLADE_M};
use touchfem_core::scene::World;

/// Where the window's pointer goes: the scene's pointer finger, or its blade twin while blade
/// mode is on. Writing a position is three relaxed atomic stores, as for
/// [`PointerShared::set_position`]; the haptic loop reads each finger through a
/// [`PointerDevice`](touchfem_core::devices::pointer::PointerDevice).
#[derive(Clone, Debug)]
pub struct PointerRoute {
    finger: Arc<PointerShared>,
    twin: Result<(Arc<PointerShared>, BladeTwin), String>,
    blade: bool,
}

impl PointerRoute {
    /// The route for `world`'s pointer finger, with its blade twin if it has one
    /// ([`blade_twin`]); blade mode off, both lifted.
    pub fn new(world: &World) -> PointerRoute {
        PointerRoute {
            finger: Arc::new(PointerShared::default()),
            twin: blade_twin(world).map(|t| (Arc::new(PointerShared::default()), t)),
            blade: false,
        }
    }

    /// The scene's pointer finger's shared position.
    pub fn finger(&self) -> &Arc<PointerShared> {
        &self.finger
    }

    /// The blade twin's shared position and the twin, if the world has one.
    pub fn twin(&self) -> Option<(&Arc<PointerShared>, BladeTwin)> {
        self.twin.as_ref().ok().map(|(s, t)| (s, *t))
    }

    /// Whether blade mode is on.
    pub fn blade_on(&self) -> bool {
        self.blade
    }

    /// The blade's depth while blade mode is on, m.
    pub fn blade_depth_m(&self) -> Option<f64> {
        self.twin().filter(|_| self.blade).map(|(_, t)| t.depth_m)
    }

    /// Turns blade mode on or off (`B`): lifts the finger that was driven and returns whether
    /// blade mode is now on; a world without a twin returns why, and nothing changes.
    pub fn toggle_blade(&mut self) -> Result<bool, String> {
        if let Err(why) = &self.twin {
            return Err(why.clone());
        }
        self.lift();
        self.blade = !self.blade;
        Ok(self.blade)
    }

    /// Puts the pointer's finger (or the blade, in blade mode) at `p` (m, scene frame; NaN
    /// lifts it).
    pub fn set_position(&self, p: DVec3) {
        self.active().set_position(p);
    }

    /// Lifts both fingers.
    pub fn lift(&self) {
        self.finger.set_position(DVec3::NAN);
        if let Ok((s, _)) = &self.twin {
            s.set_position(DVec3::NAN);
        }
    }

    /// The force the haptic loop last sent to the finger the pointer drives, N (a blade's is
    /// zero).
    pub fn force(&self) -> DVec3 {
        self.active().force()
    }

    fn active(&self) -> &PointerShared {
        match (&self.twin, self.blade) {
            (Ok((s, _)), true) => s,
            _ => &self.finger,
        }
    }
}
