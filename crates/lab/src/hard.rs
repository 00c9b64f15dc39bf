//! Hard cases, measured: nearly incompressible material, slivers and needles that still pass
//! validation, and extreme scales of stiffness and size. For each: the precompute's residual,
//! the f64 product against an independent dense LU solve (nalgebra, partial pivoting: a
//! different algorithm and ordering from the sparse Cholesky), the f32 storage error as the GPU
//! sees it (f32 entries, f32 sums), and the force of the paper's Fig. 1b press scaled to the
//! body. `tests/hard_cases.rs` holds these to bounds; `touchfem bench --hard` prints them.
//! Also volumetric locking: the press's force against ν at two resolutions.

use glam::DVec3;
use std::fmt::Write as _;
use touchfem_core::compliance::conditioning::dense_k;
use touchfem_core::compliance::precision::{displace_f16, displace_f32};
use touchfem_core::mesh::worst_quality;

use touchfem_core::compliance::{Compliance, NodeSet, Selection};
use touchfem_core::contact::force::ForceModel;
use touchfem_core::fem::Stiffness;
use touchfem_core::mesh::units::{Formulation, LengthUnit, Material};
use touchfem_core::mesh::{grid_raw, Mesh, RawMesh};
use touchfem_core::scene::Body;

/// One hard case's numbers.
#[derive(Clone, Debug, serde::Serialize)]
pub struct HardCase {
    /// What it is.
    pub case: String,
    /// Mesh nodes.
    pub nodes: usize,
    /// Worst element quality `6V/ℓ³` (regular tet 0.707; validation refuses ≤ 1e-8).
    pub worst_quality: f64,
    /// Young's modulus, Pa.
    pub young_pa: f64,
    /// Poisson's ratio.
    pub poisson: f64,
    /// Edge of the body, m.
    pub size_m: f64,
    /// The precompute's `max |K·L − I|` relative to `max |K|·max |L|`.
    pub residual: f64,
    /// `max |L·F − u_LU| / max |u_LU|` for a load at the top centre.
    pub f64_error: f64,
    /// The same product from f32 entries summed in f32 (the GPU's arithmetic), against f64.
    pub f32_error: f64,
    /// The same from f16 entries (L scaled by a power of two near max |L|, as both f16
    /// layouts store it) summed in f32, against f64.
    pub f16_error: f64,
    /// Force of the Fig. 1b press (a sixth of the edge, down at the top centre), N.
    pub press_force_n: f64,
    /// Precompute wall time, s.
    pub precompute_s: f64,
}

/// The cube of edge `size_mm` with `cells` cells, its z nodes moved by `z_map` (mm → mm;
/// monotone), in `unit` (the coordinates are written in that unit), bottom clamped.
fn body(
    cells: [usize; 3],
    size_mm: f64,
    unit: LengthUnit,
    material: Material,
    map: impl Fn([f64; 3]) -> [f64; 3],
) -> Result<Mesh, crate::error::Error> {
    let mut raw: RawMesh = grid_raw(cells, [size_mm; 3], |_, _, _| true);
    let s = match unit {
        LengthUnit::Millimetre => 1.0,
        LengthUnit::Metre => 1e-3,
    };
    for p in &mut raw.nodes {
        *p = map(*p).map(|v| v * s);
    }
    let mut mesh = Mesh::from_raw(raw, unit, material)?;
    mesh.set_fixed_group("fixed")?;
    Ok(mesh)
}

/// The displacement of every node under `forces` by a dense LU solve of the free-DOF stiffness.
pub fn dense_lu_solve(
    mesh: &Mesh,
    forces: &[(u32, DVec3)],
) -> Result<Vec<DVec3>, crate::error::Error> {
    let k = Stiffness::assemble(mesh)?;
    let n = k.dofs.n_free;
    // (Of a mixed system, its condensed stiffness: the free DOFs only.)
    let a = dense_k(&k);
    let mut b = nalgebra::DVector::<f64>::zeros(n);
    for &(node, f) in forces {
        for ax in 0..3 {
            if let Some(d) = k.dofs.free(node, ax) {
                b[d] += f[ax];
            }
        }
    }
    let x = a
        .lu()
        .solve(&b)
        .ok_or_else(|| crate::error::Error::Study("the dense stiffness is singular".into()))?;
    Ok((0..mesh.nodes.len() as u32)
        .map(|node| {
            DVec3::from_array(std::array::from_fn(|ax| {
                k.dofs.free(node, ax).map(|d| x[d]).unwrap_or(0.0)
            }))
        })
        .collect())
}

