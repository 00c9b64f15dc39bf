//! The displacement colour map (viridis), its legend (a colour bar labelled in mm, or µm or nm
//! for small displacements, and the force arrow's scale in mm per N or a readable variant) and
//! the "nice" scales both use.

use super::pixels::RgbaPixels;

/// Opacity of the legend's dark box (more than the status line's: it may lie over the object).
const BOX_ALPHA: f32 = 0.75;

/// Viridis (matplotlib's perceptually uniform colour map; van der Walt & Smith), sRGB, at
/// `i / 9` for `i = 0..=9`; linear in between. The renderer's fragments sample it through a
/// 256-entry table of it.
pub const VIRIDIS: [[u8; 3]; 10] = [
    [0x44, 0x01, 0x54],
    [0x48, 0x28, 0x78],
    [0x3e, 0x4a, 0x89],
    [0x31, 0x68, 0x8e],
    [0x26, 0x82, 0x8e],
    [0x1f, 0x9e, 0x89],
    [0x35, 0xb7, 0x79],
    [0x6d, 0xcd, 0x59],
    [0xb4, 0xde, 0x2c],
    [0xfd, 0xe7, 0x25],
];

/// The colour map at `t` (clamped to 0..=1), sRGB bytes.
pub fn viridis(t: f64) -> [u8; 3] {
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let x = t * (VIRIDIS.len() - 1) as f64;
    let i = (x.floor() as usize).min(VIRIDIS.len() - 2);
    let f = x - i as f64;
    let (a, b) = (VIRIDIS[i], VIRIDIS[i + 1]);
    std::array::from_fn(|k| {
        (f64::from(a[k]) + f * (f64::from(b[k]) - f64::from(a[k]))).round() as u8
    })
}

/// Entries of [`colormap_lut`].
pub(crate) const LUT_LEN: usize = 256;

/// The colour map as the renderer's fragments read it (`render.wgsl`'s `colormap_lut`): at
/// `t = i / 255`, interpolated in sRGB between the [`VIRIDIS`] stops like the legend, then
/// converted to linear RGB (alpha 1). A fragment interpolates linearly between two entries:
/// within 10⁻³ of the exact colour (two lookups instead of nine blends and three `pow`s a
/// pixel on a software rasteriser).
pub(crate) fn colormap_lut() -> [[f32; 4]; LUT_LEN] {
    let to_linear = |c: f64| {
        if c <= 0.04045 {
            c / 12.92
        } else {
            ((c + 0.055) / 1.055).powf(2.4)
        }
    };
    std::array::from_fn(|i| {
        let x = i as f64 / (LUT_LEN - 1) as f64 * (VIRIDIS.len() - 1) as f64;
        let k = (x.floor() as usize).min(VIRIDIS.len() - 2);
        let f = x - k as f64;
        let (a, b) = (VIRIDIS[k], VIRIDIS[k + 1]);
        let srgb = |j: usize| (f64::from(a[j]) + f * (f64::from(b[j]) - f64::from(a[j]))) / 255.0;
        [
            to_linear(srgb(0)) as f32,
            to_linear(srgb(1)) as f32,
            to_linear(srgb(2)) as f32,
            1.0,
        ]
    })
}

/// The smallest "nice" number (1, 2, 2.5 or 5 times a power of ten) at least `x` (up to a
/// relative 10⁻⁶, so that rounding keeps a nice `x` as it is); `x > 0` finite, else 1.
pub(crate) fn nice_ceil(x: f64) -> f64 {
    if !(x.is_finite() && x > 0.0) {
        return 1.0;
    }
    let p = 10f64.powf(x.log10().floor());
    for m in [1.0, 2.0, 2.5, 5.0, 10.0] {
        if m * p >= x * (1.0 - 1e-6) {
            return m * p;
        }
    }
    10.0 * p
}

