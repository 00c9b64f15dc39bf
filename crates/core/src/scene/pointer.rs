//! The pointer a viewer adds to a scene, and the pointer's *blade twin* (`B` in `touchfem view`
//! and in the web page).
//!
//! A haptic world's tools are fixed when it is built, and a cutter starts only for a world with
//! a blade finger. So a viewer loads a scene that has a cuttable object with one more finger,
//! `[[finger]] device = "pointer"` with `tool = { blade = DEPTH }` appended to the scene's text
//! ([`pointer_fingers`]): the pointer's blade twin. The viewer writes the pointer's position
//! into exactly one of the two fingers — the scene's pointer finger while blade mode is off,
//! the twin while it is on — and lifts the other one (a NaN position: an absent finger, zero
//! force, no contact). Nothing on the haptic path changes and no state is added to it: the
//! twin is an ordinary blade finger, which presses nothing (its force is zero) and whose
//! strokes go to the cutter like a scripted blade's.
//!
//! The twin's depth: the depth of the scene's first blade finger if it has one, else
//! [`DEFAULT_BLADE_M`] (5 mm), or a quarter of the smallest side of the first cuttable object's
//! bounding box if that is less.

use super::{DeviceSpec, FingerSpec, World};
use crate::limits::MAX_FINGERS;

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

/// The blade depth a viewer gives the pointer's twin in `world` (see the module
/// documentation), m; `None` when no object is cuttable.
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

fn is_pointer(f: &FingerSpec) -> bool {
    matches!(f.device, DeviceSpec::Pointer)
}

/// The pointer's blade twin in `world`, or why the pointer cannot become a blade there (the
/// text a viewer shows when `B` is pressed).
pub fn blade_twin(world: &World) -> Result<BladeTwin, String> {
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
                "blade: no blade finger could be added for the pointer (the scene has \
                 {MAX_FINGERS} fingers, or an inline `finger` array)"
            )
        })
}

/// The `[[finger]]` tables a viewer appends to `world`'s scene text: a pointer finger when the
/// scene has none (a sphere of `sphere` scene units when given), and the pointer's blade twin
/// when an object is cuttable and the pointer is not a blade already, as far as
/// [`MAX_FINGERS`] allows. Empty when nothing is to be added. The compliance does not depend on
/// the fingers: the world loaded again from the longer text has the same objects.
pub fn pointer_fingers(world: &World, sphere: Option<f64>) -> String {
    let pointer = world.fingers.iter().find(|f| is_pointer(f));
    let mut fingers = world.fingers.len();
    let mut extra = String::new();
    if pointer.is_none() {
        if fingers >= MAX_FINGERS {
            return extra;
        }
        extra.push_str("\n[[finger]]\ndevice = \"pointer\"\n");
        if let Some(r) = sphere {
            extra.push_str(&format!("tool = {{ sphere = {r:?} }}\n"));
        }
        fingers += 1;
    }
    let pointer_is_blade = pointer.is_some_and(|f| f.tool.blade_depth().is_some());
    let has_twin = pointer.is_some() && blade_twin(world).is_ok();
    if let Some(depth_m) =
        twin_depth_m(world).filter(|_| !pointer_is_blade && !has_twin && fingers < MAX_FINGERS)
    {
        let depth = depth_m / world.unit.to_metres();
        extra.push_str(&format!(
            "\n[[finger]]  # the pointer's blade twin (`B` in `touchfem view` and the page)\n\
             device = \"pointer\"\ntool = {{ blade = {depth:?} }}\n"
        ));
    }
    extra
}
