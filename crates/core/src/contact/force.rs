//! The haptic force: the finger's displacement turned into an equivalent force boundary
//! condition without touching `L` (the paper's eq. 7, 9–12), an exact variant, and the coupled
//! solve for several fingers. Everything here is fixed-size and allocates nothing.
//!
//! * **Paper** (eq. 9–12): `f_i = L_ii⁻¹ u` at each vertex of the contact triangle, weighted by
//!   the area coordinates, `F_i = α_i f_i`, and the reaction `F = −Σ F_i` goes to the finger.
//! * **Exact**: the contact point's own compliance `W = Σ_ij α_i α_j L_ij`; the point force
//!   `G = W⁻¹ u` is applied as nodal forces `F_i = α_i G`, so that the surface point under the
//!   finger (interpolated with the same α) moves by exactly `u`. Agrees with the paper at a vertex.
//! * **Coupled**: for m fingers, the 3m×3m system `Σ_l W_kl G_l = u_k` with
//!   `W_kl = Σ_{i∈T_k, j∈T_l} α_ki α_lj L_ij`, the exact variant generalised.
//!
//! A triangle vertex that is clamped (or not touchable) has no column in `L`; it is given the
//! compliance [`Compliance::clamp_compliance`] (ten times stiffer than the stiffest touchable
//! node) so the force near a clamp is large but finite.

use glam::{DMat3, DVec3};

use crate::compliance::{invert3, Compliance};
use crate::contact::ContactPoint;

pub use crate::limits::MAX_FINGERS;
/// Most entries in a force boundary condition: three vertices per point finger, and the
/// contact nodes of the spheres on the object.
pub(crate) const MAX_BC: usize = 3 * MAX_FINGERS + crate::contact::MAX_PATCH;

/// Which force formula to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum ForceModel {
    /// The paper's interpolation of vertex stiffnesses (eq. 9–12).
    #[default]
    Paper,
    /// The contact point's exact compliance.
    Exact,
}

/// A force boundary condition: external nodal forces on touchable columns, newtons.
/// Fixed capacity, `Copy`, so it can be published lock-free from the haptic loop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ForceBc {
    len: usize,
    entries: [(u32, DVec3); MAX_BC],
}

impl Default for ForceBc {
    fn default() -> Self {
        ForceBc {
            len: 0,
            entries: [(0, DVec3::ZERO); MAX_BC],
        }
    }
}

impl ForceBc {
    /// The active (column, force) pairs.
    pub fn entries(&self) -> &[(u32, DVec3)] {
        &self.entries[..self.len]
    }
    /// Number of active columns.
    pub fn len(&self) -> usize {
        self.len
    }
    /// True when no force is applied.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    /// Removes all entries.
    pub fn clear(&mut self) {
        self.len = 0;
    }
    /// Adds `f` to column `c` (merging with an existing entry). Returns false when full.
    pub fn add(&mut self, c: u32, f: DVec3) -> bool {
        for e in &mut self.entries[..self.len] {
            if e.0 == c {
                e.1 += f;
                return true;
            }
        }
        if self.len == MAX_BC {
            return false;
        }
        self.entries[self.len] = (c, f);
        self.len += 1;
        true
    }
    /// The entries as f32, for the GPU pass.
    pub fn to_f32(&self) -> ([(u32, [f32; 3]); MAX_BC], usize) {
        let mut out = [(0u32, [0f32; 3]); MAX_BC];
        for (o, e) in out.iter_mut().zip(self.entries()) {
            *o = (e.0, e.1.as_vec3().to_array());
        }
        (out, self.len)
    }
}

/// The result of one force step for one finger.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FingerForce {
    /// The force fed back to the finger (eq. 12), newtons.
    pub feedback: DVec3,
}

/// Compliance between two mesh nodes for the force solve: `L_ij` for touchable pairs, the clamp
/// compliance on the diagonal of a non-touchable node, zero otherwise.
#[inline]
fn pair_block(c: &Compliance, i: u32, j: u32) -> DMat3 {
    match (c.col_of(i), c.col_of(j)) {
        (Some(ci), Some(cj)) => c.touch_block(ci, cj),
        _ if i == j => DMat3::from_diagonal(DVec3::splat(c.clamp_compliance())),
        _ => DMat3::ZERO,
    }
}