/// The largest "nice" number (1, 2 or 5 times a power of ten) at most `x`; `x > 0` finite, else 1.
pub(crate) fn nice_floor(x: f64) -> f64 {
    if !(x.is_finite() && x > 0.0) {
        return 1.0;
    }
    let p = 10f64.powf(x.log10().floor());
    for m in [5.0, 2.0, 1.0] {
        if m * p <= x * (1.0 + 1e-6) {
            return m * p;
        }
    }
    p
}

/// The colour scale's full-scale displacement for a largest displacement `max_m` (m): a tick
/// step of 1, 2, 2.5 or 5 times a power of ten, and the smallest multiple of it at least
/// `max_m`, with 4 or 5 steps (8 mm → 0..8 in steps of 2; 7.05 mm → 0..8; 5 mm → 0..5 in 1).
/// Returns (full scale, step), both metres.
pub fn displacement_scale(max_m: f64) -> (f64, f64) {
    if !(max_m.is_finite() && max_m > 0.0) {
        return (1e-3, 2.5e-4);
    }
    let step = nice_ceil(max_m / 5.0);
    let n = (max_m / step * (1.0 - 1e-6)).ceil().max(1.0);
    (n * step, step)
}

/// The force arrow's scale (m of arrow per N) that draws a force of `force_n` newtons about
/// `length_m` long, rounded down to a nice number (so the arrow is at most that long).
pub fn arrow_scale(force_n: f64, length_m: f64) -> f64 {
    if !(force_n.is_finite() && force_n > 0.0 && length_m > 0.0) {
        return 1e-3;
    }
    // In mm per N, rounded down to 1, 2, 5 × 10^k.
    nice_floor(length_m * 1e3 / force_n) * 1e-3
}

/// What the legend shows.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LegendSpec {
    /// Height of the colour bar, pixels (e.g. [`LegendSpec::bar_for`] the image height); the
    /// text is a tenth of it, 10 to 14 pixels.
    pub bar_px: u32,
    /// The colour bar: full scale and tick step of |u|, metres (see [`displacement_scale`]).
    pub displacement: Option<(f64, f64)>,
    /// The force arrow's scale, metres of arrow per newton.
    pub arrow_m_per_n: Option<f64>,
    /// The force to print, newtons (the arrow's length), if any.
    pub force_n: Option<f64>,
}

impl LegendSpec {
    /// A colour bar height for an image `height` pixels high: a third of it, 60 to 150 pixels.
    pub fn bar_for(height: u32) -> u32 {
        (height / 3).clamp(60, 150)
    }
}

/// Text height of the legend for a colour bar `bar_px` high: a tenth of it, 10 to 14 pixels
/// (so the legend stays a corner of a small image).
fn text_px(bar_px: u32) -> f32 {
    (bar_px as f32 / 10.0).clamp(10.0, 14.0)
}
/// Colour bar width, pixels.
const BAR_W: u32 = 18;
/// Margin inside the legend box, pixels.
const MARGIN: u32 = 8;

/// Formats `v` with as many decimals as `step` needs (at most 3); never `-0`.
fn label(v: f64, step: f64) -> String {
    let decimals = (0..=3)
        .find(|&d| {
            let s = step * 10f64.powi(d);
            (s - s.round()).abs() < 1e-6 * s.abs().max(1.0)
        })
        .unwrap_or(3);
    no_negative_zero(format!("{v:.*}", decimals as usize))
}

/// `"0"` for a formatted number that reads as zero (`-0`, `0.000`, `-0.00`), else `s`.
fn no_negative_zero(s: String) -> String {
    let mantissa = s.split(['e', 'E']).next().unwrap_or("");
    if mantissa.chars().all(|c| matches!(c, '-' | '+' | '0' | '.')) {
        "0".into()
    } else {
        s
    }
}

/// `v` in scientific notation with `digits` decimals in the mantissa (`2.50e-11`); `0` for zero.
fn scientific(v: f64, digits: usize) -> String {
    if v == 0.0 || !v.is_finite() {
        return if v.is_finite() {
            "0".into()
        } else {
            format!("{v}")
        };
    }
    no_negative_zero(format!("{v:.digits$e}"))
}

