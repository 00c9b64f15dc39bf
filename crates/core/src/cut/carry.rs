//! The capacitance and `V` carried from one cut to the next. A cut changes `ΔK′` only on
//! the DOFs `T` its tets touch (`E = ΔK′₁ − ΔK′₀`, zero outside `T × T`), so the new
//! capacitance is the old one plus a term of rank `|T|`:
//!
//! `C₁ = C₀ + S G Sᵀ`, `S = P_T + C₀ L_DD[:, T]`, `G = (I − E_TT L′₀[T, T])⁻¹ E_TT`,
//! `L′₀[T, T] = L_DD[T, :] S`
//!
//! (`L′₁ = L′₀ + L′₀[:, T] G L′₀[T, :]` with `L′₀[:, T] = U S`: the Woodbury identity once
//! more, on the body as cut so far). That costs about `2·rank²·|T|` multiply-adds where the
//! capacitance afresh (an LU and its solve) costs about `2.7·rank³`; and `V = U C` follows
//! the same way, `V₁ = V₀ + (U S) G Sᵀ`, `3·C·(2·rank·|T| + |T|²)` where `V` afresh costs
//! `3·C·rank²`. Past rank 300 a pass of the incision spent most of its time on those two.
//!
//! The updates made since the last `V` wait in `Cut::carried` until [`Cut::correction`] asks for
//! `V` again with the same `L`; a cut undone, another `L`, or updates that would cost more
//! than `V` afresh make it afresh. Both ways depend only on the cuts made, never on timing, so a replay
//! makes the same bits.
//!
//! Either way each column of `V` depends on its own column of `U` alone, so `V` is made in
//! fixed blocks of [`V_BLOCK`] columns; where it is large, a helper thread takes blocks in the
//! haptic core's idle time while the cutter's thread takes the others. Each block is the same
//! products whoever makes it, so the bits do not depend on the sharing.

use std::sync::Arc;

use faer::{MatMut, MatRef, Par};
use nalgebra::DMatrix;

use super::body::Cut;
use super::carried::{update_cost, Shared, Update};

use crate::compliance::{product_seq as product, Compliance};
use crate::Error;

/// Columns of `V` made together: a fixed grid, so a column's bits do not depend on which
/// thread makes it (at rank 600 and a pass's `|T|` of 50, a block is about 8 million
/// multiply-adds, 1–2 ms).
const V_BLOCK: usize = 128;

/// The multiply-adds of a `V` at or below which the cutter's thread makes it alone:
/// [`Cut::share_v_with`]'s usual `above`. None: a pass's own work (`U`'s rows, the opened mesh
/// and its contact surface, several ms) runs on the cutter's thread meanwhile, so a helper
/// (whose start costs about 0.1 ms) that takes even a small `V` shortens the pass. With 20
/// million, ten rounds of the incision alternated read a median delay of 36.5 ms against
/// 33 ms with none (`docs/measurements/2026-12-06-separating-cut.md`, the twelfth session).
pub const V_SHARE_ABOVE: usize = 0;

/// `m` as a faer view (nalgebra stores column-major).
fn view(m: &DMatrix<f64>) -> MatRef<'_, f64> {
    MatRef::from_column_major_slice(m.as_slice(), m.nrows(), m.ncols())
}

/// `m` as a mutable faer view.
fn view_mut(m: &mut DMatrix<f64>) -> MatMut<'_, f64> {
    let (r, c) = m.shape();
    MatMut::from_column_major_slice_mut(m.as_mut_slice(), r, c)
}

/// `G = M⁻¹ E` by faer's LU with partial pivoting on this thread; `None` when `M` is
/// singular or the result not finite.
fn lu_solve(m: &DMatrix<f64>, e: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    use faer::dyn_stack::{MemBuffer, MemStack};
    use faer::linalg::lu::partial_pivoting::{factor, solve};
    let n = m.nrows();
    let par = Par::Seq;
    let mut lu = faer::Mat::<f64>::from_fn(n, n, |i, j| m[(i, j)]);
    let (mut perm, mut perm_inv) = (vec![0usize; n], vec![0usize; n]);
    let mut buf = MemBuffer::new(
        factor::lu_in_place_scratch::<usize, f64>(n, n, par, Default::default()).or(
            solve::solve_in_place_scratch::<usize, f64>(n, e.ncols(), par),
        ),
    );
    let stack = MemStack::new(&mut buf);
    let (_, p) = factor::lu_in_place(
        lu.as_mut(),
        &mut perm,
        &mut perm_inv,
        par,
        stack,
        Default::default(),
    );
    if (0..n).any(|i| !(lu[(i, i)] != 0.0 && lu[(i, i)].is_finite())) {
        return None;
    }
    let mut x = faer::Mat::<f64>::from_fn(n, e.ncols(), |i, j| e[(i, j)]);
    solve::solve_in_place(lu.as_ref(), lu.as_ref(), p, x.as_mut(), par, stack);
    let g = DMatrix::from_fn(n, e.ncols(), |i, j| x[(i, j)]);
    g.iter().all(|v| v.is_finite()).then_some(g)
}