/// The 3×3 compliance `W = Σ_ij α_i α_j L_ij` of a contact point.
pub fn point_compliance(c: &Compliance, contact: &ContactPoint) -> DMat3 {
    let mut w = DMat3::ZERO;
    for a in 0..3 {
        for b in 0..3 {
            let s = contact.alpha[a] * contact.alpha[b];
            if s != 0.0 {
                w += pair_block(c, contact.nodes[a], contact.nodes[b]) * s;
            }
        }
    }
    w
}

/// One finger's force (paper or exact). Appends the nodal forces to `bc` and returns the
/// feedback. Allocates nothing.
#[inline]
pub fn finger_force(
    c: &Compliance,
    contact: &ContactPoint,
    model: ForceModel,
    bc: &mut ForceBc,
) -> FingerForce {
    let u = contact.displacement();
    let mut total = DVec3::ZERO;
    match model {
        ForceModel::Paper => {
            let k_clamp = 1.0 / c.clamp_compliance();
            for a in 0..3 {
                let alpha = contact.alpha[a];
                if alpha == 0.0 {
                    continue;
                }
                let node = contact.nodes[a];
                let f = match c.col_of(node) {
                    Some(col) => {
                        let f = c.diag_inv(col) * u * alpha;
                        bc.add(col as u32, f);
                        f
                    }
                    None => u * (k_clamp * alpha),
                };
                total += f;
            }
        }
        ForceModel::Exact => {
            let w = point_compliance(c, contact);
            let g = invert3(w).map(|wi| wi * u).unwrap_or(DVec3::ZERO);
            for a in 0..3 {
                let alpha = contact.alpha[a];
                if alpha == 0.0 {
                    continue;
                }
                if let Some(col) = c.col_of(contact.nodes[a]) {
                    bc.add(col as u32, g * alpha);
                }
            }
            total = g;
        }
    }
    FingerForce { feedback: -total }
}

/// The feedback of [`finger_force`] alone (N, on the finger), writing no boundary
/// condition: what a friction cone is judged by, many times a tick. Allocates nothing.
#[inline]
pub fn finger_feedback(c: &Compliance, contact: &ContactPoint, model: ForceModel) -> DVec3 {
    let u = contact.displacement();
    match model {
        ForceModel::Paper => {
            let k_clamp = 1.0 / c.clamp_compliance();
            let mut total = DVec3::ZERO;
            for a in 0..3 {
                let alpha = contact.alpha[a];
                if alpha == 0.0 {
                    continue;
                }
                total += match c.col_of(contact.nodes[a]) {
                    Some(col) => c.diag_inv(col) * u * alpha,
                    None => u * (k_clamp * alpha),
                };
            }
            -total
        }
        ForceModel::Exact => {
            -invert3(point_compliance(c, contact)).map_or(DVec3::ZERO, |wi| wi * u)
        }
    }
}

/// The coupled exact solve for several fingers (the paper's future work: grasping).
/// Writes each finger's feedback into `out[..contacts.len()]` and the nodal forces into `bc`.
/// Returns false (and zero forces) if there are more than [`MAX_FINGERS`] contacts or the
/// system is singular. Allocates nothing.
pub fn coupled_force(
    c: &Compliance,
    contacts: &[ContactPoint],
    bc: &mut ForceBc,
    out: &mut [DVec3],
) -> bool {
    let m = contacts.len();
    if m > MAX_FINGERS || out.len() < m {
        return false;
    }
    let mut g = [DVec3::ZERO; MAX_FINGERS];
    if !coupled_point_forces(c, contacts, 0.0, &mut g) {
        out[..m].iter_mut().for_each(|o| *o = DVec3::ZERO);
        return false;
    }
    for k in 0..m {
        add_point_force(c, &contacts[k], g[k], bc);
        out[k] = -g[k];
    }
    true
}