/// `v` with `sig` significant digits, trailing zeros dropped (`1000`, `0.676`, `25`, `1e-4`);
/// scientific below 1e-3 or from 1e6 on; never `-0`.
pub fn format_significant(v: f64, sig: usize) -> String {
    if v == 0.0 || !v.is_finite() {
        return if v.is_finite() {
            "0".into()
        } else {
            format!("{v}")
        };
    }
    let sig = sig.clamp(1, 12);
    let e = v.abs().log10().floor() as i32;
    if !(-3..6).contains(&e) {
        let s = scientific(v, sig - 1);
        return match s.split_once('e') {
            Some((m, exp)) if m.contains('.') => {
                format!("{}e{exp}", m.trim_end_matches('0').trim_end_matches('.'))
            }
            _ => s,
        };
    }
    let decimals = (sig as i32 - 1 - e).max(0) as usize;
    let mut s = format!("{v:.decimals$}");
    if s.contains('.') {
        s = s.trim_end_matches('0').trim_end_matches('.').to_string();
    }
    no_negative_zero(s)
}

/// The labels of a length scale (the colour bar): the unit they are in and, for each tick
/// from 0 to the full scale, its place on the bar (0 at the bottom, 1 at the top) and its text.
#[derive(Clone, Debug, PartialEq)]
pub struct LengthTicks {
    /// The unit of every label: `mm`, `µm`, `nm`, or `m` (scientific labels).
    pub unit: &'static str,
    /// (fraction of the full scale, label), from 0 up.
    pub ticks: Vec<(f64, String)>,
}

/// The most ticks [`length_ticks`] draws; a finer step is replaced by [`displacement_scale`]'s.
const MAX_TICKS: f64 = 50.0;

/// Labels for a scale from 0 to `full_m` every `step_m` (metres) that read right at any size:
/// the largest of mm, µm and nm in which the step is at least 0.1 (so the labels need at most
/// two decimals and differ), else scientific notation in m with enough digits that they
/// differ; `0` for zero, never `-0`. A step that is not positive and finite, or gives more than
/// 50 ticks, is replaced by the nice step of [`displacement_scale`]`(full_m)`.
/// `(1e-7, 2e-8)` gives `0, 20, 40, 60, 80, 100` nm; `(8e-3, 2e-3)` gives `0, 2, 4, 6, 8` mm.
pub fn length_ticks(full_m: f64, step_m: f64) -> LengthTicks {
    let ok =
        |f: f64, s: f64| f.is_finite() && s.is_finite() && f > 0.0 && s > 0.0 && f / s <= MAX_TICKS;
    let (full, step) = if ok(full_m, step_m) {
        (full_m, step_m)
    } else {
        displacement_scale(full_m)
    };
    let n = (full / step).round().max(1.0) as usize;
    let values: Vec<f64> = (0..=n).map(|i| i as f64 * step).collect();
    let place = |v: f64| v / full;
    for (unit, scale) in [("mm", 1e-3), ("µm", 1e-6), ("nm", 1e-9)] {
        let s = step / scale;
        if s >= 0.1 * (1.0 - 1e-9) && full / scale < 1e6 {
            let ticks = values
                .iter()
                .map(|&v| (place(v), label(v / scale, s)))
                .collect();
            return LengthTicks { unit, ticks };
        }
    }
    // Scientific, in metres: as many mantissa digits as the step's decade needs.
    let mantissa_digits = |v: f64| {
        let step_exp = step.log10().floor();
        let step_mantissa = step / 10f64.powf(step_exp);
        let extra = usize::from((step_mantissa * 10.0).round() % 10.0 != 0.0);
        ((v.log10().floor() - step_exp).max(0.0) as usize + extra).min(8)
    };
    let ticks = values
        .iter()
        .map(|&v| {
            let text = if v == 0.0 {
                "0".to_string()
            } else {
                scientific(v, mantissa_digits(v))
            };
            (place(v), text)
        })
        .collect();
    LengthTicks { unit: "m", ticks }
}

