//! Compression of one block to a tolerance (Halko, Martinsson & Tropp 2011): from its values,
//! a randomized range finder whose error is measured exactly, then the SVD of the small
//! projected block (§4.4 with the exact residual instead of the probabilistic estimate); seen
//! only through products, a sketch with held-out probes (§4.3) and the same SVD.

use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatRef, Par};

use super::HError;

/// Columns added to the range basis per step.
const STEP: usize = 16;

/// A block as stored: dense (column-major) or factors `U` (m × k, column-major, scaled by the
/// singular values) then `V` (n × k, row-major: one column DOF's k weights together).
pub(super) struct Compressed {
    /// `None`: dense; `Some(k)`: rank-k factors.
    pub rank: Option<u32>,
    pub data: Vec<f64>,
    /// ‖B‖_F².
    pub norm_sq: f64,
    /// ‖B − stored‖_F², measured.
    pub discarded_sq: f64,
}

/// Stores the `m × n` block `b` (column-major): dense when near, or when factors within
/// `tol·‖B‖_F` would take no less room; otherwise as factors with
/// `‖B − UVᵀ‖_F ≤ tol·‖B‖_F`, the error measured on the block itself. `seed` fixes the random
/// test vectors (the result does not depend on threads or the order of blocks).
pub(super) fn compress(
    b: &[f64],
    m: usize,
    n: usize,
    far: bool,
    tol: f64,
    seed: u64,
) -> Result<Compressed, HError> {
    let norm_sq: f64 = b.iter().map(|v| v * v).sum();
    let dense = || Compressed {
        rank: None,
        data: b.to_vec(),
        norm_sq,
        discarded_sq: 0.0,
    };
    // The largest rank whose factors are smaller than the block.
    let k_max = (m * n).saturating_sub(1) / (m + n).max(1);
    if !far || k_max == 0 {
        return Ok(dense());
    }
    let budget = tol * tol * norm_sq;
    let bm = MatRef::from_column_major_slice(b, m, n);
    if norm_sq == 0.0 {
        return Ok(Compressed {
            rank: Some(0),
            data: Vec::new(),
            norm_sq,
            discarded_sq: 0.0,
        });
    }
    // The range basis: a small block's comes from its SVD directly.
    let (q, c) = if m.min(n) <= 2 * STEP {
        (None, bm.to_owned())
    } else {
        let mut rng = SplitMix(seed);
        let mut q = Mat::<f64>::zeros(m, 0);
        let mut c = Mat::<f64>::zeros(0, n);
        let mut c_sq = 0.0f64;
        loop {
            if q.ncols() >= m.min(n) {
                break;
            }
            if q.ncols() >= k_max + STEP {
                return Ok(dense());
            }
            let p = STEP.min(m.min(n) - q.ncols());
            let omega = Mat::<f64>::from_fn(n, p, |_, _| rng.gaussian());
            let mut y = Mat::<f64>::zeros(m, p);
            matmul(
                y.as_mut(),
                Accum::Replace,
                bm,
                omega.as_ref(),
                1.0,
                Par::Seq,
            );
            // Twice against the basis so far (one pass loses orthogonality in rounding).
            for _ in 0..2 {
                if q.ncols() > 0 {
                    let mut qy = Mat::<f64>::zeros(q.ncols(), p);
                    matmul(
                        qy.as_mut(),
                        Accum::Replace,
                        q.transpose(),
                        y.as_ref(),
                        1.0,
                        Par::Seq,
                    );
                    matmul(
                        y.as_mut(),
                        Accum::Add,
                        q.as_ref(),
                        qy.as_ref(),
                        -1.0,
                        Par::Seq,
                    );
                }
            }
            let qy = y.qr().compute_thin_Q();
            let mut cy = Mat::<f64>::zeros(p, n);
            matmul(
                cy.as_mut(),
                Accum::Replace,
                qy.transpose(),
                bm,
                1.0,
                Par::Seq,
            );
            let add: f64 = cy.col_iter().map(|v| v.squared_norm_l2()).sum();
            q = concat_cols(q.as_ref(), qy.as_ref());
            c = concat_rows(c.as_ref(), cy.as_ref());
            c_sq += add;
            // ‖B − QQᵀB‖² = ‖B‖² − ‖QᵀB‖²; half the budget is left for the truncation.
            if norm_sq - c_sq <= 0.5 * budget || add <= 1e-30 * norm_sq {
                break;
            }
        }
        (Some(q), c)
    };
    let svd = c.thin_svd().map_err(|_| HError::Svd(c.nrows(), n))?;
    let s = svd.S().column_vector();
    let ns = s.nrows();
    // What the projection left out, then the smallest k whose tail fits the rest.
    let proj_sq = match &q {
        Some(_) => (norm_sq - (0..ns).map(|i| s[i] * s[i]).sum::<f64>()).max(0.0),
        None => 0.0,
    };
    let (mut k, mut tail) = (ns, 0.0);
    while k > 0 && proj_sq + tail + s[k - 1] * s[k - 1] <= budget {
        tail += s[k - 1] * s[k - 1];
        k -= 1;
    }
    if k > k_max {
        return Ok(dense());
    }
    let mut us = Mat::<f64>::from_fn(svd.U().nrows(), k, |i, l| svd.U()[(i, l)] * s[l]);
    if let Some(q) = &q {
        let mut u = Mat::<f64>::zeros(m, k);
        matmul(
            u.as_mut(),
            Accum::Replace,
            q.as_ref(),
            us.as_ref(),
            1.0,
            Par::Seq,
        );
        us = u;
    }
    let v = svd.V();
    // The error, measured: ‖B − UVᵀ‖² (rounding may push it past the budget: dense then).
    let mut r = bm.to_owned();
    matmul(
        r.as_mut(),
        Accum::Add,
        us.as_ref(),
        v.subcols(0, k).transpose(),
        -1.0,
        Par::Seq,
    );
    let discarded_sq: f64 = r.col_iter().map(|v| v.squared_norm_l2()).sum();
    if discarded_sq > budget {
        return Ok(dense());
    }
    let mut data = Vec::with_capacity(k * (m + n));
    for l in 0..k {
        data.extend((0..m).map(|i| us[(i, l)]));
    }
    for j in 0..n {
        data.extend((0..k).map(|l| v[(j, l)]));
    }
    Ok(Compressed {
        rank: Some(k as u32),
        data,
        norm_sq,
        discarded_sq,
    })
}

