//! The interactive window of `touchfem view`: a winit 0.30 application with a wgpu surface,
//! one [`Deformer`](touchfem_gpu::Deformer) per object, the pointer as a finger.
//!
//! [`run`] is independent of how the haptic side is spawned: it reads the latest
//! [`WorldSample`](touchfem_core::runtime::WorldSample) from a [`SampleReader`], shows the haptic
//! loop's [`LiveStatus`] and writes the pointer finger's position into a
//! [`PointerShared`](touchfem_core::devices::pointer::PointerShared) through a [`PointerRoute`].
//!
//! * **Left drag** (starting over an object) presses a finger into it from the point first
//!   touched `p0`, along the inward normal `−n` there: the finger is at `p0 − n·depth` with
//!   `depth = k · (pixels dragged)` (Euclidean distance from the press),
//!   `k = max(0.06 mm, 0.002 · scene diagonal)` per pixel (0.10 mm/px on the 30 mm cube: a
//!   100-pixel drag presses 10 mm). There is no lateral term: the finger moves along the normal
//!   only, so the press stays where it started whatever the drag's direction. Before pressing
//!   the finger is put 1 mm outside `p0`, so that the god-object enters through `p0` (if the
//!   haptic loop misses that position, the runtime attaches a finger that appears inside at the
//!   nearest surface point). Releasing lifts the finger (a NaN position).
//! * **Right drag** orbits ([`Orbit`](touchfem_gpu::render::Orbit)), the **wheel** zooms, **W** toggles
//!   the wireframe (on at start while the surface has fewer edges than one per 24 pixels,
//!   [`wireframe_by_default`](touchfem_gpu::render::wireframe_by_default)), **C** toggles the
//!   colours by displacement, **Esc** or closing the window quits (and sets [`LiveStatus::stop`]).
//! * **B** turns the pointer into a blade and back ([`blade`]): on a scene with a cuttable
//!   object the pointer then drives its blade twin. A left press on an object puts the blade's
//!   top just under the surface there (`max(0.2 mm, 0.5 % of the scene diagonal)`), and dragging
//!   keeps it that far under the rest surface under the pointer, along the normal there (off
//!   the object, under the plane tangent at the press): the blade, hanging its depth below,
//!   parts the material it passes in the cuttable region (no force).
//!   Without a cuttable object the status line shows `warning: …` in its place for 3 s
//!   ([`status_overlay`], cut short of the legend; the title and the log carry it whole) and
//!   nothing changes. The status line shows `blade D mm` while it is on.
//! * The status line (an overlay and the window title, which always contains `touchfem`): the
//!   largest |F| sent to a finger in N ([`force_readout`]: the pointer's, or a scripted
//!   finger's while it presses), the haptic rate, the frame time. Updated 4 times a second.
//!
//! Present mode Fifo; a redraw is requested after every frame. On CPU adapters (lavapipe) the
//! frame is drawn without MSAA ([`live_samples`](touchfem_gpu::render::live_samples)).
//!
//! Environment hooks (tests, measurements):
//! * `TOUCHFEM_VIEW_SECONDS=S`: quit after S seconds (0 to 1e6; another value is an error
//!   naming the variable);
//! * `TOUCHFEM_VIEW_LOG=FILE`: append one JSON line per second, `{"t", "frames", "fps",
//!   "frame_ms_median", "draw_ms_median", "force_n", "haptic_hz", "haptic_missed",
//!   "touching", "blade", "tets_removed", "nodes_split"}` (`frames`, `haptic_missed`: so far;
//!   `blade`: blade mode on; `tets_removed`: tets the cuts removed so far, every object (slivers,
//!   with the default blade that separates); `nodes_split`: copies of nodes the cuts made so
//!   far; `frame_ms_median`: median time between
//!   presented frames over that second;
//!   `force_n`: the largest [`force_readout`] over that second), and a final line with
//!   `"summary": true`;
//! * `TOUCHFEM_VIEW_SAMPLES=1|4`: override the MSAA sample count (another value is an error
//!   naming the variable).
//!
//! `WGPU_BACKEND` and `WGPU_ADAPTER_NAME` choose the adapter as for
//! [`Gpu::new`](touchfem_gpu::Gpu::new), among adapters that can present to the window.

mod app;
pub mod blade;
pub mod cli;

pub use blade::PointerRoute;

pub(crate) use cli::view_command;

use thiserror::Error;

use touchfem_core::runtime::{LiveStatus, SampleReader};
use touchfem_core::scene::World;
use touchfem_gpu::render::RenderError;
use touchfem_gpu::GpuError;

/// The status line's `|F|`, N: the largest force the haptic loop last sent to any finger, the
/// pointer's or the scene's own (a scripted fingertip's whole contact force), so that a press
/// the window shows is never read as 0 N because the pointer is not the finger pressing.
pub fn force_readout(sample: &touchfem_core::runtime::WorldSample) -> f64 {
    sample
        .fingers()
        .iter()
        .map(|f| f.force.length())
        .filter(|f| f.is_finite())
        .fold(0.0, f64::max)
}

