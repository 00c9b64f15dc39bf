//! Compression of one block to a tolerance: a randomized range finder whose error is measured
//! exactly, then the SVD of the small projected block (Halko, Martinsson & Tropp 2011, §4.4
//! with the exact residual instead of the probabilistic estimate).

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
struct SplitMix(u64);

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