/// Gaussian vectors a sketch holds out to estimate what its basis misses.
pub(super) const PROBES: usize = 10;

/// The factor on the probes' estimate of the residual before it is charged to the budget: the
/// estimate `‖(I − QQᵀ)BΩ'‖_F²/p` of `‖(I − QQᵀ)B‖_F²` (p = [`PROBES`] Gaussian columns) falls
/// below a tenth of it with probability below 2·10⁻⁴ (at worst `χ²₁₀ < 1`).
pub(super) const SAFETY: f64 = 10.0;

/// `products(transpose, X, out)`: `out = B·X` (`transpose` false) or `Bᵀ·X`.
pub(super) type Products<'a> =
    dyn FnMut(bool, MatRef<'_, f64>, faer::MatMut<'_, f64>) -> Result<(), HError> + 'a;

/// Compresses the far `m × n` block `B`, seen only through products with it, to `tol`: a
/// sketch `Y = BΩ` with `k` test vectors (starting at `k0`, doubled while short) and
/// [`PROBES`] more, `Q` an orthonormal basis of the first `k`, `Bᵀ Q` from a second product,
/// then the SVD of `QᵀB` truncated so that the probes' residual times [`SAFETY`] plus the
/// truncated tail stays within `tol²‖B‖_F²` (‖B‖_F² = ‖QᵀB‖_F² + the residual, estimated).
/// `None` when the factors would not pay (rank near the dense break-even): the caller then
/// computes the block and [`compress`]es it. Cost: `(2k + p)` vectors through the block
/// instead of all `n` columns.
pub(super) fn sketch(
    m: usize,
    n: usize,
    tol: f64,
    seed: u64,
    k0: usize,
    products: &mut Products<'_>,
) -> Result<Option<Compressed>, HError> {
    let mut rng = SplitMix(seed);
    let mut k = k0.max(1);
    loop {
        if !sketch_pays(m, n, k) {
            return Ok(None);
        }
        let omega = test_vectors(n, k + PROBES, &mut rng);
        let mut y = Mat::<f64>::zeros(m, k + PROBES);
        products(false, omega.as_ref(), y.as_mut())?;
        let (q, est) = basis(y.as_ref(), k)?;
        let mut c = Mat::<f64>::zeros(n, k);
        products(true, q.as_ref(), c.as_mut())?;
        match finish(m, n, tol, q.as_ref(), est, c.as_ref())? {
            Sketch::Short => k *= 2,
            Sketch::NotWorth => return Ok(None),
            Sketch::Done(c) => return Ok(Some(c)),
        }
    }
}

/// Whether a sketch with `k` vectors (and the probes) can still give factors that pay.
pub(super) fn sketch_pays(m: usize, n: usize, k: usize) -> bool {
    let k_max = (m * n).saturating_sub(1) / (m + n).max(1);
    k < k_max && k + PROBES < m.min(n)
}

