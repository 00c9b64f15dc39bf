//! Where a live frame's time goes, pass by pass:
//! `WGPU_BACKEND=vulkan cargo run --release --example frame_cost SCENE [WxH]`
//! (default 640x480; `SAMPLES=4` for MSAA). The scene's first object, one contact triangle's
//! worth of columns pressed; each line is the median and the minimum of 80 frames, each
//! submitted and waited for: the deformation pass alone, then the draw (which includes it)
//! plain and coloured by |u|, with and without the wireframe.
use std::time::Instant;
use touchfem::render::{Camera, Coloring, Edges, Frame, FrameObject, RenderOptions, Renderer};
use touchfem::wgpu;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let size: Vec<u32> = a
        .get(2)
        .map(|s| s.split('x').map(|v| v.parse().unwrap()).collect())
        .unwrap_or(vec![640, 480]);
    let world = touchfem::scene::World::load(&a[1], "script").expect("scene");
    let o = &world.objects[0];
    let gpu = touchfem::gpu::Gpu::new_headless().expect("gpu");
    let mut d = touchfem::gpu::Deformer::new(
        &gpu.device,
        &gpu.queue,
        &o.scene.compliance,
        &o.scene.mesh.nodes,
        &o.scene.mesh.surface,
        &Default::default(),
    )
    .expect("deformer");
    let c = &o.scene.compliance;
    // Three columns, 0.1 N each.
    let forces: Vec<(u32, [f32; 3])> = (0..3u32.min(c.cols().len() as u32))
        .map(|i| (i, [0.0, 0.0, -0.1]))
        .collect();
    d.set_forces(&gpu.queue, &forces).unwrap();
    let edges = Edges::new(&gpu.device, &d);
    let samples: u32 = std::env::var("SAMPLES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1);
    let opts = RenderOptions {
        samples,
        ..Default::default()
    };
    let r = Renderer::with_options(&gpu.device, [size[0], size[1]], opts).unwrap();
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
    let (min, max) = o.scene.mesh.bounds();
    let cam = Camera::framing(min, max, size[0] as f64 / size[1] as f64);
    let objects = [FrameObject {
        deformer: &d,
        offset: o.offset,
        bounds: (min, max),
        edges: Some(&edges),
    }];
    println!(
        "rows {} triangles {} edges {}",
        c.rows().len(),
        o.scene.mesh.surface.len(),
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
