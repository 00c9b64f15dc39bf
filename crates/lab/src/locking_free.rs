//! The locking-free study: the standard stiffness against the four locking-free smoothings
//! ([`Smoothing::Nodal`], [`Smoothing::ElementAveraged`], [`Smoothing::Bubble`],
//! [`Smoothing::Projection`]) on the paper's cube (30 mm, E = 10 kPa, bottom clamped) under
//! one of two [`Load`]s: the test, a point force at the top centre compared away from
//! it, and a harder one, a uniform 100 Pa pressure on the whole top face, compared everywhere.
//!
//! The reference at each ν is a converged solution: the Richardson extrapolation (order
//! observed from the field at the compared nodes: the ratio of successive differences) of
//! the three finest meshes, done for each locking-free smoothing and averaged (at ν = 0.3
//! the standard element's extrapolation joins them); the spread between them is reported as
//! the reference's own uncertainty. The error of a coarse mesh is measured at the coarsest grid's
//! nodes (every mesh has them) that the load's comparison keeps ([`Load::compared`]), as
//! `max |u − u_ref| / max |u_ref|` over those nodes (the field error), and at the monitor.

use glam::DVec3;
use std::fmt::Write as _;

use touchfem_core::fem::locking_free::{self, Smoothing};
use touchfem_core::fem::Stiffness;
use touchfem_core::mesh::units::Material;
use touchfem_core::mesh::{cube_with, Mesh};

/// The load of the study.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Load {
    /// A 0.1 N point force down at the top centre (the finger's press, as a force: a
    /// prescribed displacement at one node has no converged limit). The displacement under
    /// a point force is singular, so the comparison leaves out the nodes of the coarse cells
    /// around the loaded node, and the monitor is the top edge's midpoint (15 mm away).
    PointPress,
    /// 100 Pa down on the whole top face, compared at every node, the monitor the top
    /// centre. Harder for any linear-displacement element near ν = 0.5: the incompressible
    /// solution is singular along the clamped bottom edges, where the sides bulge.
    TopPressure,
}

impl Load {
    /// Both loads, the first.
    pub const ALL: [Load; 2] = [Load::PointPress, Load::TopPressure];

    /// A short name for tables.
    pub fn name(self) -> &'static str {
        match self {
            Load::PointPress => "point-press",
            Load::TopPressure => "top-pressure",
        }
    }

    /// What the table's title says.
    fn describe(self) -> &'static str {
        match self {
            Load::PointPress => "0.1 N at the top centre, compared away from it",
            Load::TopPressure => "100 Pa on the top face, compared everywhere",
        }
    }

    /// The nodal forces (N) on `mesh` (the cube, `cells` per edge).
    fn forces(self, mesh: &Mesh, cells: usize) -> Vec<(u32, DVec3)> {
        match self {
            Load::PointPress => {
                let h = cells / 2;
                let c = (cells * (cells + 1) + h) * (cells + 1) + h;
                vec![(c as u32, DVec3::new(0.0, 0.0, -0.1))]
            }
            Load::TopPressure => top_pressure_forces(mesh),
        }
    }

    /// The monitor node on the `base`-cell grid `(i, j, k)`: its settlement fills the
    /// table's `u_mon` column.
    pub fn monitor(self, base: usize) -> (usize, usize, usize) {
        match self {
            Load::PointPress => (base / 2, 0, base),
            Load::TopPressure => (base / 2, base / 2, base),
        }
    }

    /// Whether the field error counts the `base`-grid node `(i, j, k)`: for the point press,
    /// not the nodes of the coarse cells touching the loaded node.
    pub fn compared(self, base: usize, (i, j, k): (usize, usize, usize)) -> bool {
        match self {
            Load::PointPress => {
                let h = base / 2;
                !(i.abs_diff(h) <= 1 && j.abs_diff(h) <= 1 && k + 1 >= base)
            }
            Load::TopPressure => true,
        }
    }
}

/// A stiffness: the standard element or a locking-free smoothing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum Method {
    /// Constant-strain tets as in the paper.
    Standard,
    /// A locking-free smoothing.
    LockingFree(#[serde(serialize_with = "smoothing_name")] Smoothing),
}

fn smoothing_name<S: serde::Serializer>(s: &Smoothing, ser: S) -> Result<S::Ok, S::Error> {
    ser.serialize_str(s.name())
}