/// Measures one body: see [`HardCase`].
pub fn measure(case: &str, mesh: Mesh) -> Result<HardCase, crate::error::Error> {
    let sel = Selection {
        rows: NodeSet::All,
        cols: NodeSet::FreeSurface,
    };
    let t = std::time::Instant::now();
    let c = Compliance::compute(&mesh, &sel)?;
    let precompute_s = t.elapsed().as_secs_f64();
    let (lo, hi) = mesh.bounds();
    let size = (hi - lo).max_element();
    let top = DVec3::new(0.5 * (lo.x + hi.x), 0.5 * (lo.y + hi.y), hi.z);
    // A load at the free-surface node nearest the top centre, scaled so |u| is about a
    // sixth of the edge whatever E and size are.
    let col = (0..c.cols().len())
        .min_by(|&a, &b| {
            let d = |i: usize| mesh.nodes[c.cols()[i] as usize].distance(top);
            d(a).total_cmp(&d(b))
        })
        .ok_or_else(|| crate::error::Error::Study("no touchable node".into()))?;
    let node = c.cols()[col];
    let diag = c.block(c.col_row(col), col).z_axis.z;
    let f = DVec3::new(0.0, 0.0, -(size / 6.0) / diag);
    let forces = [(col as u32, f)];
    let mut u = vec![DVec3::ZERO; c.rows().len()];
    c.displace(&forces, &mut u);
    let lu = dense_lu_solve(&mesh, &[(node, f)])?;
    // Rows are every node, in node order (the selection's rows: all nodes).
    let by_node: Vec<DVec3> = (0..mesh.nodes.len() as u32)
        .map(|n| c.row_of(n).map(|r| u[r]).unwrap_or(DVec3::ZERO))
        .collect();
    let f64_error = touchfem_core::compliance::precision::rel_err(&by_node, &lu);
    let f32_error = touchfem_core::compliance::precision::rel_err(&displace_f32(&c, &forces), &u);
    let f16_error = touchfem_core::compliance::precision::rel_err(&displace_f16(&c, &forces), &u);
    let kmax = {
        let k = Stiffness::assemble(&mesh)?;
        k.k.as_ref()
            .val()
            .iter()
            .fold(0.0f64, |m, v| m.max(v.abs()))
    };
    let lmax = c.l_f64().iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let residual = c.stats.residual / (kmax * lmax);
    let material = mesh.material;
    let quality = worst_quality(&mesh);
    let scene = Body::with_compliance(mesh, c);
    let press = scene.poke(
        top + DVec3::Z * size,
        DVec3::new(0.0, 0.0, -size / 6.0),
        ForceModel::Paper,
        20,
    )?;
    Ok(HardCase {
        case: case.into(),
        nodes: scene.mesh.nodes.len(),
        worst_quality: quality,
        young_pa: material.young_pa,
        poisson: material.poisson,
        size_m: size,
        residual,
        f64_error,
        f32_error,
        f16_error,
        press_force_n: press.feedback.length(),
        precompute_s,
    })
}

/// The paper's cube material (10 kPa) with Poisson's ratio `nu`.
fn paper(nu: f64) -> Material {
    material(10_000.0, nu)
}

fn material(young_pa: f64, poisson: f64) -> Material {
    Material { young_pa, poisson }
}

/// The paper's 30 mm cube (ν = 0.49) in 4×4×5 cells whose middle layer, between z = 12 and
/// 12.001 mm, is 1 µm thick: sliver tets (quality 4.7e-5) and side triangles of near-zero
/// area.
pub fn sliver_cube() -> Result<Mesh, crate::error::Error> {
    body([4, 4, 5], 30.0, LengthUnit::Millimetre, paper(0.49), |p| {
        let z = p[2];
        let z = if z <= 12.0 + 1e-9 {
            z
        } else {
            12.001 + (z - 18.0) * (30.0 - 12.001) / 12.0
        };
        [p[0], p[1], z]
    })
}

/// Every hard case (a few seconds in a release build).
pub fn cases() -> Result<Vec<HardCase>, crate::error::Error> {
    bodies()?
        .into_iter()
        .map(|(name, mesh)| measure(&name, mesh))
        .collect()
}

