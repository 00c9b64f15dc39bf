//! A scene: one object (mesh, rest surface, precomputed compliance) and the operations the
//! command line offers on it (load by name or path, poke).

use glam::DVec3;
use std::path::Path;

use crate::compliance::{Compliance, Selection};
use crate::contact::force::{finger_force, ForceBc, ForceModel};
use crate::contact::{
    Budget, ContactPoint, Friction, GodObject, Patch, PatchReport, Sphere, Surface,
};
use crate::mesh::units::{LengthUnit, Material};
use crate::mesh::{self, Mesh, MeshError};
use crate::Error;

pub mod file;
pub mod pointer;
mod schema;
mod world;
pub use file::{SceneSource, BUNDLED_SCENES};
pub use world::{
    CutRegion, DeviceSpec, FingerSpec, HaplySpec, HapticSettings, Object, World, HAPLY_DEFAULT_URL,
};

/// How to load a mesh given on the command line.
#[derive(Clone, Debug)]
pub struct LoadOptions {
    /// Length unit of a mesh file (bundled meshes know their own). Default: metres.
    pub unit: Option<LengthUnit>,
    /// Young's modulus override, Pa.
    pub young_pa: Option<f64>,
    /// Poisson's ratio override.
    pub poisson: Option<f64>,
    /// Formulation override (default: standard).
    pub formulation: Option<crate::mesh::units::Formulation>,
    /// The node group to clamp.
    pub fixed_group: String,
    /// Tets of another material: (physical volume group, material), disjoint (see
    /// [`Mesh::set_regions`]).
    pub regions: Vec<(String, Material)>,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions {
            unit: None,
            young_pa: None,
            poisson: None,
            formulation: None,
            fixed_group: "fixed".into(),
            regions: Vec::new(),
        }
    }
}

/// The names of the bundled meshes.
pub(crate) const BUNDLED: &[&str] = &["cube", "mouse", "phantom"];

/// Loads a bundled mesh by name (`cube`) or a mesh file by path, applies material overrides,
/// gives the regions their materials and clamps the fixed group. Returns the mesh and the length unit its coordinates are given in on
/// the command line.
pub fn load_mesh(spec: &str, opts: &LoadOptions) -> Result<(Mesh, LengthUnit), Error> {
    let (mut mesh, unit) = match spec {
        "cube" => {
            let mut m = mesh::cube();
            m.set_fixed_group(&opts.fixed_group)?;
            (m, LengthUnit::Millimetre)
        }
        "mouse" => {
            let mut m = mesh::mouse();
            m.set_fixed_group(&opts.fixed_group)?;
            (m, LengthUnit::Millimetre)
        }
        "phantom" => {
            let mut m = mesh::phantom();
            m.set_fixed_group(&opts.fixed_group)?;
            (m, LengthUnit::Millimetre)
        }
        _ => {
            let path = Path::new(spec);
            if !path.exists() {
                return Err(MeshError::UnknownBundled(spec.to_string()).into());
            }
            let unit = opts.unit.unwrap_or_default();
            let raw = mesh::io::read(path)?;
            let mut m = Mesh::from_raw(raw, unit, Material::DEFAULT)?;
            m.set_fixed_group(&opts.fixed_group)?;
            (m, unit)
        }
    };
    if let Some(e) = opts.young_pa {
        mesh.material.young_pa = e;
    }
    if let Some(nu) = opts.poisson {
        mesh.material.poisson = nu;
    }
    if let Some(f) = opts.formulation {
        mesh.formulation = f;
    }
    mesh.material
        .validate()
        .map_err(crate::fem::FemError::from)?;
    if !opts.regions.is_empty() {
        mesh.set_regions(&opts.regions)?;
    }
    Ok((mesh, unit))
}

/// One object ready to touch: mesh, walking surface, compliance.
pub struct Body {
    /// The mesh (metres).
    pub mesh: Mesh,
    /// The rest surface the god-object walks on.
    pub surface: Surface,
    /// The precomputed compliance.
    pub compliance: Compliance,
}

/// The outcome of a poke.
#[derive(Clone, Debug)]
pub struct Poke {
    /// Where the finger first touched (the surface point nearest the requested point), m.
    pub touch_point: DVec3,
    /// The final contact, if the finger is still in contact.
    pub contact: Option<ContactPoint>,
    /// The force fed back to the finger with the chosen model, N.
    pub feedback: DVec3,
    /// The paper's feedback (eq. 12), N.
    pub feedback_paper: DVec3,
    /// The exact variant's feedback, N.
    pub feedback_exact: DVec3,
    /// The force boundary condition of the chosen model.
    pub bc: ForceBc,
}

