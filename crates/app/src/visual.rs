//! The visual path's displacement update, `u = L·F` for every object, on the GPU pass when one
//! is there and healthy, on the CPU (f64) otherwise. A GPU that hangs (a wait longer than the
//! timeout) or is lost mid-run is dropped for the rest of the run with one warning; the visual
//! loop goes on with the CPU product, and the haptic loop, on its own core, never notices.
//!
//! **Cuts.** [`CutFollower`] is the one place a cut body is taken from the cutter's feed and put
//! on the GPU, for the demo's [`Visual`] ([`Visual::follow_cuts`]) and the window alike: when the
//! feed's generation moved, each object's newest [`CutBody`] is installed
//! ([`touchfem_gpu::install_cut`]: the GPU pass then carries its correction and draws its opened
//! surface; a body whose `L` is not the one on the GPU, a cut folded into a new `L`, has its `L`
//! uploaded again), and the CPU product reads its compliance.
//!
//! Orchestration over the engine's runtime (its [`World`], [`WorldSample`] and [`CutFeed`]),
//! kept out of the embeddable `touchfem-gpu`.

use glam::DVec3;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use touchfem_core::compliance::Compliance;
use touchfem_core::runtime::cutting::{CutBody, CutFeed};
use touchfem_core::runtime::WorldSample;
use touchfem_core::scene::World;

use touchfem_gpu::{install_cut, Deformer, DeformerOptions, Gpu, LStorage};

/// How long the visual loop waits for one GPU update before it gives the GPU up.
pub const GPU_TIMEOUT: Duration = Duration::from_secs(2);

/// Vertices a deformer reserves for a separating cut's copies when the scene has a cuttable
/// object ([`DeformerOptions::extra_vertices`]): room for the copies a cut makes between two
/// folds (a fold makes them rows); more re-uploads `L` with twice the room needed.
pub const CUT_VERTICES: usize = 256;

/// The deformer options of a scene's visual path: `storage`, and room for a separating cut's
/// copies when an object is cuttable ([`CUT_VERTICES`]).
pub fn deformer_options(world: &World, storage: LStorage) -> DeformerOptions {
    let cuttable = world.objects.iter().any(|o| o.cuttable.is_some());
    DeformerOptions {
        storage,
        extra_vertices: if cuttable { CUT_VERTICES } else { 0 },
        ..Default::default()
    }
}

/// The cut bodies a visual path draws, followed from the cutter's feed: the one cut install of
/// the demo's [`Visual`] and the window.
#[derive(Debug)]
pub struct CutFollower {
    /// The feed's generation last read.
    seen: u64,
    /// Each object's cut body in use (`None`: uncut).
    bodies: Vec<Option<Arc<CutBody>>>,
}

/// Where [`CutFollower::take`] puts the cut bodies on the GPU: the device, its queue, the
/// deformers (one per object, built from the scene's compliances) and their options.
pub struct GpuTarget<'a> {
    /// The device the deformers live on.
    pub device: &'a wgpu::Device,
    /// Its queue.
    pub queue: &'a wgpu::Queue,
    /// One deformer per object.
    pub deformers: &'a mut [Deformer],
    /// What a deformer is rebuilt with when a cut brings a new `L`.
    pub options: &'a DeformerOptions,
}

impl CutFollower {
    /// A follower for a scene of `objects` objects, all uncut.
    pub fn new(objects: usize) -> CutFollower {
        CutFollower {
            seen: u64::MAX,
            bodies: vec![None; objects],
        }
    }

    /// Object `o`'s cut body in use, if it was cut.
    pub fn body(&self, o: usize) -> Option<&Arc<CutBody>> {
        self.bodies.get(o)?.as_ref()
    }

