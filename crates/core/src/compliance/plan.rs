//! The solve plan of a precompute: the method, the ordering, where the factor is kept, and
//! the [`ColumnPlan`] that solves column batches on several threads.

use super::*;

/// Columns per solve batch. Batches sit on a fixed grid of column indices (batch `b` holds
/// columns `64b .. 64b + 64`), so a column's values never depend on how the work is split
/// over threads or shards: merged shards equal the unsharded result bit for bit.
pub const BATCH_COLS: usize = 64;

/// How the precompute computes its columns.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Method {
    /// A forward and a back substitution per touchable DOF, each visiting only the
    /// supernodes the column reaches and the displayed rows need
    /// ([`crate::fem::gram::UnitSolver`]).
    Columns,
    /// As `Columns` through every supernode (faer's solve; for comparisons).
    Full,
    /// Sparse forward solves for the displayed DOFs and their Gram product
    /// ([`crate::fem::gram`]); the column method where the factor is not supernodal.
    Gram,
    /// Whichever is estimated cheaper.
    #[default]
    Auto,
}

/// The method named by the environment variable `TOUCHFEM_PRECOMPUTE` (`columns`, `gram`,
/// `full`; anything else or unset: [`Method::Auto`]).
pub fn method() -> Method {
    match crate::options::var("TOUCHFEM_PRECOMPUTE")
        .as_deref()
        .ok_or(())
    {
        Ok("columns") => Method::Columns,
        Ok("full") => Method::Full,
        Ok("gram") => Method::Gram,
        _ => Method::Auto,
    }
}

/// `read(DOF column, first row, out)`: rows of an earlier batch, for [`ColumnPlan::mirror`].
pub(crate) type ReadRows<'a, E> = dyn FnMut(usize, usize, &mut [f64]) -> Result<(), E> + 'a;

/// Column nodes per pruned column solve (a batch is solved in groups of this many).
pub(crate) const SOLVE_COLS: usize = 32;

/// Panels of a hierarchical precompute between two checks of a panel's first column against
/// a direct solve.
pub(crate) const HIER_CHECK_EVERY: usize = 4;

/// Batches between two checks of a Gram batch against a direct solve of its first column.
pub(crate) const GRAM_CHECK_EVERY: usize = 16;

/// The ordering of the precompute's factorisation: METIS, or by the environment variable
/// `TOUCHFEM_ORDERING` our coordinate nested dissection (`nd`) or faer's AMD (`amd`), for
/// comparisons.
pub(crate) fn ordering() -> crate::fem::Ordering {
    match crate::options::var("TOUCHFEM_ORDERING")
        .as_deref()
        .ok_or(())
    {
        Ok("amd") => crate::fem::Ordering::Amd,
        Ok("nd") => crate::fem::Ordering::NestedDissection,
        _ => crate::fem::Ordering::Metis,
    }
}

/// Bytes of Cholesky factor above which the precompute keeps it in a file (see
/// [`factor_store`]).
#[cfg(feature = "native")]
pub(crate) const FACTOR_FILE_ABOVE: usize = 256 << 20;

/// Where the precompute keeps its Cholesky factor, by the environment variable
/// `TOUCHFEM_FACTOR`: `heap` (faer's factorisation, in memory), `file` (the out-of-core
/// multifrontal factorisation of [`crate::fem::frontal`]), or, unset or anything else, `file`
/// for factors above [`FACTOR_FILE_ABOVE`]. The file is unlinked at once and lives in the
/// cache directory ([`crate::options::cache_dir`]), or the system's temporary one.
#[cfg(feature = "native")]
pub(crate) fn factor_store() -> crate::fem::FactorStore {
    use crate::fem::FactorStore;
    let dir = crate::options::cache_dir()
        .filter(|d| std::fs::create_dir_all(d).is_ok())
        .unwrap_or_else(std::env::temp_dir);
    let threads = solver_threads();
    match crate::options::var("TOUCHFEM_FACTOR").as_deref().ok_or(()) {
        Ok("heap") => FactorStore::Heap,
        Ok("file") => FactorStore::File { dir, threads },
        _ => FactorStore::Auto {
            dir,
            threads,
            above: FACTOR_FILE_ABOVE,
        },
    }
}

/// Where the precompute keeps its Cholesky factor without the `native` feature: on the heap
/// (there are no files, and `std::env::temp_dir` panics on `wasm32-unknown-unknown`).
#[cfg(not(feature = "native"))]
pub(crate) fn factor_store() -> crate::fem::FactorStore {
    crate::fem::FactorStore::Heap
}

