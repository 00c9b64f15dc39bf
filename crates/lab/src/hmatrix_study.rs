//! The hierarchical compliance, measured: for a mesh and a tolerance ε,
//! the storage of `HMatrix` against the dense `L`, its global error, the point-load
//! displacement errors (every touchable column, each axis, against the dense `L`; the loads
//! nearest the clamps apart), and the CPU matvec time for one finger's 9 active columns against
//! the dense [`Compliance::displace`].

use std::time::Instant;

use glam::DVec3;
use touchfem_core::compliance::hmatrix::HOptions;
use touchfem_core::compliance::{Compliance, Selection};
use touchfem_core::Mesh;

use crate::error::Error;
use crate::tradeoff::median_us;

/// One row: a mesh at one tolerance.
#[derive(Clone, Debug, serde::Serialize)]
pub struct HRow {
    /// Mesh name.
    pub mesh: String,
    /// Row nodes holding `L` (free displayed nodes).
    pub rows: usize,
    /// Column nodes (touchable).
    pub cols: usize,
    /// Block tolerance ε.
    pub tolerance: f64,
    /// Blocks in the partition.
    pub blocks: usize,
    /// Blocks stored low-rank.
    pub low_rank_blocks: usize,
    /// Mean rank of the low-rank blocks.
    pub mean_rank: f64,
    /// Largest rank.
    pub max_rank: usize,
    /// Values stored in f64, bytes.
    pub bytes_f64: usize,
    /// The same in f32 (a GPU copy), bytes.
    pub bytes_f32: usize,
    /// The dense `L` in f64, bytes.
    pub dense_bytes_f64: usize,
    /// Stored values over dense values (the same in f32 and f64).
    pub ratio: f64,
    /// `‖L − L_H‖_F / ‖L‖_F` (at most ε).
    pub frobenius_rel: f64,
    /// Relative L2 point-load displacement error: median over loads.
    pub l2_median: f64,
    /// The same: worst.
    pub l2_worst: f64,
    /// Relative max-norm point-load error: median.
    pub max_median: f64,
    /// The same: worst.
    pub max_worst: f64,
    /// Worst relative L2 error over the loads at the tenth of columns nearest a clamped node
    /// (`None` without clamped displayed nodes).
    pub l2_worst_near_clamps: Option<f64>,
    /// Build time from the dense `L`, s.
    pub build_s: f64,
    /// Matvec for 9 neighbouring active columns (one finger), median µs.
    pub finger_us: f64,
    /// The dense `displace` for the same forces, median µs.
    pub finger_dense_us: f64,
    /// Matvec for 9 spread-out active columns, median µs.
    pub spread_us: f64,
    /// The dense `displace` for the same forces, median µs.
    pub spread_dense_us: f64,
}

/// Rows for the cube and the mouse (default selection: surface rows, free-surface columns) at
/// each of `tolerances`; `reps` timing repetitions.
pub fn hmatrix_rows(tolerances: &[f64], reps: usize) -> Result<Vec<HRow>, Error> {
    let mut rows = Vec::new();
    for (name, mesh) in [
        ("cube", touchfem_core::mesh::cube()),
        ("mouse", touchfem_core::mesh::mouse()),
    ] {
        let c = Compliance::compute(&mesh, &Selection::default())?;
        for &eps in tolerances {
            rows.push(measure(name, &mesh, &c, eps, reps)?);
        }
    }
    Ok(rows)
}

fn sorted(v: &[f64]) -> Vec<f64> {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    v
}

/// The force of each of a test finger's columns, N.
const FINGER_FORCE: DVec3 = DVec3::new(0.2, -0.3, -1.0);

/// The columns `cols` (mesh nodes) by distance to the nearest of `points`, nearest first.
fn nearest_to(mesh: &Mesh, cols: &[u32], points: &[DVec3]) -> Vec<usize> {
    let mut d: Vec<(f64, usize)> = cols
        .iter()
        .enumerate()
        .map(|(k, &n)| {
            let p = mesh.nodes[n as usize];
            let d = points
                .iter()
                .map(|q| q.distance_squared(p))
                .fold(f64::INFINITY, f64::min);
            (d, k)
        })
        .collect();
    d.sort_by(|a, b| a.0.total_cmp(&b.0));
    d.into_iter().map(|x| x.1).collect()
}

/// One finger's forces: the middle column of `cols` and its 8 nearest columns, each
/// (0.2, −0.3, −1) N.
pub fn finger_forces(mesh: &Mesh, cols: &[u32]) -> Vec<(u32, DVec3)> {
    let centre = mesh.nodes[cols[cols.len() / 2] as usize];
    nearest_to(mesh, cols, &[centre])
        .into_iter()
        .take(9)
        .map(|k| (k as u32, FINGER_FORCE))
        .collect()
}

