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
//!   ([`crate::contact::force::coupled_point_forces`]): the contact points move by their displacements under
//!   all the point forces at once. A fingertip compliance of [`SKIN`] × the point's own
//!   compliance keeps the system well posed when two fingers touch the same triangle, or the
//!   same point (they then share the load).
//! * **A sphere finger** ([`crate::contact::Tool::Sphere`]) has no god-object: every
//!   object's spheres are solved together as one contact problem on the deformed surface
//!   ([`crate::contact::Patch`], Signorini and Coulomb, warm-started, within a
//!   [`crate::contact::Budget`]; a solve cut short is counted in
//!   [`HapticWorld::budget_exhausted`]). Its force is minus the sum of its nodes' contact
//!   forces, on every object it presses. A point and a sphere on one object are solved
//!   apart.
//! * **Friction** (`[[object]] friction`): a point finger's god-object sticks and slips
//!   ([`crate::contact::StickSlip`], judged on the finger's own single-contact force);
//!   a sphere's nodes each have their cone.
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

pub mod bound;
pub mod coupling;
pub mod cutter;
pub(crate) mod sample;

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod pure_tests;

pub use sample::{
    sample_channel, FingerView, LiveStatus, SampleReader, SampleWriter, WorldSample, MAX_OBJECTS,
};

use glam::{DMat3, DVec3};

use self::bound::ForceBound;
use self::coupling::VirtualCoupling;
use self::cutter::{CutBody, Stroke};
use crate::compliance::Compliance;
use crate::contact::force::{
    add_point_force, coupled_point_forces, finger_feedback, finger_force, saturate, ForceBc,
    ForceModel, MAX_FINGERS,
};
use crate::contact::Surface;
use crate::contact::{
    Budget, ContactPoint, GodObject, Patch, PatchReport, Sphere, StickSlip, Tool,
};
use crate::scene::{Object, World};
use std::sync::Arc;

/// Fingertip compliance of the coupled solve, relative to each contact point's own compliance.
pub const SKIN: f64 = 1e-3;
/// Seconds over which the force of a finger attached from inside is ramped in.
pub const RAMP_S: f64 = 0.1;

/// A finger's force saturated at `max` and ramped, and the factor its nodal forces are
/// scaled by so that the visual path shows what the finger feels.
#[inline]
fn bounded(f: DVec3, max: f64, ramp: f64) -> (DVec3, f64) {
    let out = saturate(f, max) * ramp;
    let len = f.length();
    let scale = if len > 0.0 && out.is_finite() {
        out.length() / len
    } else {
        0.0
    };
    (out, scale)
}

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
    tool: Tool,
    /// Per object, the stick–slip state of a point finger's god-object (friction).
    sticks: [StickSlip; MAX_OBJECTS],
    /// A blade's engagement: the object it is in, the inward normal it hangs along and the
    /// last position of its top (object frame).
    blade: Option<(usize, DVec3, DVec3)>,
}