/// The factorised stiffness and the resolved selection, ready to solve column batches.
pub(crate) struct ColumnPlan {
    /// Displayed nodes (rows); the touchable nodes are included. The free ones come first,
    /// then the clamped ones.
    pub rows: Vec<u32>,
    /// The free rows, which hold `L` (see [`Compliance::l_rows`]).
    pub l_rows: usize,
    /// Touchable nodes (columns).
    pub cols: Vec<u32>,
    /// Assembly and factorisation times (the solve phases are filled by the caller).
    pub phases: PhaseTimes,
    pub(crate) stiff: Stiffness,
    pub(crate) factor: crate::fem::Factor,
    /// The Gram method's plan, `W`, and the row index of each of its nodes.
    pub(crate) gram: Option<(crate::fem::gram::GramPlan, Vec<f64>, Vec<u32>)>,
    /// Symmetric Gram plans: the first column whose batch is at hand when the upper rows are
    /// mirrored (see [`ColumnPlan::mirror_from`]).
    pub(crate) mirror_from: Option<usize>,
    /// The column method's pruned solver (supernodal factors).
    pub(crate) units: Option<crate::fem::gram::UnitSolver>,
    /// For the Gram method on a factor in a file: the sweeps of the check solves, which drop
    /// the pages behind them.
    pub(crate) sweeper: Option<crate::fem::gram::UnitSolver>,
    /// Batch buffers handed back by the workers, for the next batches (see
    /// [`ColumnPlan::buffer`]).
    pub(crate) pool: std::sync::Mutex<Vec<Vec<f64>>>,
}

/// A worker's groups of [`ColumnPlan::solve_cols`] (group, columns) and its seconds.
pub(crate) type GroupsSolved = (Vec<(usize, Vec<f64>)>, [f64; 3]);

/// The largest residual and the seconds solving, checking and scattering.
pub(crate) type SolveSummary = (f64, [f64; 3]);

/// A solver worker: runs until the work is out, reporting columns done to its argument.
pub(crate) type SolveWork<'a> =
    dyn Fn(&mut dyn FnMut(usize)) -> Result<SolveSummary, FemError> + Sync + 'a;

/// Runs `work` on `workers` threads, the calling one (which reports `progress`) included,
/// and combines what they return: the largest residual and, per phase, the slowest worker's
/// seconds.
pub(crate) fn run_workers(
    workers: usize,
    work: &SolveWork<'_>,
    progress: &mut dyn FnMut(usize),
) -> Result<SolveSummary, FemError> {
    let results = crate::threads::fan_out(workers, || work(progress), |_| work(&mut |_| {}));
    let mut out = (0.0f64, [0.0f64; 3]);
    for r in results {
        let (res, t) =
            r.unwrap_or_else(|_| Err(FemError::Factorisation("a solver thread panicked".into())))?;
        out.0 = out.0.max(res);
        for (a, v) in out.1.iter_mut().zip(t) {
            *a = a.max(v);
        }
    }
    Ok(out)
}

pub(crate) fn solver_threads() -> usize {
    crate::threads::available().clamp(1, 16)
}

impl ColumnPlan {
    /// Resolves and checks the selection, assembles K and factorises it, with the method of
    /// [`method`] (for the Gram method, `W` is computed here).
    pub fn new(mesh: &Mesh, sel: &Selection) -> Result<ColumnPlan, FemError> {
        Self::with_method(mesh, sel, method())
    }

    /// As [`ColumnPlan::new`] with the method `how`.
    pub(crate) fn with_method(
        mesh: &Mesh,
        sel: &Selection,
        how: Method,
    ) -> Result<ColumnPlan, FemError> {
        Self::with_method_in(mesh, sel, how, &factor_store())
    }

