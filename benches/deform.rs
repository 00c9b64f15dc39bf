//! The visual loop's `u = L·F` (+ vertex normals): the GPU pass (set_forces + encode + submit +
//! wait) in both layouts of `L` against the f64 CPU reference `Compliance::displace`, and the
//! driver's floor (submit + wait alone; with a 16-byte upload; with one and two empty
//! dispatches), in the same run. On lavapipe the floors and frames are measured twice: with the
//! driver's threads where the OS puts them (its default), and `_pinned` (see [`Contexts`]); the
//! pinned texture frame also without immediates (`_uniform_list`: the active list uploaded with
//! `write_buffer`) and without normals.
//!
//! Active columns are counted as **scalar columns of L**: one contact triangle (the paper's
//! eq. 8, three nodes with a 3-vector force each) is 9 columns. IDs read `9c_3n`: 9 scalar
//! columns on 3 column nodes.
//!
//! Cases (random compliances on box meshes' surfaces, so no FEM solve is needed):
//! * `mouse`: a 14³-cell box, 1178 displayed vertices (the paper's mouse shows 1175), all
//!   free surface nodes touchable; 9, 27, 90 and 900 active columns;
//! * `large`: a 29³-cell box, 5048 displayed vertices, 500 touchable nodes; 9 and 90 active.
//!
//! ```sh
//! WGPU_BACKEND=vulkan CARGO_BUILD_JOBS=1 cargo bench --bench deform -- --warm-up-time 1 --measurement-time 3
//! ```

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use glam::DVec3;
use touchfem::compliance::Compliance;
use touchfem::gpu::{Deformer, DeformerOptions, Gpu, LStorage, OutputTarget};
use touchfem::mesh::units::Material;
use touchfem::mesh::{cube_with, Mesh};
use touchfem::runtime::VisualPlacement;
use touchfem::wgpu;

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let v = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D);
        (v >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }
}

/// A box mesh of `cells`³ cells (30 mm) with a random compliance: rows = surface nodes, columns
/// = the first `max_cols` free surface nodes.
fn case(cells: usize, max_cols: usize) -> (Mesh, Compliance) {
    let mesh = cube_with(
        [cells; 3],
        [30.0; 3],
        Material {
            young_pa: 10_000.0,
            poisson: 0.49,
        },
    )
    .expect("box mesh");
    let rows = mesh.surface_nodes.clone();
    let mut cols = mesh.free_surface_nodes();
    cols.truncate(max_cols);
    let (nr, nc) = (rows.len(), cols.len());
    let row_of = |n: u32| rows.iter().position(|&r| r == n).unwrap();
    let mut rng = Rng(42);
    let mut l: Vec<f64> = (0..9 * nr * nc).map(|_| rng.next() * 1e-5).collect();
    for (ci, &c) in cols.iter().enumerate() {
        let r = row_of(c);
        for a in 0..3 {
            l[(3 * ci + a) * 3 * nr + 3 * r + a] += 1e-3;
        }
    }
    let n = mesh.nodes.len();
    let c = Compliance::from_dense(rows, cols, l, n).expect("compliance");
    (mesh, c)
}

fn forces(c: &Compliance, n: usize) -> Vec<(u32, [f32; 3])> {
    let nc = c.cols().len();
    let mut rng = Rng(7);
    (0..n)
        .map(|i| {
            let col = (i * 7919 % nc) as u32;
            (
                col,
                [rng.next() as f32, rng.next() as f32, rng.next() as f32],
            )
        })
        .collect()
}

/// One frame: upload the forces, record, submit, wait for completion.
fn frame(gpu: &Gpu, d: &mut Deformer, f: &[(u32, [f32; 3])]) {
    d.set_forces(&gpu.queue, f).unwrap();
    let mut enc = gpu
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
    d.encode(&mut enc);
    gpu.queue.submit([enc.finish()]);
    gpu.device
        .poll(wgpu::PollType::wait_indefinitely())
        .unwrap();
}