impl Method {
    /// The methods compared.
    pub const ALL: [Method; 5] = [
        Method::Standard,
        Method::LockingFree(Smoothing::Nodal),
        Method::LockingFree(Smoothing::ElementAveraged),
        Method::LockingFree(Smoothing::Bubble),
        Method::LockingFree(Smoothing::Projection),
    ];

    /// A short name for tables.
    pub fn name(self) -> &'static str {
        match self {
            Method::Standard => "standard",
            Method::LockingFree(Smoothing::Nodal) => "nodal",
            Method::LockingFree(Smoothing::ElementAveraged) => "elem-avg",
            Method::LockingFree(Smoothing::Bubble) => "bubble",
            Method::LockingFree(Smoothing::Projection) => "projection",
        }
    }

    /// The stiffness of `mesh` by this method.
    pub fn stiffness(self, mesh: &Mesh) -> Result<Stiffness, crate::error::Error> {
        Ok(match self {
            Method::Standard => Stiffness::assemble(mesh)?,
            Method::LockingFree(s) => locking_free::stiffness(mesh, s)?,
        })
    }
}

/// One solve: a method on a mesh at one ν.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Solve {
    /// Cells per edge.
    pub cells: usize,
    /// The monitor's settlement ([`Load::monitor`]), m.
    pub settlement_m: f64,
    /// Non-zeros of the clamped K.
    pub k_nonzeros: usize,
    /// Assembly and solve, s.
    pub seconds: f64,
    /// Displacements at the coarsest grid's compared nodes, m.
    #[serde(skip)]
    pub probes: Vec<DVec3>,
}

/// The paper's cube with `cells` per edge at `poisson` under `load`, solved by `method`:
/// the monitor's settlement and the field at the compared nodes of the `base`-cell grid.
pub fn solve(
    method: Method,
    load: Load,
    cells: usize,
    base: usize,
    poisson: f64,
) -> Result<Solve, crate::error::Error> {
    let t = std::time::Instant::now();
    let mesh = cube_with(
        [cells; 3],
        [30.0; 3],
        Material {
            young_pa: 10_000.0,
            poisson,
        },
    )?;
    let forces = load.forces(&mesh, cells);
    let k = method.stiffness(&mesh)?;
    let u = k.solve(mesh.nodes.len(), &forces)?;
    let s = cells / base.max(1);
    let id = |i: usize, j: usize, k: usize| (k * s * (cells + 1) + j * s) * (cells + 1) + i * s;
    let probes: Vec<DVec3> = (0..=base)
        .flat_map(|k| (0..=base).flat_map(move |j| (0..=base).map(move |i| (i, j, k))))
        .filter(|&p| load.compared(base, p))
        .map(|(i, j, k)| u[id(i, j, k)])
        .collect();
    let (mi, mj, mk) = load.monitor(base);
    let c = id(mi, mj, mk);
    Ok(Solve {
        cells,
        settlement_m: -u[c].z,
        k_nonzeros: k.k.compute_nnz(),
        seconds: t.elapsed().as_secs_f64(),
        probes,
    })
}

/// One row of the study's table.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Row {
    /// Poisson's ratio.
    pub poisson: f64,
    /// The method.
    pub method: Method,
    /// Cells per edge.
    pub cells: usize,
    /// The monitor's settlement, m.
    pub settlement_m: f64,
    /// `|settlement − reference| / reference`.
    pub settlement_error: f64,
    /// `max |u − u_ref| / max |u_ref|` at the coarsest grid's compared nodes.
    pub field_error: f64,
    /// Non-zeros of the clamped K.
    pub k_nonzeros: usize,
}

/// The reference at one ν.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Reference {
    /// Poisson's ratio.
    pub poisson: f64,
    /// The reference monitor settlement, m.
    pub settlement_m: f64,
    /// Each extrapolation's (method, settlement m, observed order).
    pub extrapolations: Vec<(String, f64, f64)>,
    /// Largest relative difference between the extrapolations' settlements and fields (the
    /// reference's uncertainty).
    pub spread: f64,
    /// Reference displacements at the coarsest grid's compared nodes, m.
    #[serde(skip)]
    pub probes: Vec<DVec3>,
}

/// Richardson extrapolation of a field from three meshes refined by 2, with the order `p`.
fn extrapolate(f: [&[DVec3]; 3], p: f64) -> Vec<DVec3> {
    let r = 2f64.powf(p) - 1.0;
    f[2].iter()
        .zip(f[1])
        .map(|(c, b)| *c + (*c - *b) / r)
        .collect()
}

