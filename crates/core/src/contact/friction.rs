//! Coulomb friction for a point finger: its god-object sticks where it is while the force
//! it renders stays inside the static cone, and slips towards the frictionless proxy until
//! the force is on the edge of the dynamic cone. Allocates nothing.

use glam::DVec3;

use super::tool::Friction;
use super::{feature_of, ContactPoint, Surface};

/// Bisection steps of a slip (the cone's edge found to 2⁻⁴⁰ of the slip).
const SLIP_STEPS: usize = 40;

/// The stick–slip state of one point finger's god-object on one object.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StickSlip {
    stuck: Option<(u32, DVec3)>,
    slipping: bool,
}

impl StickSlip {
    /// Forgets the stuck point (the finger left the surface).
    pub fn reset(&mut self) {
        *self = StickSlip::default();
    }

    /// Whether the last contact slipped.
    pub fn slipping(&self) -> bool {
        self.slipping
    }

    /// The contact with friction, given the frictionless one `free` (the god-object's proxy
    /// this tick) and `feedback`, the force the finger feels at a contact (N). The force is
    /// split along the surface's pseudo-normal at the stuck proxy: while `|F_t| ≤ μ F_n`
    /// (μ static while stuck, dynamic while slipping) the proxy stays; otherwise it moves
    /// along the surface towards `free` to where `|F_t| = μ_d F_n`.
    pub fn apply(
        &mut self,
        surf: &Surface,
        free: &ContactPoint,
        fr: Friction,
        feedback: impl Fn(&ContactPoint) -> DVec3,
    ) -> ContactPoint {
        let Some((tri, ps)) = self.stuck else {
            self.stuck = Some((free.tri, free.proxy));
            self.slipping = false;
            return *free;
        };
        let stuck = contact_at(surf, tri, ps, free.finger);
        let n = surf.pseudo_normal(stuck.tri, stuck.feature);
        let cone = |c: &ContactPoint| {
            let f = feedback(c);
            let fn_ = f.dot(n);
            ((f - n * fn_).length(), fn_)
        };
        let (ft, fn_) = cone(&stuck);
        if fn_.is_nan() || fn_ <= 0.0 || (free.finger - ps).dot(n) >= 0.0 || !ft.is_finite() {
            // Pulled out of the stuck point's plane, or no normal force: take the free proxy.
            self.stuck = Some((free.tri, free.proxy));
            self.slipping = false;
            return *free;
        }
        let mu = if self.slipping {
            fr.dynamic_mu
        } else {
            fr.static_mu
        };
        if ft <= mu * fn_ {
            self.slipping = false;
            return stuck;
        }
        // Slip: the point on the way to the free proxy where the force meets the dynamic cone.
        let h = |c: &ContactPoint| {
            let (ft, fn_) = cone(c);
            ft - fr.dynamic_mu * fn_
        };
        let at = |s: f64| {
            let y = ps + (free.proxy - ps) * s;
            let (t, _, q, _) = surf.walk(stuck.tri, y);
            contact_at(surf, t, q, free.finger)
        };
        let mut hi = (1.0, *free);
        if h(free) <= 0.0 {
            let mut lo = 0.0;
            for _ in 0..SLIP_STEPS {
                let mid = 0.5 * (lo + hi.0);
                let c = at(mid);
                if h(&c) > 0.0 {
                    lo = mid;
                } else {
                    hi = (mid, c);
                }
            }
        }
        let c = hi.1;
        self.stuck = Some((c.tri, c.proxy));
        self.slipping = true;
        c
    }
}

/// The contact of a finger at `finger` with its proxy at `point` on triangle `tri`.
fn contact_at(surf: &Surface, tri: u32, point: DVec3, finger: DVec3) -> ContactPoint {
    let (q, bc) = surf.closest_on_tri(tri, point);
    ContactPoint {
        tri,
        nodes: surf.tris[tri as usize],
        alpha: bc,
        proxy: q,
        finger,
        feature: feature_of(&bc),
    }
}