/// What a frame costs on this driver before any work: a 16-byte `write_buffer` (if `upload`),
/// `dispatches` dispatches of an empty shader over the same workgroups, submit, wait.
fn floor(gpu: &Gpu, rows: u32, upload: bool, dispatches: u32) -> impl FnMut() + '_ {
    let module = gpu
        .device
        .create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("empty"),
            source: wgpu::ShaderSource::Wgsl(
                "@group(0) @binding(0) var<uniform> n: vec4<u32>;
                 @compute @workgroup_size(64)
                 fn main(@builtin(global_invocation_id) g: vec3<u32>) { if g.x > n.x { return; } }"
                    .into(),
            ),
        });
    let pipeline = gpu
        .device
        .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some("empty"),
            layout: None,
            module: &module,
            entry_point: Some("main"),
            compilation_options: Default::default(),
            cache: None,
        });
    let buf = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("empty"),
        size: 16,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let bind = gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("empty"),
        layout: &pipeline.get_bind_group_layout(0),
        entries: &[wgpu::BindGroupEntry {
            binding: 0,
            resource: buf.as_entire_binding(),
        }],
    });
    gpu.queue
        .write_buffer(&buf, 0, bytemuck::cast_slice(&[rows, 0, 0, 0]));
    move || {
        if upload {
            gpu.queue
                .write_buffer(&buf, 0, bytemuck::cast_slice(&[rows, 0, 0, 0]));
        }
        let mut enc = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
        if dispatches > 0 {
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_pipeline(&pipeline);
            pass.set_bind_group(0, &bind, &[]);
            for _ in 0..dispatches {
                pass.dispatch_workgroups(rows.div_ceil(64), 1, 1);
            }
        }
        gpu.queue.submit([enc.finish()]);
        gpu.device
            .poll(wgpu::PollType::wait_indefinitely())
            .unwrap();
    }
}

/// The contexts a run compares: the driver as configured, threads where the OS puts them
/// (`threads`); and on CPU adapters also lavapipe pinned (`pinned`): created while this thread
/// is pinned to one core, so the driver's queue thread starts there too, with
/// `LP_NUM_THREADS=0` (llvmpipe runs compute on that queue thread, no worker pool) — the
/// demo's setting (`touchfem::runtime::VisualPlacement`). Both live in this process, so every number below
/// comes from one run; this thread is pinned while it measures `pinned` and free otherwise.
struct Contexts {
    threads: Gpu,
    pinned: Option<Gpu>,
    placement: VisualPlacement,
}

impl Contexts {
    /// Puts this thread where `gpu`'s frames should be submitted from.
    fn enter(&self, gpu: &Gpu) {
        if self.pinned.as_ref().is_some_and(|p| std::ptr::eq(p, gpu)) {
            self.placement.enter_visual();
        } else {
            self.placement.leave();
        }
    }
}

fn contexts() -> Contexts {
    let threads = Gpu::new_headless().unwrap_or_else(|e| panic!("{e}"));
    eprintln!("adapter: {}", threads.adapter.get_info().name);
    let placement = VisualPlacement::split();
    let cpu = threads.adapter.get_info().device_type == wgpu::DeviceType::Cpu;
    let pinned = (cpu && placement.visual.is_some()).then(|| {
        // llvmpipe reads LP_NUM_THREADS when an instance creates its screen; restore it after.
        let old = std::env::var_os("LP_NUM_THREADS");
        std::env::set_var("LP_NUM_THREADS", "0");
        placement.enter_visual();
        let g = Gpu::new_headless().unwrap_or_else(|e| panic!("{e}"));
        placement.leave();
        match old {
            Some(v) => std::env::set_var("LP_NUM_THREADS", v),
            None => std::env::remove_var("LP_NUM_THREADS"),
        }
        g
    });
    Contexts {
        threads,
        pinned,
        placement,
    }
}