    /// As [`ColumnPlan::with_method`] with the factor kept where `store` says.
    pub(crate) fn with_method_in(
        mesh: &Mesh,
        sel: &Selection,
        how: Method,
        store: &crate::fem::FactorStore,
    ) -> Result<ColumnPlan, FemError> {
        let t0 = Stopwatch::start();
        let n = mesh.nodes.len();
        let cols = sel.cols.resolve(mesh);
        let mut rows = sel.rows.resolve(mesh);
        let mut row_of_node = vec![u32::MAX; n];
        let mut col_of_node = vec![u32::MAX; n];
        for (ci, &c) in cols.iter().enumerate() {
            if c as usize >= n {
                return Err(FemError::BadSelection(format!(
                    "touchable node {c} does not exist ({n} nodes)"
                )));
            }
            if mesh.fixed[c as usize] {
                return Err(FemError::BadSelection(format!(
                    "touchable node {c} is clamped"
                )));
            }
            if col_of_node[c as usize] != u32::MAX {
                return Err(FemError::BadSelection(format!("node {c} selected twice")));
            }
            col_of_node[c as usize] = ci as u32;
        }
        for (ri, &r) in rows.iter().enumerate() {
            if r as usize >= n || row_of_node[r as usize] != u32::MAX {
                return Err(FemError::BadSelection(format!(
                    "displayed node {r} is out of range or repeated"
                )));
            }
            row_of_node[r as usize] = ri as u32;
        }
        for &c in &cols {
            if row_of_node[c as usize] == u32::MAX {
                row_of_node[c as usize] = rows.len() as u32;
                rows.push(c);
            }
        }
        // Free rows first: the clamped ones hold no `L`.
        let (mut free, clamped): (Vec<u32>, Vec<u32>) =
            rows.iter().partition(|&&r| !mesh.fixed[r as usize]);
        let l_rows = free.len();
        free.extend(clamped);
        rows = free;
        for (i, &r) in rows.iter().enumerate() {
            row_of_node[r as usize] = i as u32;
        }
        let mut phases = PhaseTimes::default();
        let stiff = Stiffness::assemble(mesh)?;
        phases.assemble_s = t0.elapsed().as_secs_f64();
        let (factor, sym_s, num_s) = stiff.factorize_in(ordering(), store)?;
        phases.factor_in_file = factor.is_mapped();
        phases.front_bytes = factor.front_bytes();
        phases.symbolic_s = sym_s;
        phases.numeric_s = num_s;
        phases.factor_nonzeros = factor.nonzeros();
        phases.column_flops = 12.0 * cols.len() as f64 * factor.nonzeros() as f64;
        phases.method = "columns".into();
        let mut cols = cols;
        let mut gram = None;
        if how != Method::Columns && how != Method::Full {
            let shown: Vec<u32> = rows
                .iter()
                .copied()
                .filter(|&r| !mesh.fixed[r as usize])
                .collect();
            if let Some(g) = crate::fem::gram::GramPlan::new(&factor, &stiff.dofs, &shown, &cols) {
                phases.gram_flops = g.forward_flops + g.gram_flops;
                if how == Method::Gram || phases.gram_flops < 0.7 * phases.column_flops {
                    let tf = Stopwatch::start();
                    if let Some(w) = g.forward(&factor, solver_threads()) {
                        phases.forward_s = tf.elapsed().as_secs_f64();
                        phases.w_bytes = g.w_bytes();
                        phases.method = "gram".into();
                        cols = g.touchable();
                        if g.symmetric() {
                            // Rows in Gram order (then the clamped ones): the columns are the
                            // first rows, and a tile's upper rows mirror earlier tiles.
                            let mut r = g.nodes().to_vec();
                            r.extend(rows.iter().filter(|&&n| mesh.fixed[n as usize]));
                            rows = r;
                            for (i, &n) in rows.iter().enumerate() {
                                row_of_node[n as usize] = i as u32;
                            }
                        }
                        let row_of: Vec<u32> =
                            g.nodes().iter().map(|&n| row_of_node[n as usize]).collect();
                        gram = Some((g, w, row_of));
                    }
                }
            }
        }
        let units = if gram.is_none() && how != Method::Full {
            let d = &stiff.dofs;
            crate::fem::gram::UnitSolver::new(
                &factor,
                rows.iter()
                    .flat_map(|&r| (0..3).filter_map(move |a| d.free(r, a))),
            )
        } else {
            None
        };
        let sweeper = if units.is_none() && factor.is_mapped() {
            crate::fem::gram::UnitSolver::new(&factor, std::iter::empty())
        } else {
            None
        };
        Ok(ColumnPlan {
            rows,
            l_rows,
            cols,
            phases,
            stiff,
            factor,
            units,
            sweeper,
            gram,
            mirror_from: None,
            pool: std::sync::Mutex::new(Vec::new()),
        })
    }

    /// For a symmetric plan (every displayed free node touchable, Gram method), promises
    /// that the batches from column `first` on will all be at hand after [`ColumnPlan::solve`]:
    /// the solve then leaves a batch's rows `first .. its first column` zero, and
    /// [`ColumnPlan::mirror`] fills them from those batches' lower rows, halving the products.
    /// Returns whether the plan is symmetric (otherwise the batches come out complete).
    pub(crate) fn mirror_from(&mut self, first: usize) -> bool {
        let sym = self.gram.as_ref().is_some_and(|g| g.0.symmetric());
        self.mirror_from = sym.then_some(first);
        sym
    }

    /// Fills the rows left for mirroring in batch `b`'s `data` (see
    /// [`ColumnPlan::mirror_from`]): `read(dof column q, first row, out)` must give rows
    /// `first .. first + out.len()` of DOF column `q` of an earlier batch. Returns the DOF
    /// rows filled.
    pub fn mirror<E>(
        &self,
        b: usize,
        data: &mut [f64],
        read: &mut ReadRows<'_, E>,
    ) -> Result<std::ops::Range<usize>, E> {
        let rows = self.mirror_rows(b);
        let chunk = self.batch_cols(b);
        let nr3 = 3 * self.l_rows;
        let k = 3 * chunk.len();
        let mut vals = vec![0.0f64; k];
        for q in rows.clone() {
            read(q, 3 * chunk.start, &mut vals)?;
            for (j, v) in vals.iter().enumerate() {
                data[j * nr3 + q] = *v;
            }
        }
        Ok(rows)
    }

    /// The DOF rows of batch `b` that [`ColumnPlan::mirror`] fills (empty unless the plan
    /// mirrors): the solve leaves them zero, so a first write may skip them.
    pub(crate) fn mirror_rows(&self, b: usize) -> std::ops::Range<usize> {
        let Some(first) = self.mirror_from else {
            return 0..0;
        };
        let start = self.batch_cols(b).start;
        3 * first.min(start)..3 * start
    }

    /// Free DOFs of K.
    pub fn free_dofs(&self) -> usize {
        self.stiff.dofs.n_free
    }

    /// Number of column batches.
    pub fn batches(&self) -> usize {
        self.cols.len().div_ceil(BATCH_COLS)
    }

    /// The column indices of batch `b`.
    pub(crate) fn batch_cols(&self, b: usize) -> std::ops::Range<usize> {
        let lo = (b * BATCH_COLS).min(self.cols.len());
        lo..(lo + BATCH_COLS).min(self.cols.len())
    }