/// Object `o`'s compliance and rest surface as the haptic path reads them: its installed cut
/// body, else the scene's.
#[inline]
fn parts<'a>(
    live: &'a [Option<Arc<CutBody>>; MAX_OBJECTS],
    obj: &'a Object,
    o: usize,
) -> (&'a Compliance, &'a Surface) {
    match live.get(o).and_then(|b| b.as_deref()) {
        Some(b) => (&b.compliance, &b.surface),
        None => (&obj.body.compliance, &obj.body.surface),
    }
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
    /// Per object, the contact problem of its spheres (only when a finger is a sphere).
    patches: [Option<Box<Patch>>; MAX_OBJECTS],
    /// Per finger, the object its sphere presses, the patch's centroid (scene frame) and
    /// its normal stiffness along its mean normal.
    sphere_touch: [Option<(usize, DVec3, DMat3)>; MAX_FINGERS],
    budget: Budget,
    exhausted: u64,
    /// Per object, the cut body installed (`None`: the scene's, uncut).
    live: [Option<Arc<CutBody>>; MAX_OBJECTS],
    /// The blades' strokes of the last tick.
    strokes: [Stroke; MAX_FINGERS],
    n_strokes: usize,
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
            tool: Tool::Point,
            sticks: [StickSlip::default(); MAX_OBJECTS],
            blade: None,
        };
        let mut fingers = [absent; MAX_FINGERS];
        let n_fingers = world.fingers.len().min(MAX_FINGERS);
        let max_force = world.haptics.max_force_n;
        let mut bounds = [ForceBound::new(max_force, None); MAX_FINGERS];
        for ((f, b), spec) in fingers.iter_mut().zip(&mut bounds).zip(&world.fingers) {
            f.model = spec.model;
            f.tool = spec.tool;
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
        let any_sphere = fingers[..n_fingers]
            .iter()
            .any(|f| matches!(f.tool, Tool::Sphere { .. }));
        let patches = std::array::from_fn(|o| {
            (any_sphere && o < world.objects.len()).then(|| {
                let mut p = Box::new(Patch::new());
                p.reserve_nodes(world.objects[o].body.mesh.nodes.len());
                p
            })
        });
        HapticWorld {
            world,
            couplings,
            patches,
            sphere_touch: [None; MAX_FINGERS],
            budget: Budget::default(),
            exhausted: 0,
            live: std::array::from_fn(|_| None),
            strokes: [Stroke {
                object: 0,
                from: DVec3::ZERO,
                to: DVec3::ZERO,
                inward: DVec3::ZERO,
                depth: 0.0,
            }; MAX_FINGERS],
            n_strokes: 0,
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
        let live = &self.live;
        self.n_strokes = 0;
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
                    // A blade's god-object walks the uncut surface (as in its update below).
                    let surf = if matches!(f.tool, Tool::Blade { .. }) {
                        &obj.body.surface
                    } else {
                        parts(live, obj, o).1
                    };
                    f.gods[o] = if surf.contains(local) {
                        f.ramp = 0.0;
                        GodObject::touching(surf.closest_global(local).0)
                    } else {
                        GodObject::new(local)
                    };
                }
            }
            if matches!(f.tool, Tool::Sphere { .. }) {
                continue;
            }
            if let Tool::Blade { depth_m } = f.tool {
                // A blade presses nothing: its god-object follows the uncut rest surface to
                // know when it is in (in the body or in a cut it made), and each tick's motion
                // in an object is a stroke.
                let mut inside = None;
                for (o, obj) in objects.iter().take(n_obj).enumerate() {
                    let surf = &obj.body.surface;
                    let local = x - obj.offset;
                    if let Some(c) = f.gods[o].update(surf, local) {
                        if inside.is_none() {
                            inside = Some((o, c, local));
                        }
                    }
                }
                f.blade = match (inside, f.blade) {
                    (Some((o, _, local)), Some((bo, inward, last))) if bo == o => {
                        if local != last && self.n_strokes < MAX_FINGERS {
                            self.strokes[self.n_strokes] = Stroke {
                                object: o,
                                from: last,
                                to: local,
                                inward,
                                depth: depth_m,
                            };
                            self.n_strokes += 1;
                        }
                        Some((o, inward, local))
                    }
                    (Some((o, c, local)), _) => {
                        let inward = -objects[o].body.surface.normals[c.tri as usize];
                        Some((o, inward, local))
                    }
                    (None, _) => None,
                };
                continue;
            }
            for (o, obj) in objects.iter().take(n_obj).enumerate() {
                let (comp, surf) = parts(live, obj, o);
                let mut c = f.gods[o].update(surf, x - obj.offset);
                match (c, obj.friction.filter(|fr| !fr.is_none())) {
                    (Some(free), Some(fr)) => {
                        let model = f.model;
                        let feel = |c: &ContactPoint| finger_feedback(comp, c, model);
                        c = Some(f.sticks[o].apply(surf, &free, fr, feel));
                    }
                    (None, _) => f.sticks[o].reset(),
                    _ => {}
                }
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
        self.spheres(dt, n, positions, &valid, forces, sample);
        for (o, obj) in objects.iter().take(n_obj).enumerate() {
            let comp = parts(&self.live, obj, o).0;
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
                let (out, scale) = bounded(f, self.max_force, self.fingers[i].ramp);
                let len = f.length();
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
            let (proxy, object) = match (touch[i], self.sphere_touch[i]) {
                (Some((o, c)), _) => (Some(c.proxy + objects[o].offset), Some(o as u8)),
                (None, Some((o, p, _))) => (Some(p), Some(o as u8)),
                (None, None) => (None, None),
            };
            sample.fingers[i] = FingerView {
                position: x,
                proxy,
                object,
                force: forces[i],
            };
        }
        self.ticks += 1;
        sample.tick = self.ticks;
    }

    /// The contact problem of object `o`'s spheres after the last step (`None` when no finger
    /// of the scene is a sphere): its nodes, forces and gaps.
    pub fn patch(&self, o: usize) -> Option<&Patch> {
        self.patches.get(o).and_then(|p| p.as_deref())
    }

    /// How many sphere solves ran out of their budget so far (each still gave a finite,
    /// bounded force).
    pub fn budget_exhausted(&self) -> u64 {
        self.exhausted
    }

    /// Sets the work a sphere solve may do each tick (default [`Budget::default`]).
    pub fn set_budget(&mut self, budget: Budget) {
        self.budget = budget;
    }

    /// The blades' strokes of the last tick (object frame), for the cutter
    /// ([`crate::haptic::cutter`]).
    pub fn strokes(&self) -> &[Stroke] {
        &self.strokes[..self.n_strokes]
    }

    /// Object `o`'s cut body installed, if any.
    pub fn cut_body(&self, o: usize) -> Option<&Arc<CutBody>> {
        self.live.get(o).and_then(|b| b.as_ref())
    }

    /// Installs object `o`'s new cut body between two ticks: from the next tick its force
    /// solve reads the cut compliance and its god-objects walk the opened surface (each
    /// finger's god-object on `o` placed again (a blade's keeps walking the uncut surface), as when a finger appears; sphere contacts and
    /// friction anchors on `o` start afresh). Returns the body it replaces, to be dropped off
    /// the haptic thread. Allocates nothing.
    pub fn install_cut(&mut self, o: usize, body: Arc<CutBody>) -> Option<Arc<CutBody>> {
        if o >= self.world.objects.len().min(MAX_OBJECTS) {
            return Some(body);
        }
        let old = self.live[o].replace(body);
        let obj = &self.world.objects[o];
        let surf = parts(&self.live, obj, o).1;
        for f in &mut self.fingers[..self.n_fingers] {
            f.sticks[o].reset();
            // A blade's god-object walks the uncut surface.
            if f.absent || !f.last_x.is_finite() || matches!(f.tool, Tool::Blade { .. }) {
                continue;
            }
            let local = f.last_x - obj.offset;
            f.gods[o] = if surf.contains(local) {
                GodObject::touching(surf.closest_global(local).0)
            } else {
                GodObject::new(local)
            };
        }
        if let Some(p) = self.patches[o].as_deref_mut() {
            p.reset();
        }
        old
    }

    /// The spheres' contact problems, object by object: each sphere finger's force is minus
    /// the sum of its contact nodes' forces on every object it presses, saturated and ramped
    /// like a point's; its nodes' forces, scaled by the same factor, go to the sample.
    fn spheres(
        &mut self,
        dt: f64,
        n: usize,
        positions: &[DVec3],
        valid: &[bool; MAX_FINGERS],
        forces: &mut [DVec3],
        sample: &mut WorldSample,
    ) {
        self.sphere_touch = [None; MAX_FINGERS];
        let objects = &self.world.objects;
        let mut raw = [DVec3::ZERO; MAX_FINGERS];
        let mut any = false;
        for (o, obj) in objects.iter().enumerate().take(MAX_OBJECTS) {
            let Some(patch) = self.patches[o].as_deref_mut() else {
                continue;
            };
            let mut spheres = [Sphere {
                centre: DVec3::NAN,
                radius: 0.0,
            }; MAX_FINGERS];
            let mut live = false;
            for i in 0..n {
                if let (Tool::Sphere { radius_m }, true) = (self.fingers[i].tool, valid[i]) {
                    spheres[i] = Sphere {
                        centre: positions[i] - obj.offset,
                        radius: radius_m,
                    };
                    live = true;
                }
            }
            if !live {
                patch.reset();
                continue;
            }
            let (comp, surf) = parts(&self.live, obj, o);
            let report: PatchReport =
                patch.solve(comp, surf, &spheres[..n], obj.friction, self.budget);
            if report.exhausted {
                self.exhausted += 1;
            }
            for i in 0..n {
                if !matches!(self.fingers[i].tool, Tool::Sphere { .. }) || !valid[i] {
                    continue;
                }
                let f = -patch.sphere_force(i);
                if f != DVec3::ZERO {
                    raw[i] += f;
                    any = true;
                    if self.sphere_touch[i].is_none() {
                        let nrm = patch.mean_normal(i);
                        let k = DMat3::from_cols(nrm, DVec3::ZERO, DVec3::ZERO)
                            * DMat3::from_cols(nrm, DVec3::ZERO, DVec3::ZERO).transpose()
                            * patch.normal_stiffness(i);
                        let c = patch.centroid(i).unwrap_or(positions[i] - obj.offset);
                        self.sphere_touch[i] = Some((o, c + obj.offset, k));
                    }
                }
            }
        }
        if !any {
            return;
        }
        for i in 0..n {
            if self.sphere_touch[i].is_none() {
                continue;
            }
            let f = raw[i];
            self.fingers[i].ramp = (self.fingers[i].ramp + dt / RAMP_S).min(1.0);
            let (out, scale) = bounded(f, self.max_force, self.fingers[i].ramp);
            let len = f.length();
            for (o, _) in objects.iter().enumerate().take(MAX_OBJECTS) {
                let Some(patch) = self.patches[o].as_deref() else {
                    continue;
                };
                for node in patch.nodes() {
                    if node.sphere == i && node.pressure > 0.0 {
                        sample.bcs[o].add(node.col, node.force * scale);
                    }
                }
            }
            forces[i] = if out.is_finite() { out } else { DVec3::ZERO };
            self.limited[i] = len > self.max_force;
        }
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
        if let Some((_, _, k)) = self.sphere_touch.get(i).copied().flatten() {
            return Some(k);
        }
        let (o, c) = self.contacts.get(i).copied().flatten()?;
        let comp = parts(&self.live, &self.world.objects[o], o).0;
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
                crate::compliance::invert3(crate::contact::force::point_compliance(comp, &c))
            }
        }
    }
}
