//! A virtual coupling (Colgate et al. 1995; Adams & Hannaford 1999) between the device and the
//! finger the FEM sees: what the hand feels never has a stiffness above what the device renders
//! stably, while the god-object and the displayed deformation stay the paper's.
//!
//! The object's force on the finger is locally `F = −K (x − p)` with `K` the contact point's
//! stiffness (3×3). A spring `k_c` between the hand and a massless virtual tool puts the two in
//! series: the hand feels `K_eff = (K⁻¹ + I/k_c)⁻¹`, whose every eigenvalue is below `k_c`, so
//! the rendered force is `(I + K/k_c)⁻¹ F` — no state, one 3×3 solve. A damper `b_c` on the
//! hand's velocity while touching restores the passivity margin a sampled spring loses
//! (Colgate's `b > K·T/2`, with `T` the measured time since the last tick). Soft objects
//! (`K ≪ k_c`) are rendered as they are. The rate limit, the continuous force and the peak
//! force are the force bound's ([`super::bound`]), applied after the coupling.

use glam::{DMat3, DVec3};

use crate::devices::limits::DeviceLimits;

/// One finger's coupling.
#[derive(Clone, Debug)]
pub(crate) struct VirtualCoupling {
    k_c: f64,
    max_damping: f64,
    last_x: Option<DVec3>,
}

impl VirtualCoupling {
    /// A coupling sized from `limits`: `k_c` = the device's stiffness limit; each tick's
    /// damping `b_c = k_c·T` (twice Colgate's bound for the measured period `T`) within the
    /// device's damping limit.
    pub fn new(limits: &DeviceLimits) -> VirtualCoupling {
        VirtualCoupling {
            k_c: limits.max_stiffness_n_per_m,
            max_damping: limits.max_damping_ns_per_m,
            last_x: None,
        }
    }

    /// Forgets the hand's motion: after a tick without a valid position no velocity is
    /// inferred across the gap.
    pub fn reset(&mut self) {
        self.last_x = None;
    }

    /// The force for the device, given the paper's force `f` on a hand at `x`, the contact's
    /// stiffness `k` (N/m; `None` when not touching) and the measured time `dt` (s) since
    /// the last call. Finite; not yet bounded (the force bound comes after).
    pub fn render(&mut self, f: DVec3, k: Option<DMat3>, x: DVec3, dt: f64) -> DVec3 {
        let dt_ok = dt.is_finite() && dt > 0.0;
        let v = match self.last_x {
            Some(p) if dt_ok && x.is_finite() && p.is_finite() => (x - p) / dt,
            _ => DVec3::ZERO,
        };
        let b_c = if dt_ok {
            (self.k_c * dt).min(self.max_damping)
        } else {
            0.0
        };
        self.last_x = Some(x);
        let target = match k {
            Some(k) if f.is_finite() => {
                let a = DMat3::IDENTITY + k * (1.0 / self.k_c);
                let spring = if a.determinant().abs() > 1e-12 {
                    a.inverse() * f
                } else {
                    DVec3::ZERO
                };
                spring - v * b_c
            }
            _ => DVec3::ZERO,
        };
        if target.is_finite() {
            target
        } else {
            DVec3::ZERO
        }
    }
}
