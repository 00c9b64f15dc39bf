//! An exact low-rank correction of a compliance, carried beside `L` instead of folded into it:
//! `L′ = L + U C Uᵀ` on the held rows and the touchable columns (a cut's Woodbury term, see
//! the `cut` room), with the nodes it pins held still.
//!
//! What each path reads:
//! * the haptic path's 3×3 blocks: `L′(i, j) = L(i, j) + U_i V_jᵀ` with `V = U Cᵀ` stored per
//!   column (`9·rank` multiply-adds a block), and `L′_ii⁻¹` stored per column;
//! * the visual path: `u = L F + U_R z`, `z = Σ_c V_cᵀ F_c` (`rank` weights a frame, then one
//!   extra dense product over the rows: on the GPU, extra columns of the same pass).
//!
//! A pinned node (no tet left, or in a piece cut off) is no longer touchable (its column is
//! dead: the haptic path treats it as clamped) and does not move (its row is zero).
//!
//! A correction may also **grow** the compliance by the nodes a cut made touchable that are
//! not among its columns ([`Correction::extra`]: the copies a split made, the nodes its faces
//! exposed). Each such node `x` has all its DOFs in the correction's set `D`, so its column of
//! `L₀` is a column of `L_D`, and the whole of `L′(·, x)` is a product of the same kind:
//! `U V_xᵀ` with `V_x = e_p(x) + C U_xᵀ` (no column of `L` at all). Its displacement, where
//! it has no row of `L`, is `U_x z + w_p(x)` with `w = Σ_c U_cᵀ F_c` over the columns of `L`
//! ([`Correction::extra_rows`]).

use std::sync::Arc;

use glam::{DMat3, DVec3};

/// `U`, `V = U Cᵀ` and what they pin, for one compliance's rows and columns.
#[derive(Clone, Debug, Default)]
pub struct Correction {
    /// The correction's rank (`U`'s columns).
    pub rank: usize,
    /// `U` on the held rows: `3·l_rows × rank`, by column (entry `q·3·l_rows + 3r + a`).
    /// Shared: the cutter keeps it to grow the next cut's from, and a renderer keeps it to
    /// draw with, without a copy.
    pub rows: Arc<Vec<f64>>,
    /// `U` on the touchable columns' nodes: entry `(3c + a)·rank + q` (shared, as `rows`).
    pub u_cols: Arc<Vec<f64>>,
    /// `V = U Cᵀ` on the touchable columns' nodes, laid out as `u_cols` (shared, as `rows`).
    pub v_cols: Arc<Vec<f64>>,
    /// Per held row: pinned (the node does not move).
    pub dead_rows: Vec<bool>,
    /// Per touchable column: pinned (no longer touchable).
    pub dead_cols: Vec<bool>,
    /// Per touchable column: `L′_cc⁻¹` (zero for a dead column).
    pub diag_inv: Vec<DMat3>,
    /// The nodes the correction makes touchable beyond the compliance's columns, in
    /// ascending order: column `cols + k` of the grown compliance is node `extra[k]`. Empty
    /// for a correction that does not grow it.
    pub extra: Vec<u32>,
    /// `U` at the extra nodes, laid out as `u_cols` (entry `(3k + a)·rank + q`).
    pub u_extra: Vec<f64>,
    /// `V` at the extra nodes, `e_p(x) + C U_xᵀ`, laid out as `u_cols`.
    pub v_extra: Vec<f64>,
    /// Per extra node: its three DOFs' places among `U`'s columns (`p(x)`).
    pub extra_place: Vec<[u32; 3]>,
    /// Per extra node: its held row, or `u32::MAX` when it has none (its displacement is
    /// then [`Correction::extra_rows`]'s).
    pub extra_row: Vec<u32>,
    /// Per extra node: `L′_xx⁻¹`.
    pub extra_diag_inv: Vec<DMat3>,
}

/// `Σ_q a_q b_q` of two rank-long slices.
#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The 3×3 block `m[a][b] = A_a · B_b` of three rank-long rows of `A` and of `B` (each
/// `3·rank` long, row `a` at `a·rank`).
#[inline]
fn outer3(a: &[f64], b: &[f64], r: usize) -> DMat3 {
    let e = |i: usize, j: usize| dot(&a[i * r..][..r], &b[j * r..][..r]);
    // glam's matrices are built from columns.
    DMat3::from_cols(
        DVec3::new(e(0, 0), e(1, 0), e(2, 0)),
        DVec3::new(e(0, 1), e(1, 1), e(2, 1)),
        DVec3::new(e(0, 2), e(1, 2), e(2, 2)),
    )
}

