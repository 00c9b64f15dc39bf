//! A cut's correction that grows the compliance by the nodes the cut made touchable: the
//! copies a split made and the nodes its faces exposed (see
//! [`crate::compliance::correction`]). Each of them has its DOFs in `D`, so its column of `L₀`
//! is a column of `L_D` and no solve is needed beyond those the cut made.

use super::body::Cut;
use crate::compliance::correction::Correction;
use crate::compliance::{invert3, Compliance};
use crate::Error;

impl Cut {
    /// `out = C U` for `u`, `rank` rows a column, column-major (`Vᵀ = C Uᵀ` of the columns
    /// whose `U` rows `u` holds row by row): faer's product, sequential, so the same bits every
    /// run. Nothing at rank 0 or without columns.
    pub(super) fn cap_times(&self, u: &[f64], out: &mut [f64]) {
        use faer::{MatMut, MatRef};
        let r = self.cap.nrows();
        if r == 0 || u.is_empty() {
            return;
        }
        let n = u.len() / r;
        crate::compliance::product_seq(
            MatMut::from_column_major_slice_mut(out, r, n),
            MatRef::from_column_major_slice(self.cap.as_slice(), r, r),
            MatRef::from_column_major_slice(u, r, n),
            false,
        );
    }

    /// [`Cut::correction`], grown by the nodes this cut made touchable: every node on the
    /// separated body's surface that moves, is not one of `c`'s columns, and is a copy or an
    /// exposed node that `c` does not display (so a displayed node the scene did not make
    /// touchable stays so). Column `c.cols().len() + k` of the corrected compliance is then
    /// node `extra[k]`: its blocks, `L′_xx⁻¹` and its displacement
    /// ([`Compliance::displace_extra`]) are exact. Costs `3·rank²` multiply-adds a node more
    /// than [`Cut::correction`].
    pub fn grown_correction(&self, c: &Compliance) -> Result<Correction, Error> {
        let surface = crate::mesh::open_surface_of(&self.tets, &self.removed);
        self.grown_correction_on(c, &surface)
    }

    /// [`Cut::grown_correction`] given the separated body's surface (its triangles, as
    /// [`Cut::separated_mesh`] has them): one pass over every tet fewer.
    pub fn grown_correction_on(
        &self,
        c: &Compliance,
        surface: &[[u32; 3]],
    ) -> Result<Correction, Error> {
        let k = self.correction(c)?;
        self.grown(c, k, surface)
    }

    /// [`Cut::grown_correction_on`] of `k`, this cut's [`Cut::correction`] for `c` (made
    /// with [`Cut::correction_meanwhile`], say, the surface made meanwhile).
    pub fn grown(
        &self,
        c: &Compliance,
        mut k: Correction,
        surface: &[[u32; 3]],
    ) -> Result<Correction, Error> {
        let r = k.rank;
        let nc = c.cols().len();
        let mut on_surface = vec![false; self.nodes.len()];
        for &v in surface.iter().flatten() {
            if let Some(s) = on_surface.get_mut(v as usize) {
                *s = true;
            }
        }
        let mut extra = Vec::new();
        let mut places = Vec::new();
        for (v, _) in on_surface.iter().enumerate().filter(|(_, &s)| s) {
            let v = v as u32;
            if self.holds_still(v) || c.col_of(v).is_some() {
                continue;
            }
            let origin = self.origin[v as usize];
            // A node the scene displays but did not make touchable (nor its copies) stays so.
            if c.row_of(origin).is_some() && c.col_of(origin).is_none() {
                continue;
            }
            let p = [0, 1, 2].map(|a| self.dof(v, a).map(|f| self.place[f]));
            let [Some(p0), Some(p1), Some(p2)] = p else {
                continue;
            };
            if [p0, p1, p2].contains(&u32::MAX) {
                continue;
            }
            extra.push(v);
            places.push([p0, p1, p2]);
        }
        let nx = extra.len();
        // U at the extra nodes: their rows of L_D (by symmetry, L₀ at D's columns).
        let mut u_extra = vec![0.0; 3 * nx * r];
        for (x, p) in places.iter().enumerate() {
            for a in 0..3 {
                let f = self.d[p[a] as usize];
                for q in 0..r {
                    u_extra[(3 * x + a) * r + q] = self.ld[(f, q)];
                }
            }
        }
        // V = C U_xᵀ + e_p(x) (their L₀ column, which L does not hold, is U e_p(x)).
        let mut v_extra = vec![0.0; 3 * nx * r];
        self.cap_times(&u_extra, &mut v_extra);
        for (x, p) in places.iter().enumerate() {
            for a in 0..3 {
                v_extra[(3 * x + a) * r + p[a] as usize] += 1.0;
            }
        }
        k.extra_row = (extra.iter())
            .map(|&v| match c.row_of(v) {
                Some(row) if row < c.l_rows() => row as u32,
                _ => u32::MAX,
            })
            .collect();
        k.extra = extra;
        k.u_extra = u_extra;
        k.v_extra = v_extra;
        k.extra_place = places;
        let mut diag_inv = Vec::with_capacity(nx);
        for x in 0..nx {
            let b = k.extra_block(nc + x, nc + x);
            diag_inv.push(invert3(b).ok_or_else(|| {
                Error::Input(format!(
                    "the cut left node {} with a singular compliance",
                    k.extra[x]
                ))
            })?);
        }
        k.extra_diag_inv = diag_inv;
        Ok(k)
    }
}
