//! `touchfem bench --plot FILE.png`: time against error on log–log axes, one panel per mesh,
//! one colour and marker per visual-update method (each point one active-column count).

use std::path::Path;

use crate::error::Error;
use crate::tradeoff::Row;

/// Errors below this are drawn at it (the f64 reference has error 0).
pub(crate) const ERROR_FLOOR: f64 = 1e-16;

/// Registers the bundled font as plotters' "sans-serif" (once per process).
pub(crate) fn register_font() {
    static FONT_ONCE: std::sync::Once = std::sync::Once::new();
    FONT_ONCE.call_once(|| {
        let _ = plotters::style::register_font(
            "sans-serif",
            plotters::style::FontStyle::Normal,
            touchfem_gpu::render::FONT,
        );
    });
}

/// Draws with plotters into an RGB image of `size` pixels and writes it to `path` as a PNG
/// (with the bundled font registered as "sans-serif"). `draw` returns plotters' errors as text.
pub fn draw_png(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(
        &plotters::prelude::DrawingArea<
            plotters::prelude::BitMapBackend<'_>,
            plotters::coord::Shift,
        >,
    ) -> Result<(), String>,
) -> Result<(), String> {
    use plotters::prelude::*;
    register_font();
    let mut rgb = vec![0u8; size.0 as usize * size.1 as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, size).into_drawing_area();
        draw(&root)?;
        root.present().map_err(|e| e.to_string())?;
    }
    image::save_buffer_with_format(
        path,
        &rgb,
        size.0,
        size.1,
        image::ExtendedColorType::Rgb8,
        image::ImageFormat::Png,
    )
    .map_err(|e| e.to_string())
}

/// One hierarchical `L` for the memory panel: its worst point-load error and the bytes the
/// GPU holds, with the dense `L`'s beside it.
#[derive(Clone, Debug)]
pub struct MemoryPoint {
    /// Mesh name.
    pub mesh: String,
    /// Tolerance ε.
    pub tolerance: f64,
    /// Worst relative point-load error.
    pub error: f64,
    /// GPU bytes of the hierarchical `L`.
    pub gpu_bytes: f64,
    /// GPU bytes of the dense f32 `L`.
    pub dense_gpu_bytes: f64,
}

/// Draws the visual-update rows of `meshes` (panels left to right) into a PNG, then, when
/// `memory` has points, a panel of GPU memory against error (the hierarchical `L` at each
/// tolerance, the dense `L` as a dashed level per mesh).
pub fn write_plot(
    path: &Path,
    rows: &[Row],
    meshes: &[&str],
    memory: &[MemoryPoint],
) -> Result<(), Error> {
    use plotters::prelude::*;
    let perr = |e: String| Error::Study(format!("{}: cannot draw the plot: {e}", path.display()));
    register_font();
    let visual: Vec<&Row> = rows
        .iter()
        .filter(|r| crate::tradeoff::is_visual(r) && r.time_us > 0.0)
        .collect();
    let mut methods: Vec<&str> = Vec::new();
    for r in &visual {
        if !methods.contains(&r.method.as_str()) {
            methods.push(&r.method);
        }
    }
    let palette = [
        RGBColor(0, 0, 0),
        RGBColor(230, 25, 75),
        RGBColor(60, 180, 75),
        RGBColor(0, 130, 200),
        RGBColor(245, 130, 48),
        RGBColor(145, 30, 180),
        RGBColor(70, 150, 150),
        RGBColor(240, 50, 230),
        RGBColor(128, 128, 0),
        RGBColor(170, 110, 40),
        RGBColor(128, 0, 0),
        RGBColor(0, 0, 128),
        RGBColor(100, 100, 100),
        RGBColor(200, 160, 0),
    ];
    let n = meshes.len().max(1) as u32 + u32::from(!memory.is_empty());
    draw_png(path, (560 * n + 220, 480), |root| {
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let (plots, legend) = root.split_horizontally(560 * n);
        let panels = plots.split_evenly((1, n as usize));
        if let Some(panel) = panels.get(meshes.len()).filter(|_| !memory.is_empty()) {
            memory_panel(panel, memory, &palette)?;
        }
        for (panel, mesh) in panels.iter().zip(meshes) {
            let here: Vec<&&Row> = visual.iter().filter(|r| r.mesh == *mesh).collect();
            let tmin = here.iter().map(|r| r.time_us).fold(f64::INFINITY, f64::min);
            let tmax = here.iter().map(|r| r.time_us).fold(0.0, f64::max);
            let (tmin, tmax) = if here.is_empty() {
                (1.0, 10.0)
            } else {
                (tmin * 0.5, tmax * 2.0)
            };
            let nodes = here.first().map_or(0, |r| r.nodes);
            let mut chart = ChartBuilder::on(panel)
                .caption(
                    format!("{mesh} ({nodes} nodes): time against error"),
                    ("sans-serif", 18),
                )
                .margin(12)
                .x_label_area_size(40)
                .y_label_area_size(64)
                .build_cartesian_2d(
                    (tmin..tmax).log_scale(),
                    (ERROR_FLOOR * 0.5..1.0f64).log_scale(),
                )
                .map_err(|e| e.to_string())?;
            chart
                .configure_mesh()
                .x_desc("time per frame (µs)")
                .y_desc("max |Δu| / max |u|")
                .y_label_formatter(&|v| format!("{v:.0e}"))
                .x_label_formatter(&|v| format!("{v:.0e}"))
                .draw()
                .map_err(|e| e.to_string())?;
            for (i, m) in methods.iter().enumerate() {
                let color = palette[i % palette.len()];
                let pts: Vec<(f64, f64)> = here
                    .iter()
                    .filter(|r| r.method == *m)
                    .map(|r| (r.time_us, r.rel_error.max(ERROR_FLOOR)))
                    .collect();
                let style = color.filled();
                match i % 3 {
                    0 => chart
                        .draw_series(pts.iter().map(|p| Circle::new(*p, 5, style)))
                        .map(|_| ()),
                    1 => chart
                        .draw_series(pts.iter().map(|p| TriangleMarker::new(*p, 6, style)))
                        .map(|_| ()),
                    _ => chart
                        .draw_series(pts.iter().map(|p| Cross::new(*p, 5, color.stroke_width(2))))
                        .map(|_| ()),
                }
                .map_err(|e| e.to_string())?;
            }
        }
        // The legend: one line per method, in its colour.
        for (i, m) in methods.iter().enumerate() {
            let color = palette[i % palette.len()];
            let y = 40 + 24 * i as i32;
            match i % 3 {
                0 => legend.draw(&Circle::new((16, y), 5, color.filled())),
                1 => legend.draw(&TriangleMarker::new((16, y), 6, color.filled())),
                _ => legend.draw(&Cross::new((16, y), 5, color.stroke_width(2))),
            }
            .map_err(|e| e.to_string())?;
            legend
                .draw(&Text::new(
                    m.to_string(),
                    (30, y - 8),
                    ("sans-serif", 15).into_font(),
                ))
                .map_err(|e| e.to_string())?;
        }
        legend
            .draw(&Text::new(
                format!("error 0 drawn at {ERROR_FLOOR:.0e}"),
                (8, 40 + 24 * methods.len() as i32 + 10),
                ("sans-serif", 13).into_font(),
            ))
            .map_err(|e| e.to_string())?;
        Ok(())
    })
    .map_err(perr)
}