/// `cols` Gaussian test vectors of length `n` from `rng`.
pub(super) fn test_vectors(n: usize, cols: usize, rng: &mut SplitMix) -> Mat<f64> {
    Mat::<f64>::from_fn(n, cols, |_, _| rng.gaussian())
}

/// From a sketch `Y = BΩ` (`k` + [`PROBES`] columns): `Q`, an orthonormal basis of its first
/// `k` columns, and the probes' estimate of `‖(I − QQᵀ)B‖_F²`.
pub(super) fn basis(y: MatRef<'_, f64>, k: usize) -> Result<(Mat<f64>, f64), HError> {
    if y.col_iter().any(|c| c.iter().any(|v| !v.is_finite())) {
        return Err(HError::NonFinite);
    }
    let q = y.subcols(0, k).qr().compute_thin_Q();
    let mut probe = y.subcols(k, PROBES).to_owned();
    for _ in 0..2 {
        let mut qp = Mat::<f64>::zeros(k, PROBES);
        matmul(
            qp.as_mut(),
            Accum::Replace,
            q.transpose(),
            probe.as_ref(),
            1.0,
            Par::Seq,
        );
        matmul(
            probe.as_mut(),
            Accum::Add,
            q.as_ref(),
            qp.as_ref(),
            -1.0,
            Par::Seq,
        );
    }
    let est: f64 = probe.col_iter().map(|c| c.squared_norm_l2()).sum::<f64>() / PROBES as f64;
    Ok((q, est))
}

/// What a sketch gave.
pub(super) enum Sketch {
    /// The factors, within the tolerance.
    Done(Compressed),
    /// The basis misses too much: sketch again with more vectors.
    Short,
    /// The factors would not pay.
    NotWorth,
}

/// Truncates a sketch: `q` the basis (`m × k`), `est` the probes' residual, `c = BᵀQ`
/// (`n × k`); see [`sketch`].
pub(super) fn finish(
    m: usize,
    n: usize,
    tol: f64,
    q: MatRef<'_, f64>,
    est: f64,
    c: MatRef<'_, f64>,
) -> Result<Sketch, HError> {
    let k = q.ncols();
    let k_max = (m * n).saturating_sub(1) / (m + n).max(1);
    if c.col_iter().any(|c| c.iter().any(|v| !v.is_finite())) {
        return Err(HError::NonFinite);
    }
    let c_sq: f64 = c.col_iter().map(|c| c.squared_norm_l2()).sum();
    let norm_sq = c_sq + est;
    let budget = tol * tol * norm_sq;
    if norm_sq == 0.0 {
        return Ok(Sketch::Done(Compressed {
            rank: Some(0),
            data: Vec::new(),
            norm_sq,
            discarded_sq: 0.0,
        }));
    }
    if SAFETY * est > 0.5 * budget {
        return Ok(Sketch::Short);
    }
    // QᵀB = Cᵀ = (V S Uᵀ)ᵀ with C = V S Uᵀ: B ≈ (Q U S) Vᵀ.
    let svd = c.thin_svd().map_err(|_| HError::Svd(n, k))?;
    let s = svd.S().column_vector();
    let (mut r, mut tail) = (s.nrows(), 0.0);
    while r > 0 && SAFETY * est + tail + s[r - 1] * s[r - 1] <= budget {
        tail += s[r - 1] * s[r - 1];
        r -= 1;
    }
    if r > k_max {
        return Ok(Sketch::NotWorth);
    }
    let (v, uq) = (svd.U(), svd.V());
    let mut us = Mat::<f64>::zeros(m, r);
    let uqs = Mat::<f64>::from_fn(k, r, |i, l| uq[(i, l)] * s[l]);
    matmul(us.as_mut(), Accum::Replace, q, uqs.as_ref(), 1.0, Par::Seq);
    let mut data = Vec::with_capacity(r * (m + n));
    for l in 0..r {
        data.extend((0..m).map(|i| us[(i, l)]));
    }
    for j in 0..n {
        data.extend((0..r).map(|l| v[(j, l)]));
    }
    Ok(Sketch::Done(Compressed {
        rank: Some(r as u32),
        data,
        norm_sq,
        discarded_sq: est + tail,
    }))
}

fn concat_cols(a: MatRef<'_, f64>, b: MatRef<'_, f64>) -> Mat<f64> {
    Mat::from_fn(a.nrows(), a.ncols() + b.ncols(), |i, j| {
        if j < a.ncols() {
            a[(i, j)]
        } else {
            b[(i, j - a.ncols())]
        }
    })
}

fn concat_rows(a: MatRef<'_, f64>, b: MatRef<'_, f64>) -> Mat<f64> {
    Mat::from_fn(a.nrows() + b.nrows(), a.ncols(), |i, j| {
        if i < a.nrows() {
            a[(i, j)]
        } else {
            b[(i - a.nrows(), j)]
        }
    })
}