    /// A zeroed batch buffer of `len` values, reused from the pool when one is there. A 45k
    /// mesh's batch is 46 MB, above glibc's largest `mmap` threshold (32 MB): each fresh one
    /// came from new pages (17.5k nodes with every large allocation mapped: 14.3 → 17.6–18.6 s).
    pub(crate) fn buffer(&self, len: usize) -> Vec<f64> {
        let mut v = self
            .pool
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .pop()
            .unwrap_or_default();
        v.clear();
        v.resize(len, 0.0);
        v
    }

    /// Hands a batch buffer back for the next batches.
    pub(crate) fn give_back(&self, v: Vec<f64>) {
        self.pool.lock().unwrap_or_else(|e| e.into_inner()).push(v);
    }

    /// Solves the batches `batches` (indices on the batch grid) on all cores. For each batch, `sink(b, data)` receives its
    /// slice of L (`9·R'·batch columns` f64, R' = [`ColumnPlan::l_rows`], this module's layout) from whichever worker solved
    /// it; a sink returning `false` stops the work (the caller keeps its own error). Returns
    /// max |K·x − e| over one checked DOF column per batch and the slowest worker's seconds
    /// solving, checking and scattering. `progress(columns done)` is called on the calling
    /// thread now and then.
    pub fn solve(
        &self,
        batches: &[usize],
        sink: &(dyn Fn(usize, &mut [f64]) -> bool + Sync),
        progress: &mut dyn FnMut(usize),
    ) -> Result<(f64, [f64; 3]), FemError> {
        self.solve_until(
            batches,
            sink,
            progress,
            &std::sync::atomic::AtomicBool::new(false),
        )
    }

    /// As [`ColumnPlan::solve`], with the stop flag the caller's: it is set when a sink
    /// returns `false` or a worker fails, and a sink that waits for another batch must give
    /// up when it is set. Workers take `batches` in the order given.
    pub(crate) fn solve_until(
        &self,
        batches: &[usize],
        sink: &(dyn Fn(usize, &mut [f64]) -> bool + Sync),
        progress: &mut dyn FnMut(usize),
        stop: &std::sync::atomic::AtomicBool,
    ) -> Result<(f64, [f64; 3]), FemError> {
        if let Some(u) = &self.units {
            return self.solve_pruned(batches, sink, progress, stop, u);
        }
        let workers = solver_threads().min(batches.len().max(1));
        let next = std::sync::atomic::AtomicUsize::new(0);
        let done = std::sync::atomic::AtomicUsize::new(0);
        let work = |progress: &mut dyn FnMut(usize)| -> Result<(f64, [f64; 3]), FemError> {
            use std::sync::atomic::Ordering::Relaxed;
            let mut acc = (0.0f64, [0.0f64; 3]);
            loop {
                if stop.load(Relaxed) {
                    return Ok(acc);
                }
                let Some(&b) = batches.get(next.fetch_add(1, Relaxed)) else {
                    return Ok(acc);
                };
                let (res, t, mut data) = self.solve_batch(b).inspect_err(|_| {
                    stop.store(true, Relaxed);
                })?;
                acc.0 = acc.0.max(res);
                for (a, v) in acc.1.iter_mut().zip(t) {
                    *a += v;
                }
                if !sink(b, &mut data) {
                    stop.store(true, Relaxed);
                }
                self.give_back(data);
                let d = done.fetch_add(self.batch_cols(b).len(), Relaxed);
                progress(d + self.batch_cols(b).len());
            }
        };
        run_workers(workers, &work, progress)
    }