/// The outcome of a sphere's poke ([`Body::poke_sphere`]).
#[derive(Clone, Debug)]
pub struct SpherePoke {
    /// Where the sphere first touched (the surface point nearest the requested point), m.
    pub touch_point: DVec3,
    /// The sphere's centre at the start (R outside along the surface normal there), m.
    pub start_centre: DVec3,
    /// The sphere's centre at the end, m.
    pub centre: DVec3,
    /// The force fed back to the finger (minus the sum of the contact forces), N.
    pub feedback: DVec3,
    /// The contact forces on the object: (column of `L`, force), N.
    pub forces: Vec<(u32, DVec3)>,
    /// The mesh nodes carrying a contact force at the end.
    pub contact_nodes: Vec<u32>,
    /// With a slide: per step, the distance slid (m) and the feedback (N).
    pub trace: Vec<[f64; 4]>,
    /// The last solve's report.
    pub report: PatchReport,
}

/// Ticks a sphere's push is split into by [`Body::poke_sphere`] (the contact state, and with
/// friction the stick–slip history, carried from one to the next).
pub const SPHERE_PUSH_STEPS: usize = 20;

impl Body {
    /// The largest contact problem [`Body::poke_sphere`] solves: every touchable node, at most
    /// 1024.
    pub fn patch_capacity(&self) -> usize {
        self.compliance.cols().len().clamp(1, 1024)
    }

    /// A sphere of `radius` (m) touches the surface point nearest `at` (its centre `radius`
    /// outside along the surface normal there), moves by `push` in [`SPHERE_PUSH_STEPS`]
    /// steps, then by `slide` (total, steps) with the contact state carried along; every
    /// step is solved to convergence. Errors on non-finite input or a bad radius.
    pub fn poke_sphere(
        &self,
        at: DVec3,
        push: DVec3,
        radius: f64,
        friction: Option<Friction>,
        slide: Option<(DVec3, usize)>,
    ) -> Result<SpherePoke, Error> {
        let tool = crate::contact::Tool::sphere(radius)?;
        let (lo, hi) = self.mesh.bounds();
        tool.check_fits(lo.distance(hi))?;
        if !at.is_finite() || !push.is_finite() {
            return Err(Error::Input(format!(
                "non-finite sphere position {at} or push {push}"
            )));
        }
        if let Some((d, _)) = slide {
            if !d.is_finite() {
                return Err(Error::Input(format!("non-finite slide {d}")));
            }
        }
        let (tri, p0) = self.surface.closest_global(at);
        let (_, bc) = self.surface.closest_on_tri(tri, p0);
        let n = self
            .surface
            .pseudo_normal(tri, crate::contact::feature_of(&bc));
        let start = p0 + n * radius;
        let mut patch = Patch::with_capacity(self.patch_capacity());
        let mut report = PatchReport::default();
        let solve = |centre: DVec3, patch: &mut Patch| {
            let sphere = [Sphere { centre, radius }];
            patch.solve(
                &self.compliance,
                &self.surface,
                &sphere,
                friction,
                Budget::UNLIMITED,
            )
        };
        for s in 1..=SPHERE_PUSH_STEPS {
            let c = start + push * (s as f64 / SPHERE_PUSH_STEPS as f64);
            report = solve(c, &mut patch);
        }
        let mut centre = start + push;
        let mut trace = Vec::new();
        if let Some((d, steps)) = slide {
            let steps = steps.max(1);
            for s in 1..=steps {
                let c = start + push + d * (s as f64 / steps as f64);
                report = solve(c, &mut patch);
                let f = -patch.sphere_force(0);
                trace.push([(c - start - push).length(), f.x, f.y, f.z]);
                centre = c;
            }
        }
        let forces: Vec<(u32, DVec3)> = patch
            .nodes()
            .filter(|n| n.pressure > 0.0)
            .map(|n| (n.col, n.force))
            .collect();
        let contact_nodes = patch
            .nodes()
            .filter(|n| n.pressure > 0.0)
            .map(|n| n.node)
            .collect();
        Ok(SpherePoke {
            touch_point: p0,
            start_centre: start,
            centre,
            feedback: -patch.sphere_force(0),
            forces,
            contact_nodes,
            trace,
            report,
        })
    }

    /// Precomputes the compliance for `sel` and builds the surface.
    pub fn new(mesh: Mesh, sel: &Selection) -> Result<Body, Error> {
        let compliance = Compliance::compute(&mesh, sel)?;
        Ok(Body::with_compliance(mesh, compliance))
    }

    /// Builds a scene around an already computed (or cached) compliance.
    pub fn with_compliance(mesh: Mesh, compliance: Compliance) -> Body {
        let surface = Surface::new(&mesh);
        Body {
            mesh,
            surface,
            compliance,
        }
    }