/// The observed order of convergence of a field from three meshes refined by 2:
/// `log2(‖f₁ − f₀‖ / ‖f₂ − f₁‖)` (Euclidean norms over the probes), `None` unless the
/// differences shrink.
fn field_order(f: [&[DVec3]; 3]) -> Option<f64> {
    let norm = |a: &[DVec3], b: &[DVec3]| -> f64 {
        a.iter()
            .zip(b)
            .map(|(x, y)| (*x - *y).length_squared())
            .sum::<f64>()
            .sqrt()
    };
    let (d1, d2) = (norm(f[1], f[0]), norm(f[2], f[1]));
    (d2 > 0.0 && d2 < d1).then(|| (d1 / d2).log2())
}

/// The Richardson extrapolation of three solves on meshes refined by 2 (same load, ν and
/// base grid), at the order observed from their fields: the monitor's settlement (m), the
/// order, and the field at the compared nodes. `None` unless the field converges.
pub fn richardson(s: [&Solve; 3]) -> Option<(f64, f64, Vec<DVec3>)> {
    let three = [&s[0].probes[..], &s[1].probes[..], &s[2].probes[..]];
    let order = field_order(three)?;
    let (b, c) = (s[1].settlement_m, s[2].settlement_m);
    let limit = c + (c - b) / (2f64.powf(order) - 1.0);
    Some((limit, order, extrapolate(three, order)))
}

fn max_len(v: &[DVec3]) -> f64 {
    v.iter().map(|x| x.length()).fold(0.0, f64::max)
}

/// The field error of `u` against `reference` (same nodes): `max |u − u_ref| / max |u_ref|`.
pub fn field_error(u: &[DVec3], reference: &[DVec3]) -> f64 {
    u.iter()
        .zip(reference)
        .map(|(x, y)| (*x - *y).length())
        .fold(0.0, f64::max)
        / max_len(reference)
}

/// The study under `load` at each of `poissons`: every method on the `coarse` meshes (cells
/// per edge, the first the base grid), against the reference from `fine` (three meshes, each
/// twice the last, multiples of the base). Returns the rows and the references.
pub fn study(
    load: Load,
    poissons: &[f64],
    coarse: &[usize],
    fine: [usize; 3],
) -> Result<(Vec<Row>, Vec<Reference>), crate::error::Error> {
    let base = coarse.first().copied().unwrap_or(4);
    let mut rows = Vec::new();
    let mut refs = Vec::new();
    for &nu in poissons {
        let mut solves: Vec<(Method, Vec<Solve>)> = Vec::new();
        let mut extrapolations = Vec::new();
        let mut fields: Vec<Vec<DVec3>> = Vec::new();
        for m in Method::ALL {
            let mut s = Vec::new();
            for &c in coarse {
                s.push(solve(m, load, c, base, nu)?);
            }
            // The standard element converges too slowly near ν = 0.5 to extrapolate (its
            // error constant grows with the bulk modulus): only at ν ≤ 0.3.
            if m != Method::Standard || nu <= 0.3 {
                let f: Vec<Solve> = fine
                    .iter()
                    .map(|&c| match s.iter().find(|x| x.cells == c) {
                        Some(x) => Ok(x.clone()),
                        None => solve(m, load, c, base, nu),
                    })
                    .collect::<Result<_, _>>()?;
                if let Some((limit, order, field)) = richardson([&f[0], &f[1], &f[2]]) {
                    extrapolations.push((m.name().to_string(), limit, order));
                    fields.push(field);
                } else {
                    log::warn!("{} at ν {nu}: the field does not converge", m.name());
                }
            }
            solves.push((m, s));
        }
        if extrapolations.is_empty() {
            return Err(crate::error::Error::Study(format!(
                "no converged reference at ν {nu}"
            )));
        }
        let k = extrapolations.len() as f64;
        let settlement = extrapolations.iter().map(|e| e.1).sum::<f64>() / k;
        let n = fields[0].len();
        let probes: Vec<DVec3> = (0..n)
            .map(|i| fields.iter().map(|f| f[i]).sum::<DVec3>() / k)
            .collect();
        let mut spread = 0.0f64;
        for (e, f) in extrapolations.iter().zip(&fields) {
            spread = spread
                .max((e.1 - settlement).abs() / settlement)
                .max(field_error(f, &probes));
        }
        for (m, s) in &solves {
            for x in s {
                rows.push(Row {
                    poisson: nu,
                    method: *m,
                    cells: x.cells,
                    settlement_m: x.settlement_m,
                    settlement_error: (x.settlement_m - settlement).abs() / settlement,
                    field_error: field_error(&x.probes, &probes),
                    k_nonzeros: x.k_nonzeros,
                });
            }
        }
        refs.push(Reference {
            poisson: nu,
            settlement_m: settlement,
            extrapolations,
            spread,
            probes,
        });
    }
    Ok((rows, refs))
}