    /// [`ColumnPlan::solve_until`] for the column method's pruned sweeps: the work is shared
    /// out by groups of [`SOLVE_COLS`] column nodes, not whole batches, so a few batches keep
    /// every core busy (the 45k organ's ball: 5 batches, 10 groups). A batch goes to the sink
    /// once its last group is in, from the worker that solved that group, after its first
    /// column's check.
    pub(crate) fn solve_pruned(
        &self,
        batches: &[usize],
        sink: &(dyn Fn(usize, &mut [f64]) -> bool + Sync),
        progress: &mut dyn FnMut(usize),
        stop: &std::sync::atomic::AtomicBool,
        u: &crate::fem::gram::UnitSolver,
    ) -> Result<(f64, [f64; 3]), FemError> {
        use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};
        let groups = |b: usize| self.batch_cols(b).len().div_ceil(SOLVE_COLS);
        let units: Vec<(usize, usize)> = batches
            .iter()
            .enumerate()
            .flat_map(|(i, &b)| (0..groups(b)).map(move |g| (i, g)))
            .collect();
        // Each batch's slice of L while its groups come in, and the groups still out.
        let pending: Vec<(std::sync::Mutex<Vec<f64>>, AtomicUsize)> = batches
            .iter()
            .map(|&b| {
                (
                    std::sync::Mutex::new(Vec::new()),
                    AtomicUsize::new(groups(b)),
                )
            })
            .collect();
        let workers = solver_threads().min(units.len().max(1));
        let next = AtomicUsize::new(0);
        let done = AtomicUsize::new(0);
        // Rows of a solve: every unknown of the system (a mixed one's pressures too).
        let (nr, nf) = (self.l_rows, self.stiff.n());
        let per = 3 * SOLVE_COLS;
        let work = |progress: &mut dyn FnMut(usize)| -> Result<(f64, [f64; 3]), FemError> {
            let mut acc = (0.0f64, [0.0f64; 3]);
            let mut x = Mat::<f64>::zeros(nf, 0);
            loop {
                if stop.load(Relaxed) {
                    return Ok(acc);
                }
                let Some(&(i, g)) = units.get(next.fetch_add(1, Relaxed)) else {
                    return Ok(acc);
                };
                let b = batches[i];
                let chunk = self.batch_cols(b);
                let mut dofs = Vec::with_capacity(per);
                for ci in chunk.clone().skip(g * SOLVE_COLS).take(SOLVE_COLS) {
                    for a in 0..3 {
                        dofs.push(self.first_dof(self.cols[ci])? + a);
                    }
                }
                let ts = Stopwatch::start();
                if x.ncols() < dofs.len() {
                    x = Mat::zeros(nf, per);
                } else {
                    x.fill(0.0);
                }
                let mut xg = x.as_mut().subcols_mut(0, dofs.len());
                u.solve(&self.factor, &dofs, xg.rb_mut());
                acc.1[0] += ts.elapsed().as_secs_f64();
                let tsc = Stopwatch::start();
                {
                    let mut out = pending[i].0.lock().unwrap_or_else(|e| e.into_inner());
                    if out.is_empty() {
                        *out = self.buffer(9 * nr * chunk.len());
                    }
                    for jj in 0..dofs.len() {
                        let xc = xg.rb().col(jj);
                        let j = g * per + jj;
                        self.scatter_rows(|d| xc[u.row(d)], &mut out[j * 3 * nr..][..3 * nr])
                            .inspect_err(|_| stop.store(true, Relaxed))?;
                    }
                }
                acc.1[2] += tsc.elapsed().as_secs_f64();
                if pending[i].1.fetch_sub(1, Relaxed) != 1 {
                    continue;
                }
                // The batch's last group: check its first column, hand it over.
                let mut out =
                    std::mem::take(&mut *pending[i].0.lock().unwrap_or_else(|e| e.into_inner()));
                let tc = Stopwatch::start();
                let node = self.cols[chunk.start];
                let (xs, residual) = self
                    .check_solve(node)
                    .and_then(|(xs, r)| self.agrees(&out, &xs, |_| true, node).map(|_| (xs, r)))
                    .inspect_err(|_| stop.store(true, Relaxed))?;
                drop(xs);
                acc.1[1] += tc.elapsed().as_secs_f64();
                acc.0 = acc.0.max(residual);
                if !sink(b, &mut out) {
                    stop.store(true, Relaxed);
                }
                self.give_back(out);
                let d = done.fetch_add(chunk.len(), Relaxed);
                progress(d + chunk.len());
            }
        };
        run_workers(workers, &work, progress)
    }

    /// Products with blocks of `L` through the Gram method's `W` (`None` without it).
    pub(crate) fn gram_products(&self) -> Option<GramProducts<'_>> {
        let (gp, w, row_of) = self.gram.as_ref()?;
        let mut pos_of_row = vec![usize::MAX; self.rows.len()];
        for (g, &r) in row_of.iter().enumerate() {
            pos_of_row[r as usize] = g;
        }
        let at: std::collections::HashMap<u32, usize> =
            self.rows.iter().enumerate().map(|(i, &n)| (n, i)).collect();
        let pos_of_col = self
            .cols
            .iter()
            .map(|n| at.get(n).map(|&r| pos_of_row[r]))
            .collect::<Option<Vec<usize>>>()?;
        if pos_of_col.contains(&usize::MAX) {
            return None;
        }
        Some(GramProducts {
            gp,
            w,
            pos_of_row,
            pos_of_col,
        })
    }

    /// The columns `want` (column indices, any order) of `L` for the hierarchical build, on
    /// all cores: `3R' × 3|want|` column-major (R' = [`ColumnPlan::l_rows`], rows by index),
    /// column `3q + b` for `want[q]` axis `b`. With `check`, the first column is checked
    /// against a direct solve. Returns the columns, the check's residual and the seconds solving, checking and
    /// scattering (summed over workers).
    ///
    /// The columns come in groups (ranges of `want` covering it), each with the rows it needs
    /// (`None`: all): the Gram method's tiles then compute only those rows (the other methods
    /// solve every row); the first column's rows of its group are the ones checked.
    pub(crate) fn solve_col_groups(
        &self,
        want: &[u32],
        parts: &[(std::ops::Range<usize>, Option<Vec<bool>>)],
        check: bool,
    ) -> Result<(Vec<f64>, f64, [f64; 3]), FemError> {
        use std::sync::atomic::{AtomicUsize, Ordering::Relaxed};
        let nr = self.l_rows;
        let ld = 3 * nr;
        if want.iter().any(|&c| c as usize >= self.cols.len()) {
            return Err(FemError::BadSelection(
                "a column index is out of range".into(),
            ));
        }
        if parts.iter().map(|p| p.0.len()).sum::<usize>() != want.len()
            || parts.iter().any(|p| p.0.end > want.len())
            || parts
                .iter()
                .any(|p| p.1.as_ref().is_some_and(|n| n.len() < self.l_rows))
        {
            return Err(FemError::BadSelection(
                "column groups do not cover the columns".into(),
            ));
        }
        // Groups of columns solved together; the Gram tiles want ascending indices.
        let mut order: Vec<usize> = (0..want.len()).collect();
        let per = if self.gram.is_some() {
            BATCH_COLS
        } else {
            SOLVE_COLS
        };
        let mut groups: Vec<(&[usize], usize)> = Vec::new();
        for (r, _) in parts {
            let o = &mut order[r.clone()];
            if self.gram.is_some() {
                o.sort_by_key(|&q| want[q]);
            }
        }
        for (pi, (r, _)) in parts.iter().enumerate() {
            // A part of the caller's is one group when it is not much wider than a batch.
            let per = if r.len() <= 2 * per {
                r.len().max(1)
            } else {
                per
            };
            groups.extend(order[r.clone()].chunks(per).map(|g| (g, pi)));
        }
        // The rows wanted, in the Gram plan's node order (the other methods solve every row).
        let gram_rows: Vec<Option<Vec<bool>>> = parts
            .iter()
            .map(|(_, need)| match (&self.gram, need) {
                (Some((_, _, row_of)), Some(need)) => {
                    Some(row_of.iter().map(|&r| need[r as usize]).collect())
                }
                _ => None,
            })
            .collect();
        let next = AtomicUsize::new(0);
        let work = || -> Result<GroupsSolved, FemError> {
            let mut got = Vec::new();
            let mut t = [0.0f64; 3];
            loop {
                let gi = next.fetch_add(1, Relaxed);
                let Some(&(g, pi)) = groups.get(gi) else {
                    return Ok((got, t));
                };
                let cols: Vec<usize> = g.iter().map(|&q| want[q] as usize).collect();
                let mut out = vec![0.0f64; ld * 3 * cols.len()];
                let ts = Stopwatch::start();
                if let Some((gp, w, row_of)) = &self.gram {
                    let m = 3 * gp.nodes().len();
                    let mut tile = vec![0.0f64; m * 3 * cols.len()];
                    gp.tile_cols(w, &cols, gram_rows[pi].as_deref(), &mut tile, m);
                    t[0] += ts.elapsed().as_secs_f64();
                    let tsc = Stopwatch::start();
                    for j in 0..3 * cols.len() {
                        let (src, dst) = (&tile[j * m..][..m], &mut out[j * ld..][..ld]);
                        for (gi, &ri) in row_of.iter().enumerate() {
                            for a in 0..3 {
                                let v = src[3 * gi + a];
                                if !v.is_finite() {
                                    return Err(FemError::Singular {
                                        node: gp.nodes()[gi],
                                        dof: a,
                                    });
                                }
                                dst[3 * ri as usize + a] = v;
                            }
                        }
                    }
                    t[2] += tsc.elapsed().as_secs_f64();
                } else {
                    let nf = self.stiff.n();
                    let mut dofs = Vec::with_capacity(3 * cols.len());
                    for &ci in &cols {
                        let d = self.first_dof(self.cols[ci])?;
                        dofs.extend([d, d + 1, d + 2]);
                    }
                    let mut x = Mat::<f64>::zeros(nf, dofs.len());
                    match &self.units {
                        Some(u) => u.solve(&self.factor, &dofs, x.as_mut()),
                        None => {
                            for (j, &d) in dofs.iter().enumerate() {
                                x[(d, j)] = 1.0;
                            }
                            self.factor.solve_in_place(&mut x);
                        }
                    }
                    t[0] += ts.elapsed().as_secs_f64();
                    let tsc = Stopwatch::start();
                    for j in 0..dofs.len() {
                        let xc = x.col(j);
                        let dst = &mut out[j * ld..][..ld];
                        match &self.units {
                            Some(u) => self.scatter_rows(|d| xc[u.row(d)], dst)?,
                            None => self.scatter_rows(|d| xc[d], dst)?,
                        }
                    }
                    t[2] += tsc.elapsed().as_secs_f64();
                }
                got.push((gi, out));
            }
        };
        let workers = solver_threads().min(groups.len()).max(1);
        let results = crate::threads::fan_out(workers, work, |_| work());
        let mut out = vec![0.0f64; ld * 3 * want.len()];
        let mut times = [0.0f64; 3];
        for r in results {
            let (got, t) = r.unwrap_or_else(|_| {
                Err(FemError::Factorisation("a solver thread panicked".into()))
            })?;
            for (a, v) in times.iter_mut().zip(t) {
                *a += v;
            }
            for (gi, data) in got {
                for (k, &q) in groups[gi].0.iter().enumerate() {
                    out[3 * q * ld..][..3 * ld].copy_from_slice(&data[3 * k * ld..][..3 * ld]);
                }
            }
        }
        let mut residual = 0.0;
        if let Some((r0, need)) = parts.iter().find(|p| check && !p.0.is_empty()) {
            let tc = Stopwatch::start();
            let q0 = r0.start;
            let node = self.cols[want[q0] as usize];
            let (xs, r) = self.check_solve(node)?;
            let at = &out[3 * q0 * ld..][..3 * ld];
            self.agrees(at, &xs, |ri| need.as_ref().is_none_or(|n| n[ri]), node)?;
            residual = r;
            times[1] += tc.elapsed().as_secs_f64();
        }
        Ok((out, residual, times))
    }

    /// Solves one batch: its slice of L, the residual of its checked column and the seconds
    /// spent solving, checking and scattering.
    pub(crate) fn solve_batch(&self, batch: usize) -> Result<(f64, [f64; 3], Vec<f64>), FemError> {
        if let Some((g, w, row_of)) = &self.gram {
            return self.gram_batch(batch, g, w, row_of);
        }
        let nr = self.l_rows;
        let nf = self.stiff.n();
        let chunk = self.batch_cols(batch);
        let mut times = [0.0f64; 3];
        let mut b = Mat::<f64>::zeros(nf, 3 * chunk.len());
        for (k, ci) in chunk.clone().enumerate() {
            for a in 0..3 {
                let d = self
                    .stiff
                    .dofs
                    .free(self.cols[ci], a)
                    .ok_or(FemError::BadSelection("a touchable node is clamped".into()))?;
                b[(d, 3 * k + a)] = 1.0;
            }
        }
        let ts = Stopwatch::start();
        self.factor.solve_in_place(&mut b);
        times[0] += ts.elapsed().as_secs_f64();
        let tc = Stopwatch::start();
        // The check K·x = e costs about as much as a solve per column: it is done on one DOF
        // column per batch (the batch's first), which catches a bad factorisation all the same.
        let residual = {
            let node = self.cols[chunk.start];
            let e = self.first_dof(node)?;
            let xs: Vec<f64> = (0..nf).map(|i| b[(i, 0)]).collect();
            if xs.iter().any(|v| !v.is_finite()) {
                return Err(FemError::Singular { node, dof: e });
            }
            self.unit_residual(&xs, e)
        };
        times[1] += tc.elapsed().as_secs_f64();
        let tsc = Stopwatch::start();
        let mut out = self.buffer(9 * nr * chunk.len());
        for j in 0..3 * chunk.len() {
            let x = b.col(j);
            self.scatter_rows(|d| x[d], &mut out[j * 3 * nr..][..3 * nr])?;
        }
        times[2] += tsc.elapsed().as_secs_f64();
        Ok((residual, times, out))
    }

    /// One DOF column of `L` into `dst` (3R', this module's layout): each stored row's
    /// entries from `x(free DOF)`; a non-finite value is [`FemError::Singular`].
    pub(crate) fn scatter_rows(
        &self,
        x: impl Fn(usize) -> f64,
        dst: &mut [f64],
    ) -> Result<(), FemError> {
        for (ri, &r) in self.rows[..self.l_rows].iter().enumerate() {
            for a in 0..3 {
                if let Some(d) = self.stiff.dofs.free(r, a) {
                    let v = x(d);
                    if !v.is_finite() {
                        return Err(FemError::Singular { node: r, dof: d });
                    }
                    dst[3 * ri + a] = v;
                }
            }
        }
        Ok(())
    }

    /// Checks that the batch's first column `out` (this module's layout) equals the direct
    /// solve `xs` on the displayed rows `keep(row)` accepts, to 1e-8 of max |x|.
    pub(crate) fn agrees(
        &self,
        out: &[f64],
        xs: &[f64],
        keep: impl Fn(usize) -> bool,
        node: u32,
    ) -> Result<(), FemError> {
        let scale = xs.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        let mut diff = 0.0f64;
        for (ri, &r) in self.rows[..self.l_rows].iter().enumerate() {
            if !keep(ri) {
                continue; // mirrored later, or not wanted
            }
            for a in 0..3 {
                if let Some(d) = self.stiff.dofs.free(r, a) {
                    diff = diff.max((out[3 * ri + a] - xs[d]).abs());
                }
            }
        }
        if diff.is_nan() || diff > 1e-8 * scale {
            return Err(FemError::Factorisation(format!(
                "the computed column disagrees with a direct solve by {:.1e} of max |L| \
                 (column of node {node})",
                diff / scale
            )));
        }
        Ok(())
    }

    /// The free DOF of a touchable node's x axis.
    pub(crate) fn first_dof(&self, node: u32) -> Result<usize, FemError> {
        self.stiff
            .dofs
            .free(node, 0)
            .ok_or(FemError::BadSelection("a touchable node is clamped".into()))
    }

    /// faer's full solve of `K x = e` for `node`'s x axis, and its residual max |K·x − e|:
    /// the independent check of the pruned and Gram batches.
    pub(crate) fn check_solve(&self, node: u32) -> Result<(Vec<f64>, f64), FemError> {
        let e = self.first_dof(node)?;
        let nf = self.stiff.n();
        let mut b = Mat::<f64>::zeros(nf, 1);
        let sweeps = self.units.as_ref().or(self.sweeper.as_ref());
        let xs: Vec<f64> = match sweeps.filter(|_| self.factor.is_mapped()) {
            // A factor in a file: a sweep that drops the pages behind it (faer's solve
            // would map the whole factor into this process).
            Some(u) => {
                u.solve_full(&self.factor, &[e], b.as_mut());
                (0..nf).map(|d| b[(u.row(d), 0)]).collect()
            }
            None => {
                b[(e, 0)] = 1.0;
                self.factor.solve_in_place(&mut b);
                (0..nf).map(|i| b[(i, 0)]).collect()
            }
        };
        let residual = self.unit_residual(&xs, e);
        Ok((xs, residual))
    }

    /// max |K·x − e_e| for a solution `x` of K·x = e_e.
    pub(crate) fn unit_residual(&self, x: &[f64], e: usize) -> f64 {
        let mut kx = vec![0.0; x.len()];
        self.stiff.mul(x, &mut kx);
        kx.iter().enumerate().fold(0.0f64, |r, (i, v)| {
            let target = if i == e { 1.0 } else { 0.0 };
            r.max((v - target).abs())
        })
    }

    /// The Gram method's batch: its tile of `(K⁻¹)[S, T]` moved into this module's layout;
    /// every [`GRAM_CHECK_EVERY`]th batch compares its first column with a direct solve.
    pub(crate) fn gram_batch(
        &self,
        batch: usize,
        g: &crate::fem::gram::GramPlan,
        w: &[f64],
        row_of: &[u32],
    ) -> Result<(f64, [f64; 3], Vec<f64>), FemError> {
        let nr = self.l_rows;
        let chunk = self.batch_cols(batch);
        let mut times = [0.0f64; 3];
        let m = 3 * g.nodes().len();
        let nt = 3 * chunk.len();
        let ts = Stopwatch::start();
        let skip = match self.mirror_from {
            Some(first) => first.min(chunk.start)..chunk.start,
            None => 0..0,
        };
        let mut out = self.buffer(9 * nr * chunk.len());
        // Rows in Gram order (symmetric plans): the products land in the batch itself.
        let in_order = row_of.iter().enumerate().all(|(g, &r)| g == r as usize);
        if in_order {
            g.tile(w, chunk.start, chunk.end, skip.clone(), &mut out, 3 * nr);
            times[0] = ts.elapsed().as_secs_f64();
            if let Some(i) = out.iter().position(|v| !v.is_finite()) {
                let gi = (i % (3 * nr)) / 3;
                return Err(FemError::Singular {
                    node: self.rows[gi],
                    dof: i % 3,
                });
            }
        }
        let mut tile = Vec::new();
        if !in_order {
            tile.resize(m * nt, 0.0f64);
            g.tile(w, chunk.start, chunk.end, skip.clone(), &mut tile, m);
            times[0] = ts.elapsed().as_secs_f64();
        }
        let tsc = Stopwatch::start();
        // Otherwise each row moves to its place in this module's layout.
        for j in (0..nt).filter(|_| !in_order) {
            let src = &tile[j * m..][..m];
            let dst = &mut out[j * 3 * nr..][..3 * nr];
            for (gi, &ri) in row_of.iter().enumerate() {
                for a in 0..3 {
                    let v = src[3 * gi + a];
                    if !v.is_finite() {
                        return Err(FemError::Singular {
                            node: g.nodes()[gi],
                            dof: a,
                        });
                    }
                    dst[3 * ri as usize + a] = v;
                }
            }
        }
        times[2] = tsc.elapsed().as_secs_f64();
        let tc = Stopwatch::start();
        let mut residual = 0.0f64;
        if batch.is_multiple_of(GRAM_CHECK_EVERY) {
            let node = self.cols[chunk.start];
            let (xs, r) = self.check_solve(node)?;
            residual = r;
            // The Gram column must be the direct solve's displayed rows.
            self.agrees(&out, &xs, |ri| !skip.contains(&ri), node)?;
        }
        times[1] = tc.elapsed().as_secs_f64();
        Ok((residual, times, out))
    }
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use crate::compliance::{Compliance, Method, Selection};
    use crate::fem::locking_free::tests::{condensed_inverse, two_region_block};
    use crate::fem::locking_free::{stiffness, Smoothing};
    use crate::fem::FactorStore;

    /// Every precompute method, both factor stores, on the locking-free formulation's
    /// (stabilised) system: `L` against the inverse of its condensed stiffness, formed
    /// densely (`fem::locking_free`'s check holds the system itself to it).
    #[cfg_attr(test, test)]
    pub(crate) fn every_method_gives_the_locking_free_compliance() {
        let m = two_region_block();
        let assembled = stiffness(&m, Smoothing::Nodal).expect("K");
        let (dense_inv, dscale) = condensed_inverse(&m, &assembled, Smoothing::CHOSEN);
        // The factor in a file needs the `native` feature.
        let mut stores = vec![FactorStore::Heap];
        if cfg!(feature = "native") {
            stores.push(FactorStore::File {
                dir: std::env::temp_dir(),
                threads: 2,
            });
        }
        let sel = Selection::default();
        for how in [Method::Columns, Method::Full, Method::Gram] {
            for store in &stores {
                let c = Compliance::compute_in(&m, &sel, how, store, &mut |_, _| {}).expect("L");
                let mut worst = 0.0f64;
                for (ci, &cn) in c.cols().iter().enumerate() {
                    for (ri, &rn) in c.rows().iter().enumerate() {
                        let got = c.block(ri, ci);
                        for a in 0..3 {
                            for b in 0..3 {
                                let (Some(r), Some(k)) =
                                    (assembled.dofs.free(rn, a), assembled.dofs.free(cn, b))
                                else {
                                    continue;
                                };
                                let g = got.col(b)[a];
                                worst = worst.max((g - dense_inv[(r, k)]).abs());
                            }
                        }
                    }
                }
                assert!(worst <= 1e-9 * dscale, "{how:?} {store:?}: {worst:e}");
            }
        }
    }
}