/// Adds the nodal forces `F_i = α_i G` of a point force `G` at a contact to `bc` (columns only:
/// a clamped vertex takes its share into the clamp). Returns false when `bc` is full.
#[inline]
pub fn add_point_force(c: &Compliance, contact: &ContactPoint, g: DVec3, bc: &mut ForceBc) -> bool {
    let mut ok = true;
    for i in 0..3 {
        let alpha = contact.alpha[i];
        if alpha != 0.0 {
            if let Some(col) = c.col_of(contact.nodes[i]) {
                ok &= bc.add(col as u32, g * alpha);
            }
        }
    }
    ok
}

/// The point forces `G_k` (newtons, on the object) that move each contact point by its
/// displacement when applied together: `Σ_l W_kl G_l = u_k`. `skin` adds a fingertip
/// compliance of `skin · tr(W_kk)/3` to each diagonal block, which keeps the system positive
/// definite when two fingers touch the same point (0 gives the exact coupled solve). Writes
/// `g[..contacts.len()]`; returns false (all zero) if there are more than [`MAX_FINGERS`]
/// contacts or the system is not positive definite. Allocates nothing.
pub fn coupled_point_forces(
    c: &Compliance,
    contacts: &[ContactPoint],
    skin: f64,
    g: &mut [DVec3],
) -> bool {
    let m = contacts.len();
    if m > MAX_FINGERS || g.len() < m {
        return false;
    }
    const N: usize = 3 * MAX_FINGERS;
    let mut a = [[0.0f64; N]; N];
    let mut rhs = [0.0f64; N];
    for k in 0..m {
        for l in 0..m {
            let mut w = DMat3::ZERO;
            for i in 0..3 {
                for j in 0..3 {
                    let s = contacts[k].alpha[i] * contacts[l].alpha[j];
                    if s != 0.0 {
                        w += pair_block(c, contacts[k].nodes[i], contacts[l].nodes[j]) * s;
                    }
                }
            }
            if k == l && skin > 0.0 {
                let tr = w.x_axis.x + w.y_axis.y + w.z_axis.z;
                w += DMat3::from_diagonal(DVec3::splat(skin * tr / 3.0));
            }
            for r in 0..3 {
                for q in 0..3 {
                    a[3 * k + r][3 * l + q] = w.col(q)[r];
                }
            }
        }
        let u = contacts[k].displacement();
        rhs[3 * k..3 * k + 3].copy_from_slice(&u.to_array());
    }
    let n = 3 * m;
    // Cholesky in place on the leading n×n block (W is symmetric positive definite).
    for j in 0..n {
        let d = a[j][j] - a[j][..j].iter().map(|v| v * v).sum::<f64>();
        if !d.is_finite() || d <= 0.0 {
            g[..m].iter_mut().for_each(|o| *o = DVec3::ZERO);
            return false;
        }
        let d = d.sqrt();
        a[j][j] = d;
        for i in j + 1..n {
            let s = a[i][j] - (0..j).map(|p| a[i][p] * a[j][p]).sum::<f64>();
            a[i][j] = s / d;
        }
    }
    for i in 0..n {
        let mut s = rhs[i];
        for p in 0..i {
            s -= a[i][p] * rhs[p];
        }
        rhs[i] = s / a[i][i];
    }
    for i in (0..n).rev() {
        let mut s = rhs[i];
        for p in i + 1..n {
            s -= a[p][i] * rhs[p];
        }
        rhs[i] = s / a[i][i];
    }
    for k in 0..m {
        g[k] = DVec3::new(rhs[3 * k], rhs[3 * k + 1], rhs[3 * k + 2]);
    }
    g[..m].iter().all(|v| v.is_finite())
}

/// Limits a force to a finite vector of at most `max_n` newtons, keeping its direction.
#[inline]
pub fn saturate(f: DVec3, max_n: f64) -> DVec3 {
    if !f.is_finite() {
        return DVec3::ZERO;
    }
    let n = f.length();
    if n > max_n {
        f * (max_n / n)
    } else {
        f
    }
}
