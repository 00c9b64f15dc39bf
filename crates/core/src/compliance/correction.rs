//! An exact low-rank correction of a compliance, carried beside `L` instead of folded into it:
//! `L′ = L + U C Uᵀ` on the held rows and the touchable columns (a cut's Woodbury term, see
//! [`crate::cut`]), with the nodes it pins held still.
//!
//! What each path reads:
//! * the haptic path's 3×3 blocks: `L′(i, j) = L(i, j) + U_i V_jᵀ` with `V = U Cᵀ` stored per
//!   column (`9·rank` multiply-adds a block), and `L′_ii⁻¹` stored per column;
//! * the visual path: `u = L F + U_R z`, `z = Σ_c V_cᵀ F_c` (`rank` weights a frame, then one
//!   extra dense product over the rows: on the GPU, extra columns of the same pass).
//!
//! A pinned node (no tet left, or in a piece cut off) is no longer touchable (its column is
//! dead: the haptic path treats it as clamped) and does not move (its row is zero).

use glam::{DMat3, DVec3};

/// `U`, `V = U Cᵀ` and what they pin, for one compliance's rows and columns.
#[derive(Clone, Debug, Default)]
pub struct Correction {
    /// The correction's rank (`U`'s columns).
    pub rank: usize,
    /// `U` on the held rows: `3·l_rows × rank`, by column (entry `q·3·l_rows + 3r + a`).
    pub rows: Vec<f64>,
    /// `U` on the touchable columns' nodes: entry `(3c + a)·rank + q`.
    pub u_cols: Vec<f64>,
    /// `V = U Cᵀ` on the touchable columns' nodes, laid out as `u_cols`.
    pub v_cols: Vec<f64>,
    /// Per held row: pinned (the node does not move).
    pub dead_rows: Vec<bool>,
    /// Per touchable column: pinned (no longer touchable).
    pub dead_cols: Vec<bool>,
    /// Per touchable column: `L′_cc⁻¹` (zero for a dead column).
    pub diag_inv: Vec<DMat3>,
}

impl Correction {
    /// `U_i V_jᵀ` between columns `i` and `j` (m/N); zero when either is dead.
    #[inline]
    pub fn col_block(&self, i: usize, j: usize) -> DMat3 {
        if self.dead_cols[i] || self.dead_cols[j] {
            return DMat3::ZERO;
        }
        let r = self.rank;
        let mut m = [[0.0f64; 3]; 3];
        for (a, row) in m.iter_mut().enumerate() {
            let ui = &self.u_cols[(3 * i + a) * r..][..r];
            for (b, e) in row.iter_mut().enumerate() {
                let vj = &self.v_cols[(3 * j + b) * r..][..r];
                *e = ui.iter().zip(vj).map(|(x, y)| x * y).sum();
            }
        }
        // m[a][b] is entry (a, b): glam's matrices are built from columns.
        DMat3::from_cols(
            DVec3::new(m[0][0], m[1][0], m[2][0]),
            DVec3::new(m[0][1], m[1][1], m[2][1]),
            DVec3::new(m[0][2], m[1][2], m[2][2]),
        )
    }

    /// `U_r V_cᵀ` between held row `r` and column `c` (m/N); zero when either is dead.
    #[inline]
    pub fn row_block(&self, r: usize, c: usize) -> DMat3 {
        if self.dead_rows.get(r).copied().unwrap_or(true) || self.dead_cols[c] {
            return DMat3::ZERO;
        }
        let k = self.rank;
        let nr3 = self.dead_rows.len() * 3;
        let mut out = DMat3::ZERO;
        for b in 0..3 {
            let vc = &self.v_cols[(3 * c + b) * k..][..k];
            let mut col = DVec3::ZERO;
            for (q, &v) in vc.iter().enumerate() {
                let u = &self.rows[q * nr3 + 3 * r..][..3];
                col += DVec3::new(u[0], u[1], u[2]) * v;
            }
            *out.col_mut(b) = col;
        }
        out
    }

    /// The weights `z = Σ_c V_cᵀ F_c` of a force boundary condition (column index, N) into
    /// `z` (`rank` long). Forces on dead columns are ignored.
    pub fn weights(&self, forces: &[(u32, DVec3)], z: &mut [f64]) {
        let r = self.rank;
        z[..r].fill(0.0);
        for &(c, f) in forces {
            let c = c as usize;
            if self.dead_cols.get(c).copied().unwrap_or(true) {
                continue;
            }
            for a in 0..3 {
                let fa = f[a];
                if fa == 0.0 {
                    continue;
                }
                for (zq, &v) in z[..r].iter_mut().zip(&self.v_cols[(3 * c + a) * r..][..r]) {
                    *zq += v * fa;
                }
            }
        }
    }

    /// `out[r] += U_r z` over the held rows, and dead rows set to zero.
    pub fn add_rows(&self, z: &[f64], out: &mut [DVec3]) {
        let nr = self.dead_rows.len();
        let nr3 = 3 * nr;
        for (q, &zq) in z[..self.rank].iter().enumerate() {
            if zq == 0.0 {
                continue;
            }
            let col = &self.rows[q * nr3..][..nr3];
            for (r, o) in out[..nr].iter_mut().enumerate() {
                *o += DVec3::new(col[3 * r], col[3 * r + 1], col[3 * r + 2]) * zq;
            }
        }
        for (o, &dead) in out[..nr].iter_mut().zip(&self.dead_rows) {
            if dead {
                *o = DVec3::ZERO;
            }
        }
    }

    /// `U` on the held rows rounded to f32, by column: what the GPU pass takes as extra
    /// columns.
    pub fn rows_f32(&self) -> Vec<f32> {
        self.rows.iter().map(|&v| v as f32).collect()
    }

    /// What is left of this correction once folded into `L`: rank 0, the same pinned rows
    /// and columns and the same `L′_cc⁻¹`.
    pub fn pins_only(&self) -> Correction {
        Correction {
            rank: 0,
            rows: Vec::new(),
            u_cols: Vec::new(),
            v_cols: Vec::new(),
            dead_rows: self.dead_rows.clone(),
            dead_cols: self.dead_cols.clone(),
            diag_inv: self.diag_inv.clone(),
        }
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        8 * (self.rows.len() + self.u_cols.len() + self.v_cols.len())
            + self.dead_rows.len()
            + self.dead_cols.len()
            + 72 * self.diag_inv.len()
    }
}