/// The error ratios the targets are stated in, for one coarse mesh: (locking-free at
/// the highest ν) / (standard at the lowest ν), and (locking-free at the highest ν) /
/// (standard at the highest ν), by field error, for each smoothing.
pub fn ratios(rows: &[Row], cells: usize) -> Vec<(Smoothing, f64, f64)> {
    let lo = rows.iter().map(|r| r.poisson).fold(f64::INFINITY, f64::min);
    let hi = rows
        .iter()
        .map(|r| r.poisson)
        .fold(f64::NEG_INFINITY, f64::max);
    let err = |m: Method, nu: f64| {
        rows.iter()
            .find(|r| r.method == m && r.poisson == nu && r.cells == cells)
            .map_or(f64::NAN, |r| r.field_error)
    };
    Method::ALL
        .iter()
        .filter_map(|&m| match m {
            Method::LockingFree(s) => Some(s),
            Method::Standard => None,
        })
        .map(|s| {
            let lf = err(Method::LockingFree(s), hi);
            (
                s,
                lf / err(Method::Standard, lo),
                lf / err(Method::Standard, hi),
            )
        })
        .collect()
}

/// The study's table under `load` as text.
pub fn table(load: Load, rows: &[Row], refs: &[Reference]) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "locking-free study ({}): the paper's cube, {}; error against a converged reference",
        load.name(),
        load.describe()
    );
    for r in refs {
        let ex: Vec<String> = r
            .extrapolations
            .iter()
            .map(|(m, s, p)| format!("{m} {:.4} um (order {p:.2})", s * 1e6))
            .collect();
        let _ = writeln!(
            out,
            "  reference ν {}: {:.4} um ({}; spread {:.1e})",
            r.poisson,
            r.settlement_m * 1e6,
            ex.join(", "),
            r.spread
        );
    }
    let _ = writeln!(
        out,
        "{:>8} {:>10} {:>6} {:>11} {:>10} {:>10} {:>9}",
        "poisson", "method", "cells", "u_mon um", "u_err", "field_err", "K_nnz"
    );
    for r in rows {
        let _ = writeln!(
            out,
            "{:>8} {:>10} {:>6} {:>11.4} {:>10.3e} {:>10.3e} {:>9}",
            r.poisson,
            r.method.name(),
            r.cells,
            r.settlement_m * 1e6,
            r.settlement_error,
            r.field_error,
            r.k_nonzeros
        );
    }
    let coarse = rows.iter().map(|r| r.cells).min().unwrap_or(4);
    for (s, a, b) in ratios(rows, coarse) {
        let _ = writeln!(
            out,
            "{}^3, {}: field error at the highest ν / standard's at the lowest {a:.2}x; / standard's at the highest {b:.3}",
            coarse,
            s.name()
        );
    }
    out
}

/// Nodal forces (N) of a uniform 100 Pa pressure on the top face (z = 30 mm) of the paper's
/// 30 mm cube, lumped a third of each top triangle's share per corner.
pub(crate) fn top_pressure_forces(mesh: &Mesh) -> Vec<(u32, DVec3)> {
    let mut f = vec![DVec3::ZERO; mesh.nodes.len()];
    for tri in &mesh.surface {
        let p = tri.map(|i| mesh.nodes[i as usize]);
        if p.iter().all(|q| q.z >= 0.03 - 1e-9) {
            let area = 0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length();
            for &v in tri {
                f[v as usize].z -= 100.0 * area / 3.0;
            }
        }
    }
    f.iter()
        .enumerate()
        .filter(|(_, v)| **v != DVec3::ZERO)
        .map(|(i, v)| (i as u32, *v))
        .collect()
}