/// The force arrow's scale as the legend states it (`arrow 20 mm/N`): mm per N while that
/// reads 0.1 to 9999, else per mN, µN or nN for small forces, µm or nm per N for large ones,
/// else scientific in m/N.
pub fn arrow_label(m_per_n: f64) -> String {
    if !(m_per_n.is_finite() && m_per_n > 0.0) {
        return "arrow - mm/N".into();
    }
    let mm_per_n = m_per_n * 1e3;
    let candidates = [
        ("mm/N", mm_per_n),
        ("mm/mN", mm_per_n * 1e-3),
        ("mm/µN", mm_per_n * 1e-6),
        ("mm/nN", mm_per_n * 1e-9),
        ("µm/N", mm_per_n * 1e3),
        ("nm/N", mm_per_n * 1e6),
    ];
    match candidates
        .iter()
        .find(|(_, v)| (0.1 * (1.0 - 1e-9)..1e4).contains(v))
    {
        Some((unit, v)) => format!("arrow {} {unit}", format_significant(*v, 3)),
        None => format!("arrow {} m/N", scientific(m_per_n, 2)),
    }
}

/// Alpha-blends white text into `img` with its top-left corner at (`x`, `y`).
fn draw_text(img: &mut RgbaPixels, x: f32, y: f32, text: &str, px: f32) -> f32 {
    let (w, h) = (i64::from(img.width()), i64::from(img.height()));
    super::text::rasterize(text, px, x, y, |px, py, v| {
        if (0..w).contains(&px) && (0..h).contains(&py) {
            let p = img.get_pixel_mut(px as u32, py as u32);
            // Over a straight-alpha pixel: white with coverage v.
            let a0 = f32::from(p[3]) / 255.0;
            let a = v + a0 * (1.0 - v);
            for ch in p.iter_mut().take(3) {
                let c0 = f32::from(*ch) / 255.0;
                let c = if a > 0.0 {
                    (v + c0 * a0 * (1.0 - v)) / a
                } else {
                    0.0
                };
                *ch = (255.0 * c).round() as u8;
            }
            p[3] = (255.0 * a).round() as u8;
        }
    })
}

/// The legend as a straight-alpha RGBA image (white text and the colour bar on a translucent
/// dark box): `|u| (mm)` over a vertical viridis bar, 0 at the bottom, ticks every step; then
/// the arrow's scale (`arrow 20 mm/N`) and the force (`|F| 0.676 N`). `None` when the spec shows
/// nothing.
pub fn legend_image(spec: &LegendSpec) -> Option<RgbaPixels> {
    let px = text_px(spec.bar_px);
    let line = (px * 1.3).ceil() as u32;
    let mut lines: Vec<String> = Vec::new();
    if let Some(m_per_n) = spec.arrow_m_per_n {
        lines.push(arrow_label(m_per_n));
    }
    if let Some(f) = spec.force_n {
        lines.push(format!("|F| {} N", format_force(f)));
    }
    let (bar_h, ticks, unit) = match spec.displacement {
        Some((full, step)) => {
            let t = length_ticks(full, step);
            (spec.bar_px.max(20), t.ticks, t.unit)
        }
        None => (0, Vec::new(), "mm"),
    };
    if bar_h == 0 && lines.is_empty() {
        return None;
    }
    let title = format!("|u| ({unit})");
    let title = title.as_str();
    let tick_w = ticks
        .iter()
        .map(|(_, s)| super::text::text_width(s, px))
        .fold(0.0f32, f32::max);
    let mut w = lines
        .iter()
        .map(|s| super::text::text_width(s, px))
        .fold(0.0f32, f32::max);
    if bar_h > 0 {
        w = w
            .max(super::text::text_width(title, px))
            .max(BAR_W as f32 + 6.0 + tick_w);
    }
    let w = w.ceil() as u32 + 2 * MARGIN;
    let bar_block = if bar_h > 0 {
        line + bar_h + line / 2 + 4
    } else {
        0
    };
    let h = MARGIN * 2 + bar_block + line * lines.len() as u32;
    let box_a = (255.0 * BOX_ALPHA).round() as u8;
    let mut img = RgbaPixels::from_pixel(w, h, [0, 0, 0, box_a]);
    let mut y = MARGIN as f32;
    if bar_h > 0 {
        draw_text(&mut img, MARGIN as f32, y, title, px);
        // The bar starts half a line below the title so the top tick's label fits.
        let top = (y as u32) + line + line / 2 - 2;
        for j in 0..bar_h {
            let t = 1.0 - f64::from(j) / f64::from(bar_h - 1);
            let [r, g, b] = viridis(t);
            for i in 0..BAR_W {
                img.put_pixel(MARGIN + i, top + j, [r, g, b, 255]);
            }
        }
        for (t, s) in &ticks {
            let ty = top + ((1.0 - t) * f64::from(bar_h - 1)).round() as u32;
            for i in 0..4 {
                img.put_pixel(MARGIN + BAR_W + i, ty, [255, 255, 255, 255]);
            }
            let text_y = ty as f32 - px * 0.6;
            draw_text(&mut img, (MARGIN + BAR_W + 6) as f32, text_y, s, px);
        }
        y = (top + bar_h + line / 2 + 4) as f32;
    }
    for s in &lines {
        draw_text(&mut img, MARGIN as f32, y, s, px);
        y += line as f32;
    }
    Some(img)
}

