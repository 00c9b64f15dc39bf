//! Where a live frame's time goes, pass by pass:
//! `WGPU_BACKEND=vulkan cargo run --release --example frame_cost SCENE [WxH]`
//! (missing or bad arguments: the usage on stderr, exit status 2)
//! (default 640x480; `SAMPLES=4` for MSAA). The scene's first object, one contact triangle's
//! worth of columns pressed; each line is the median and the minimum of 80 frames, each
//! submitted and waited for: the deformation pass alone, then the draw (which includes it)
//! plain and coloured by |u|, with and without the wireframe.
use std::time::Instant;
use touchfem::render::{Camera, Coloring, Edges, Frame, FrameObject, RenderOptions, Renderer};
use touchfem::wgpu;

const USAGE: &str = "usage: frame_cost SCENE [WxH]   (SCENE: a scene file, bundled scene or mesh; \
default 640x480; SAMPLES=1|4 in the environment for MSAA)";

/// Prints `error: {msg}` and the usage to stderr and exits with status 2 (bad input).
fn usage_error(msg: &str) -> ! {
    eprintln!("error: {msg}");
    eprintln!("{USAGE}");
    std::process::exit(2)
}

/// Prints `error: {msg}` to stderr and exits with `code`.
fn die(code: i32, msg: impl std::fmt::Display) -> ! {
    eprintln!("error: {msg}");
    std::process::exit(code)
}

fn main() {
    let a: Vec<String> = std::env::args().skip(1).collect();
    if a.is_empty() || a.len() > 2 || a.iter().any(|s| s == "-h" || s == "--help") {
        usage_error("expected SCENE [WxH]");
    }
    let size: [u32; 2] = match a.get(1) {
        Some(s) => touchfem_app::args::parse_size(s).unwrap_or_else(|e| usage_error(&e)),
        None => [640, 480],
    };
    let samples: u32 = match std::env::var("SAMPLES") {
        Err(_) => 1,
        Ok(s) => match s.trim().parse() {
            Ok(n @ (1 | 4)) => n,
            _ => usage_error(&format!("SAMPLES={s:?}: expected 1 or 4")),
        },
    };
    let world = touchfem::scene::World::load(&a[0], "script").unwrap_or_else(|e| die(2, e));
    let Some(o) = world.objects.first() else {
        die(2, format!("{}: no object", a[0]));
    };
    let gpu = touchfem::gpu::Gpu::new_headless().unwrap_or_else(|e| die(1, e));
    let mut d = touchfem::gpu::Deformer::new(
        &gpu.device,
        &gpu.queue,
        &o.body.compliance,
        &o.body.mesh.nodes,
        &o.body.mesh.surface,
        &Default::default(),
    )
    .unwrap_or_else(|e| die(1, e));
    let c = &o.body.compliance;
    // Three columns, 0.1 N each.
    let forces: Vec<(u32, [f32; 3])> = (0..3u32.min(c.cols().len() as u32))
        .map(|i| (i, [0.0, 0.0, -0.1]))
        .collect();
    d.set_forces(&gpu.queue, &forces).unwrap();
    let edges = Edges::new(&gpu.device, &d);
    let opts = RenderOptions {
        samples,
        ..Default::default()
    };
    let r =
        Renderer::with_options(&gpu.device, [size[0], size[1]], opts).unwrap_or_else(|e| die(1, e));
    let tex = gpu.device.create_texture(&wgpu::TextureDescriptor {
        label: None,
        size: wgpu::Extent3d {
            width: size[0],
            height: size[1],
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: opts.format,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
        view_formats: &[],
    });
    let view = tex.create_view(&Default::default());
    let (min, max) = o.body.mesh.bounds();
    let cam = Camera::framing(min, max, size[0] as f64 / size[1] as f64);
    let objects = [FrameObject {
        deformer: &d,
        offset: o.offset,
        bounds: (min, max),
        edges: Some(&edges),
        deformed: false,
    }];
    println!(
        "rows {} triangles {} ({} smooth) edges {}",
        c.rows().len(),
        o.body.mesh.surface.len(),
        d.stats().smooth_triangles,
        edges.index_count() / 2
    );
    let time = |label: &str, f: &dyn Fn(&mut wgpu::CommandEncoder)| {
        let mut v = Vec::new();
        for _ in 0..80 {
            let t = Instant::now();
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            f(&mut enc);
            gpu.queue.submit([enc.finish()]);
            gpu.device
                .poll(wgpu::PollType::wait_indefinitely())
                .unwrap();
            v.push(t.elapsed().as_secs_f64() * 1e3);
        }
        v.sort_by(f64::total_cmp);
        println!(
            "{label:40} median {:.2} ms  min {:.2}",
            v[v.len() / 2],
            v[0]
        );
    };
    time("deform only", &|enc| d.encode(enc));
    for (label, wire, col) in [
        ("draw plain", false, false),
        ("draw plain+wire", true, false),
        ("draw color", false, true),
        ("draw color+wire", true, true),
    ] {
        let frame = Frame {
            objects: &objects,
            camera: cam,
            fingers: &[],
            finger_radii: &[],
            patch: &[],
            proxies: &[],
            scale: (max - min).length(),
            wireframe: wire,
            overlay: None,
            coloring: if col {
                Coloring::displacement(1e-3)
            } else {
                Coloring::Plain
            },
            arrows: &[],
            legend: None,
        };
        time(label, &|enc| {
            r.draw(&gpu.device, &gpu.queue, enc, &view, &frame).unwrap()
        });
    }
}
