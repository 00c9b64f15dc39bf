//! A cut's correction of `L` ([`Cut::correction`]): `U` read from `L_D` at the compliance's
//! held rows and columns (only the columns new since the last `U` are read), `V` made from
//! `U` ([`super::carry`]), and each column's `L′_cc⁻¹`. Where `V` is large and a helper
//! makes part of it, the calling thread meanwhile makes `U`'s rows and whatever else the
//! pass needs that does not need `V` ([`Cut::correction_meanwhile`]).

use std::sync::Arc;

use glam::DMat3;

use super::body::Cut;
use crate::compliance::correction::Correction;
use crate::compliance::{invert3, Compliance};
use crate::Error;

impl Cut {
    /// The correction to carry beside `c` (the uncut body's compliance, `L` on the host) so
    /// that it reads `L′` exactly: `U` at its held rows and touchable columns, `V = U Cᵀ`, the
    /// pinned rows and columns, and `L′_cc⁻¹` of every column left. Costs
    /// `3·C·rank²` multiply-adds (`V`) and the copy of `U`'s rows; made off the haptic
    /// thread, then handed over with [`Compliance::with_correction`].
    pub fn correction(&self, c: &Compliance) -> Result<Correction, Error> {
        self.correction_meanwhile(c, || ()).map(|(k, ())| k)
    }

    /// [`Cut::correction`], with `meanwhile` run on the calling thread (once, with `U`'s
    /// rows) while the helper of [`Cut::share_v_with`] makes the first blocks of `V`: the
    /// work of a pass that does not need `V` (the separated mesh, its contact surface)
    /// overlapped with it. Without a helper it runs before `V`. The same bits as
    /// [`Cut::correction`]; its result comes back beside the correction.
    pub fn correction_meanwhile<T>(
        &self,
        c: &Compliance,
        meanwhile: impl FnOnce() -> T,
    ) -> Result<(Correction, T), Error> {
        if !c.holds_l() {
            return Err(Error::Input(
                "carrying a cut needs L on the host (not a lean compliance)".into(),
            ));
        }
        let r = self.d.len();
        let nr = c.l_rows();
        let nc = c.cols().len();
        let dof = |node: u32, a: usize| -> Option<usize> {
            if self.pinned.get(node as usize).copied().unwrap_or(true) {
                None
            } else {
                self.dof(node, a)
            }
        };
        let mut dead_rows = vec![false; nr];
        // (Each held row's place in a column of `U`, and its DOF; the same of the columns.)
        let mut at: Vec<(usize, usize)> = Vec::with_capacity(3 * nr);
        for (k, &node) in c.rows()[..nr].iter().enumerate() {
            dead_rows[k] = self.pinned.get(node as usize).copied().unwrap_or(true);
            for a in 0..3 {
                if let Some(d) = dof(node, a) {
                    at.push((3 * k + a, d));
                }
            }
        }
        let mut dead_cols = vec![false; nc];
        let mut at_cols: Vec<(usize, usize)> = Vec::with_capacity(3 * nc);
        for (ci, &node) in c.cols().iter().enumerate() {
            dead_cols[ci] = self.pinned.get(node as usize).copied().unwrap_or(true);
            for a in 0..3 {
                if let Some(d) = dof(node, a) {
                    at_cols.push((3 * ci + a, d));
                }
            }
        }
        // U at the columns first (V needs it), at the rows beside V (it does not).
        let (u_cols, last_rows) = self.u_cols_of(c, (&at_cols, &dead_cols), 3 * nr);
        let (mut meanwhile, mut last_rows) = (Some(meanwhile), Some(last_rows));
        let mut done: Option<(Arc<Vec<f64>>, T)> = None;
        let mut beside = || {
            if let (Some(f), Some(last)) = (meanwhile.take(), last_rows.take()) {
                let rows = self.u_rows_of(last, (&at, &dead_rows));
                done = Some((rows, f()));
            }
        };
        // V = U Cᵀ for every column at once (a matrix product; u_cols is U row by row, so
        // U's transpose column-major: Vᵀ = C Uᵀ).
        let v_cols = self.v_times(c, &u_cols, &mut beside);
        // (v_times runs it; this only where it did not.)
        beside();
        let Some((rows, out)) = done else {
            return Err(Error::Input("the correction's rows were not made".into()));
        };
        self.keep_u(c, r, &rows, &u_cols);
        let mut k = Correction {
            rank: r,
            rows,
            u_cols,
            v_cols,
            dead_rows,
            dead_cols,
            diag_inv: Vec::new(),
            ..Correction::default()
        };
        let mut diag_inv = Vec::with_capacity(nc);
        for ci in 0..nc {
            if k.dead_cols[ci] {
                diag_inv.push(DMat3::ZERO);
                continue;
            }
            let b = c.block(c.col_row(ci), ci) + k.col_block(ci, ci);
            diag_inv.push(invert3(b).ok_or_else(|| {
                Error::Input(format!(
                    "the cut left node {} with a singular compliance",
                    c.cols()[ci]
                ))
            })?);
        }
        k.diag_inv = diag_inv;
        Ok((k, out))
    }
}