/// One row: `c` compressed at `eps` (η = 2, leaves of 32 nodes).
pub fn measure(
    name: &str,
    mesh: &Mesh,
    c: &Compliance,
    eps: f64,
    reps: usize,
) -> Result<HRow, Error> {
    measure_with(name, mesh, c, eps, reps).map(|r| r.0)
}

/// A row, its hierarchical `L` and the finger's forces it timed.
type Measured = (
    HRow,
    touchfem_core::compliance::hmatrix::HMatrix,
    Vec<(u32, DVec3)>,
);

/// As [`measure`], with the hierarchical `L` and the finger's forces it timed.
fn measure_with(
    name: &str,
    mesh: &Mesh,
    c: &Compliance,
    eps: f64,
    reps: usize,
) -> Result<Measured, Error> {
    let t = Instant::now();
    let h = c.compress(mesh, &HOptions::new(eps))?;
    let build_s = t.elapsed().as_secs_f64();
    let ranks: Vec<usize> = h.blocks().filter_map(|b| b.rank).collect();
    let e = c.load_errors(&h);
    let (l2, mx) = (sorted(&e.l2), sorted(&e.max));
    let pick = |v: &[f64], q: f64| v[((v.len() - 1) as f64 * q).round() as usize];

    // Columns by distance to the nearest clamped displayed node.
    let clamped: Vec<DVec3> = c.rows()[c.l_rows()..]
        .iter()
        .map(|&n| mesh.nodes[n as usize])
        .collect();
    let cols = c.cols();
    let near_clamps = (!clamped.is_empty()).then(|| {
        nearest_to(mesh, cols, &clamped)[..cols.len().div_ceil(10)]
            .iter()
            .flat_map(|&k| e.l2[3 * k..3 * k + 3].iter().copied())
            .fold(0.0, f64::max)
    });

    // One finger: column n/2 and its 8 nearest columns; spread: 9 columns evenly apart.
    let finger = finger_forces(mesh, cols);
    let force = FINGER_FORCE;
    let spread: Vec<(u32, DVec3)> = (0..9.min(cols.len()))
        .map(|i| ((i * cols.len() / 9) as u32, force))
        .collect();
    let mut out = vec![DVec3::ZERO; c.rows().len()];
    let mut time = |f: &[(u32, DVec3)], dense: bool| {
        median_us(reps, || {
            if dense {
                c.displace(f, &mut out)
            } else {
                h.displace(f, &mut out)
            }
        })
    };
    let (finger_us, finger_dense_us) = (time(&finger, false), time(&finger, true));
    let (spread_us, spread_dense_us) = (time(&spread, false), time(&spread, true));

    let row = HRow {
        mesh: name.into(),
        rows: h.rows(),
        cols: h.cols(),
        tolerance: eps,
        blocks: h.blocks().count(),
        low_rank_blocks: ranks.len(),
        mean_rank: ranks.iter().sum::<usize>() as f64 / ranks.len().max(1) as f64,
        max_rank: ranks.iter().copied().max().unwrap_or(0),
        bytes_f64: h.bytes_f64(),
        bytes_f32: h.bytes_f32(),
        dense_bytes_f64: 8 * h.dense_values(),
        ratio: h.stored_values() as f64 / h.dense_values() as f64,
        frobenius_rel: h.truncation_error() / h.norm(),
        l2_median: pick(&l2, 0.5),
        l2_worst: pick(&l2, 1.0),
        max_median: pick(&mx, 0.5),
        max_worst: pick(&mx, 1.0),
        l2_worst_near_clamps: near_clamps,
        build_s,
        finger_us,
        finger_dense_us,
        spread_us,
        spread_dense_us,
    };
    Ok((row, h, finger))
}

/// One row of `touchfem bench`'s hierarchical table: [`HRow`]'s storage and point-load
/// errors, what the GPU holds, and one finger's pass on the GPU against the dense pass in the
/// same run.
#[derive(Clone, Debug, serde::Serialize)]
pub struct BenchRow {
    /// Storage, errors and CPU times.
    #[serde(flatten)]
    pub h: HRow,
    /// Bytes the GPU holds for the hierarchical `L` (f32 values and tables).
    pub gpu_bytes: u64,
    /// Bytes of the dense `L` in f32.
    pub dense_gpu_bytes: u64,
    /// `gpu_bytes / dense_gpu_bytes`.
    pub gpu_ratio: f64,
    /// One finger's 9 neighbouring columns, the hierarchical pass on the GPU, median µs per
    /// frame (forces, encode, submit, wait); `None` without a GPU.
    pub gpu_pass_us: Option<f64>,
    /// The same forces through the dense `L` in the deformer's default layout, same run.
    pub gpu_dense_pass_us: Option<f64>,
}