/// The hard cases' bodies, named.
pub fn bodies() -> Result<Vec<(String, Mesh)>, crate::error::Error> {
    let mm = LengthUnit::Millimetre;
    let id = |p: [f64; 3]| p;
    let mut out = Vec::new();
    for nu in [0.49, 0.499, 0.4999] {
        let m = body([4, 4, 4], 30.0, mm, paper(nu), id)?;
        out.push((format!("nu={nu}"), m));
    }
    // The same bodies with well-shaped cells of the same counts, for comparison.
    out.push((
        "well-shaped 4x4x5".into(),
        body([4, 4, 5], 30.0, mm, paper(0.49), id)?,
    ));
    out.push((
        "well-shaped 6x4x4".into(),
        body([6, 4, 4], 30.0, mm, paper(0.49), id)?,
    ));
    out.push(("sliver layer (1 µm)".into(), sliver_cube()?));
    // A column of cells 1 µm wide in x, between x = 20 and 20.001 mm (6 columns of cells),
    // beside the press: needles.
    let needle = |p: [f64; 3]| {
        let x = p[0];
        let x = if x <= 20.0 + 1e-9 {
            x
        } else if x <= 25.0 + 1e-9 {
            20.0 + (x - 20.0) * 0.001 / 5.0
        } else {
            20.001 + (x - 25.0) * (30.0 - 20.001) / 5.0
        };
        [x, p[1], p[2]]
    };
    out.push((
        "needle column (1 µm)".into(),
        body([6, 4, 4], 30.0, mm, paper(0.49), needle)?,
    ));
    // Extreme scales: the same cube at E = 1 Pa and 1 m, at 1 GPa and 1 mm, and in metres.
    out.push((
        "E=1 Pa, 1 m".into(),
        body([4, 4, 4], 1000.0, mm, material(1.0, 0.3), id)?,
    ));
    out.push((
        "E=1 GPa, 1 mm".into(),
        body([4, 4, 4], 1.0, mm, material(1e9, 0.3), id)?,
    ));
    out.push((
        "E=1 GPa, 1 mm, in metres".into(),
        body([4, 4, 4], 1.0, LengthUnit::Metre, material(1e9, 0.3), id)?,
    ));
    Ok(out)
}

/// One row of the locking table.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct LockingRow {
    /// Poisson's ratio.
    pub poisson: f64,
    /// Top-centre settlement under a uniform 100 Pa pressure on the top face, m, on 4³, 8³
    /// and 16³ cells.
    pub settlement_m: [f64; 3],
    /// Force of the Fig. 1b press (5 mm down at the top centre), N, on 4³ and 8³ cells.
    pub press_force_n: [f64; 2],
    /// The settlement with the locking-free stiffness ([`Formulation::LockingFree`]), m, on
    /// 4³, 8³ and 16³ cells.
    pub locking_free_settlement_m: [f64; 3],
    /// The press's force with the locking-free stiffness, N, on 4³ and 8³ cells.
    pub locking_free_press_force_n: [f64; 2],
}

/// Volumetric locking on the paper's cube (E = 10 kPa) against ν. A distributed load shows
/// it: the coarse mesh settles less than the fine one (it is too stiff), more so as ν → 0.5.
/// The paper's point press is shown beside it: its force roughly halves with each refinement
/// at every ν, since a point load has no limit in 3D, and that hides locking. Each row has
/// the same numbers with the locking-free stiffness beside the standard ones.
pub fn locking() -> Result<Vec<LockingRow>, crate::error::Error> {
    let mut out = Vec::new();
    for nu in [0.3, 0.45, 0.49, 0.499, 0.4999] {
        let [settlement, lf_settlement] = [Formulation::Standard, Formulation::LockingFree].map(
            |f| -> Result<[f64; 3], crate::error::Error> {
                let mut s = [0.0; 3];
                for (i, n) in [4usize, 8, 16].iter().enumerate() {
                    let mut mesh = touchfem_core::mesh::cube_with([*n; 3], [30.0; 3], paper(nu))?;
                    mesh.formulation = f;
                    s[i] = settlement(&mesh)?;
                }
                Ok(s)
            },
        );
        let [press, lf_press] = [Formulation::Standard, Formulation::LockingFree].map(
            |f| -> Result<[f64; 2], crate::error::Error> {
                let mut press = [0.0; 2];
                for (i, n) in [4usize, 8].iter().enumerate() {
                    let mut mesh = touchfem_core::mesh::cube_with([*n; 3], [30.0; 3], paper(nu))?;
                    mesh.formulation = f;
                    let scene = Body::new(mesh, &Selection::default())?;
                    let p = scene.poke(
                        DVec3::new(0.015, 0.015, 0.03),
                        DVec3::new(0.0, 0.0, -0.005),
                        ForceModel::Paper,
                        20,
                    )?;
                    press[i] = p.feedback.length();
                }
                Ok(press)
            },
        );
        out.push(LockingRow {
            poisson: nu,
            settlement_m: settlement?,
            press_force_n: press?,
            locking_free_settlement_m: lf_settlement?,
            locking_free_press_force_n: lf_press?,
        });
    }
    Ok(out)
}