/// A force in newtons with three significant digits (scientific below 1 mN and from 1 MN);
/// never `-0`.
fn format_force(f: f64) -> String {
    if f == 0.0 || !f.is_finite() {
        return if f.is_finite() {
            "0".into()
        } else {
            format!("{f}")
        };
    }
    let e = f.abs().log10().floor() as i32;
    if !(-3..6).contains(&e) {
        return scientific(f, 2);
    }
    let digits = (2 - e).max(0);
    no_negative_zero(format!("{f:.*}", digits as usize))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::text::FONT;
    use ab_glyph::{Font, FontRef};

    #[test]
    fn nice_scales() {
        let (full, step) = displacement_scale(8e-3);
        assert!((full - 8e-3).abs() < 1e-12 && (step - 2e-3).abs() < 1e-12);
        let (full, step) = displacement_scale(7.05e-3);
        assert!((full - 8e-3).abs() < 1e-12 && (step - 2e-3).abs() < 1e-12);
        let (full, step) = displacement_scale(5e-3);
        assert!((full - 5e-3).abs() < 1e-12 && (step - 1e-3).abs() < 1e-12);
        let (full, step) = displacement_scale(0.3e-3);
        assert!((full - 0.3e-3).abs() < 1e-12 && (step - 0.1e-3).abs() < 1e-12);
        assert_eq!(nice_ceil(3.0), 5.0);
        assert_eq!(nice_floor(19.3), 10.0);
        assert!((arrow_scale(0.676, 0.013) * 1e3 - 10.0).abs() < 1e-9);
        assert!((arrow_scale(0.028, 0.037) * 1e3 - 1000.0).abs() < 1e-6);
        assert_eq!(format_force(0.675621), "0.676");
        assert_eq!(format_force(0.028036), "0.0280");
        assert_eq!(label(2.5, 2.5), "2.5");
        assert_eq!(label(8.0, 2.0), "8");
    }

    fn texts(t: &LengthTicks) -> Vec<&str> {
        t.ticks.iter().map(|(_, s)| s.as_str()).collect()
    }

    /// Every tick label differs from the others, none reads `-0` or a bare `-`.
    fn distinct_and_clean(t: &LengthTicks) {
        let s = texts(t);
        let mut seen = std::collections::BTreeSet::new();
        for l in &s {
            assert!(seen.insert(*l), "duplicate label {l} in {s:?}");
            assert!(!l.starts_with('-'), "{s:?}");
        }
        assert_eq!(s[0], "0", "{s:?}");
        assert_eq!(t.ticks[0].0, 0.0);
        assert!((t.ticks.last().unwrap().0 - 1.0).abs() < 1e-9);
    }

    #[test]
    fn length_labels_read_right_at_any_scale() {
        // The usual millimetre scales are as before.
        let t = length_ticks(8e-3, 2e-3);
        assert_eq!((t.unit, texts(&t)), ("mm", vec!["0", "2", "4", "6", "8"]));
        let t = length_ticks(5e-3, 2.5e-3);
        assert_eq!(texts(&t), vec!["0", "2.5", "5.0"]);
        let t = length_ticks(0.3e-3, 0.1e-3);
        assert_eq!((t.unit, texts(&t)), ("mm", vec!["0", "0.1", "0.2", "0.3"]));
        // 0 .. 1e-7 m (poke --push 0,0,-0.0001 in mm): nanometres, distinct.
        let (full, step) = displacement_scale(1e-7);
        let t = length_ticks(full, step);
        assert_eq!(t.unit, "nm");
        assert_eq!(texts(&t), vec!["0", "20", "40", "60", "80", "100"]);
        // Micrometres.
        let t = length_ticks(5e-5, 1e-5);
        assert_eq!(
            (t.unit, texts(&t)),
            ("µm", vec!["0", "10", "20", "30", "40", "50"])
        );
        let t = length_ticks(2e-7, 5e-8);
        assert_eq!(t.unit, "nm");
        // Below a tenth of a nanometre: scientific metres, still distinct.
        let (full, step) = displacement_scale(1e-13);
        let t = length_ticks(full, step);
        assert_eq!(t.unit, "m");
        assert!(texts(&t)[1].contains("e-"), "{:?}", texts(&t));
        distinct_and_clean(&t);
        // Every scale from 1e-15 m to 100 m gives distinct, clean labels.
        for k in -150..=20 {
            let max = 10f64.powf(k as f64 / 10.0) * 1.37;
            let (full, step) = displacement_scale(max);
            let t = length_ticks(full, step);
            assert!(t.ticks.len() >= 2 && t.ticks.len() <= 7, "{max}: {t:?}");
            distinct_and_clean(&t);
        }
        // A nonsense step is replaced by a nice one instead of drawing a million ticks.
        for (full, step) in [
            (1.0, 1e-300),
            (1e-3, 0.0),
            (1e-3, f64::NAN),
            (f64::NAN, 1.0),
        ] {
            let t = length_ticks(full, step);
            assert!(t.ticks.len() <= 51, "{full} {step}: {}", t.ticks.len());
        }
    }

    #[test]
    fn zero_never_reads_negative() {
        assert_eq!(label(-0.0, 0.001), "0");
        assert_eq!(label(-0.0001, 0.001), "0");
        assert_eq!(label(0.0, 2.0), "0");
        assert_eq!(format_significant(-0.0, 3), "0");
        assert_eq!(format_significant(0.0, 3), "0");
        assert_eq!(format_force(-0.0), "0");
        assert_eq!(scientific(-0.0, 2), "0");
        assert_eq!(no_negative_zero("-0.000".into()), "0");
        assert_eq!(no_negative_zero("-0.0e0".into()), "0");
        assert_eq!(no_negative_zero("-0.001".into()), "-0.001");
    }

    #[test]
    fn arrow_and_force_labels_pick_a_readable_unit() {
        assert_eq!(arrow_label(0.010), "arrow 10 mm/N");
        assert_eq!(arrow_label(1.0), "arrow 1000 mm/N");
        assert_eq!(arrow_label(2.5e-4), "arrow 0.25 mm/N");
        // The tiny poke: 1e8 mm/N reads 100 mm/µN.
        assert_eq!(arrow_label(1e5), "arrow 100 mm/µN");
        assert_eq!(arrow_label(20.0), "arrow 20 mm/mN");
        assert_eq!(arrow_label(5e-6), "arrow 5 µm/N");
        assert_eq!(arrow_label(2e-9), "arrow 2 nm/N");
        assert!(arrow_label(1e20).ends_with(" m/N"), "{}", arrow_label(1e20));
        assert!(
            arrow_label(1e-20).contains("e-20"),
            "{}",
            arrow_label(1e-20)
        );
        assert_eq!(format_force(2.8e-7), "2.80e-7");
        assert_eq!(format_force(12.34), "12.3");
        assert_eq!(format_significant(1000.0, 3), "1000");
        assert_eq!(format_significant(0.25, 3), "0.25");
        assert_eq!(format_significant(1e-4, 6), "1e-4");
        assert_eq!(format_significant(-1.35124e-5, 6), "-1.35124e-5");
    }

    /// The bundled font draws the units' µ.
    #[test]
    fn the_font_has_micro() {
        let font = FontRef::try_from_slice(FONT).unwrap();
        assert_ne!(font.glyph_id('µ').0, 0);
    }

    #[test]
    fn viridis_ends_and_middle() {
        assert_eq!(viridis(0.0), VIRIDIS[0]);
        assert_eq!(viridis(1.0), VIRIDIS[9]);
        assert_eq!(viridis(-1.0), VIRIDIS[0]);
        assert_eq!(viridis(f64::NAN), VIRIDIS[0]);
        assert_eq!(viridis(4.0 / 9.0), VIRIDIS[4]);
    }

    /// The fragments' table: sRGB-interpolated viridis, linearised; between entries (as the
    /// shader reads it) within 10⁻³ of the exact colour, and at the stops the legend's bytes.
    #[test]
    fn colormap_lut_follows_the_legend() {
        let lut = super::colormap_lut();
        let to_srgb = |c: f64| {
            if c <= 0.0031308 {
                12.92 * c
            } else {
                1.055 * c.powf(1.0 / 2.4) - 0.055
            }
        };
        let exact = |t: f64| -> [f64; 3] {
            let x = t * 9.0;
            let k = (x.floor() as usize).min(8);
            let f = x - k as f64;
            std::array::from_fn(|j| {
                let (a, b) = (f64::from(VIRIDIS[k][j]), f64::from(VIRIDIS[k + 1][j]));
                let c: f64 = (a + f * (b - a)) / 255.0;
                if c <= 0.04045 {
                    c / 12.92
                } else {
                    ((c + 0.055) / 1.055).powf(2.4)
                }
            })
        };
        let mut worst = 0.0f64;
        for s in 0..=10_000 {
            let t = s as f64 / 10_000.0;
            // As render.wgsl's `viridis`.
            let x = t * 255.0;
            let i = (x.floor() as usize).min(254);
            let f = x - i as f64;
            let e = exact(t);
            for j in 0..3 {
                let got = f64::from(lut[i][j]) + f * f64::from(lut[i + 1][j] - lut[i][j]);
                worst = worst.max((got - e[j]).abs());
            }
        }
        assert!(worst < 1e-3, "worst {worst:e}");
        for (k, stop) in VIRIDIS.iter().enumerate() {
            // Stop k sits at t = k/9; the nearest entries bracket it.
            let t = k as f64 / 9.0;
            let e = exact(t);
            for j in 0..3 {
                assert_eq!((to_srgb(e[j]) * 255.0).round() as u8, stop[j], "stop {k}");
            }
        }
        assert_eq!(lut[0][3], 1.0);
    }

    #[test]
    fn legend_shows_the_bar_and_the_arrow_scale() {
        let spec = LegendSpec {
            bar_px: 150,
            displacement: Some((8e-3, 2e-3)),
            arrow_m_per_n: Some(1.0),
            force_n: Some(0.028),
        };
        let img = legend_image(&spec).expect("a legend");
        assert!(img.height() > 150 && img.width() > BAR_W);
        // The bar's bottom is viridis(0), its top viridis(1).
        let x = MARGIN + BAR_W / 2;
        let col: Vec<[u8; 3]> = (0..img.height())
            .map(|y| {
                let p = img.get_pixel(x, y);
                [p[0], p[1], p[2]]
            })
            .collect();
        assert!(col.contains(&VIRIDIS[0]) && col.contains(&VIRIDIS[9]));
        assert!(legend_image(&LegendSpec {
            bar_px: 150,
            displacement: None,
            arrow_m_per_n: None,
            force_n: None
        })
        .is_none());
    }
}