fn bench_case(
    crit: &mut Criterion,
    ctx: &Contexts,
    name: &str,
    cells: usize,
    cols: usize,
    nodes: &[usize],
) {
    let (mesh, c) = case(cells, cols);
    let nr = c.rows().len();
    let deformer = |gpu: &Gpu, storage, output, no_immediates| {
        Deformer::new(
            &gpu.device,
            &gpu.queue,
            &c,
            &mesh.nodes,
            &mesh.surface,
            &DeformerOptions {
                storage,
                output,
                no_immediates,
                ..Default::default()
            },
        )
        .expect("deformer")
    };
    let positions_only = |gpu: &Gpu| OutputTarget {
        buffer: gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("positions only"),
            size: 16 * nr as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::VERTEX,
            mapped_at_creation: false,
        }),
        offset: 0,
        stride: 16,
        normal_offset: None,
    };
    // (id, context, deformer): every GPU variant of a frame.
    let mut variants: Vec<(&str, &Gpu, Deformer)> = vec![
        (
            "gpu_texture",
            &ctx.threads,
            deformer(&ctx.threads, LStorage::Texture, None, false),
        ),
        (
            "gpu_buffers",
            &ctx.threads,
            deformer(&ctx.threads, LStorage::Buffers, None, false),
        ),
    ];
    if let Some(g) = &ctx.pinned {
        variants.push((
            "gpu_texture_pinned",
            g,
            deformer(g, LStorage::Texture, None, false),
        ));
        variants.push((
            "gpu_texture_pinned_uniform_list",
            g,
            deformer(g, LStorage::Texture, None, true),
        ));
        variants.push((
            "gpu_texture_pinned_no_normals",
            g,
            deformer(g, LStorage::Texture, Some(positions_only(g)), false),
        ));
        variants.push((
            "gpu_buffers_pinned",
            g,
            deformer(g, LStorage::Buffers, None, false),
        ));
    }
    let mut group = crit.benchmark_group(format!("{name}_{nr}rows_{}cols", c.cols().len()));
    group.sample_size(30);
    // The driver's fixed costs, for comparison with the frames below.
    let floors = [("", Some(&ctx.threads)), ("_pinned", ctx.pinned.as_ref())];
    for (suffix, gpu) in floors {
        let Some(gpu) = gpu else { continue };
        for (id, upload, dispatches) in [
            ("gpu_floor_submit", false, 0),
            ("gpu_floor_upload", true, 0),
            ("gpu_floor_empty_dispatch", true, 1),
            ("gpu_floor_two_empty_dispatches", true, 2),
        ] {
            ctx.enter(gpu);
            group.bench_function(format!("{id}{suffix}"), |b| {
                b.iter(floor(gpu, nr as u32, upload, dispatches))
            });
        }
    }
    let mut out = vec![DVec3::ZERO; nr];
    for &n in nodes {
        let f = forces(&c, n);
        let f64s: Vec<(u32, DVec3)> = f
            .iter()
            .map(|&(col, v)| (col, DVec3::from(v.map(f64::from))))
            .collect();
        let id = format!("{}c_{n}n", 3 * n);
        for (vid, gpu, d) in &mut variants {
            ctx.enter(gpu);
            group.bench_with_input(BenchmarkId::new(*vid, &id), &f, |b, f| {
                b.iter(|| frame(gpu, d, f))
            });
        }
        ctx.placement.leave();
        group.bench_with_input(BenchmarkId::new("cpu_f64", &id), &f64s, |b, f| {
            b.iter(|| {
                c.displace(f, &mut out);
                std::hint::black_box(&out);
            })
        });
    }
    group.finish();
}

fn benches(crit: &mut Criterion) {
    let ctx = contexts();
    bench_case(crit, &ctx, "mouse", 14, usize::MAX, &[3, 9, 30, 300]);
    bench_case(crit, &ctx, "large", 29, 500, &[3, 30]);
}

criterion_group!(deform, benches);
criterion_main!(deform);
