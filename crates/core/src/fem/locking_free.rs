//! The locking-free stiffness of linear tets ([`Formulation::LockingFree`]): the energy split
//! into a deviatoric part, per tet as in the standard element (shear modulus μ), and a
//! volumetric part whose dilatation is smoothed over the tets around each node, so that a
//! nearly incompressible body (ν → 0.5) is not over-constrained by one volume constraint per
//! tet (volumetric locking).
//!
//! With `θ_e = Σ_b ∇N_b·u_b` the dilatation of tet `e` (volume `V_e`, bulk modulus
//! `κ_e = λ_e + 2μ_e/3`), the nodal dilatation is the volume-weighted mean around node `a`,
//! `θ_a = Σ_{e∋a} (V_e/4) θ_e / V_a` with `V_a = Σ_{e∋a} V_e/4`, and
//!
//! * [`Smoothing::Nodal`] (averaged nodal pressure, Bonet & Burton 1998): volumetric energy
//!   `½ Σ_a κ_a V_a θ_a²` (`κ_a` the volume-weighted mean of `κ_e`); `K_vol = Σ_a κ_a V_a b_a b_aᵀ`
//!   with `θ_a = b_aᵀu`, which couples nodes up to two edges apart;
//! * [`Smoothing::ElementAveraged`]: the tet's dilatation is the mean of its four nodal ones,
//!   `θ̄_e = ¼ Σ_{a∈e} θ_a`, volumetric energy `½ Σ_e κ_e V_e θ̄_e²`: three edges apart, a
//!   denser `K`.
//!
//! Both are sums of positive semi-definite rank-one terms plus the standard deviatoric
//! element matrices, so `K` stays linear, symmetric and positive definite once clamped; for an
//! affine displacement every θ equals the tet's, so the nodal forces are those of the standard
//! element (the patch test passes). [`Formulation::LockingFree`] uses [`Smoothing::CHOSEN`];
//! `docs/measurements/2026-12-02-locking-free.md` says why.

use glam::DVec3;

use super::{shape_gradients, FemError, Stiffness};
use crate::mesh::Mesh;
use crate::units::{Formulation, Material};

/// Where the volumetric strain is smoothed (see the module's text).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Smoothing {
    /// Averaged nodal dilatation (Bonet & Burton 1998): two-ring stencil.
    Nodal,
    /// Each tet's dilatation the mean of its nodes' averaged dilatations: three-ring stencil.
    ElementAveraged,
}

impl Smoothing {
    /// The smoothing of [`Formulation::LockingFree`].
    pub const CHOSEN: Smoothing = Smoothing::Nodal;

    /// A short name for tables.
    pub fn name(self) -> &'static str {
        match self {
            Smoothing::Nodal => "nodal",
            Smoothing::ElementAveraged => "element-averaged",
        }
    }
}

/// 3×3 node-pair blocks of a stiffness, per row node: `(column node, K_ab row-major)`.
pub(crate) type Blocks = Vec<Vec<(u32, [f64; 9])>>;

/// The deviatoric 12×12 stiffness of a constant-strain tet (shear modulus `mu`, pascals):
/// `V μ (g_a,j g_b,i + δ_ij g_a·g_b − ⅔ g_a,i g_b,j)`, DOFs ordered (node, axis). Adding
/// `κ V g_a,i g_b,j` gives the standard element.
pub fn deviatoric_element(g: &[DVec3; 4], vol: f64, mu: f64) -> [[f64; 12]; 12] {
    let mut k = [[0.0; 12]; 12];
    for a in 0..4 {
        for b in 0..4 {
            let ga = g[a].to_array();
            let gb = g[b].to_array();
            let dot = g[a].dot(g[b]);
            for i in 0..3 {
                for j in 0..3 {
                    let mut v = mu * ga[j] * gb[i] - 2.0 / 3.0 * mu * ga[i] * gb[j];
                    if i == j {
                        v += mu * dot;
                    }
                    k[3 * a + i][3 * b + j] = vol * v;
                }
            }
        }
    }
    k
}