/// The top-centre settlement (m) of the 30 mm cube `mesh` under a uniform 100 Pa pressure on
/// its top face.
fn settlement(mesh: &Mesh) -> Result<f64, crate::error::Error> {
    let forces = crate::locking_free::top_pressure_forces(mesh);
    let u = touchfem_core::fem::solve_static(mesh, &forces)?;
    let centre = DVec3::new(0.015, 0.015, 0.03);
    let c = (0..mesh.nodes.len())
        .min_by(|&a, &b| {
            mesh.nodes[a]
                .distance(centre)
                .total_cmp(&mesh.nodes[b].distance(centre))
        })
        .unwrap_or(0);
    Ok(-u[c].z)
}

/// `touchfem bench --hard`: the table (returned, for the caller to print) of every hard case and the locking table; with `json`, writes
/// them as `{"hard": [HardCase...], "locking": [LockingRow...], "locking_free": {LOAD:
/// {"rows", "references"}}, "machine"}` (one study per [`crate::locking_free::Load`], by its
/// name, from [`crate::locking_free::study`]).
pub fn bench(json: Option<&std::path::Path>) -> Result<String, crate::error::Error> {
    let mut out = String::new();
    let cases = cases()?;
    let _ = writeln!(
        out,
        "{:<26} {:>5} {:>9} {:>9} {:>9} {:>9} {:>9} {:>11} {:>8}",
        "case", "nodes", "quality", "residual", "f64_err", "f32_err", "f16_err", "press_N", "pre_s"
    );
    for c in &cases {
        let _ = writeln!(
            out,
            "{:<26} {:>5} {:>9.1e} {:>9.1e} {:>9.1e} {:>9.1e} {:>9.1e} {:>11.4e} {:>8.3}",
            c.case,
            c.nodes,
            c.worst_quality,
            c.residual,
            c.f64_error,
            c.f32_error,
            c.f16_error,
            c.press_force_n,
            c.precompute_s
        );
    }
    let lock = locking()?;
    let _ = writeln!(out, "\nvolumetric locking on the paper's cube: settlement under 100 Pa on the top face, and the Fig. 1b press");
    let _ = writeln!(
        out,
        "{:>8} {:>13} {:>11} {:>11} {:>11} {:>10} {:>10} {:>10} {:>10}",
        "poisson",
        "formulation",
        "u 4^3 um",
        "u 8^3 um",
        "u 16^3 um",
        "4^3/16^3",
        "F 4^3 N",
        "F 8^3 N",
        "F 4/8"
    );
    for r in &lock {
        for (name, [a, b, c], [f4, f8]) in [
            ("standard", r.settlement_m, r.press_force_n),
            (
                "locking-free",
                r.locking_free_settlement_m,
                r.locking_free_press_force_n,
            ),
        ] {
            let _ = writeln!(
                out,
                "{:>8} {:>13} {:>11.3} {:>11.3} {:>11.3} {:>10.3} {:>10.4} {:>10.4} {:>10.3}",
                r.poisson,
                name,
                a * 1e6,
                b * 1e6,
                c * 1e6,
                a / c,
                f4,
                f8,
                f4 / f8
            );
        }
    }
    let mut studies = serde_json::Map::new();
    for load in crate::locking_free::Load::ALL {
        let (rows, refs) =
            crate::locking_free::study(load, &[0.3, 0.49, 0.4999], &[4, 8], [8, 16, 32])?;
        let _ = writeln!(out);
        out.push_str(&crate::locking_free::table(load, &rows, &refs));
        studies.insert(
            load.name().to_string(),
            serde_json::json!({"rows": rows, "references": refs}),
        );
    }
    if let Some(path) = json {
        let v = serde_json::json!({
            "hard": cases,
            "locking": lock,
            "locking_free": studies,
            "machine": crate::report::machine(),
        });
        crate::tradeoff::write_json(path, &v)?;
    }
    Ok(out)
}
