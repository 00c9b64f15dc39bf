//! One haptic tick for every finger of a scene: god-objects, the force solve (one finger alone,
//! or all fingers on an object solved together), bounded forces, and the boundary conditions
//! for the visual path. Allocates nothing after [`HapticWorld::new`].
//!
//! # Rules
//! * **Each finger has its own god-object on each object** (in that object's frame). A finger
//!   touches at most one object at a time: the first, in scene order, whose god-object reports
//!   a contact.
//! * **One contact on an object**: the finger's force model (the paper's eq. 9–12, or exact).
//!   **Several contacts on one object** are solved together
//!   ([`crate::force::coupled_point_forces`]): the contact points move by their displacements under
//!   all the point forces at once. A fingertip compliance of [`SKIN`] × the point's own
//!   compliance keeps the system well posed when two fingers touch the same triangle, or the
//!   same point (they then share the load).
//! * **Bounded**: each finger's force is saturated at the scene's `max_force_n`, and the nodal
//!   forces it causes are scaled by the same factor, so the visual path shows what the finger
//!   feels. After the model, the ramp and the coupling, every finger's force passes its
//!   `ForceBound` last: finite, rate-limited in measured time, held to the device's
//!   continuous force, and at most the smaller of the scene's and the device's peak force.
//! * **Time is measured**: [`HapticWorld::step_dt`] takes the seconds since the last tick (the
//!   device's clock may tick at 4–8 kHz); the ramp, the coupling's damping and the force
//!   bound's rate are per second, not per tick.
//! * **A finger that starts inside an object** — or reappears there after a tick without a
//!   valid position (NaN from the device, or the window's pointer being lifted) — is attached
//!   to the nearest point of that object's surface, as if it had pressed in from there, and
//!   its force is ramped in linearly over [`RAMP_S`] so the device does not jolt.
//! * **No valid position** (NaN or infinite): zero force for that finger, no contact.
//! * **A finger with device limits** ([`crate::scene::FingerSpec::limits`]) feels the force
//!   through a `VirtualCoupling` sized from them: stiffness at most the device's, damped,
//!   reset after a tick without a valid position. The displayed deformation and the
//!   god-object stay the paper's.
//! * **A device cannot leave its workspace in a tick**: a position more than the workspace's
//!   diameter (`2 · workspace_radius_m`) from the finger's last valid one is a glitch, and
//!   counts as no valid position (zero force; the finger is placed afresh, and ramped in if
//!   inside, at its next reading).

use glam::{DMat3, DVec3};

use super::bound::ForceBound;
use super::coupling::VirtualCoupling;
use super::sample::{FingerView, WorldSample, MAX_OBJECTS};
use crate::contact::{ContactPoint, GodObject};
use crate::force::{
    add_point_force, coupled_point_forces, finger_force, saturate, ForceBc, ForceModel, MAX_FINGERS,
};
use crate::scene::World;

/// Fingertip compliance of the coupled solve, relative to each contact point's own compliance.
pub const SKIN: f64 = 1e-3;
/// Seconds over which the force of a finger attached from inside is ramped in.
pub const RAMP_S: f64 = 0.1;

#[derive(Clone, Copy, Debug)]
struct FingerState {
    gods: [GodObject; MAX_OBJECTS],
    /// True until a valid position has been seen (and after an invalid one).
    absent: bool,
    /// The last valid position (NaN while absent).
    last_x: DVec3,
    /// The largest move in one tick the device can make (its workspace's diameter), m.
    max_jump: f64,
    /// Force ramp, 0..=1.
    ramp: f64,
    model: ForceModel,
}

/// The haptic state of a scene: every finger's god-objects and ramp. See the module docs.
pub struct HapticWorld<'w> {
    world: &'w World,
    fingers: [FingerState; MAX_FINGERS],
    n_fingers: usize,
    period: f64,
    max_force: f64,
    bounds: [ForceBound; MAX_FINGERS],
    ticks: u64,
    contacts: [Option<(usize, ContactPoint)>; MAX_FINGERS],
    couplings: [Option<VirtualCoupling>; MAX_FINGERS],
    limited: [bool; MAX_FINGERS],
}

