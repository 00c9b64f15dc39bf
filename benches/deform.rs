//! The visual loop's `u = L·F`: the GPU pass (set_forces + encode + submit + wait) against the
//! f64 CPU reference `Compliance::displace`, in the same run.
//!
//! Cases (random compliances on box meshes' surfaces, so no FEM solve is needed):
//! * `mouse`: a 14³-cell box, 1178 displayed vertices (the paper's mouse has 1713 nodes), all
//!   free surface nodes touchable; 9, 90 and 900 active columns;
//! * `large`: a 29³-cell box, 5048 displayed vertices, 500 touchable columns; 9 and 90 active.
//!
//! ```sh
//! WGPU_BACKEND=vulkan CARGO_BUILD_JOBS=1 cargo bench --bench deform -- --warm-up-time 1 --measurement-time 3
//! ```

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use glam::DVec3;
use touchfem::compliance::Compliance;
use touchfem::gpu::{Deformer, DeformerOptions, Gpu};
use touchfem::mesh::{cube_with, Mesh};
use touchfem::units::Material;
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

fn bench_case(
    crit: &mut Criterion,
    gpu: &Gpu,
    name: &str,
    cells: usize,
    cols: usize,
    actives: &[usize],
) {
    let (mesh, c) = case(cells, cols);
    let mut d = Deformer::new(
        &gpu.device,
        &gpu.queue,
        &c,
        &mesh.nodes,
        &mesh.surface,
        &DeformerOptions::default(),
    )
    .expect("deformer");
    let mut group = crit.benchmark_group(format!(
        "{name}_{}rows_{}cols",
        c.rows().len(),
        c.cols().len()
    ));
    let mut out = vec![DVec3::ZERO; c.rows().len()];
    for &n in actives {
        let f = forces(&c, n);
        let f64s: Vec<(u32, DVec3)> = f
            .iter()
            .map(|&(col, v)| (col, DVec3::from(v.map(f64::from))))
            .collect();
        group.bench_with_input(BenchmarkId::new("gpu", n), &f, |b, f| {
            b.iter(|| {
                d.set_forces(&gpu.queue, f).unwrap();
                let mut enc = gpu
                    .device
                    .create_command_encoder(&wgpu::CommandEncoderDescriptor::default());
                d.encode(&mut enc);
                gpu.queue.submit([enc.finish()]);
                gpu.device
                    .poll(wgpu::PollType::wait_indefinitely())
                    .unwrap();
            })
        });
        group.bench_with_input(BenchmarkId::new("cpu_f64", n), &f64s, |b, f| {
            b.iter(|| {
                c.displace(f, &mut out);
                std::hint::black_box(&out);
            })
        });
    }
    group.finish();
}

fn benches(crit: &mut Criterion) {
    let gpu = Gpu::new_headless().unwrap_or_else(|e| panic!("{e}"));
    eprintln!("adapter: {}", gpu.adapter.get_info().name);
    bench_case(crit, &gpu, "mouse", 14, usize::MAX, &[9, 90, 900]);
    bench_case(crit, &gpu, "large", 29, 500, &[9, 90]);
}

criterion_group!(deform, benches);
criterion_main!(deform);