    /// Takes `feed`'s newest cut bodies if its generation moved (a lock, only then). Each body
    /// new to its object is put on the object's deformer when `gpu` is given
    /// ([`install_cut`], from the compliance uploaded so far) and becomes the object's body.
    /// A body for an object the scene lacks, or one that displays other rows than the scene,
    /// is left out with a warning. Returns the objects whose body changed, and the first GPU
    /// error (after which no more bodies go to the GPU: draw from the CPU's `displace`).
    pub fn take(
        &mut self,
        feed: &CutFeed,
        world: &World,
        mut gpu: Option<GpuTarget<'_>>,
    ) -> (Vec<usize>, Option<String>) {
        let mut changed = Vec::new();
        let mut failure = None;
        let now = feed.generation.load(Ordering::Acquire);
        if now == self.seen {
            return (changed, failure);
        }
        self.seen = now;
        for (o, body) in feed.latest() {
            if o >= self.bodies.len() || o >= world.objects.len() {
                log::warn!(
                    "a cut body for object {o}, but the scene has {}",
                    world.objects.len()
                );
                continue;
            }
            if self.bodies[o]
                .as_ref()
                .is_some_and(|b| Arc::ptr_eq(b, &body))
            {
                continue;
            }
            let obj = &world.objects[o];
            // A separating cut's fold adds rows (its copies); it drops none of the scene's.
            let shown = &body.compliance;
            if (obj.body.compliance.rows().iter()).any(|&v| shown.row_of(v).is_none()) {
                log::warn!(
                    "a cut body of '{}' does not display every row of the scene; not drawn",
                    obj.name
                );
                continue;
            }
            if let Some(g) = gpu.as_mut().filter(|_| failure.is_none()) {
                let uploaded = self.bodies[o]
                    .as_ref()
                    .map_or(&obj.body.compliance, |b| &b.compliance);
                let installed = match g.deformers.get_mut(o) {
                    Some(d) => install_cut(
                        g.device,
                        g.queue,
                        d,
                        uploaded,
                        &body.compliance,
                        &body.triangles,
                        &body.rest,
                        g.options,
                    )
                    .map_err(|e| e.to_string()),
                    None => Err("no deformer".into()),
                };
                if let Err(e) = installed {
                    failure = Some(format!("cannot draw the cut of '{}': {e}", obj.name));
                }
            }
            self.bodies[o] = Some(body);
            changed.push(o);
        }
        (changed, failure)
    }
}

/// The displacement update of every object of a scene.
pub struct Visual<'a> {
    world: &'a World,
    gpu: Option<&'a Gpu>,
    deformers: Vec<Deformer>,
    cpu: Vec<Vec<DVec3>>,
    failure: Option<String>,
    timeout: Duration,
    options: DeformerOptions,
    /// The cutter's feed, once followed.
    feed: Option<Arc<CutFeed>>,
    /// Each object's cut body in use.
    cuts: CutFollower,
    /// Bumped whenever an object's drawn surface or deformer changes.
    surface_generation: u64,
}