/// The hierarchical table of `body` at each of `tolerances` (`gpu`: with the passes timed).
pub fn bench_rows(
    name: &str,
    body: &touchfem_core::scene::Body,
    tolerances: &[f64],
    reps: usize,
    gpu: Option<&touchfem_gpu::Gpu>,
) -> Result<Vec<BenchRow>, Error> {
    let c = &body.compliance;
    let mut out = Vec::new();
    let mut dense_us = None;
    for &eps in tolerances {
        let (r, h, finger) = measure_with(name, &body.mesh, c, eps, reps)?;
        let (gpu_bytes, dense_gpu_bytes) = (
            touchfem_gpu::hier_gpu_bytes(&h, false),
            4 * h.dense_values() as u64,
        );
        let mut gpu_pass_us = None;
        if let Some(g) = gpu {
            if dense_us.is_none() {
                dense_us = Some(pass_us(g, body, c, &finger, reps)?);
            }
            let hc = Compliance::from_hier(
                c.rows().to_vec(),
                c.l_rows(),
                c.cols().to_vec(),
                h,
                body.mesh.nodes.len(),
            )?;
            gpu_pass_us = Some(pass_us(g, body, &hc, &finger, reps)?);
        }
        out.push(BenchRow {
            h: r,
            gpu_bytes,
            dense_gpu_bytes,
            gpu_ratio: gpu_bytes as f64 / dense_gpu_bytes.max(1) as f64,
            gpu_pass_us,
            gpu_dense_pass_us: dense_us,
        });
    }
    Ok(out)
}

/// The time-against-error rows of a hierarchical table (methods `hmatrix-f64-EPS`: the CPU
/// product for one finger's 9 neighbouring columns and 9 spread-out ones; `hmatrix-gpu-EPS`:
/// the GPU pass for the finger), each with the worst point-load error.
pub fn tradeoff_of(table: &[BenchRow], nodes: usize) -> Vec<crate::tradeoff::Row> {
    let mut rows = Vec::new();
    for r in table {
        let eps = r.h.tolerance;
        let mut times = vec![(format!("hmatrix-f64-{eps:.0e}"), r.h.finger_us)];
        times.push((format!("hmatrix-f64-{eps:.0e}"), r.h.spread_us));
        if let Some(t) = r.gpu_pass_us {
            times.push((format!("hmatrix-gpu-{eps:.0e}"), t));
        }
        for (method, t) in times {
            rows.push(crate::tradeoff::Row {
                method,
                mesh: r.h.mesh.clone(),
                nodes,
                active_columns: 9,
                time_us: t,
                rel_error: r.h.l2_worst,
            });
        }
    }
    rows
}

/// Median µs of one GPU frame of `forces` through `c` (the deformer's default layout).
pub fn pass_us(
    g: &touchfem_gpu::Gpu,
    body: &touchfem_core::scene::Body,
    c: &Compliance,
    forces: &[(u32, DVec3)],
    reps: usize,
) -> Result<f64, Error> {
    let mut d = touchfem_gpu::Deformer::new(
        &g.device,
        &g.queue,
        c,
        &body.mesh.nodes,
        &body.mesh.surface,
        &Default::default(),
    )?;
    let f32s: Vec<(u32, [f32; 3])> = forces
        .iter()
        .map(|&(col, f)| (col, f.as_vec3().to_array()))
        .collect();
    for _ in 0..3 {
        crate::tradeoff::gpu_frame(g, &mut d, &f32s)?;
    }
    let mut failed = None;
    let t = median_us(reps.clamp(5, 200), || {
        if let Err(e) = crate::tradeoff::gpu_frame(g, &mut d, &f32s) {
            failed = Some(e);
        }
    });
    match failed {
        Some(e) => Err(e),
        None => Ok(t),
    }
}

/// A hierarchical precompute from the factor's solves on a mesh too large for the dense `L`
/// to be compared whole, checked against an independent dense precompute of a sample of its
/// columns (`Selection { rows: surface, cols: the sample }`, a separate factorisation and
/// solves): the study behind `touchfem bench --scene MESH --tolerance EPS`.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SampledRow {
    /// Mesh name.
    pub mesh: String,
    /// Mesh nodes.
    pub nodes: usize,
    /// Row nodes holding `L`.
    pub rows: usize,
    /// Column nodes.
    pub cols: usize,
    /// Tolerance ε.
    pub tolerance: f64,
    /// Seconds of the hierarchical precompute (assembly, factorisation, solves, compression).
    pub precompute_s: f64,
    /// Of which compressing the panels.
    pub compress_s: f64,
    /// Values stored in f32, bytes.
    pub bytes_f32: usize,
    /// The dense `L` in f32, bytes.
    pub dense_bytes_f32: usize,
    /// Mean rank of the low-rank blocks.
    pub mean_rank: f64,
    /// Sampled columns (each loaded along its three axes).
    pub sampled: usize,
    /// Relative L2 point-load error: median and worst over the sample.
    pub l2_median: f64,
    /// The same, worst.
    pub l2_worst: f64,
    /// Worst over the sampled columns nearest a clamped node (a tenth of the sample).
    pub l2_worst_near_clamps: f64,
    /// `‖L − L_H‖_F / ‖L‖_F` as the truncations measured it (at most ε).
    pub frobenius_rel: f64,
    /// The worst point load's `‖Δu‖₂ / (ε‖L‖_F)`: the per-load guarantee holds when ≤ 1.
    pub bound_used: f64,
}

