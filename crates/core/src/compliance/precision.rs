//! What storing `L` in f32 or f16 costs in accuracy: the displacement under a load in each
//! precision, and the relative error against the f64 reference.

use glam::{DVec3, Vec3};

use crate::compliance::Compliance;

/// `u = L·F` in the GPU's f32 arithmetic ([`Compliance::displace_f32`]), in f64.
pub fn displace_f32(c: &Compliance, forces: &[(u32, DVec3)]) -> Vec<DVec3> {
    let mut u = vec![Vec3::ZERO; c.rows().len()];
    c.displace_f32(forces, &mut u);
    u.iter().map(|v| v.as_dvec3()).collect()
}

/// `u = L·F` in the GPU's half-float arithmetic ([`Compliance::displace_f16`]), in f64.
pub fn displace_f16(c: &Compliance, forces: &[(u32, DVec3)]) -> Vec<DVec3> {
    let mut u = vec![Vec3::ZERO; c.rows().len()];
    c.displace_f16(forces, &mut u);
    u.iter().map(|v| v.as_dvec3()).collect()
}

/// `max |a − reference| / max |reference|` (the absolute error when the reference is zero).
pub fn rel_err(a: &[DVec3], reference: &[DVec3]) -> f64 {
    let scale = reference.iter().map(|v| v.length()).fold(0.0, f64::max);
    let e = a
        .iter()
        .zip(reference)
        .map(|(x, y)| (*x - *y).length())
        .fold(0.0, f64::max);
    if scale > 0.0 {
        e / scale
    } else {
        e
    }
}