impl<'a> Visual<'a> {
    /// Uploads every object's compliance to `gpu` (when given); a GPU that fails here is
    /// dropped as it would be mid-run.
    pub fn new(world: &'a World, gpu: Option<&'a Gpu>) -> Visual<'a> {
        let mut v = Visual {
            world,
            gpu,
            deformers: Vec::new(),
            cpu: world
                .objects
                .iter()
                .map(|o| vec![DVec3::ZERO; o.body.compliance.rows().len()])
                .collect(),
            failure: None,
            timeout: GPU_TIMEOUT,
            options: DeformerOptions::default(),
            feed: None,
            cuts: CutFollower::new(world.objects.len()),
            surface_generation: 0,
        };
        if let Some(g) = gpu {
            let options = match LStorage::from_env() {
                Ok(storage) => deformer_options(world, storage),
                Err(e) => {
                    v.give_up(e.to_string());
                    return v;
                }
            };
            v.options = options.clone();
            for o in &world.objects {
                let s = &o.body;
                match Deformer::new(
                    &g.device,
                    &g.queue,
                    &s.compliance,
                    &s.mesh.nodes,
                    &s.mesh.surface,
                    &options,
                ) {
                    Ok(d) => v.deformers.push(d),
                    Err(e) => {
                        v.give_up(format!("cannot upload '{}': {e}", o.name));
                        break;
                    }
                }
            }
        }
        v
    }

    /// Follows the cutter's feed (e.g. [`LiveStatus::cuts`](touchfem_core::runtime::LiveStatus)):
    /// from the next [`update`](Self::update), each object is drawn from its newest cut body.
    pub fn follow_cuts(&mut self, feed: Arc<CutFeed>) {
        self.feed = Some(feed);
    }

    /// Object `o`'s cut body in use, if it was cut: its `triangles` are the surface to draw
    /// with [`cpu_displacement`](Self::cpu_displacement) when the GPU is not in use.
    pub fn cut_body(&self, o: usize) -> Option<&Arc<CutBody>> {
        self.cuts.body(o)
    }

    /// Bumped each time an object's drawn surface or deformer changes (a cut taken): what a
    /// caller compares to rebuild what it derived from the deformers (wireframe edges).
    pub fn surface_generation(&self) -> u64 {
        self.surface_generation
    }

    /// The compliance object `o` is displaced with: its cut body's, or the scene's.
    pub fn compliance(&self, o: usize) -> &Compliance {
        match self.cuts.body(o) {
            Some(b) => &b.compliance,
            None => &self.world.objects[o].body.compliance,
        }
    }

    /// Takes the feed's newest cut bodies ([`CutFollower::take`]).
    fn take_cuts(&mut self) {
        let Some(feed) = &self.feed else {
            return;
        };
        let gpu = match self.gpu {
            Some(g) if self.failure.is_none() => Some(GpuTarget {
                device: &g.device,
                queue: &g.queue,
                deformers: &mut self.deformers,
                options: &self.options,
            }),
            _ => None,
        };
        let (changed, failure) = self.cuts.take(feed, self.world, gpu);
        if let Some(why) = failure {
            self.give_up(why);
        }
        self.surface_generation += changed.len() as u64;
    }

    /// Sets how long one GPU update may take before the GPU is given up.
    pub fn set_timeout(&mut self, t: Duration) {
        self.timeout = t;
    }

    /// The GPU's deformers (one per object) while the GPU is in use.
    pub fn deformers(&self) -> Option<&[Deformer]> {
        self.gpu_ok().then_some(&self.deformers[..])
    }

    /// Whether the GPU pass is in use.
    pub fn gpu_ok(&self) -> bool {
        self.gpu.is_some() && self.failure.is_none()
    }

    /// Why the GPU was given up, if it was.
    pub fn failure(&self) -> Option<&str> {
        self.failure.as_deref()
    }

    /// Where the update runs: "gpu", "cpu-f64", or "cpu-f64 (gpu failed: …)".
    pub fn backend(&self) -> String {
        match (&self.gpu, &self.failure) {
            (Some(_), None) => "gpu".into(),
            (_, Some(f)) => format!("cpu-f64 (gpu failed: {f})"),
            (None, None) => "cpu-f64".into(),
        }
    }

    /// The CPU displacement of object `o` (rows of its compliance, [`compliance`](Self::compliance)),
    /// valid after an update on the CPU.
    pub fn cpu_displacement(&self, o: usize) -> &[DVec3] {
        &self.cpu[o]
    }

    fn give_up(&mut self, why: String) {
        log::warn!("the GPU pass failed ({why}); the visual path goes on on the CPU");
        self.failure = Some(why);
    }

    /// Updates every object's displacement for `sample`; returns the time it took, µs
    /// (submit to completion on the GPU).
    pub fn update(&mut self, sample: &WorldSample) -> f64 {
        let t = Instant::now();
        self.take_cuts();
        if self.gpu_ok() {
            if let Err(why) = self.update_gpu(sample) {
                self.give_up(why);
            } else {
                return t.elapsed().as_secs_f64() * 1e6;
            }
        }
        let t = Instant::now();
        for o in 0..self.world.objects.len() {
            // An object whose L stayed in its cache file keeps its last shape. A cut body's
            // compliance carries its correction: `displace` adds it; a hierarchical one's
            // `displace` is its compressed product.
            let c = match self.cuts.body(o) {
                Some(b) => &b.compliance,
                None => &self.world.objects[o].body.compliance,
            };
            if c.holds_l() || c.hier().is_some() {
                // (A separating cut's fold adds rows.)
                self.cpu[o].resize(c.rows().len(), DVec3::ZERO);
                c.displace(sample.bc(o).entries(), &mut self.cpu[o]);
            }
        }
        t.elapsed().as_secs_f64() * 1e6
    }

    fn update_gpu(&mut self, sample: &WorldSample) -> Result<(), String> {
        let g = self.gpu.expect("checked");
        let mut enc = g.device.create_command_encoder(&Default::default());
        for (o, d) in self.deformers.iter_mut().enumerate() {
            let (mut f, n) = sample.bc(o).to_f32();
            // (A newer separating body's copies: left out for this frame.)
            let n = d.keep_known(&mut f[..n]);
            d.set_forces(&g.queue, &f[..n]).map_err(|e| e.to_string())?;
            d.encode(&mut enc);
        }
        let idx = g.queue.submit([enc.finish()]);
        g.device
            .poll(wgpu::PollType::Wait {
                submission_index: Some(idx),
                timeout: Some(self.timeout),
            })
            .map(|_| ())
            .map_err(|e| format!("waiting for the update: {e}"))
    }
}

pub use touchfem_gpu::render::{frame_objects, SampleMarks};