/// A sparse vector over nodes with a 3-vector per node (a dilatation's gradient).
type Sparse = Vec<(u32, DVec3)>;

/// Adds `w·x` into `acc` (entries merged by node; `slot` is scratch, all `usize::MAX`
/// between calls).
fn axpy(acc: &mut Sparse, slot: &mut [usize], w: f64, x: &[(u32, DVec3)]) {
    for &(n, v) in x {
        let s = &mut slot[n as usize];
        if *s == usize::MAX {
            *s = acc.len();
            acc.push((n, DVec3::ZERO));
        }
        acc[*s].1 += w * v;
    }
}

/// Clears the scratch entries `acc` set.
fn reset(acc: &Sparse, slot: &mut [usize]) {
    for &(n, _) in acc {
        slot[n as usize] = usize::MAX;
    }
}

/// The node-pair blocks of the locking-free stiffness of `mesh` with `smoothing`, each tet's
/// material from `material_of(tet)` (assumed valid). With `skip_fixed`, the rows and columns
/// of clamped nodes are left out (as [`Stiffness`] needs); else the whole (singular) stiffness.
pub(crate) fn blocks(
    mesh: &Mesh,
    smoothing: Smoothing,
    material_of: &dyn Fn(usize) -> Material,
    skip_fixed: bool,
) -> Blocks {
    let n = mesh.nodes.len();
    let nt = mesh.tets.len();
    let skip = |v: u32| skip_fixed && mesh.fixed[v as usize];
    // Per tet: shape gradients, volume, μ, κ.
    let mut geo = Vec::with_capacity(nt);
    let mut vol_a = vec![0.0f64; n];
    let mut kvol_a = vec![0.0f64; n];
    for (t, tet) in mesh.tets.iter().enumerate() {
        let (g, vol) = shape_gradients(tet.map(|i| mesh.nodes[i as usize]));
        let (lambda, mu) = material_of(t).lame();
        let kappa = lambda + 2.0 * mu / 3.0;
        for &a in tet {
            vol_a[a as usize] += 0.25 * vol;
            kvol_a[a as usize] += 0.25 * vol * kappa;
        }
        geo.push((g, vol, mu, kappa));
    }
    // Tets around each node (CSR).
    let mut start = vec![0usize; n + 1];
    for tet in &mesh.tets {
        for &a in tet {
            start[a as usize + 1] += 1;
        }
    }
    for a in 0..n {
        start[a + 1] += start[a];
    }
    let mut fill = start.clone();
    let mut around = vec![0u32; start[n]];
    for (t, tet) in mesh.tets.iter().enumerate() {
        for &a in tet {
            around[fill[a as usize]] = t as u32;
            fill[a as usize] += 1;
        }
    }
    // b_a: θ_a = b_aᵀ u.
    let mut slot = vec![usize::MAX; n];
    let mut b: Vec<Sparse> = Vec::with_capacity(n);
    for a in 0..n {
        let mut acc = Sparse::new();
        for &t in &around[start[a]..start[a + 1]] {
            let (g, vol, _, _) = &geo[t as usize];
            let w = 0.25 * vol / vol_a[a];
            let tet = mesh.tets[t as usize];
            let terms: [(u32, DVec3); 4] = std::array::from_fn(|k| (tet[k], g[k]));
            axpy(&mut acc, &mut slot, w, &terms);
        }
        reset(&acc, &mut slot);
        b.push(acc);
    }
    // The volumetric rank-one terms (weight, vector).
    let terms: Vec<(f64, Sparse)> = match smoothing {
        Smoothing::Nodal => b
            .into_iter()
            .enumerate()
            .map(|(a, v)| (kvol_a[a], v))
            .collect(),
        Smoothing::ElementAveraged => mesh
            .tets
            .iter()
            .enumerate()
            .map(|(t, tet)| {
                let mut acc = Sparse::new();
                for &a in tet {
                    axpy(&mut acc, &mut slot, 0.25, &b[a as usize]);
                }
                reset(&acc, &mut slot);
                let (_, vol, _, kappa) = geo[t];
                (kappa * vol, acc)
            })
            .collect(),
    };
    // The terms each node appears in (CSR): (term, index in the term).
    let mut tstart = vec![0usize; n + 1];
    for (_, v) in &terms {
        for &(j, _) in v {
            tstart[j as usize + 1] += 1;
        }
    }
    for a in 0..n {
        tstart[a + 1] += tstart[a];
    }
    let mut tfill = tstart.clone();
    let mut in_terms = vec![(0u32, 0u32); tstart[n]];
    for (k, (_, v)) in terms.iter().enumerate() {
        for (p, &(j, _)) in v.iter().enumerate() {
            in_terms[tfill[j as usize]] = (k as u32, p as u32);
            tfill[j as usize] += 1;
        }
    }
    // Rows: the deviatoric element matrices and the rank-one terms through each node.
    let mut out: Blocks = vec![Vec::new(); n];
    for i in 0..n {
        if skip(i as u32) {
            continue;
        }
        let row = &mut out[i];
        let mut at = |j: u32, row: &mut Vec<(u32, [f64; 9])>| -> usize {
            let s = &mut slot[j as usize];
            if *s == usize::MAX {
                *s = row.len();
                row.push((j, [0.0; 9]));
            }
            *s
        };
        for &t in &around[start[i]..start[i + 1]] {
            let tet = mesh.tets[t as usize];
            let (g, vol, mu, _) = &geo[t as usize];
            let ke = deviatoric_element(g, *vol, *mu);
            let Some(la) = tet.iter().position(|&v| v as usize == i) else {
                continue;
            };
            for (lb, &j) in tet.iter().enumerate() {
                if skip(j) {
                    continue;
                }
                let s = at(j, row);
                for r in 0..3 {
                    for c in 0..3 {
                        row[s].1[3 * r + c] += ke[3 * la + r][3 * lb + c];
                    }
                }
            }
        }
        for &(k, p) in &in_terms[tstart[i]..tstart[i + 1]] {
            let (w, v) = &terms[k as usize];
            let ci = *w * v[p as usize].1;
            for &(j, cj) in v {
                if skip(j) {
                    continue;
                }
                let s = at(j, row);
                let (ci, cj) = (ci.to_array(), cj.to_array());
                for r in 0..3 {
                    for c in 0..3 {
                        row[s].1[3 * r + c] += ci[r] * cj[c];
                    }
                }
            }
        }
        for &(j, _) in row.iter() {
            slot[j as usize] = usize::MAX;
        }
    }
    out
}

/// The locking-free stiffness of `mesh` over its free DOFs with `smoothing` (whatever
/// `mesh.formulation` says; [`Stiffness::assemble`] uses [`Smoothing::CHOSEN`] for
/// [`Formulation::LockingFree`]). Checks the material and the clamps as `assemble` does.
pub fn stiffness(mesh: &Mesh, smoothing: Smoothing) -> Result<Stiffness, FemError> {
    mesh.material.validate()?;
    super::check_constrained(mesh)?;
    let material_of = |_t: usize| mesh.material;
    Stiffness::from_blocks(mesh, &blocks(mesh, smoothing, &material_of, true))
}

/// The full (unclamped) locking-free stiffness as a dense matrix, for tests on small meshes.
pub fn dense(mesh: &Mesh, smoothing: Smoothing) -> Vec<Vec<f64>> {
    let material_of = |_t: usize| mesh.material;
    super::dense_from_blocks(
        mesh.nodes.len(),
        &blocks(mesh, smoothing, &material_of, false),
    )
}

/// Whether `mesh` asks for this formulation.
pub(crate) fn wanted(mesh: &Mesh) -> bool {
    mesh.formulation == Formulation::LockingFree
}
