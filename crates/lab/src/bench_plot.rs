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

/// Draws the visual-update rows of `meshes` (panels left to right) into a PNG.
pub fn write_plot(path: &Path, rows: &[Row], meshes: &[&str]) -> Result<(), Error> {
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
    let n = meshes.len().max(1) as u32;
    let root = BitMapBackend::new(path, (560 * n + 220, 480)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| perr(e.to_string()))?;
    let (plots, legend) = root.split_horizontally(560 * n);
    let panels = plots.split_evenly((1, n as usize));
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
            .map_err(|e| perr(e.to_string()))?;
        chart
            .configure_mesh()
            .x_desc("time per frame (µs)")
            .y_desc("max |Δu| / max |u|")
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .x_label_formatter(&|v| format!("{v:.0e}"))
            .draw()
            .map_err(|e| perr(e.to_string()))?;
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
            .map_err(|e| perr(e.to_string()))?;
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
        .map_err(|e| perr(e.to_string()))?;
        legend
            .draw(&Text::new(
                m.to_string(),
                (30, y - 8),
                ("sans-serif", 15).into_font(),
            ))
            .map_err(|e| perr(e.to_string()))?;
    }
    legend
        .draw(&Text::new(
            format!("error 0 drawn at {ERROR_FLOOR:.0e}"),
            (8, 40 + 24 * methods.len() as i32 + 10),
            ("sans-serif", 13).into_font(),
        ))
        .map_err(|e| perr(e.to_string()))?;
    root.present().map_err(|e| perr(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_plot_has_a_marker_per_row() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.png");
        let row = |m: &str, t: f64, e: f64| Row {
            method: m.into(),
            mesh: "cube".into(),
            nodes: 125,
            active_columns: 9,
            time_us: t,
            rel_error: e,
        };
        let rows = vec![
            row("cpu-f64", 2.0, 0.0),
            row("cpu-f32", 3.0, 1e-7),
            row("cg-1e-6", 1000.0, 5e-7),
            row("force-paper", 0.1, 0.4),
        ];
        write_plot(&path, &rows, &["cube"]).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (780, 480));
        // The three visual methods' colours are drawn (black, red, green markers).
        for c in [[230u8, 25, 75], [60, 180, 75]] {
            let n = img.pixels().filter(|p| p.0 == c).count();
            assert!(n > 10, "colour {c:?}: {n} pixels");
        }
    }
}
