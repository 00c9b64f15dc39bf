//! The `view` window's blade mode (`B`): the pointer finger's *blade twin*.
//!
//! A haptic world's tools are fixed when it is built, and the cutter's thread
//! ([`touchfem_core::runtime::cutting::CutThread`]) starts only for a world with a blade
//! finger. So `view` loads a scene that has a cuttable object with one more finger,
//! `[[finger]] device = "pointer"` with `tool = { blade = DEPTH }` appended to the scene's text
//! ([`super::cli::load_with_pointer_as`], so a recorded session replays it): the pointer's blade
//! twin. The window writes the pointer's position into exactly one of the two fingers — the
//! scene's pointer finger while blade mode is off, the twin while it is on — and the other one
//! is lifted (a NaN position: an absent finger, zero force, no contact). Nothing on the haptic
//! path changes and no state is added to it: the twin is an ordinary blade finger, which presses
//! nothing (its force is zero) and whose strokes go to the cutter's thread like a scripted
//! blade's.
//!
//! The twin's depth: the depth of the scene's first blade finger if it has one, else
//! [`DEFAULT_BLADE_M`] (5 mm), or a quarter of the smallest side of the first cuttable object's
//! bounding box if that is less.

use glam::DVec3;
use std::sync::Arc;

use touchfem_core::devices::pointer::PointerShared;
use touchfem_core::scene::{DeviceSpec, World};

/// The blade twin's depth when the scene has no blade finger (at most a quarter of the
/// cuttable object's smallest bounding-box side), m.
pub const DEFAULT_BLADE_M: f64 = 5e-3;

/// The pointer's blade twin in a loaded world.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BladeTwin {
    /// The scene's pointer finger (the first `device = "pointer"` finger).
    pub pointer: usize,
    /// The twin: a later `device = "pointer"` finger whose tool is a blade.
    pub finger: usize,
    /// Its blade's depth, m.
    pub depth_m: f64,
}

/// The blade depth `view` gives the pointer's twin in `world` (see the module documentation),
/// m; `None` when no object is cuttable.
pub fn twin_depth_m(world: &World) -> Option<f64> {
    let cuttable = world.objects.iter().find(|o| o.cuttable.is_some())?;
    if let Some(d) = world.fingers.iter().find_map(|f| f.tool.blade_depth()) {
        return Some(d);
    }
    let (lo, hi) = cuttable.body.mesh.bounds();
    let side = (hi - lo).min_element();
    let quarter = if side.is_finite() && side > 0.0 {
        0.25 * side
    } else {
        DEFAULT_BLADE_M
    };
    Some(DEFAULT_BLADE_M.min(quarter))
}

/// The pointer's blade twin in `world`, or why the pointer cannot become a blade there (the
/// text the window shows when `B` is pressed).
pub fn blade_twin(world: &World) -> Result<BladeTwin, String> {
    let is_pointer = |f: &touchfem_core::scene::FingerSpec| matches!(f.device, DeviceSpec::Pointer);
    let Some(pointer) = world.fingers.iter().position(is_pointer) else {
        return Err("blade: this scene has no pointer finger".into());
    };
    if world.fingers[pointer].tool.blade_depth().is_some() {
        return Err("blade: the pointer is a blade already".into());
    }
    if world.objects.iter().all(|o| o.cuttable.is_none()) {
        return Err("blade: no object in this scene is cuttable".into());
    }
    world
        .fingers
        .iter()
        .enumerate()
        .skip(pointer + 1)
        .find_map(|(i, f)| {
            let depth_m = f.tool.blade_depth().filter(|_| is_pointer(f))?;
            Some(BladeTwin {
                pointer,
                finger: i,
                depth_m,
            })
        })
        .ok_or_else(|| {
            format!(
                "blade: no blade finger could be added for the pointer (the scene has {} \
                 fingers, or an inline `finger` array)",
                touchfem_core::contact::force::MAX_FINGERS
            )
        })
}

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