/// A character's advance in the status overlay, pixels: DejaVu Sans Mono (monospaced, 1233
/// of 2048 units an em) at the overlay's 15 pixels.
const STATUS_CHAR_PX: f32 = 15.0 * 1233.0 / 2048.0;

/// The status overlay's text in a window `width_px` wide whose legend (top right) is
/// `legend_px` wide: the status line, or, while a notice is up, `warning: NOTICE` in its place
/// (the window title keeps both). Cut with `…` so that it ends at least 8 pixels before the
/// legend: both overlays sit 8 pixels from their edge, and the text has a 4-pixel pad each side.
pub fn status_overlay(status: &str, notice: Option<&str>, width_px: u32, legend_px: u32) -> String {
    let text = match notice {
        Some(n) => format!("warning: {n}"),
        None => status.to_string(),
    };
    let free = width_px as f32 - 8.0 - legend_px as f32 - 8.0 - 8.0 - 2.0 * 4.0;
    let fit = (free / STATUS_CHAR_PX).floor().max(1.0) as usize;
    if text.chars().count() <= fit {
        text
    } else {
        let mut cut: String = text.chars().take(fit - 1).collect();
        cut.push('…');
        cut
    }
}

/// How to open the window.
#[derive(Clone, Debug)]
pub struct WindowOptions {
    /// Inner size in physical pixels (width, height).
    pub size: [u32; 2],
    /// The window title's prefix (should contain `touchfem`; the status is appended).
    pub title: String,
    /// Start with the surface coloured by the displacement (`C` toggles it).
    pub colors: bool,
}

/// What a window session did.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct WindowSummary {
    /// Frames presented.
    pub frames: u64,
    /// Seconds the window was open (from the first frame).
    pub seconds: f64,
    /// Median time between presented frames, ms.
    pub frame_ms_median: f64,
    /// The largest |F| of the pointer finger seen by the window, N.
    pub max_force_n: f64,
}

/// Errors of the window.
#[derive(Debug, Error)]
pub enum ViewError {
    /// No adapter, no device, a deformer that cannot be built.
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// The renderer could not be built or could not draw.
    #[error(transparent)]
    Render(#[from] RenderError),
    /// The event loop could not start or failed.
    #[error("window event loop: {0}")]
    EventLoop(#[from] winit::error::EventLoopError),
    /// The window could not be created.
    #[error("cannot open a window: {0}")]
    Window(#[from] winit::error::OsError),
    /// wgpu could not make a surface for the window.
    #[error("cannot create a surface for the window: {0}")]
    Surface(#[from] wgpu::CreateSurfaceError),
    /// The surface cannot be presented to with this adapter, or acquiring a frame failed.
    #[error("surface: {0}")]
    Present(String),
    /// The device reported an error (validation, out of memory) or was lost.
    #[error("GPU device error: {0}")]
    Device(String),
    /// The scene has more objects than the window draws.
    #[error("{0} objects; the window draws at most {1}")]
    TooManyObjects(usize, usize),
    /// The haptic loop ended by a panic.
    #[error("the haptic thread panicked")]
    HapticPanicked,
    /// An environment hook (`TOUCHFEM_VIEW_SECONDS`, `TOUCHFEM_VIEW_SAMPLES`) has a bad value.
    #[error("{0}")]
    Env(String),
}

/// Checks the window's environment hooks (`TOUCHFEM_VIEW_SECONDS`: seconds in [0, 1e6];
/// `TOUCHFEM_VIEW_SAMPLES`: 1 or 4): an error names the variable. [`run`] checks them too; call
/// this first to fail before anything is loaded.
pub(crate) fn check_env() -> Result<(), ViewError> {
    app::EnvHooks::from_env()
        .map(|_| ())
        .map_err(ViewError::Env)
}

/// Opens the window on `world` and runs it until Esc, closing, `TOUCHFEM_VIEW_SECONDS` or the
/// end of the haptic loop ([`LiveStatus::done`]; a panic there is
/// [`ViewError::HapticPanicked`]). Sets [`LiveStatus::stop`] on the way out and lifts the
/// pointer finger (and its blade twin). Must run on the main thread (winit). `pointer`: the
/// finger the mouse drives (and its blade twin), if the scene has one; without it the window
/// only shows.
pub fn run(
    world: &World,
    reader: SampleReader,
    status: &LiveStatus,
    pointer: Option<PointerRoute>,
    opts: &WindowOptions,
) -> Result<WindowSummary, ViewError> {
    let n = world.objects.len();
    if n > touchfem_gpu::render::MAX_FRAME_OBJECTS {
        return Err(ViewError::TooManyObjects(
            n,
            touchfem_gpu::render::MAX_FRAME_OBJECTS,
        ));
    }
    let hooks = app::EnvHooks::from_env().map_err(ViewError::Env)?;
    let event_loop = winit::event_loop::EventLoop::new()?;
    let mut app = app::App::new(world, reader, status, pointer.clone(), opts, &hooks);
    let ran = event_loop.run_app(&mut app);
    status.stop.store(true, std::sync::atomic::Ordering::SeqCst);
    if let Some(p) = &pointer {
        p.lift();
    }
    ran?;
    app.finish()
}