impl Correction {
    /// `U_i V_jᵀ` between columns `i` and `j` (m/N); zero when either is dead.
    #[inline]
    pub fn col_block(&self, i: usize, j: usize) -> DMat3 {
        if self.dead_cols[i] || self.dead_cols[j] {
            return DMat3::ZERO;
        }
        let r = self.rank;
        outer3(&self.u_cols[3 * i * r..], &self.v_cols[3 * j * r..], r)
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
    /// `z` (`rank` long); an extra column's too ([`Correction::extra`]). Forces on dead or
    /// unknown columns are ignored.
    pub fn weights(&self, forces: &[(u32, DVec3)], z: &mut [f64]) {
        let r = self.rank;
        z[..r].fill(0.0);
        let nc = self.dead_cols.len();
        for &(c, f) in forces {
            let c = c as usize;
            let v = if c < nc {
                if self.dead_cols[c] {
                    continue;
                }
                &self.v_cols[3 * c * r..][..3 * r]
            } else if c - nc < self.extra.len() {
                &self.v_extra[3 * (c - nc) * r..][..3 * r]
            } else {
                continue;
            };
            for a in 0..3 {
                let fa = f[a];
                if fa == 0.0 {
                    continue;
                }
                for (zq, &v) in z[..r].iter_mut().zip(&v[a * r..][..r]) {
                    *zq += v * fa;
                }
            }
        }
    }

    /// Column `c`'s rows of `U` and of `V` (`3·rank` each), a column of `L` or an extra one;
    /// `None` when it is dead or unknown.
    #[inline]
    fn uv(&self, c: usize) -> Option<(&[f64], &[f64])> {
        let (r, nc) = (self.rank, self.dead_cols.len());
        if c < nc {
            (!self.dead_cols[c]).then(|| {
                let o = 3 * c * r;
                (&self.u_cols[o..][..3 * r], &self.v_cols[o..][..3 * r])
            })
        } else {
            let o = 3 * (c - nc) * r;
            (c - nc < self.extra.len())
                .then(|| (&self.u_extra[o..][..3 * r], &self.v_extra[o..][..3 * r]))
        }
    }

    /// `L′(node of column i, column j)` where either is an extra column (m/N): all of it is
    /// the correction's, `U_i V_jᵀ`, or by symmetry `(U_j V_iᵀ)ᵀ` when only `i` is extra (its
    /// `L₀` column is in `V_i`, its row is not in `U_i V_jᵀ`). Zero when either is dead.
    pub fn extra_block(&self, i: usize, j: usize) -> DMat3 {
        let (Some((ui, vi)), Some((uj, vj))) = (self.uv(i), self.uv(j)) else {
            return DMat3::ZERO;
        };
        let nc = self.dead_cols.len();
        if j >= nc {
            outer3(ui, vj, self.rank)
        } else {
            outer3(uj, vi, self.rank).transpose()
        }
    }

    /// `L′(held row r, extra column x)`: `U_r V_xᵀ` (m/N); zero when the row is dead.
    pub fn row_extra_block(&self, r: usize, x: usize) -> DMat3 {
        if self.dead_rows.get(r).copied().unwrap_or(true) || x >= self.extra.len() {
            return DMat3::ZERO;
        }
        let k = self.rank;
        let nr3 = self.dead_rows.len() * 3;
        let vx = &self.v_extra[3 * x * k..][..3 * k];
        let mut out = DMat3::ZERO;
        for b in 0..3 {
            let mut col = DVec3::ZERO;
            for (q, &v) in vx[b * k..][..k].iter().enumerate() {
                let u = &self.rows[q * nr3 + 3 * r..][..3];
                col += DVec3::new(u[0], u[1], u[2]) * v;
            }
            *out.col_mut(b) = col;
        }
        out
    }

    /// The displacements of the extra nodes that have no held row (`extra_row` is
    /// `u32::MAX`; the others get theirs from [`Correction::add_rows`]), in `extra`'s order
    /// (zero for the others): `U_x z + w_p(x)`, with `z` from [`Correction::weights`] and
    /// `w = Σ_c U_cᵀ F_c` over the columns of `L` in `forces`.
    pub fn extra_rows(&self, forces: &[(u32, DVec3)], z: &[f64], out: &mut [DVec3]) {
        let r = self.rank;
        let mut w = vec![0.0; r];
        self.column_weights(forces, &mut w);
        for (k, o) in out.iter_mut().enumerate().take(self.extra.len()) {
            if self.extra_row[k] != u32::MAX {
                *o = DVec3::ZERO;
                continue;
            }
            let u = &self.u_extra[3 * k * r..][..3 * r];
            let p = self.extra_place[k];
            *o = DVec3::new(
                dot(&u[..r], &z[..r]) + w[p[0] as usize],
                dot(&u[r..2 * r], &z[..r]) + w[p[1] as usize],
                dot(&u[2 * r..], &z[..r]) + w[p[2] as usize],
            );
        }
    }

    /// `w = Σ_c U_cᵀ F_c` over the live columns of `L` in `forces` (column index, N) into `w`
    /// (`rank` long): what the extra nodes without a row add to `U_x z`
    /// ([`Correction::extra_rows`]).
    pub fn column_weights(&self, forces: &[(u32, DVec3)], w: &mut [f64]) {
        let r = self.rank;
        let nc = self.dead_cols.len();
        w[..r].fill(0.0);
        for &(c, f) in forces {
            let c = c as usize;
            if c >= nc || self.dead_cols[c] {
                continue;
            }
            for a in 0..3 {
                let u = &self.u_cols[(3 * c + a) * r..][..r];
                for (wq, &uq) in w[..r].iter_mut().zip(u) {
                    *wq += uq * f[a];
                }
            }
        }
    }

    /// The indices into [`Correction::extra`] of the extra nodes without a held row (their
    /// displacement is [`Correction::extra_rows`]'s; a renderer draws each as a vertex of its
    /// own), in order.
    pub fn rowless_extras(&self) -> impl Iterator<Item = usize> + '_ {
        (0..self.extra.len()).filter(|&k| self.extra_row[k] == u32::MAX)
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
            rows: Arc::default(),
            u_cols: Arc::default(),
            v_cols: Arc::default(),
            dead_rows: self.dead_rows.clone(),
            dead_cols: self.dead_cols.clone(),
            diag_inv: self.diag_inv.clone(),
            ..Correction::default()
        }
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        8 * (self.rows.len() + self.u_cols.len() + self.v_cols.len())
            + 8 * (self.u_extra.len() + self.v_extra.len())
            + 20 * self.extra.len()
            + self.dead_rows.len()
            + self.dead_cols.len()
            + 72 * (self.diag_inv.len() + self.extra_diag_inv.len())
    }
}
