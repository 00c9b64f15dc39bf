//! Hertz's law, independent of us: a rigid sphere pressed into a large block clamped at its
//! base must give `F = (4/3)·E/(1−ν²)·√R·d^{3/2}`; a point finger gives a force linear in the
//! depth instead. The block is graded: `h` under the contact, growing away from it.

use glam::DVec3;
use touchfem_core::compliance::{NodeSet, Selection};
use touchfem_core::mesh::graded_block;
use touchfem_core::scene::Body;
use touchfem_core::{Formulation, Material};

use crate::Error;

/// The study's set-up (lengths in millimetres).
#[derive(Clone, Debug, PartialEq)]
pub struct HertzSetup {
    /// The block, mm.
    pub size_mm: [f64; 3],
    /// Cell size under the contact, mm.
    pub h_mm: f64,
    /// Half-width of the fine region (and its depth), mm.
    pub fine_mm: f64,
    /// Cell growth beyond it.
    pub growth: f64,
    /// Sphere radius, mm.
    pub radius_mm: f64,
    /// Depths, mm.
    pub depths_mm: Vec<f64>,
    /// Young's modulus, Pa.
    pub young_pa: f64,
    /// Poisson's ratio.
    pub poisson: f64,
    /// The stiffness formulation.
    pub formulation: Formulation,
}

impl HertzSetup {
    /// The block: 80 × 80 × 40 mm, E = 10 kPa, R = 10 mm, d = 0.2 … 1.5 mm, with
    /// cells of `h_mm` under the contact.
    pub fn block(poisson: f64, h_mm: f64) -> HertzSetup {
        HertzSetup {
            size_mm: [80.0, 80.0, 40.0],
            h_mm,
            fine_mm: 5.5,
            growth: 1.35,
            radius_mm: 10.0,
            depths_mm: vec![0.2, 0.3, 0.5, 0.7, 1.0, 1.5],
            young_pa: 10_000.0,
            poisson,
            formulation: Formulation::Standard,
        }
    }
}

/// One depth's forces.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct HertzRow {
    /// Depth, m.
    pub depth_m: f64,
    /// The sphere's force, N.
    pub sphere_n: f64,
    /// Hertz's force, N.
    pub hertz_n: f64,
    /// A point finger's force at the same depth, N.
    pub point_n: f64,
    /// Nodes in contact.
    pub contact_nodes: usize,
}

/// The study's outcome.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct HertzTable {
    /// Mesh nodes.
    pub nodes: usize,
    /// Cell size under the contact, m.
    pub h_m: f64,
    /// Poisson's ratio.
    pub poisson: f64,
    /// Per depth.
    pub rows: Vec<HertzRow>,
    /// The fitted exponent of the sphere's force against depth (least squares in log–log).
    pub exponent: f64,
    /// The fitted prefactor over Hertz's, with the exponent held at 3/2.
    pub prefactor_ratio: f64,
    /// The fitted exponent of the point finger's force.
    pub point_exponent: f64,
}

/// Fits `y = a·x^b` by least squares in log–log; returns `(a, b)`.
pub fn power_fit(x: &[f64], y: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    let lx: Vec<f64> = x.iter().map(|v| v.ln()).collect();
    let ly: Vec<f64> = y.iter().map(|v| v.ln()).collect();
    let mx = lx.iter().sum::<f64>() / n;
    let my = ly.iter().sum::<f64>() / n;
    let sxy: f64 = lx.iter().zip(&ly).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = lx.iter().map(|a| (a - mx).powi(2)).sum();
    let b = sxy / sxx;
    ((my - b * mx).exp(), b)
}

/// Hertz's force of a rigid sphere (radius `r`, m) pressed `d` (m) into a half-space.
pub fn hertz_force(young_pa: f64, poisson: f64, r: f64, d: f64) -> f64 {
    4.0 / 3.0 * young_pa / (1.0 - poisson * poisson) * r.sqrt() * d.powf(1.5)
}

/// The study's body: the graded block with its compliance for the top nodes the deepest press
/// can reach, and the middle of its top face (m).
pub fn block_body(s: &HertzSetup) -> Result<(Body, DVec3), Error> {
    let material = Material {
        young_pa: s.young_pa,
        poisson: s.poisson,
    };
    let mut mesh = graded_block(s.size_mm, s.fine_mm, s.h_mm, s.growth, material)
        .map_err(touchfem_core::Error::from)?;
    mesh.formulation = s.formulation;
    let mm = 1e-3;
    let top = DVec3::new(0.5 * s.size_mm[0], 0.5 * s.size_mm[1], s.size_mm[2]) * mm;
    let r = s.radius_mm * mm;
    let d_max = s.depths_mm.iter().cloned().fold(0.0, f64::max) * mm;
    let reach = 1.25 * (r * d_max).sqrt() + 2.0 * s.h_mm * mm;
    let touch: Vec<u32> = mesh
        .free_surface_nodes()
        .into_iter()
        .filter(|&v| {
            let p = mesh.nodes[v as usize];
            (p.z - top.z).abs() < 1e-9 && (p - top).truncate().length() <= reach
        })
        .collect();
    if touch.is_empty() {
        return Err(Error::Study("no touchable node under the sphere".into()));
    }
    let sel = Selection {
        rows: NodeSet::Nodes(touch.clone()),
        cols: NodeSet::Nodes(touch),
    };
    Ok((Body::new(mesh, &sel)?, top))
}