    /// The finger touches the surface at the point nearest `at` and moves by `push` (metres) in
    /// `steps` haptic ticks; returns the final force. A push out of the object frees the finger.
    pub fn poke(
        &self,
        at: DVec3,
        push: DVec3,
        model: ForceModel,
        steps: usize,
    ) -> Result<Poke, Error> {
        if !at.is_finite() || !push.is_finite() {
            return Err(Error::Input(format!(
                "non-finite finger position {at} or push {push}"
            )));
        }
        let (tri, p0) = self.surface.closest_global(at);
        let mut god = GodObject::touching(tri);
        let steps = steps.max(1);
        let mut contact = None;
        for s in 1..=steps {
            let x = p0 + push * (s as f64 / steps as f64);
            contact = god.update(&self.surface, x);
        }
        Ok(self.poke_result(p0, contact, model))
    }

    /// A poke's outcome from its final contact: the feedback with `model`, the paper's and the
    /// exact one, and the boundary condition of `model`.
    fn poke_result(&self, p0: DVec3, contact: Option<ContactPoint>, model: ForceModel) -> Poke {
        let mut out = Poke {
            touch_point: p0,
            contact,
            feedback: DVec3::ZERO,
            feedback_paper: DVec3::ZERO,
            feedback_exact: DVec3::ZERO,
            bc: ForceBc::default(),
        };
        if let Some(c) = contact {
            let mut scratch = ForceBc::default();
            out.feedback_paper =
                finger_force(&self.compliance, &c, ForceModel::Paper, &mut scratch).feedback;
            scratch.clear();
            out.feedback_exact =
                finger_force(&self.compliance, &c, ForceModel::Exact, &mut scratch).feedback;
            out.feedback = finger_force(&self.compliance, &c, model, &mut out.bc).feedback;
        }
        out
    }

    /// A point finger touches the surface point nearest `at`, moves by `push` in `steps`
    /// ticks, then by `slide` (total, steps) over an object with `friction` (none: the
    /// frictionless god-object): the god-object sticks and slips
    /// ([`crate::contact::StickSlip`]). Returns the final poke (its `contact` and `bc` with
    /// friction applied) and, per slide step, the distance slid (m) and the feedback (N).
    pub fn poke_slide(
        &self,
        at: DVec3,
        push: DVec3,
        model: ForceModel,
        friction: Option<Friction>,
        slide: Option<(DVec3, usize)>,
        steps: usize,
    ) -> Result<(Poke, Vec<[f64; 4]>), Error> {
        if !at.is_finite() || !push.is_finite() {
            return Err(Error::Input(format!(
                "non-finite finger position {at} or push {push}"
            )));
        }
        let (dslide, nslide) = slide.unwrap_or((DVec3::ZERO, 0));
        if !dslide.is_finite() {
            return Err(Error::Input(format!("non-finite slide {dslide}")));
        }
        let (tri, p0) = self.surface.closest_global(at);
        let mut god = GodObject::touching(tri);
        let mut stick = crate::contact::StickSlip::default();
        let steps = steps.max(1);
        let feel =
            |c: &ContactPoint| crate::contact::force::finger_feedback(&self.compliance, c, model);
        let mut contact = None;
        let mut step = |x: DVec3| -> Option<ContactPoint> {
            let free = god.update(&self.surface, x);
            match (free, friction.filter(|f| !f.is_none())) {
                (Some(c), Some(fr)) => Some(stick.apply(&self.surface, &c, fr, feel)),
                (Some(c), None) => Some(c),
                (None, _) => {
                    stick.reset();
                    None
                }
            }
        };
        for s in 1..=steps {
            contact = step(p0 + push * (s as f64 / steps as f64));
        }
        let mut trace = Vec::with_capacity(nslide);
        for s in 1..=nslide {
            let d = dslide * (s as f64 / nslide as f64);
            contact = step(p0 + push + d);
            let f = contact.as_ref().map_or(DVec3::ZERO, feel);
            trace.push([d.length(), f.x, f.y, f.z]);
        }
        let out = self.poke_result(p0, contact, model);
        Ok((out, trace))
    }

    /// The contact of a finger at `x` that entered through the surface point nearest it
    /// (`None` if `x` is outside). Brute force: for tests and reports, not the haptic loop.
    pub fn surface_contact(&self, x: DVec3) -> Option<ContactPoint> {
        let (tri, _) = self.surface.closest_global(x);
        GodObject::touching(tri).update(&self.surface, x)
    }

    /// The applied nodal forces of a boundary condition as (mesh node, force) pairs.
    pub fn nodal_forces(&self, bc: &ForceBc) -> Vec<(u32, DVec3)> {
        bc.entries()
            .iter()
            .map(|&(c, f)| (self.compliance.col_node(c as usize), f))
            .collect()
    }
}