impl Cut {
    /// The capacitance after a cut that changed `ΔK′` from `before` (`L_D` and `ΔK′` grown
    /// to the new rank already): `C₀ + S G Sᵀ`, the update kept for `V`. Errors where
    /// the stiffness became singular or the result is not finite (then `C` is the old one,
    /// grown by zeros).
    pub(super) fn update_capacitance(&mut self, before: &DMatrix<f64>) -> Result<(), Error> {
        let r = self.d.len();
        let r0 = self.cap.nrows().min(r);
        let mut c = DMatrix::zeros(r, r);
        c.view_mut((0, 0), (r0, r0))
            .copy_from(&self.cap.view((0, 0), (r0, r0)));
        // T: the places whose row of ΔK′ changed.
        let t: Vec<usize> = (0..r)
            .filter(|&i| (0..r).any(|j| self.dk[(i, j)] != before[(i, j)]))
            .collect();
        let carried = self.carried.get_mut().unwrap_or_else(|e| e.into_inner());
        if t.is_empty() {
            self.cap = c;
            return Ok(());
        }
        let n = t.len();
        // L_DD[:, T] (r × |T|) from L_D's columns at T, rows at D.
        let mut a_t = DMatrix::zeros(r, n);
        for (j, &q) in t.iter().enumerate() {
            let col = self.ld.column(q);
            for (a, &fa) in self.d.iter().enumerate() {
                a_t[(a, j)] = col[fa];
            }
        }
        // S = P_T + C₀ L_DD[:, T] (C₀ is zero past r0).
        let mut s = DMatrix::zeros(r, n);
        product(
            MatMut::from_column_major_slice_with_stride_mut(s.as_mut_slice(), r0, n, r),
            view(&c).submatrix(0, 0, r0, r0),
            view(&a_t).submatrix(0, 0, r0, n),
            false,
        );
        for (j, &q) in t.iter().enumerate() {
            s[(q, j)] += 1.0;
        }
        // L′₀[T, T] = L_DD[T, :] S; M = I − E_TT L′₀[T, T].
        let mut lt = DMatrix::zeros(n, n);
        product(view_mut(&mut lt), view(&a_t).transpose(), view(&s), false);
        let e = DMatrix::from_fn(n, n, |i, j| self.dk[(t[i], t[j])] - before[(t[i], t[j])]);
        let m = DMatrix::identity(n, n) - &e * &lt;
        let Some(g) = lu_solve(&m, &e) else {
            self.cap = c;
            carried.pending.clear();
            carried.v = None;
            return Err(Error::Input(
                "the cut left a singular stiffness (a piece that no clamp holds was not found)"
                    .into(),
            ));
        };
        // C₁ = C₀ + S (G Sᵀ).
        let mut gst = DMatrix::zeros(n, r);
        product(view_mut(&mut gst), view(&g), view(&s).transpose(), false);
        product(view_mut(&mut c), view(&s), view(&gst), true);
        if !c.iter().all(|v| v.is_finite()) {
            self.cap = DMatrix::zeros(r, r);
            carried.pending.clear();
            carried.v = None;
            return Err(Error::Input("the cut's correction is not finite".into()));
        }
        self.cap = c;
        // Kept for V while the updates cost less than making it afresh (`2·rank·|T| + |T|²`
        // against `rank²` multiply-adds a column).
        let waiting = carried.waiting(r);
        if carried.v.is_some() && waiting + update_cost(r, n) < r * r {
            carried.pending.push(Update { s, g });
        } else {
            carried.pending.clear();
            carried.v = None;
        }
        Ok(())
    }