/// Runs the study: the graded block, its compliance for the top nodes under the sphere, the
/// sphere pressed to each depth (frictionless), and a point finger at the same depths.
pub fn study(s: &HertzSetup) -> Result<HertzTable, Error> {
    let mm = 1e-3;
    let r = s.radius_mm * mm;
    let (body, top) = block_body(s)?;
    let nodes = body.mesh.nodes.len();
    let mut rows = Vec::new();
    for &d in &s.depths_mm {
        let d = d * mm;
        let push = DVec3::new(0.0, 0.0, -d);
        let sphere = body.poke_sphere(top, push, r, None, None)?;
        log::debug!("{:?} cap {}", sphere.report, body.patch_capacity());
        let point = body.poke(
            top,
            push,
            touchfem_core::contact::force::ForceModel::Exact,
            1,
        )?;
        rows.push(HertzRow {
            depth_m: d,
            sphere_n: sphere.feedback.z,
            hertz_n: hertz_force(s.young_pa, s.poisson, r, d),
            point_n: point.feedback.z,
            contact_nodes: sphere.contact_nodes.len(),
        });
    }
    let ds: Vec<f64> = rows.iter().map(|r| r.depth_m).collect();
    let fs: Vec<f64> = rows.iter().map(|r| r.sphere_n).collect();
    let ps: Vec<f64> = rows.iter().map(|r| r.point_n).collect();
    let (_, exponent) = power_fit(&ds, &fs);
    let (_, point_exponent) = power_fit(&ds, &ps);
    // Prefactor with the exponent held at 3/2: least squares of F against d^{3/2}.
    let num: f64 = rows.iter().map(|r| r.sphere_n * r.hertz_n).sum();
    let den: f64 = rows.iter().map(|r| r.hertz_n * r.hertz_n).sum();
    Ok(HertzTable {
        nodes,
        h_m: s.h_mm * mm,
        poisson: s.poisson,
        rows,
        exponent,
        prefactor_ratio: num / den,
        point_exponent,
    })
}

/// Draws F against d on log–log axes: each table's sphere (one series per table), Hertz's
/// curve for the first table's material, and the first table's point finger.
pub fn write_plot(path: &std::path::Path, tables: &[(String, HertzTable)]) -> Result<(), Error> {
    use plotters::prelude::*;
    let perr = |e: String| Error::Study(format!("{}: cannot draw the plot: {e}", path.display()));
    crate::bench_plot::register_font();
    let Some((_, first)) = tables.first() else {
        return Err(Error::Study("no table to plot".into()));
    };
    let all = tables.iter().flat_map(|t| t.1.rows.iter());
    let (mut fmin, mut fmax) = (f64::INFINITY, 0.0f64);
    for r in all {
        for f in [r.sphere_n, r.hertz_n, r.point_n] {
            fmin = fmin.min(f);
            fmax = fmax.max(f);
        }
    }
    let dmin = first.rows.first().map_or(1e-4, |r| r.depth_m) * 1e3 * 0.8;
    let dmax = first.rows.last().map_or(2e-3, |r| r.depth_m) * 1e3 * 1.2;
    crate::bench_plot::draw_png(path, (720, 520), |root| {
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let mut chart = ChartBuilder::on(root)
            .caption(
                "A rigid sphere (R = 10 mm) pressed into a block: force against depth",
                ("sans-serif", 18),
            )
            .margin(14)
            .x_label_area_size(44)
            .y_label_area_size(70)
            .build_cartesian_2d(
                (dmin..dmax).log_scale(),
                (fmin * 0.7..fmax * 1.4).log_scale(),
            )
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc("depth d (mm)")
            .y_desc("force (N)")
            .draw()
            .map_err(|e| e.to_string())?;
        let hertz: Vec<(f64, f64)> = (0..=40)
            .map(|k| {
                let d = dmin * (dmax / dmin).powf(k as f64 / 40.0);
                let r = first
                    .rows
                    .first()
                    .map_or(0.0, |r| r.hertz_n / r.depth_m.powf(1.5));
                (d, r * (d * 1e-3).powf(1.5))
            })
            .collect();
        chart
            .draw_series(LineSeries::new(hertz, BLACK.stroke_width(2)))
            .map_err(|e| e.to_string())?
            .label(format!("Hertz, ν = {}", first.poisson))
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], BLACK.stroke_width(2)));
        let point: Vec<(f64, f64)> = first
            .rows
            .iter()
            .map(|r| (r.depth_m * 1e3, r.point_n))
            .collect();
        chart
            .draw_series(LineSeries::new(
                point.clone(),
                RGBColor(120, 120, 120).stroke_width(2),
            ))
            .map_err(|e| e.to_string())?
            .label("point finger (∝ d)")
            .legend(|(x, y)| {
                PathElement::new(
                    vec![(x, y), (x + 18, y)],
                    RGBColor(120, 120, 120).stroke_width(2),
                )
            });
        let palette = [
            RGBColor(230, 25, 75),
            RGBColor(0, 130, 200),
            RGBColor(60, 180, 75),
            RGBColor(245, 130, 48),
        ];
        for (k, (label, t)) in tables.iter().enumerate() {
            let c = palette[k % palette.len()];
            let pts: Vec<(f64, f64)> = t
                .rows
                .iter()
                .map(|r| (r.depth_m * 1e3, r.sphere_n))
                .collect();
            chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, 4, c.filled())))
                .map_err(|e| e.to_string())?
                .label(format!(
                    "{label}: exponent {:.3}, {:.3}× Hertz",
                    t.exponent, t.prefactor_ratio
                ))
                .legend(move |(x, y)| Circle::new((x + 9, y), 4, c.filled()));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(|e| e.to_string())?;
        Ok(())
    })
    .map_err(perr)
}
