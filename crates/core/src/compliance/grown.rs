//! Folding a correction that grows the compliance ([`Correction::extra`]): the folded `L′`
//! gains a column for each extra node and a row for each that had none, so that after the
//! fold the copies and exposed nodes a cut made touchable are rows and columns of `L` like
//! any other (and a later cut's correction starts from rank 0 again).

use std::sync::Arc;

use nalgebra::{DMatrix, DMatrixView};

use super::correction::Correction;
use super::{index_maps, Compliance, FemError};

impl Compliance {
    /// [`Compliance::folded`] for a correction `k` with extra nodes: rows become the free
    /// rows, then the extra nodes without a row, then the clamped rows; columns become the
    /// columns, then the extra nodes (so every column index stays valid, and an extra
    /// column keeps its index). `9·(R + X)·(C + X)·rank` multiply-adds.
    pub(super) fn folded_grown(&self, k: &Correction) -> Result<Compliance, FemError> {
        let (nr, nc, nx, r) = (self.l_rows, self.cols.len(), k.extra.len(), k.rank);
        let new_rows: Vec<usize> = (0..nx).filter(|&x| k.extra_row[x] == u32::MAX).collect();
        let (nr2, nc2) = (nr + new_rows.len(), nc + nx);
        let (nr3, nc3, nx3) = (3 * nr, 3 * nc, 3 * nx);
        // `U_R` column-major (`3·R × rank`); `Uᵀ` and `Vᵀ` of the columns column-major
        // (`rank × 3·n`, one column a DOF), as stored.
        let uct = DMatrixView::from_slice(&k.u_cols, r, nc3);
        let uxt = DMatrixView::from_slice(&k.u_extra, r, nx3);
        let vxt = DMatrixView::from_slice(&k.v_extra, r, nx3);
        let mut l = DMatrix::<f64>::zeros(3 * nr2, 3 * nc2);
        // Old rows × old columns: L + U_R V_Cᵀ; old rows × extra columns: U_R V_Xᵀ.
        l.view_mut((0, 0), (nr3, nc3))
            .copy_from(&DMatrixView::from_slice(&self.l, nr3, nc3));
        if r > 0 {
            let ld = 3 * nr2;
            let dst = l.as_mut_slice();
            gemm_seq(dst, (nr3, nc3, ld), &k.rows, &k.v_cols, r, true);
            gemm_seq(
                &mut dst[nc3 * ld..],
                (nr3, nx3, ld),
                &k.rows,
                &k.v_extra,
                r,
                false,
            );
            // New rows: × old columns `(U_C V_xᵀ)ᵀ = V_x U_Cᵀ` (symmetry: an extra node's row
            // of `L₀` is not in `U_x V_Cᵀ`), × extra columns `U_x V_Xᵀ`.
            let vx_uc = vxt.transpose() * uct;
            let ux_vx = uxt.transpose() * vxt;
            for (i, &x) in new_rows.iter().enumerate() {
                for a in 0..3 {
                    let (dst, src) = (nr3 + 3 * i + a, 3 * x + a);
                    for j in 0..nc3 {
                        l[(dst, j)] = vx_uc[(src, j)];
                    }
                    for j in 0..nx3 {
                        l[(dst, nc3 + j)] = ux_vx[(src, j)];
                    }
                }
            }
        }
        pin_and_check(&mut l, k)?;
        let mut rows: Vec<u32> = self.rows[..nr].to_vec();
        rows.extend(new_rows.iter().map(|&x| k.extra[x]));
        rows.extend_from_slice(&self.rows[nr..]);
        let mut cols = self.cols.clone();
        cols.extend_from_slice(&k.extra);
        let n_nodes = (self.row_of_node.len()).max(k.extra.last().map_or(0, |&v| v as usize + 1));
        let (row_of_node, col_of_node, col_row) = index_maps(&rows, &cols, n_nodes)?;
        let mut dead_rows = k.dead_rows.clone();
        dead_rows.resize(nr2, false);
        let mut dead_cols = k.dead_cols.clone();
        dead_cols.resize(nc2, false);
        let mut diag_inv = k.diag_inv.clone();
        diag_inv.extend_from_slice(&k.extra_diag_inv);
        let mut c = self.clone();
        c.rows = rows;
        c.cols = cols;
        c.row_of_node = row_of_node;
        c.col_of_node = col_of_node;
        c.col_row = col_row;
        c.l_rows = nr2;
        c.l = Arc::new(l.data.into());
        c.diag_inv = diag_inv.clone();
        c.correction = Some(Arc::new(Correction {
            dead_rows,
            dead_cols,
            diag_inv,
            ..Correction::default()
        }));
        Ok(c)
    }
}

/// `dst = a·b` (`add`: `dst += a·b`) by faer's product on the calling thread alone: the same
/// bits on every run (a replay folds and cuts to the same `L` and correction), about twice
/// nalgebra's on one core. What every dense product of a cut and a fold goes through.
pub(crate) fn product_seq(
    dst: faer::MatMut<'_, f64>,
    a: faer::MatRef<'_, f64>,
    b: faer::MatRef<'_, f64>,
    add: bool,
) {
    let accum = if add {
        faer::Accum::Add
    } else {
        faer::Accum::Replace
    };
    faer::linalg::matmul::matmul(dst, accum, a, b, 1.0, faer::Par::Seq);
}

/// [`product_seq`] for `a` (`m × k`) and `b` (`k × n`) column-major into the `m × n` block at
/// the start of `dst` whose columns are `ld` apart (`accumulate`: added). Nothing when a
/// dimension is 0.
pub(super) fn gemm_seq(
    dst: &mut [f64],
    (m, n, ld): (usize, usize, usize),
    a: &[f64],
    b: &[f64],
    k: usize,
    accumulate: bool,
) {
    use faer::{MatMut, MatRef};
    if m == 0 || n == 0 || k == 0 {
        return;
    }
    product_seq(
        MatMut::from_column_major_slice_with_stride_mut(&mut dst[..(n - 1) * ld + m], m, n, ld),
        MatRef::from_column_major_slice(&a[..m * k], m, k),
        MatRef::from_column_major_slice(&b[..k * n], k, n),
        accumulate,
    );
}

/// Zeroes a folded `l`'s columns and rows that `k` marks dead (pinned nodes), and errors
/// unless every entry is finite.
pub(super) fn pin_and_check(l: &mut DMatrix<f64>, k: &Correction) -> Result<(), FemError> {
    for (c, &dead) in k.dead_cols.iter().enumerate() {
        if dead {
            l.columns_mut(3 * c, 3).fill(0.0);
        }
    }
    for (row, &dead) in k.dead_rows.iter().enumerate() {
        if dead {
            l.rows_mut(3 * row, 3).fill(0.0);
        }
    }
    if !l.iter().all(|v| v.is_finite()) {
        return Err(FemError::BadSelection(
            "the folded compliance is not finite".into(),
        ));
    }
    Ok(())
}