impl<'w> HapticWorld<'w> {
    /// The haptic state of `world`, every finger absent (its first valid position places it).
    pub fn new(world: &'w World) -> HapticWorld<'w> {
        let absent = FingerState {
            gods: [GodObject::new(DVec3::NAN); MAX_OBJECTS],
            absent: true,
            last_x: DVec3::NAN,
            max_jump: f64::INFINITY,
            ramp: 1.0,
            model: ForceModel::Paper,
        };
        let mut fingers = [absent; MAX_FINGERS];
        let n_fingers = world.fingers.len().min(MAX_FINGERS);
        let max_force = world.haptics.max_force_n;
        let mut bounds = [ForceBound::new(max_force, None); MAX_FINGERS];
        for ((f, b), spec) in fingers.iter_mut().zip(&mut bounds).zip(&world.fingers) {
            f.model = spec.model;
            *b = ForceBound::new(max_force, spec.limits.as_ref());
            if let Some(l) = &spec.limits {
                if l.workspace_radius_m.is_finite() && l.workspace_radius_m > 0.0 {
                    f.max_jump = 2.0 * l.workspace_radius_m;
                }
            }
        }
        let couplings = std::array::from_fn(|i| {
            world
                .fingers
                .get(i)
                .and_then(|f| f.limits.as_ref())
                .map(VirtualCoupling::new)
        });
        HapticWorld {
            world,
            couplings,
            limited: [false; MAX_FINGERS],
            fingers,
            n_fingers,
            period: 1.0 / world.haptics.rate_hz,
            max_force,
            bounds,
            ticks: 0,
            contacts: [None; MAX_FINGERS],
        }
    }

    /// Number of fingers.
    pub fn fingers(&self) -> usize {
        self.n_fingers
    }

    /// The force bound of finger `i` (N): the smaller of the scene's `max_force_n` and its
    /// device's peak force.
    pub fn force_bound(&self, i: usize) -> f64 {
        self.bounds.get(i).map_or(0.0, |b| b.bound())
    }

    /// [`HapticWorld::step_dt`] one nominal period (`1 / rate_hz`) after the last tick.
    pub fn step(&mut self, positions: &[DVec3], forces: &mut [DVec3], sample: &mut WorldSample) {
        self.step_dt(self.period, positions, forces, sample)
    }

    /// One tick, `dt` seconds (measured) after the last: `positions[i]` is finger i's device
    /// position (metres, scene frame). Writes the force for each finger's device into
    /// `forces[i]` — finite, within its `ForceBound` — and the tick's boundary conditions
    /// and finger views into `sample`, every field a reader looks at (so `sample` may be a
    /// stale buffer, written in place). Allocates nothing.
    pub fn step_dt(
        &mut self,
        dt: f64,
        positions: &[DVec3],
        forces: &mut [DVec3],
        sample: &mut WorldSample,
    ) {
        let dt = if dt.is_finite() { dt.max(0.0) } else { 0.0 };
        let objects = &self.world.objects;
        let n_obj = objects.len().min(MAX_OBJECTS);
        let n = self.n_fingers.min(positions.len()).min(forces.len());
        sample.n_objects = n_obj;
        sample.n_fingers = n;
        for bc in &mut sample.bcs {
            bc.clear();
        }
        // God-objects: which object each finger touches, and where.
        let mut touch: [Option<(usize, ContactPoint)>; MAX_FINGERS] = [None; MAX_FINGERS];
        let mut valid = [false; MAX_FINGERS];
        let mut glitch = [false; MAX_FINGERS];
        for i in 0..n {
            let x = positions[i];
            let f = &mut self.fingers[i];
            glitch[i] = x.is_finite() && !f.absent && x.distance(f.last_x) > f.max_jump;
            if !x.is_finite() || glitch[i] {
                f.absent = true;
                f.last_x = DVec3::NAN;
                if let Some(c) = &mut self.couplings[i] {
                    c.reset();
                }
                continue;
            }
            valid[i] = true;
            f.last_x = x;
            if f.absent {
                f.absent = false;
                f.ramp = 1.0;
                for (o, obj) in objects.iter().take(n_obj).enumerate() {
                    let local = x - obj.offset;
                    let surf = &obj.body.surface;
                    f.gods[o] = if surf.contains(local) {
                        f.ramp = 0.0;
                        GodObject::touching(surf.closest_global(local).0)
                    } else {
                        GodObject::new(local)
                    };
                }
            }
            for (o, obj) in objects.iter().take(n_obj).enumerate() {
                let c = f.gods[o].update(&obj.body.surface, x - obj.offset);
                if touch[i].is_none() {
                    touch[i] = c.map(|c| (o, c));
                }
            }
            if touch[i].is_some() {
                f.ramp = (f.ramp + dt / RAMP_S).min(1.0);
            }
        }
        // Forces, object by object.
        forces[..n].fill(DVec3::ZERO);
        self.limited[..n].fill(false);
        for (o, obj) in objects.iter().take(n_obj).enumerate() {
            let comp = &obj.body.compliance;
            let mut who = [0usize; MAX_FINGERS];
            let mut contacts = [None::<ContactPoint>; MAX_FINGERS];
            let mut m = 0;
            for (i, t) in touch.iter().enumerate().take(n) {
                if let Some((oi, c)) = *t {
                    if oi == o {
                        who[m] = i;
                        contacts[m] = Some(c);
                        m += 1;
                    }
                }
            }
            if m == 0 {
                continue;
            }
            let mut list = [ContactPoint::default(); MAX_FINGERS];
            for k in 0..m {
                list[k] = contacts[k].unwrap_or_default();
            }
            let mut own = [ForceBc::default(); MAX_FINGERS];
            let mut feedback = [DVec3::ZERO; MAX_FINGERS];
            if m == 1 {
                feedback[0] =
                    finger_force(comp, &list[0], self.fingers[who[0]].model, &mut own[0]).feedback;
            } else {
                let mut g = [DVec3::ZERO; MAX_FINGERS];
                if coupled_point_forces(comp, &list[..m], SKIN, &mut g) {
                    for k in 0..m {
                        add_point_force(comp, &list[k], g[k], &mut own[k]);
                        feedback[k] = -g[k];
                    }
                }
            }
            for k in 0..m {
                let i = who[k];
                let f = feedback[k];
                let out = saturate(f, self.max_force) * self.fingers[i].ramp;
                let len = f.length();
                let scale = if len > 0.0 && out.is_finite() {
                    out.length() / len
                } else {
                    0.0
                };
                for &(col, v) in own[k].entries() {
                    sample.bcs[o].add(col, v * scale);
                }
                forces[i] = if out.is_finite() { out } else { DVec3::ZERO };
                self.limited[i] = len > self.max_force;
            }
        }
        self.contacts = touch;
        // What each hand feels: through its device's coupling, where it has one.
        for i in 0..n {
            let x = positions[i];
            if !valid[i] || self.couplings[i].is_none() {
                continue;
            }
            // Only a coupled finger needs its contact's stiffness (a 3×3 inverse).
            let k = self.contact_stiffness(i);
            if let Some(c) = &mut self.couplings[i] {
                let paper = forces[i];
                forces[i] = c.render(paper, k, x, dt);
                if (forces[i] - paper).length() > 0.01 * paper.length() + 1e-9 {
                    self.limited[i] = true;
                }
            }
        }
        // The force bound, last of all.
        for i in 0..n {
            if !valid[i] {
                self.bounds[i].reset();
                forces[i] = DVec3::ZERO;
                self.limited[i] = glitch[i];
                continue;
            }
            let (f, limited) = self.bounds[i].apply(forces[i], dt);
            forces[i] = f;
            self.limited[i] |= limited;
        }
        for i in 0..n {
            let x = positions[i];
            sample.fingers[i] = FingerView {
                position: x,
                proxy: touch[i].map(|(o, c)| c.proxy + objects[o].offset),
                object: touch[i].map(|(o, _)| o as u8),
                force: forces[i],
            };
        }
        self.ticks += 1;
        sample.tick = self.ticks;
    }

    /// Whether finger `i`'s force in the last step was changed by a limit: saturated at the
    /// scene's `max_force_n`, or rendered by its device's coupling more than 1 % away from the
    /// paper's force.
    pub fn limited(&self, i: usize) -> bool {
        self.limited.get(i).copied().unwrap_or(false)
    }

    /// The stiffness (N/m, 3×3) of finger `i`'s contact point after the last step, `None` when
    /// it does not touch: `Σ α_j L_jj⁻¹` for the paper's model, `W⁻¹` for the exact one (a
    /// clamped vertex counts with the clamp compliance). What a virtual coupling is sized
    /// against. Allocates nothing.
    pub(crate) fn contact_stiffness(&self, i: usize) -> Option<DMat3> {
        let (o, c) = self.contacts.get(i).copied().flatten()?;
        let comp = &self.world.objects[o].body.compliance;
        match self.fingers[i].model {
            ForceModel::Paper => {
                let mut k = DMat3::ZERO;
                for a in 0..3 {
                    let kv = match comp.col_of(c.nodes[a]) {
                        Some(col) => comp.diag_inv(col),
                        None => DMat3::from_diagonal(DVec3::splat(1.0 / comp.clamp_compliance())),
                    };
                    k += kv * c.alpha[a];
                }
                Some(k)
            }
            ForceModel::Exact => {
                crate::compliance::invert3(crate::force::point_compliance(comp, &c))
            }
        }
    }
}