    /// `Vᵀ = C Uᵀ` (`u`: `Uᵀ`, `rank × 3·C` column-major, of compliance `c`'s columns; the
    /// result laid out as `u`): from the last `V` and the updates since where they were made
    /// for `c`'s `L`, else afresh ([`Cut::cap_times`]); kept (shared, not copied) for the next
    /// cut.
    pub(super) fn v_times(
        &self,
        c: &Compliance,
        u: &[f64],
        meanwhile: &mut dyn FnMut(),
    ) -> Arc<Vec<f64>> {
        let r = self.cap.nrows();
        if r == 0 || u.is_empty() {
            meanwhile();
            return Arc::new(vec![0.0; u.len()]);
        }
        let cols = u.len() / r;
        // (Not locked while `V` is made: `meanwhile` takes buffers too.)
        let (last, mut out, pending, helper) = {
            let mut carried = self.carried.lock().unwrap_or_else(|e| e.into_inner());
            let last = carried.v.take();
            let out = carried.buffer(u.len());
            (
                last,
                out,
                std::mem::take(&mut carried.pending),
                carried.helper.clone(),
            )
        };
        let updates = match last {
            Some((base, r0, v0)) if base.shares_l(c) && r0 <= r && v0.len() == r0 * cols => {
                // (Appended column by column: each entry written once, in order.)
                for j in 0..cols {
                    out.extend_from_slice(&v0[j * r0..(j + 1) * r0]);
                    out.resize(out.len() + r - r0, 0.0);
                }
                Some(&pending[..])
            }
            _ => {
                out.resize(u.len(), 0.0);
                None
            }
        };
        let macs = cols
            * updates.map_or(r * r, |ups| {
                (ups.iter())
                    .map(|x| update_cost(x.s.nrows(), x.g.nrows()))
                    .sum()
            });
        let helper = helper.and_then(|(cpus, above)| (macs > above).then_some(cpus));
        self.v_blocks(u, &mut out, updates, helper.as_deref(), meanwhile);
        let mut carried = self.carried.lock().unwrap_or_else(|e| e.into_inner());
        let out = carried.share(out);
        carried.v = Some((c.clone(), r, out.clone()));
        out
    }

    /// How far behind the `V` this cut carries is: the multiply-adds of the updates waiting
    /// for it over those of `V` afresh (`None`: it carries none). The next
    /// [`Cut::correction`] costs about this fraction of `V` afresh (or `V` afresh at `None`).
    pub fn v_behind(&self) -> Option<f64> {
        let carried = self.carried.lock().unwrap_or_else(|e| e.into_inner());
        carried.v.as_ref()?;
        let r = self.cap.nrows().max(1);
        let cost = carried.waiting(r);
        Some(cost as f64 / (r * r) as f64)
    }

    /// Lets a helper thread on `cpus` (the haptic loop's cores, in their idle time) make part
    /// of each `V` of more than `above` multiply-adds (usually [`V_SHARE_ABOVE`]; `None`:
    /// the calling thread makes all of it). The same bits either way.
    pub fn share_v_with(&mut self, cpus: Option<Arc<[usize]>>, above: usize) {
        let carried = self.carried.get_mut().unwrap_or_else(|e| e.into_inner());
        carried.helper = cpus.map(|c| (c, above));
    }

    /// Makes `Vᵀ` into `out` (`rank × cols`, as `u`) block by block: `C Uᵀ` afresh, or, given
    /// `updates`, `out` (the last `V`, grown) plus each update's `S (G (Sᵀ Uᵀ))` at the rank
    /// of its cut. With `helper`, a thread there takes blocks too, while this one first
    /// runs `meanwhile` (without, `meanwhile` runs first).
    fn v_blocks(
        &self,
        u: &[f64],
        out: &mut [f64],
        updates: Option<&[Update]>,
        helper: Option<&[usize]>,
        meanwhile: &mut dyn FnMut(),
    ) {
        let r = self.cap.nrows();
        let block = |(j0, o): (usize, &mut [f64])| {
            let m = o.len() / r;
            let ub = &u[j0 * r..][..m * r];
            let Some(ups) = updates else {
                self.cap_times(ub, o);
                return;
            };
            for upd in ups {
                let (ri, n) = upd.s.shape();
                let ut = MatRef::from_column_major_slice_with_stride(ub, ri, m, r);
                let mut wt = DMatrix::zeros(n, m);
                product(view_mut(&mut wt), view(&upd.s).transpose(), ut, false);
                let mut y = DMatrix::zeros(n, m);
                product(view_mut(&mut y), view(&upd.g), view(&wt), false);
                product(
                    MatMut::from_column_major_slice_with_stride_mut(o, ri, m, r),
                    view(&upd.s),
                    view(&y),
                    true,
                );
            }
        };
        let blocks = (out.chunks_mut(V_BLOCK * r).enumerate()).map(|(k, o)| (k * V_BLOCK, o));
        // (A block left half made cannot be made again where it adds to the last `V`.)
        let lost = crate::threads::share_jobs(blocks, helper, meanwhile, block);
        assert!(lost.is_empty(), "the helper making V's blocks failed");
    }

