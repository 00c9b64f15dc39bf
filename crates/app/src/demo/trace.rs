//! Each object's force trace from a recorded session: replayed tick by tick through the
//! haptic path (deterministic, so it is exactly the run's), written as CSV and drawn with
//! `plotters`.

use glam::DVec3;
use std::io::Write;
use std::path::Path;

use crate::error::Error;
use touchfem_core::contact::force::MAX_FINGERS;
use touchfem_core::runtime::session::Session;
use touchfem_core::runtime::{HapticWorld, WorldSample, MAX_OBJECTS};
use touchfem_core::scene::World;

/// The font the plots use (DejaVu Sans Mono, bundled).
pub use touchfem_gpu::render::FONT;

/// One object's force over a session: per tick, the sum of the forces sent to the fingers
/// touching it (N) and how many there were.
#[derive(Clone, Debug, Default)]
pub struct ForceTrace {
    /// Tick times, s.
    pub t: Vec<f64>,
    /// Summed finger forces, N.
    pub force: Vec<DVec3>,
    /// Fingers touching.
    pub contacts: Vec<u8>,
}

/// Replays `session` through `world`'s haptic path (its cuts at the ticks they were made)
/// and returns one trace per object.
pub fn traces(world: &World, session: &Session) -> Result<Vec<ForceTrace>, touchfem_core::Error> {
    let mut hw = HapticWorld::new(world);
    let mut cuts = touchfem_core::runtime::session::CutReplay::new(world, session)?;
    let n = session.header.fingers;
    let dt = 1.0 / session.header.rate_hz;
    let mut sample = WorldSample::default();
    let mut f = [DVec3::ZERO; MAX_FINGERS];
    let mut out = vec![ForceTrace::default(); world.objects.len().min(MAX_OBJECTS)];
    for (i, tick) in session.ticks.iter().enumerate() {
        hw.step_dt(tick.dt, &tick.positions[..n], &mut f[..n], &mut sample);
        for (o, tr) in out.iter_mut().enumerate() {
            let mut sum = DVec3::ZERO;
            let mut c = 0u8;
            for fv in sample.fingers() {
                if fv.object == Some(o as u8) {
                    sum += fv.force;
                    c += 1;
                }
            }
            tr.t.push(i as f64 * dt);
            tr.force.push(sum);
            tr.contacts.push(c);
        }
        cuts.after_tick(i, &mut hw)?;
    }
    Ok(out)
}

/// Writes a trace as CSV: `t_s,fx_n,fy_n,fz_n,force_n,contacts`.
pub(crate) fn write_csv(path: &Path, tr: &ForceTrace) -> Result<(), Error> {
    let werr = |source| Error::Write {
        path: path.to_path_buf(),
        source,
    };
    let mut w = std::io::BufWriter::new(std::fs::File::create(path).map_err(werr)?);
    writeln!(w, "t_s,fx_n,fy_n,fz_n,force_n,contacts").map_err(werr)?;
    for ((t, f), c) in tr.t.iter().zip(&tr.force).zip(&tr.contacts) {
        writeln!(
            w,
            "{t:.4},{:.6e},{:.6e},{:.6e},{:.6e},{c}",
            f.x,
            f.y,
            f.z,
            f.length()
        )
        .map_err(werr)?;
    }
    w.flush().map_err(werr)
}

/// Draws a trace (|F| and its components against time) to a PNG.
pub fn write_plot(path: &Path, title: &str, tr: &ForceTrace) -> Result<(), Error> {
    use plotters::prelude::*;
    let perr = |e: String| Error::Input(format!("{}: cannot draw the plot: {e}", path.display()));
    touchfem_lab::bench_plot::draw_png(path, (800, 400), |root| {
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let t_max = tr.t.last().copied().unwrap_or(1.0).max(1e-3);
        let f_max = tr
            .force
            .iter()
            .map(|f| f.abs().max_element().max(f.length()))
            .fold(0.0, f64::max)
            .max(1e-3)
            * 1.1;
        let mut chart = ChartBuilder::on(root)
            .caption(title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(36)
            .y_label_area_size(56)
            .build_cartesian_2d(0.0..t_max, -f_max..f_max)
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .x_desc("time (s)")
            .y_desc("force on the finger (N)")
            .draw()
            .map_err(|e| e.to_string())?;
        type Series = (&'static str, RGBColor, fn(&DVec3) -> f64);
        let series: [Series; 4] = [
            ("|F|", BLACK, |f| f.length()),
            ("Fx", RED, |f| f.x),
            ("Fy", GREEN, |f| f.y),
            ("Fz", BLUE, |f| f.z),
        ];
        for (name, color, get) in series {
            chart
                .draw_series(LineSeries::new(
                    tr.t.iter().zip(&tr.force).map(|(t, f)| (*t, get(f))),
                    color.stroke_width(2),
                ))
                .map_err(|e| e.to_string())?
                .label(name)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], color));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(|e| e.to_string())?;
        Ok(())
    })
    .map_err(perr)
}

/// Writes frames as an animated GIF (looping, `delay_ms` per frame).
pub(crate) fn write_gif(
    path: &Path,
    frames: &[image::RgbaImage],
    delay_ms: u32,
) -> Result<(), Error> {
    use image::codecs::gif::{GifEncoder, Repeat};
    let werr = |e: String| Error::Input(format!("{}: cannot write the GIF: {e}", path.display()));
    let file = std::fs::File::create(path).map_err(|e| werr(e.to_string()))?;
    let mut enc = GifEncoder::new_with_speed(std::io::BufWriter::new(file), 10);
    enc.set_repeat(Repeat::Infinite)
        .map_err(|e| werr(e.to_string()))?;
    for f in frames {
        let frame = image::Frame::from_parts(
            f.clone(),
            0,
            0,
            image::Delay::from_numer_denom_ms(delay_ms, 1),
        );
        enc.encode_frame(frame).map_err(|e| werr(e.to_string()))?;
    }
    Ok(())
}
