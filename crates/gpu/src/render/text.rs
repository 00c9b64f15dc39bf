//! Text rasterised on the CPU with ab_glyph from the bundled DejaVu Sans Mono: the one glyph
//! loop behind the status line ([`super::Overlay`]) and the legend.

use ab_glyph::{Font, FontRef, PxScale, ScaleFont};

/// The bundled font (`assets/DejaVuSansMono.ttf`).
pub const FONT: &[u8] = include_bytes!("../../../../assets/DejaVuSansMono.ttf");

/// The bundled font, parsed.
fn font() -> FontRef<'static> {
    FontRef::try_from_slice(FONT).expect("the bundled font parses")
}

/// Width of `text` at `px` pixels high, pixels.
pub(crate) fn text_width(text: &str, px: f32) -> f32 {
    let font = font();
    let scaled = font.as_scaled(PxScale::from(px));
    text.chars()
        .map(|c| scaled.h_advance(font.glyph_id(c)))
        .sum()
}

/// Ascent and descent (negative) of the font at `px` pixels high, pixels.
pub(crate) fn line_metrics(px: f32) -> (f32, f32) {
    let font = font();
    let scaled = font.as_scaled(PxScale::from(px));
    (scaled.ascent(), scaled.descent())
}

/// Rasterises one line of `text` at `px` pixels high with its top-left corner at (`x`, `y`):
/// calls `cover(px, py, v)` for each covered pixel (integer coordinates, possibly outside any
/// image; coverage `v` in [0, 1]). Characters the font lacks draw its `.notdef` glyph. Returns
/// the advance, pixels.
pub(crate) fn rasterize(
    text: &str,
    px: f32,
    x: f32,
    y: f32,
    mut cover: impl FnMut(i64, i64, f32),
) -> f32 {
    let font = font();
    let scale = PxScale::from(px);
    let scaled = font.as_scaled(scale);
    let mut pen = x;
    for c in text.chars() {
        let id = font.glyph_id(c);
        let glyph = id.with_scale_and_position(scale, ab_glyph::point(pen, y + scaled.ascent()));
        pen += scaled.h_advance(id);
        let Some(outline) = font.outline_glyph(glyph) else {
            continue;
        };
        let b = outline.px_bounds();
        outline.draw(|gx, gy, v| {
            cover(
                b.min.x as i64 + i64::from(gx),
                b.min.y as i64 + i64::from(gy),
                v.clamp(0.0, 1.0),
            );
        });
    }
    pen - x
}