    /// `U` at `c`'s columns, transposed (`rank × 3·C`, column-major; `nr3`: `3·R`, `c`'s
    /// held rows), and the last `U`'s rank and rows where [`Cut::u_rows_of`] can copy them
    /// (read for the same `L`): each
    /// `(place, DOF)` of `cols` read from `L_D`, the places of dead nodes zero. The columns
    /// of `L_D` read for the last `U` of the same `L` are copied from it (they do not
    /// change: a cut only adds columns, and a node once pinned stays dead), so only the new
    /// ones are read: the same bits either way.
    pub(super) fn u_cols_of(
        &self,
        c: &Compliance,
        (cols, dead_cols): (&[(usize, usize)], &[bool]),
        nr3: usize,
    ) -> (Shared, Option<(usize, Shared)>) {
        let r = self.d.len();
        let nc3 = 3 * dead_cols.len();
        let mut carried = self.carried.lock().unwrap_or_else(|e| e.into_inner());
        let last = carried.u.take().filter(|(base, k0, rows0, cols0)| {
            base.shares_l(c) && *k0 <= r && rows0.len() == nr3 * k0 && cols0.len() == nc3 * k0
        });
        let (r0, cols0) = match &last {
            Some((_, k0, _, cols0)) => (*k0, &cols0[..]),
            None => (0, &[][..]),
        };
        // The new columns' entries at the columns first (rank-major, small), then each column
        // of U's row: its old entries, then its new ones. (Built by appending, each entry
        // written once and in order: at rank 600 these are tens of megabytes, and a pass
        // beside the renderer is bound by memory.)
        let dr = r - r0;
        let mut new = vec![0.0; nc3 * dr];
        for q in r0..r {
            let col = self.ld.column(q);
            for &(j, d) in cols {
                new[j * dr + q - r0] = col[d];
            }
        }
        let mut u_cols = carried.buffer(nc3 * r);
        for j in 0..nc3 {
            if dead_cols[j / 3] {
                u_cols.resize(u_cols.len() + r, 0.0);
            } else {
                u_cols.extend_from_slice(&cols0[j * r0..][..r0]);
                u_cols.extend_from_slice(&new[j * dr..][..dr]);
            }
        }
        let u_cols = carried.share(u_cols);
        (u_cols, last.map(|(_, k0, rows0, _)| (k0, rows0)))
    }

    /// `U` at the held rows (`3·R × rank`, column-major) whose `(place, DOF)` are `rows`,
    /// after [`Cut::u_cols_of`]: the `last` `U`'s rows copied where it gave them, the new
    /// columns of `L_D` read, a dead row zero.
    pub(super) fn u_rows_of(
        &self,
        last: Option<(usize, Shared)>,
        (rows, dead_rows): (&[(usize, usize)], &[bool]),
    ) -> Shared {
        let r = self.d.len();
        let nr3 = 3 * dead_rows.len();
        let (r0, rows0) = match &last {
            Some((k0, rows0)) => (*k0, &rows0[..]),
            None => (0, &[][..]),
        };
        let mut u_rows = (self.carried.lock().unwrap_or_else(|e| e.into_inner())).buffer(nr3 * r);
        u_rows.extend_from_slice(rows0);
        // Nodes pinned since: dead, zero.
        for (k, _) in dead_rows.iter().enumerate().filter(|p| *p.1) {
            for q in 0..r0 {
                u_rows[q * nr3 + 3 * k..][..3].fill(0.0);
            }
        }
        for q in r0..r {
            let col = self.ld.column(q);
            let at = u_rows.len();
            u_rows.resize(at + nr3, 0.0);
            let out = &mut u_rows[at..];
            for &(i, d) in rows {
                out[i] = col[d];
            }
        }
        (self.carried.lock().unwrap_or_else(|e| e.into_inner())).share(u_rows)
    }

    /// Keeps `U` (its `rows` and `cols` at `rank`, read for `c`) for the next correction.
    pub(super) fn keep_u(&self, c: &Compliance, rank: usize, rows: &Shared, cols: &Shared) {
        let mut carried = self.carried.lock().unwrap_or_else(|e| e.into_inner());
        carried.u = Some((c.clone(), rank, rows.clone(), cols.clone()));
    }
}