/// SplitMix64: a small deterministic generator for the test vectors.
pub(super) struct SplitMix(pub(super) u64);

impl SplitMix {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// A standard normal number (Box–Muller).
    fn gaussian(&mut self) -> f64 {
        let u1 = ((self.next() >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
        let u2 = (self.next() >> 11) as f64 / (1u64 << 53) as f64;
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    /// A `m × n` matrix with singular values `10^(-i/4)` (i = 0, 1, …) and random singular
    /// vectors: its best rank-r error is known exactly.
    fn decaying(m: usize, n: usize, seed: u64) -> (Mat<f64>, Vec<f64>) {
        let mut rng = SplitMix(seed);
        let r = m.min(n);
        let a = Mat::<f64>::from_fn(m, r, |_, _| rng.gaussian());
        let b = Mat::<f64>::from_fn(n, r, |_, _| rng.gaussian());
        let (u, v) = (a.qr().compute_thin_Q(), b.qr().compute_thin_Q());
        let s: Vec<f64> = (0..r).map(|i| 10f64.powf(-(i as f64) / 4.0)).collect();
        let us = Mat::<f64>::from_fn(m, r, |i, l| u[(i, l)] * s[l]);
        let mut out = Mat::<f64>::zeros(m, n);
        matmul(
            out.as_mut(),
            Accum::Replace,
            us.as_ref(),
            v.transpose(),
            1.0,
            Par::Seq,
        );
        (out, s)
    }

    /// The sketch, seeing the block only through products, meets the tolerance measured on
    /// the block, keeps a rank within 3 of the optimal one for the same error, and reports
    /// an error within a factor of the true one; a block whose rank does not pay is left to
    /// the caller.
    #[cfg_attr(test, test)]
    pub(crate) fn a_sketch_meets_the_tolerance_with_a_near_optimal_rank() {
        let (m, n) = (300, 240);
        for (seed, tol) in [(1u64, 1e-2), (2, 1e-3), (3, 1e-4), (4, 1e-6)] {
            let (b, s) = decaying(m, n, seed);
            let mut calls = 0;
            let mut through = |t: bool, x: MatRef<'_, f64>, out: faer::MatMut<'_, f64>| {
                calls += 1;
                let op = if t { b.transpose() } else { b.as_ref() };
                matmul(out, Accum::Replace, op, x, 1.0, Par::Seq);
                Ok(())
            };
            let c = sketch(m, n, tol, seed, 20, &mut through)
                .expect("sketch")
                .expect("pays");
            let k = c.rank.expect("factors") as usize;
            let u = MatRef::from_column_major_slice(&c.data[..m * k], m, k);
            let v = MatRef::from_row_major_slice(&c.data[m * k..], n, k);
            let mut r = b.clone();
            matmul(r.as_mut(), Accum::Add, u, v.transpose(), -1.0, Par::Seq);
            let err = r.norm_l2();
            let norm = b.norm_l2();
            assert!(err <= tol * norm, "{tol:e}: error {:e}", err / norm);
            // The smallest rank with this error, from the known spectrum.
            let total: f64 = s.iter().map(|x| x * x).sum();
            let best = (0..s.len())
                .find(|&r| s[r..].iter().map(|x| x * x).sum::<f64>() <= (err * err).max(0.0))
                .unwrap_or(s.len());
            assert!(k <= best + 3, "{tol:e}: rank {k}, optimal {best}");
            assert!(((c.norm_sq - total) / total).abs() < 1e-6, "{tol:e}: norm");
            let reported = c.discarded_sq.sqrt();
            assert!(
                reported <= 3.0 * err && err <= 3.0 * reported.max(1e-300),
                "{tol:e}: reported {reported:e}, true {err:e}"
            );
            assert!(calls >= 2);
        }
        // Full rank to the tolerance: the factors would not pay.
        let (b, _) = decaying(60, 50, 9);
        let mut through = |t: bool, x: MatRef<'_, f64>, out: faer::MatMut<'_, f64>| {
            let op = if t { b.transpose() } else { b.as_ref() };
            matmul(out, Accum::Replace, op, x, 1.0, Par::Seq);
            Ok(())
        };
        assert!(sketch(60, 50, 1e-12, 9, 20, &mut through)
            .expect("sketch")
            .is_none());
        // A product that returns a non-finite value is an error, not factors.
        let mut bad = |_: bool, _: MatRef<'_, f64>, mut out: faer::MatMut<'_, f64>| {
            out[(0, 0)] = f64::NAN;
            Ok(())
        };
        assert!(matches!(
            sketch(300, 240, 1e-3, 1, 20, &mut bad),
            Err(HError::NonFinite)
        ));
    }
}
