//! A status line of text over the frame: rasterised on the CPU with ab_glyph from the bundled
//! DejaVu Sans Mono into a small RGBA texture (only when the text changes, a few times a
//! second), drawn as a screen-space quad, blended.

use bytemuck::{Pod, Zeroable};

use super::pixels::RgbaPixels;

use super::{depth_state, multisample, uniform_layout, RenderOptions};

/// The WGSL source of the overlay (`shaders/overlay.wgsl`).
pub(crate) const OVERLAY_WGSL: &str = include_str!("../../../../shaders/overlay.wgsl");

/// Padding around the text, pixels.
const PAD: f32 = 4.0;
/// Opacity of the dark box behind the text.
const BOX_ALPHA: f32 = 0.55;
/// Distance of the image from the target's edges, pixels (see [`Anchor`]).
const ORIGIN: [f32; 2] = [8.0, 8.0];

/// Which corner of the target an [`Overlay`] sits in, 8 pixels from its edges.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Anchor {
    /// The top-left corner (the status line).
    #[default]
    TopLeft,
    /// The top-right corner (the legend).
    TopRight,
}
/// Text height, pixels.
pub(super) const TEXT_PX: f32 = 15.0;

/// Rasterises one line of `text` at `px` pixels high: white glyphs on a translucent dark box
/// (straight alpha), with a 4-pixel margin. Characters the font lacks draw its `.notdef`
/// glyph.
pub(crate) fn rasterize_text(text: &str, px: f32) -> RgbaPixels {
    let px = px.max(1.0);
    let (ascent, descent) = super::text::line_metrics(px);
    let w = (super::text::text_width(text, px) + 2.0 * PAD)
        .ceil()
        .max(1.0) as u32;
    let h = (ascent - descent + 2.0 * PAD).ceil().max(1.0) as u32;
    let mut coverage = vec![0f32; (w * h) as usize];
    super::text::rasterize(text, px, PAD, PAD, |px, py, v| {
        if (0..i64::from(w)).contains(&px) && (0..i64::from(h)).contains(&py) {
            let c = &mut coverage[(py as u32 * w + px as u32) as usize];
            *c = c.max(v);
        }
    });
    RgbaPixels::from_fn(w, h, |x, y| {
        let c = coverage[(y * w + x) as usize];
        // White text over a black box of opacity BOX_ALPHA, as one straight-alpha layer.
        let a = c + (1.0 - c) * BOX_ALPHA;
        let v = if a > 0.0 { c / a } else { 0.0 };
        let v8 = (255.0 * v).round() as u8;
        [v8, v8, v8, (255.0 * a).round() as u8]
    })
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct QuadGpu {
    rect: [f32; 4],
    target_size: [f32; 4],
}

/// A text overlay for a [`super::Renderer`] of the same [`RenderOptions`]: set its text with
/// [`set_text`](Self::set_text) (which re-rasterises only when the text changed) and pass it in
/// [`super::Frame::overlay`].
#[derive(Debug)]
pub struct Overlay {
    pipeline: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
    uniform: wgpu::Buffer,
    image: Option<(wgpu::BindGroup, [u32; 2])>,
    text: String,
    anchor: Anchor,
}

impl Overlay {
    /// Builds the overlay's pipeline for targets drawn with `options`.
    pub fn new(device: &wgpu::Device, options: RenderOptions) -> Overlay {
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("touchfem overlay.wgsl"),
            source: wgpu::ShaderSource::Wgsl(OVERLAY_WGSL.into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("touchfem overlay"),
            entries: &[
                uniform_layout(0, wgpu::ShaderStages::VERTEX_FRAGMENT, false, None),
                wgpu::BindGroupLayoutEntry {
                    binding: 1,
                    visibility: wgpu::ShaderStages::FRAGMENT,
                    ty: wgpu::BindingType::Texture {
                        sample_type: wgpu::TextureSampleType::Float { filterable: false },
                        view_dimension: wgpu::TextureViewDimension::D2,
                        multisampled: false,
                    },
                    count: None,
                },
            ],
        });
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("touchfem overlay"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some("touchfem overlay"),
            layout: Some(&pl),
            vertex: wgpu::VertexState {
                module: &module,
                entry_point: Some("vs_overlay"),
                compilation_options: Default::default(),
                buffers: &[],
            },
            primitive: wgpu::PrimitiveState {
                topology: wgpu::PrimitiveTopology::TriangleStrip,
                ..Default::default()
            },
            // The pass has a depth attachment; the overlay ignores it.
            depth_stencil: Some(depth_state(false, wgpu::CompareFunction::Always)),
            multisample: multisample(options.samples),
            fragment: Some(wgpu::FragmentState {
                module: &module,
                entry_point: Some("fs_overlay"),
                compilation_options: Default::default(),
                targets: &[Some(wgpu::ColorTargetState {
                    format: options.format,
                    blend: Some(wgpu::BlendState::ALPHA_BLENDING),
                    write_mask: wgpu::ColorWrites::ALL,
                })],
            }),
            multiview_mask: None,
            cache: None,
        });
        let uniform = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("touchfem overlay quad"),
            size: std::mem::size_of::<QuadGpu>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Overlay {
            pipeline,
            layout,
            uniform,
            image: None,
            text: String::new(),
            anchor: Anchor::TopLeft,
        }
    }

    /// Puts the overlay in `anchor`'s corner (default [`Anchor::TopLeft`]).
    pub fn set_anchor(&mut self, anchor: Anchor) {
        self.anchor = anchor;
    }

    /// Size of the image shown (width, height), pixels; `None` when hidden.
    pub fn image_size(&self) -> Option<[u32; 2]> {
        self.image.as_ref().map(|(_, s)| *s)
    }

    /// The text shown.
    pub fn text(&self) -> &str {
        &self.text
    }

    /// Shows `text` (one line): re-rasterises and uploads it when it differs from the text
    /// shown; an empty text hides the overlay.
    pub fn set_text(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, text: &str) {
        if text == self.text && (self.image.is_some() || text.is_empty()) {
            return;
        }
        self.text = text.to_string();
        if text.is_empty() {
            self.image = None;
            return;
        }
        let img = rasterize_text(text, TEXT_PX);
        self.upload(device, queue, &img);
    }

    /// Shows `img` (straight-alpha sRGB RGBA, drawn 1:1), e.g. a [`super::legend_image`];
    /// `None` hides the overlay. The text of [`text`](Self::text) is cleared.
    pub fn set_image(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        img: Option<&RgbaPixels>,
    ) {
        self.text.clear();
        match img {
            Some(img) => self.upload(device, queue, img),
            None => self.image = None,
        }
    }

    fn upload(&mut self, device: &wgpu::Device, queue: &wgpu::Queue, img: &RgbaPixels) {
        let size = wgpu::Extent3d {
            width: img.width(),
            height: img.height(),
            depth_or_array_layers: 1,
        };
        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("touchfem overlay text"),
            size,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba8UnormSrgb,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        queue.write_texture(
            texture.as_image_copy(),
            img.as_raw(),
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(4 * img.width()),
                rows_per_image: Some(img.height()),
            },
            size,
        );
        let view = texture.create_view(&Default::default());
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("touchfem overlay"),
            layout: &self.layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: self.uniform.as_entire_binding(),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: wgpu::BindingResource::TextureView(&view),
                },
            ],
        });
        self.image = Some((bind_group, [img.width(), img.height()]));
    }

    /// Writes the quad's placement for a target of `target` pixels.
    pub(super) fn prepare(&self, queue: &wgpu::Queue, target: [u32; 2]) {
        if let Some((_, [w, h])) = &self.image {
            let x = match self.anchor {
                Anchor::TopLeft => ORIGIN[0],
                Anchor::TopRight => target[0] as f32 - ORIGIN[0] - *w as f32,
            };
            let q = QuadGpu {
                rect: [x, ORIGIN[1], *w as f32, *h as f32],
                target_size: [target[0] as f32, target[1] as f32, 0.0, 0.0],
            };
            queue.write_buffer(&self.uniform, 0, bytemuck::bytes_of(&q));
        }
    }

    /// Draws the quad into `pass` (after [`prepare`](Self::prepare)).
    pub(super) fn record(&self, pass: &mut wgpu::RenderPass<'_>) {
        if let Some((bind_group, _)) = &self.image {
            pass.set_pipeline(&self.pipeline);
            pass.set_bind_group(0, bind_group, &[]);
            pass.draw(0..4, 0..1);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Text rasterises to glyph coverage: some pixels nearly white and opaque (stems), the
    /// margin only the translucent box, and a longer text makes a wider image.
    #[test]
    fn text_has_glyph_coverage() {
        let img = rasterize_text("touchfem |F| 1.23 N", 15.0);
        assert!(
            img.height() >= 15 && img.height() < 40,
            "{:?}",
            img.dimensions()
        );
        let lit = img.pixels().filter(|p| p[0] > 200 && p[3] > 230).count();
        let total = (img.width() * img.height()) as usize;
        assert!(lit > 40, "only {lit} bright pixels of {total}");
        assert!(lit < total / 2, "{lit} bright pixels of {total}");
        let corner = img.get_pixel(0, 0);
        assert_eq!(corner[0], 0);
        assert_eq!(corner[3], (255.0 * BOX_ALPHA).round() as u8);
        let wider = rasterize_text("touchfem |F| 1.23 N, 1000 Hz", 15.0);
        assert!(wider.width() > img.width());
        assert_eq!(wider.height(), img.height());
    }
}