/// GPU memory (MB, log) against the worst point-load error (log), one colour per mesh.
fn memory_panel<DB: plotters::prelude::DrawingBackend>(
    panel: &plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
    memory: &[MemoryPoint],
    palette: &[plotters::prelude::RGBColor],
) -> Result<(), String> {
    use plotters::prelude::*;
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| x.to_string();
    let mb = |b: f64| (b / 1e6).max(1e-3);
    let ymin = memory
        .iter()
        .map(|p| mb(p.gpu_bytes))
        .fold(f64::INFINITY, f64::min)
        * 0.5;
    let ymax = memory
        .iter()
        .map(|p| mb(p.dense_gpu_bytes))
        .fold(0.0, f64::max)
        * 2.0;
    let xmin = memory
        .iter()
        .map(|p| p.error.max(ERROR_FLOOR))
        .fold(1.0, f64::min)
        * 0.3;
    let mut chart = ChartBuilder::on(panel)
        .caption(
            "hierarchical L: GPU memory against error",
            ("sans-serif", 18),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(64)
        .build_cartesian_2d((xmin..1.0f64).log_scale(), (ymin..ymax).log_scale())
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc("worst point-load error ‖Δu‖/‖u‖")
        .y_desc("GPU MB")
        .x_label_formatter(&|v| format!("{v:.0e}"))
        .draw()
        .map_err(e)?;
    let mut meshes: Vec<&str> = Vec::new();
    for p in memory {
        if !meshes.contains(&p.mesh.as_str()) {
            meshes.push(&p.mesh);
        }
    }
    for (i, mesh) in meshes.iter().enumerate() {
        let color = palette[(i + 1) % palette.len()];
        let pts: Vec<&MemoryPoint> = memory.iter().filter(|p| p.mesh == *mesh).collect();
        chart
            .draw_series(pts.iter().map(|p| {
                Circle::new(
                    (p.error.max(ERROR_FLOOR), mb(p.gpu_bytes)),
                    5,
                    color.filled(),
                )
            }))
            .map_err(e)?
            .label(format!("{mesh} (dashed: dense)"))
            .legend(move |(x, y)| Circle::new((x, y), 5, color.filled()));
        let dense = mb(pts[0].dense_gpu_bytes);
        chart
            .draw_series(DashedLineSeries::new(
                [(xmin, dense), (1.0, dense)],
                6,
                4,
                color.stroke_width(2),
            ))
            .map_err(e)?;
        for p in &pts {
            chart
                .draw_series(std::iter::once(Text::new(
                    format!("{:.0e}", p.tolerance),
                    (p.error.max(ERROR_FLOOR) * 1.15, mb(p.gpu_bytes) * 1.1),
                    ("sans-serif", 12).into_font(),
                )))
                .map_err(e)?;
        }
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(e)?;
    Ok(())
}
