//! A virtual coupling (Colgate et al. 1995; Adams & Hannaford 1999) between the device and the
//! finger the FEM sees: what the hand feels never has a stiffness above what the device renders
//! stably, while the god-object and the displayed deformation stay the paper's.
//!
//! The object's force on the finger is locally `F = −K (x − p)` with `K` the contact point's
//! stiffness (3×3). A spring `k_c` between the hand and a massless virtual tool puts the two in
//! series: the hand feels `K_eff = (K⁻¹ + I/k_c)⁻¹`, whose every eigenvalue is below `k_c`, so
//! the rendered force is `(I + K/k_c)⁻¹ F` — no state, one 3×3 solve. A damper `b_c` on the
//! hand's velocity while touching restores the passivity margin a sampled spring loses
//! (Colgate's `b > K·T/2`). Force changes are rate-limited, and the force is finite and at most
//! the device's peak. Soft objects (`K ≪ k_c`) are rendered as they are.

use glam::{DMat3, DVec3};

use crate::devices::limits::DeviceLimits;

/// One finger's coupling.
#[derive(Clone, Debug)]
pub struct VirtualCoupling {
    k_c: f64,
    b_c: f64,
    max_force: f64,
    max_step: f64,
    last_force: DVec3,
    last_x: Option<DVec3>,
    dt: f64,
}

impl VirtualCoupling {
    /// A coupling sized from `limits` at `rate_hz`: `k_c` = the device's stiffness limit,
    /// `b_c` = `k_c·T` (twice Colgate's bound) within its damping limit, force steps of at most
    /// 5 % of the peak force a tick.
    pub fn new(limits: &DeviceLimits, rate_hz: f64) -> VirtualCoupling {
        let dt = 1.0 / rate_hz;
        let k_c = limits.max_stiffness_n_per_m;
        VirtualCoupling {
            k_c,
            b_c: (k_c * dt).min(limits.max_damping_ns_per_m),
            max_force: limits.max_force_n,
            max_step: 0.05 * limits.max_force_n,
            last_force: DVec3::ZERO,
            last_x: None,
            dt,
        }
    }

    /// Forgets the hand's motion and the last force: after a tick without a valid position
    /// the next force starts from zero (rate-limited in) and no velocity is inferred across
    /// the gap.
    pub fn reset(&mut self) {
        self.last_force = DVec3::ZERO;
        self.last_x = None;
    }

    /// The coupling's stiffness `k_c`, N/m.
    pub fn stiffness(&self) -> f64 {
        self.k_c
    }

    /// The force to send the device, given the paper's force `f` on a hand at `x` and the
    /// contact's stiffness `k` (N/m; `None` when not touching).
    pub fn render(&mut self, f: DVec3, k: Option<DMat3>, x: DVec3) -> DVec3 {
        let v = match self.last_x {
            Some(p) if x.is_finite() && p.is_finite() => (x - p) / self.dt,
            _ => DVec3::ZERO,
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
                spring - v * self.b_c
            }
            _ => DVec3::ZERO,
        };
        let step = (target - self.last_force).clamp_length_max(self.max_step);
        let mut out = self.last_force + step;
        if !out.is_finite() {
            out = DVec3::ZERO;
        }
        out = out.clamp_length_max(self.max_force);
        self.last_force = out;
        out
    }
}