/// [`SampledRow`] for `mesh` at `eps` with `sample` columns: evenly spread over the touchable
/// nodes, plus the `sample / 10` nearest a clamped node.
pub fn sampled_row(
    name: &str,
    mesh: &Mesh,
    eps: f64,
    sample: usize,
) -> Result<(SampledRow, Compliance), Error> {
    let sel = Selection::default();
    let t = Instant::now();
    let hc = Compliance::compute_hier(mesh, &sel, &HOptions::new(eps), &mut |_, _| {})?;
    let precompute_s = t.elapsed().as_secs_f64();
    let h = hc
        .hier()
        .ok_or_else(|| Error::Study("no hierarchical L".into()))?;
    let cols = hc.cols();
    // The sample: evenly spread, then the nearest the clamps.
    let mut pick: Vec<usize> = (0..sample.min(cols.len()))
        .map(|i| i * cols.len() / sample.min(cols.len()))
        .collect();
    let clamped: Vec<DVec3> = (0..mesh.nodes.len())
        .filter(|&n| mesh.fixed[n])
        .map(|n| mesh.nodes[n])
        .collect();
    let near = nearest_to(mesh, cols, &clamped);
    let n_near = (sample / 10).max(1).min(near.len());
    let near_set: Vec<usize> = near[..n_near].to_vec();
    pick.extend(near_set.iter().copied());
    pick.sort_unstable();
    pick.dedup();
    let nodes: Vec<u32> = pick.iter().map(|&k| cols[k]).collect();
    let reference = Compliance::compute(
        mesh,
        &Selection {
            rows: touchfem_core::compliance::NodeSet::Surface,
            cols: touchfem_core::compliance::NodeSet::Nodes(nodes.clone()),
        },
    )?;
    let (mut u, mut uh) = (
        vec![DVec3::ZERO; reference.rows().len()],
        vec![DVec3::ZERO; hc.rows().len()],
    );
    let (mut all, mut worst_near, mut worst_abs) = (Vec::new(), 0.0f64, 0.0f64);
    for (&k, &node) in pick.iter().zip(&nodes) {
        let rc = reference
            .col_of(node)
            .ok_or_else(|| Error::Study("sample column".into()))?;
        for b in 0..3 {
            reference.displace(&[(rc as u32, DVec3::AXES[b])], &mut u);
            hc.displace(&[(k as u32, DVec3::AXES[b])], &mut uh);
            let (mut d2, mut n2) = (0.0, 0.0);
            for (i, &rn) in reference.rows().iter().enumerate() {
                let Some(j) = hc.row_of(rn) else { continue };
                d2 += (uh[j] - u[i]).length_squared();
                n2 += u[i].length_squared();
            }
            let e = if n2 > 0.0 { (d2 / n2).sqrt() } else { 0.0 };
            worst_abs = worst_abs.max(d2.sqrt());
            all.push(e);
            if near_set.contains(&k) {
                worst_near = worst_near.max(e);
            }
        }
    }
    let all = sorted(&all);
    let ranks: Vec<usize> = h.blocks().filter_map(|b| b.rank).collect();
    let compress_s = hc.stats.phases.finish_s;
    Ok((
        SampledRow {
            mesh: name.into(),
            nodes: mesh.nodes.len(),
            rows: h.rows(),
            cols: h.cols(),
            tolerance: eps,
            precompute_s,
            compress_s,
            bytes_f32: h.bytes_f32(),
            dense_bytes_f32: 4 * h.dense_values(),
            mean_rank: ranks.iter().sum::<usize>() as f64 / ranks.len().max(1) as f64,
            sampled: pick.len(),
            l2_median: all[all.len() / 2],
            l2_worst: all[all.len() - 1],
            l2_worst_near_clamps: worst_near,
            frobenius_rel: h.truncation_error() / h.norm().max(f64::MIN_POSITIVE),
            bound_used: worst_abs / (eps * h.norm()).max(f64::MIN_POSITIVE),
        },
        hc,
    ))
}
