//! Scene files (TOML; the schema is in `docs/reference/scene-schema.md`): parsing with serde
//! and the `toml` crate, then validation and loading into a [`World`]. Every error names the
//! file, the line and the key.
//!
//! Only what the scene names is precomputed: rows for each object's displayed surface, columns
//! for its touchable nodes (`touchable`: the free surface, a group, or a ball). Compliances are
//! cached by a key that includes the selection (see [`crate::cache`]) in
//! `$TOUCHFEM_CACHE_DIR` (default `$XDG_CACHE_HOME/touchfem` or `~/.cache/touchfem`; set it to
//! an empty string to turn caching off). A cache that cannot be written costs a warning, never
//! the computed compliance.

use glam::DVec3;
use std::path::{Path, PathBuf};
use toml::Spanned;

use super::schema::{
    line_of, toml_error, BallToml, FileToml, HaplyToml, LimitsToml, Table, TouchableToml,
};
use super::world::{DeviceSpec, FingerSpec, HaplySpec, HapticSettings, Object, World};
use super::{load_mesh, Body, LoadOptions};
use crate::compliance::hmatrix::HOptions;
use crate::compliance::{Compliance, NodeSet, Selection};
use crate::contact::force::ForceModel;
use crate::devices::limits::DeviceLimits;
use crate::limits::MAX_FINGERS;
use crate::limits::MAX_OBJECTS;
use crate::mesh::units::LengthUnit;
use crate::Error;

/// The bundled scenes: (name, TOML text).
pub const BUNDLED_SCENES: &[(&str, &str)] = &[
    ("fig1", include_str!("../../../../scenes/fig1.toml")),
    ("fig2", include_str!("../../../../scenes/fig2.toml")),
    ("pinch", include_str!("../../../../scenes/pinch.toml")),
    ("palpate", include_str!("../../../../scenes/palpate.toml")),
    ("rub", include_str!("../../../../scenes/rub.toml")),
    ("incision", include_str!("../../../../scenes/incision.toml")),
];

/// Where a scene comes from: its name, text and the directory relative paths start from.
#[derive(Clone, Debug)]
pub struct SceneSource {
    /// The scene's name (file stem or bundled name).
    pub name: String,
    /// The file's text.
    pub text: String,
    /// Relative mesh paths are resolved from here.
    pub dir: PathBuf,
    /// How errors name the file.
    pub label: String,
}

impl SceneSource {
    /// A bundled scene (one of [`BUNDLED_SCENES`]) or a scene file; `None` if `spec` is neither
    /// a bundled name nor a `.toml` path.
    pub fn find(spec: &str) -> Result<Option<SceneSource>, Error> {
        if let Some((name, text)) = BUNDLED_SCENES.iter().find(|(n, _)| *n == spec) {
            return Ok(Some(SceneSource {
                name: name.to_string(),
                text: text.to_string(),
                dir: PathBuf::from("."),
                label: format!("bundled scene '{name}'"),
            }));
        }
        let path = Path::new(spec);
        if path.extension().is_some_and(|e| e == "toml") {
            let text = std::fs::read_to_string(path)
                .map_err(|e| Error::Body(format!("{spec}: cannot read the scene file: {e}")))?;
            // Absolute, so a recorded session replays from any directory.
            let dir = path
                .parent()
                .map(|p| {
                    if p.as_os_str().is_empty() {
                        Path::new(".")
                    } else {
                        p
                    }
                })
                .and_then(|p| p.canonicalize().ok())
                .unwrap_or_else(|| PathBuf::from("."));
            let name = path
                .file_stem()
                .map_or("scene".into(), |s| s.to_string_lossy().into_owned());
            return Ok(Some(SceneSource {
                name,
                text,
                dir,
                label: spec.to_string(),
            }));
        }
        Ok(None)
    }

    /// A bundled scene or scene file ([`SceneSource::find`]), else a mesh as one object
    /// touched by `device` ([`SceneSource::for_mesh`]).
    pub(crate) fn find_or_mesh(spec: &str, device: &str) -> Result<SceneSource, Error> {
        Ok(SceneSource::find(spec)?.unwrap_or_else(|| SceneSource::for_mesh(spec, device)))
    }

    /// A one-object scene around a mesh (bundled name or file) touched by `device`.
    pub fn for_mesh(spec: &str, device: &str) -> SceneSource {
        let (mesh, dir) = if crate::scene::BUNDLED.contains(&spec) {
            (spec.to_string(), PathBuf::from("."))
        } else {
            let p = Path::new(spec);
            let dir = p
                .parent()
                .map(Path::to_path_buf)
                .unwrap_or_else(|| PathBuf::from("."));
            let file = p
                .file_name()
                .map_or(spec.into(), |f| f.to_string_lossy().into_owned());
            (file, dir)
        };
        let unit = if crate::scene::BUNDLED.contains(&spec) {
            "mm"
        } else {
            "m"
        };
        let text = format!(
            "unit = \"{unit}\"\n\n[[object]]\nmesh = {mesh:?}\n\n[[finger]]\ndevice = {device:?}\n"
        );
        SceneSource {
            name: Path::new(spec)
                .file_stem()
                .map_or(spec.into(), |s| s.to_string_lossy().into_owned()),
            text,
            dir,
            label: format!("mesh '{spec}'"),
        }
    }
}

/// The largest Young's modulus a scene accepts, Pa (diamond is about 1.2e12).
pub(crate) const MAX_YOUNG_PA: f64 = 1e13;
/// The largest magnitude of a coordinate, offset or radius in a scene file, in its unit.
pub const MAX_COORDINATE: f64 = 1e9;
/// The largest magnitude of a keyframe time in a scene file, s (about 11.6 days).
pub(crate) const MAX_KEYFRAME_SECONDS: f64 = 1e6;

/// Whether every component of `v` is finite and at most [`MAX_COORDINATE`] in magnitude.
fn coordinates_ok(v: &[f64]) -> bool {
    v.iter().all(|x| x.is_finite() && x.abs() <= MAX_COORDINATE)
}

fn unit_of(s: &str) -> Option<LengthUnit> {
    match s {
        "m" => Some(LengthUnit::Metre),
        "mm" => Some(LengthUnit::Millimetre),
        _ => None,
    }
}

pub use crate::options::cache_dir;

impl World {
    /// Loads a scene: a bundled scene's name, a `.toml` scene file, or a mesh (bundled name or
    /// file) as a one-object scene touched by one `device` finger.
    pub fn load(spec: &str, device: &str) -> Result<World, Error> {
        World::load_with(spec, device, cache_dir().as_deref())
    }

    /// As [`World::load`], with the compliance cache in `cache` (`None`: no cache).
    pub fn load_with(spec: &str, device: &str, cache: Option<&Path>) -> Result<World, Error> {
        World::from_source_with(&SceneSource::find_or_mesh(spec, device)?, cache)
    }

    /// As [`World::load`] for a live session: [`Hold::Live`].
    pub fn load_live(spec: &str, device: &str) -> Result<World, Error> {
        let src = SceneSource::find_or_mesh(spec, device)?;
        World::from_source_holding(&src, cache_dir().as_deref(), Hold::Live)
    }

    /// Parses, validates and precomputes a scene, caching compliances in [`cache_dir`].
    /// Warnings (a cache that cannot be written) go to stderr.
    #[cfg(feature = "native")]
    pub(crate) fn from_source(src: &SceneSource) -> Result<World, Error> {
        World::from_source_with(src, cache_dir().as_deref())
    }

    /// As `World::from_source`, with the compliance cache in `cache` (`None`: no cache).
    pub fn from_source_with(src: &SceneSource, cache: Option<&Path>) -> Result<World, Error> {
        World::from_source_holding(src, cache, Hold::Dense)
    }

    /// As [`World::from_source_with`], keeping on the host what `hold` says.
    pub fn from_source_holding(
        src: &SceneSource,
        cache: Option<&Path>,
        hold: Hold,
    ) -> Result<World, Error> {
        World::build(src, &mut |name, mesh, sel, compression, key, fingers| {
            let near_from = match hold {
                // A hierarchical L is small: held whole.
                _ if fingers > 1 || compression.is_some() => None,
                Hold::Dense => None,
                Hold::Live => Some(NEAR_ONLY_BYTES),
                Hold::Near => Some(0),
            };
            compute_cached(cache, name, mesh, sel, compression, key, near_from).map(Some)
        })
    }

    /// As [`World::from_source_with`], each object's compliance given by `compliance` from its
    /// plan (name, mesh, selection, compression, cache key): the pure engine's way in, with no
    /// file and no thread (e.g. read from bytes with [`crate::cache::load_bytes`], or computed
    /// with [`Compliance::compute`]).
    pub fn from_source_by(
        src: &SceneSource,
        compliance: &mut dyn FnMut(&PlannedObject) -> Result<Compliance, Error>,
    ) -> Result<World, Error> {
        World::build(src, &mut |name, mesh, sel, compression, key, _| {
            let plan = PlannedObject {
                name: name.to_string(),
                mesh: mesh.clone(),
                selection: sel.clone(),
                compression: compression.copied(),
                key,
            };
            compliance(&plan).map(Some)
        })
    }

    /// The fingers a scene declares, without computing any compliance (the meshes are read).
    pub fn fingers_of(src: &SceneSource) -> Result<Vec<FingerSpec>, Error> {
        Ok(World::build(src, &mut |_, _, _, _, _, _| Ok(None))?.fingers)
    }

    /// What a scene asks to precompute, without computing it: for each object its name, mesh
    /// (scene units applied), selection and cache key (see `touchfem precompute`).
    pub fn plan(src: &SceneSource) -> Result<Vec<PlannedObject>, Error> {
        let mut out = Vec::new();
        World::build(src, &mut |name, mesh, sel, compression, key, _| {
            out.push(PlannedObject {
                name: name.to_string(),
                mesh: mesh.clone(),
                selection: sel.clone(),
                compression: compression.copied(),
                key,
            });
            Ok(None)
        })?;
        Ok(out)
    }

    /// The hash a load of `src` gives ([`World::hash`]: its text and each object's cache key),
    /// without precomputing anything (the meshes are read).
    #[cfg(feature = "native")]
    pub(crate) fn hash_of(src: &SceneSource) -> Result<u64, Error> {
        Ok(World::build(src, &mut |_, _, _, _, _, _| Ok(None))?.hash)
    }

    /// Parses and validates a scene; `compute` gives each object's compliance (`None`: leave the
    /// object out).
    fn build(src: &SceneSource, compute: &mut Compute<'_>) -> Result<World, Error> {
        let text = &src.text;
        let at = |span: std::ops::Range<usize>, key: &str, msg: String| {
            Error::Body(format!(
                "{}: line {}, key `{key}`: {msg}",
                src.label,
                line_of(text, span.start)
            ))
        };
        let file: FileToml = toml::from_str(text).map_err(|e| toml_error(&src.label, text, &e))?;
        let unit = match &file.unit {
            None => LengthUnit::Metre,
            Some(u) => unit_of(u.get_ref()).ok_or_else(|| {
                at(
                    u.span(),
                    "unit",
                    format!("'{}' is not a unit: use \"m\" or \"mm\"", u.get_ref()),
                )
            })?,
        };
        let s = unit.to_metres();
        if file.object.is_empty() {
            return Err(Error::Body(format!(
                "{}: no [[object]]: a scene needs at least one",
                src.label
            )));
        }
        if file.object.len() > MAX_OBJECTS {
            let span = file.object[MAX_OBJECTS].span();
            return Err(at(
                span,
                "object",
                format!("at most {MAX_OBJECTS} objects in a scene"),
            ));
        }
        if file.finger.len() > MAX_FINGERS {
            let span = file.finger[MAX_FINGERS].span();
            return Err(at(
                span,
                "finger",
                format!("at most {MAX_FINGERS} fingers in a scene"),
            ));
        }
        let mut hasher = xxhash_rust::xxh3::Xxh3::new();
        hasher.update(text.as_bytes());
        let mut objects = Vec::new();
        for o in &file.object {
            let o = o.get_ref();
            let mesh_spec = o.mesh.get_ref();
            let mesh_unit = match &o.mesh_unit {
                None => None,
                Some(u) => Some(unit_of(u.get_ref()).ok_or_else(|| {
                    at(
                        u.span(),
                        "mesh_unit",
                        format!("'{}' is not a unit: use \"m\" or \"mm\"", u.get_ref()),
                    )
                })?),
            };
            if let Some(y) = &o.young {
                let v = *y.get_ref();
                if !(v.is_finite() && v > 0.0 && v <= MAX_YOUNG_PA) {
                    return Err(at(
                        y.span(),
                        "young",
                        format!("{v} is outside (0, {MAX_YOUNG_PA:e}] Pa"),
                    ));
                }
            }
            if let Some(off) = &o.offset {
                if !coordinates_ok(off.get_ref()) {
                    return Err(at(
                        off.span(),
                        "offset",
                        format!("each coordinate must be finite and at most {MAX_COORDINATE:e} in magnitude"),
                    ));
                }
            }
            let formulation = match &o.formulation {
                None => None,
                Some(f) => Some(
                    f.get_ref()
                        .parse::<crate::mesh::units::Formulation>()
                        .map_err(|e| at(f.span(), "formulation", e))?,
                ),
            };
            let friction = match &o.friction {
                None => None,
                Some(f) => {
                    let v = f.get_ref();
                    Some(
                        crate::contact::Friction::new(v.static_mu, v.dynamic)
                            .map_err(|e| at(f.span(), "friction", e.to_string()))?,
                    )
                }
            };
            let fixed = o
                .fixed
                .as_ref()
                .map_or("fixed".to_string(), |f| f.get_ref().clone());
            let opts = LoadOptions {
                unit: mesh_unit,
                young_pa: o.young.as_ref().map(|v| *v.get_ref()),
                poisson: o.poisson.as_ref().map(|v| *v.get_ref()),
                formulation,
                fixed_group: fixed,
                regions: Vec::new(),
            };
            for r in &o.region {
                let r = r.get_ref();
                let v = *r.young.get_ref();
                if !(v.is_finite() && v > 0.0 && v <= MAX_YOUNG_PA) {
                    return Err(at(
                        r.young.span(),
                        "region.young",
                        format!("{v} is outside (0, {MAX_YOUNG_PA:e}] Pa"),
                    ));
                }
                if let Some(nu) = &r.poisson {
                    let v = *nu.get_ref();
                    if !(v.is_finite() && v > -1.0 && v < 0.5) {
                        return Err(at(
                            nu.span(),
                            "region.poisson",
                            format!("{v} is outside (-1, 0.5)"),
                        ));
                    }
                }
            }
            let path = if crate::scene::BUNDLED.contains(&mesh_spec.as_str()) {
                mesh_spec.clone()
            } else {
                let p = src.dir.join(mesh_spec);
                if !p.exists() {
                    return Err(at(
                        o.mesh.span(),
                        "mesh",
                        format!(
                            "'{mesh_spec}' is neither a bundled mesh ({}) nor a file ({} does not exist)",
                            crate::scene::BUNDLED.join(", "),
                            p.display()
                        ),
                    ));
                }
                p.to_string_lossy().into_owned()
            };
            let key_span = |k: &str| match k {
                "young" => o.young.as_ref().map(|v| v.span()),
                "poisson" => o.poisson.as_ref().map(|v| v.span()),
                "fixed" => o.fixed.as_ref().map(|v| v.span()),
                _ => None,
            };
            let (mut mesh, _) = load_mesh(&path, &opts).map_err(|e| {
                let key = match &e {
                    Error::Mesh(crate::MeshError::MissingGroup { .. }) => "fixed",
                    Error::Fem(crate::fem::FemError::Material(_)) => {
                        if key_span("poisson").is_some() {
                            "poisson"
                        } else {
                            "young"
                        }
                    }
                    _ => "mesh",
                };
                at(key_span(key).unwrap_or(o.mesh.span()), key, e.to_string())
            })?;
            if !o.region.is_empty() {
                // A region without `poisson` keeps the object's.
                let specs: Vec<(String, crate::mesh::units::Material)> = o
                    .region
                    .iter()
                    .map(|r| {
                        let r = r.get_ref();
                        let material = crate::mesh::units::Material {
                            young_pa: *r.young.get_ref(),
                            poisson: r
                                .poisson
                                .as_ref()
                                .map_or(mesh.material.poisson, |v| *v.get_ref()),
                        };
                        (r.group.get_ref().clone(), material)
                    })
                    .collect();
                mesh.set_regions(&specs).map_err(|e| {
                    use crate::MeshError as M;
                    let group = match &e {
                        M::NoVolumeGroup { name, .. }
                        | M::NotVolumeGroup { name, .. }
                        | M::EmptyVolumeGroup { name } => name,
                        M::OverlappingRegions { second, .. } => second,
                        M::BadRegionMaterial { group, .. } => group,
                        _ => "",
                    };
                    let span = o
                        .region
                        .iter()
                        .rev()
                        .find(|r| r.get_ref().group.get_ref() == group)
                        .map_or(o.mesh.span(), |r| r.get_ref().group.span());
                    at(span, "region.group", e.to_string())
                })?;
            }
            let offset = o
                .offset
                .as_ref()
                .map_or(DVec3::ZERO, |v| DVec3::from_array(*v.get_ref()) * s);
            if !offset.is_finite() {
                let span = o.offset.as_ref().map(|v| v.span()).unwrap_or(o.mesh.span());
                return Err(at(span, "offset", "not finite".into()));
            }
            let free = mesh.free_surface_nodes();
            let cols = match &o.touchable {
                None => NodeSet::FreeSurface,
                Some(t) => match t.get_ref() {
                    TouchableToml::Name(n) if n == "all" => NodeSet::FreeSurface,
                    TouchableToml::Name(g) => {
                        let Some(ids) = mesh.groups.get(g) else {
                            return Err(at(
                                t.span(),
                                "touchable",
                                format!(
                                    "no group '{g}' in the mesh (groups: {})",
                                    mesh.groups.keys().cloned().collect::<Vec<_>>().join(", ")
                                ),
                            ));
                        };
                        let set: std::collections::BTreeSet<u32> = ids.iter().copied().collect();
                        let nodes: Vec<u32> =
                            free.iter().copied().filter(|n| set.contains(n)).collect();
                        if nodes.is_empty() {
                            return Err(at(
                                t.span(),
                                "touchable",
                                format!("group '{g}' holds no free-surface node"),
                            ));
                        }
                        NodeSet::Nodes(nodes)
                    }
                    TouchableToml::Ball(b) => {
                        let (c, r) = ball(b, s, offset, || t.span(), "touchable", &at)?;
                        let nodes: Vec<u32> = free
                            .iter()
                            .copied()
                            .filter(|&n| mesh.nodes[n as usize].distance(c) <= r)
                            .collect();
                        if nodes.is_empty() {
                            return Err(at(
                                t.span(),
                                "touchable",
                                format!(
                                    "the ball (center {:?}, radius {}) holds no free-surface node of '{mesh_spec}'",
                                    b.center, b.radius
                                ),
                            ));
                        }
                        NodeSet::Nodes(nodes)
                    }
                },
            };
            let cuttable = match &o.cuttable {
                None => None,
                Some(t) => Some(cut_region(&mesh, t, s, offset, &at)?),
            };
            let compression = match &o.compression {
                None => None,
                Some(c) => {
                    let opts = HOptions::new(c.get_ref().tolerance);
                    opts.check()
                        .map_err(|e| at(c.span(), "compression", e.to_string()))?;
                    if o.cuttable.is_some() {
                        return Err(at(
                            c.span(),
                            "compression",
                            "a cuttable object needs a dense L (a cut updates L exactly by low \
                             rank): remove `compression` or `cuttable`"
                                .into(),
                        ));
                    }
                    Some(opts)
                }
            };
            // A cuttable region's free nodes are touchable too: a cut exposes them, and their
            // columns come from the same correction as the rest.
            let cols = match &cuttable {
                None => cols,
                Some(region) => {
                    let mut set: std::collections::BTreeSet<u32> =
                        cols.resolve(&mesh).into_iter().collect();
                    for (t, tet) in mesh.tets.iter().enumerate() {
                        if region.contains(t) {
                            set.extend(tet.iter().copied().filter(|&v| !mesh.fixed[v as usize]));
                        }
                    }
                    NodeSet::Nodes(set.into_iter().collect())
                }
            };
            let sel = Selection {
                rows: NodeSet::Surface,
                cols,
            };
            let key = crate::cache::key_for(&mesh, &sel, compression.as_ref());
            hasher.update(&key.to_le_bytes());
            let name = o.name.clone().unwrap_or_else(|| {
                Path::new(mesh_spec)
                    .file_stem()
                    .map_or(mesh_spec.clone(), |s| s.to_string_lossy().into_owned())
            });
            let Some(compliance) = compute(
                &name,
                &mesh,
                &sel,
                compression.as_ref(),
                key,
                file.finger.len(),
            )?
            else {
                continue;
            };
            objects.push(Object {
                name,
                body: Body::with_compliance(mesh, compliance),
                offset,
                friction,
                cuttable,
            });
        }
        let mut fingers = Vec::new();
        for f in &file.finger {
            let f = f.get_ref();
            let model = match f.model.as_ref().map(|m| (m.get_ref().as_str(), m.span())) {
                None | Some(("paper", _)) => ForceModel::Paper,
                Some(("exact", _)) => ForceModel::Exact,
                Some((other, span)) => {
                    return Err(at(
                        span,
                        "model",
                        format!("'{other}' is not a force model: use \"paper\" or \"exact\""),
                    ))
                }
            };
            let device = match f.device.get_ref().as_str() {
                "script" => {
                    let Some(p) = &f.path else {
                        return Err(at(
                            f.device.span(),
                            "path",
                            "a script finger needs a path of [t, x, y, z] keyframes".into(),
                        ));
                    };
                    let keys = p.get_ref();
                    if keys.is_empty() {
                        return Err(at(p.span(), "path", "the path is empty".into()));
                    }
                    for (i, k) in keys.iter().enumerate() {
                        if !k.iter().all(|v| v.is_finite()) {
                            return Err(at(
                                p.span(),
                                "path",
                                format!("keyframe {} is not finite", i + 1),
                            ));
                        }
                        if k[0].abs() > MAX_KEYFRAME_SECONDS || !coordinates_ok(&k[1..]) {
                            return Err(at(
                                p.span(),
                                "path",
                                format!(
                                    "keyframe {}: |t| must be at most {MAX_KEYFRAME_SECONDS:e} s and each coordinate at most {MAX_COORDINATE:e} in magnitude",
                                    i + 1
                                ),
                            ));
                        }
                        if i > 0 && k[0] <= keys[i - 1][0] {
                            return Err(at(
                                p.span(),
                                "path",
                                format!(
                                    "times must increase: keyframe {} has t = {} after t = {}",
                                    i + 1,
                                    k[0],
                                    keys[i - 1][0]
                                ),
                            ));
                        }
                    }
                    DeviceSpec::Script(
                        keys.iter()
                            .map(|k| (k[0], DVec3::new(k[1], k[2], k[3]) * s))
                            .collect(),
                    )
                }
                "pointer" => DeviceSpec::Pointer,
                "udp" => DeviceSpec::Udp,
                "replay" => DeviceSpec::Replay,
                "haply" => DeviceSpec::Haply(haply_spec(
                    f.haply.as_ref(),
                    f.device.span(),
                    s,
                    &objects,
                    &at,
                )?),
                other => {
                    return Err(at(
                        f.device.span(),
                        "device",
                        format!(
                            "'{other}' is not a device: use \"script\", \"udp\", \"pointer\", \"replay\" or \"haply\""
                        ),
                    ))
                }
            };
            if let (Some(h), false) = (&f.haply, matches!(device, DeviceSpec::Haply(_))) {
                return Err(at(
                    h.span(),
                    "haply",
                    "only a haply finger (`device = \"haply\"`) takes a haply table".into(),
                ));
            }
            if f.path.is_some() && !matches!(device, DeviceSpec::Script(_)) {
                let span = f.path.as_ref().map(|p| p.span()).unwrap_or(0..0);
                return Err(at(span, "path", "only a script finger takes a path".into()));
            }
            let limits = match &f.limits {
                None => None,
                Some(l) => {
                    let span = l.span();
                    let limits = match l.get_ref() {
                        LimitsToml::Preset(name) => DeviceLimits::named(name),
                        LimitsToml::Numbers(n) => {
                            let d = DeviceLimits {
                                name: n.name.clone().unwrap_or_else(|| "custom".into()),
                                max_force_n: n.max_force_n,
                                max_continuous_force_n: n.max_continuous_force_n,
                                max_stiffness_n_per_m: n.max_stiffness_n_per_m,
                                max_damping_ns_per_m: n.max_damping_ns_per_m,
                                workspace_radius_m: n.workspace_radius_m,
                            };
                            d.validate().map(|_| d)
                        }
                    };
                    Some(limits.map_err(|e| at(span, "limits", e.to_string()))?)
                }
            };
            let tool = match &f.tool {
                None => crate::contact::Tool::Point,
                Some(t) => {
                    let span = t.span();
                    use crate::contact::Tool;
                    // A positive length that underflows to 0 m is too short (checked below),
                    // not a sign error.
                    let positive = |v: f64| v.is_finite() && v > 0.0;
                    let (key, tool) = match (t.get_ref().sphere, t.get_ref().blade) {
                        (Some(r), None) if positive(r) => {
                            ("tool.sphere", Tool::Sphere { radius_m: r * s })
                        }
                        (Some(r), None) => (
                            "tool.sphere",
                            Tool::sphere(r * s)
                                .map_err(|e| at(span.clone(), "tool.sphere", e.to_string()))?,
                        ),
                        (None, Some(d)) if positive(d) => {
                            ("tool.blade", Tool::Blade { depth_m: d * s })
                        }
                        (None, Some(d)) => (
                            "tool.blade",
                            Tool::blade(d * s)
                                .map_err(|e| at(span.clone(), "tool.blade", e.to_string()))?,
                        ),
                        _ => {
                            return Err(at(
                                span,
                                "tool",
                                "give exactly one of `sphere = R` or `blade = DEPTH`".into(),
                            ))
                        }
                    };
                    // The one rule for a user's lengths (`Tool::check_fits`): it holds for
                    // one of the objects at least.
                    if let Some(e) = objects
                        .iter()
                        .map(|o: &Object| {
                            let (lo, hi) = o.body.mesh.bounds();
                            tool.check_fits(lo.distance(hi))
                        })
                        .reduce(|a, b| if a.is_ok() || b.is_ok() { Ok(()) } else { a })
                        .and_then(|r| r.err())
                    {
                        return Err(at(span, key, e.to_string()));
                    }
                    tool
                }
            };
            fingers.push(FingerSpec {
                device,
                model,
                limits,
                tool,
            });
        }
        let mut haptics = HapticSettings::default();
        if let Some(h) = &file.haptics {
            if let Some(r) = &h.rate_hz {
                let v = *r.get_ref();
                if !(v.is_finite() && (100.0..=20_000.0).contains(&v)) {
                    return Err(at(
                        r.span(),
                        "rate_hz",
                        format!("{v} is outside 100 ..= 20000 Hz"),
                    ));
                }
                haptics.rate_hz = v;
            }
            if let Some(m) = &h.max_force_n {
                let v = *m.get_ref();
                if !(v.is_finite() && v > 0.0) {
                    return Err(at(
                        m.span(),
                        "max_force_n",
                        format!("{v} is not a positive force"),
                    ));
                }
                haptics.max_force_n = v;
            }
        }
        // Early warning: a body whose compliance loses more than 1e-3 in f32 or f16 storage.
        for o in &objects {
            let (e32, e16) = crate::compliance::conditioning::storage_error(&o.body.compliance);
            if let Some(w) = crate::compliance::conditioning::storage_warning(&o.name, e32, e16) {
                log::warn!("{w}");
            }
        }
        Ok(World {
            name: src.name.clone(),
            unit,
            objects,
            fingers,
            haptics,
            source: text.clone(),
            dir: src.dir.clone(),
            hash: hasher.digest(),
        })
    }
}

/// Gives an object's compliance during [`World::build`]: (name, mesh, selection, cache key,
/// the scene's finger count).
type Compute<'a> = dyn FnMut(
        &str,
        &crate::Mesh,
        &Selection,
        Option<&HOptions>,
        u64,
        usize,
    ) -> Result<Option<Compliance>, Error>
    + 'a;

/// How much of each object's `L` a loaded scene keeps on the host.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Hold {
    /// All of it, f64: exact CPU displacements (`poke`, `--vtu`, the demo's pictures, the CPU
    /// fallback of the visual path) and any pair of nodes for several fingers.
    #[default]
    Dense,
    /// For a live session (`view`, `serve`): when the scene has at most one finger and the
    /// object's `L` is in the cache and at least `NEAR_ONLY_BYTES`, only the blocks that
    /// finger's force solve reads ([`crate::compliance::near::NearBlocks`]); the GPU copy is then read
    /// from the cache file. `TOUCHFEM_HOST_L=dense` keeps all of it; `near` holds only the
    /// blocks whatever the size (still one finger and a cache file at most).
    Live,
    /// As [`Hold::Live`] whatever the size of `L`.
    Near,
}

/// The smallest f64 `L` (bytes) that a live session with one finger leaves in its cache file.
pub(crate) const NEAR_ONLY_BYTES: u64 = 256 << 20;

/// One object of a scene as `touchfem precompute` sees it.
#[derive(Clone, Debug)]
pub struct PlannedObject {
    /// The object's name (file names of its cache derive from it).
    pub name: String,
    /// Its mesh, in metres.
    pub mesh: crate::Mesh,
    /// Rows and columns to precompute.
    pub selection: Selection,
    /// `L` stored hierarchically with these options (the scene's `compression`), or dense.
    pub compression: Option<HOptions>,
    /// The cache key ([`crate::cache::key`], or [`crate::cache::key_hier`] when compressed).
    pub key: u64,
}

/// A `{ center, radius }` ball of the scene (units `s` to metres, the object at `offset`) in
/// the object's frame: its centre and radius, m. Errors name `key`.
/// A Haply finger's settings from its `haply` table (`None`: every default), lengths in the
/// scene's unit `s` (metres per unit) except `device_centre` (metres, the device's frame).
/// The default `scene_centre` is the middle of the top of the objects' bounds.
fn haply_spec(
    h: Option<&Spanned<Table<HaplyToml>>>,
    device_span: std::ops::Range<usize>,
    s: f64,
    objects: &[Object],
    at: &dyn Fn(std::ops::Range<usize>, &str, String) -> Error,
) -> Result<HaplySpec, Error> {
    use crate::devices::workspace::{Workspace, DEFAULT_DEVICE_CENTRE};
    let span = || h.map_or(device_span.clone(), |h| h.span());
    let t = h.map(|h| &h.get_ref().0);
    let url = t
        .and_then(|t| t.url.clone())
        .unwrap_or_else(|| crate::scene::HAPLY_DEFAULT_URL.into());
    if !url.starts_with("ws://") || url.len() <= "ws://".len() {
        return Err(at(
            span(),
            "haply.url",
            format!("'{url}' is not a WebSocket address: give ws://HOST:PORT (the Haply Inverse Service's is ws://127.0.0.1:10001)"),
        ));
    }
    let device_id = t.and_then(|t| t.device_id.clone());
    if device_id.as_deref() == Some("") {
        return Err(at(span(), "haply.device_id", "is empty".into()));
    }
    let device_centre = t
        .and_then(|t| t.device_centre)
        .unwrap_or(DEFAULT_DEVICE_CENTRE);
    if !coordinates_ok(&device_centre) {
        return Err(at(
            span(),
            "haply.device_centre",
            format!("must be finite and at most {MAX_COORDINATE:e} in magnitude"),
        ));
    }
    let scene_centre = match t.and_then(|t| t.scene_centre) {
        Some(c) if coordinates_ok(&c) => DVec3::from_array(c) * s,
        Some(_) => {
            return Err(at(
                span(),
                "haply.scene_centre",
                format!("must be finite and at most {MAX_COORDINATE:e} in magnitude"),
            ))
        }
        None => {
            let mut lo = DVec3::splat(f64::INFINITY);
            let mut hi = DVec3::splat(f64::NEG_INFINITY);
            for o in objects {
                let (a, b) = o.body.mesh.bounds();
                lo = lo.min(a + o.offset);
                hi = hi.max(b + o.offset);
            }
            let c = DVec3::new(0.5 * (lo.x + hi.x), 0.5 * (lo.y + hi.y), hi.z);
            if c.is_finite() {
                c
            } else {
                DVec3::ZERO
            }
        }
    };
    let scale = t.and_then(|t| t.scale).unwrap_or(1.0);
    if !(scale.is_finite() && scale > 0.0 && scale <= 1e6 && (1.0 / scale).is_finite()) {
        return Err(at(
            span(),
            "haply.scale",
            format!("{scale} is not a positive scale in (0, 1e6]"),
        ));
    }
    Ok(HaplySpec {
        url,
        device_id,
        workspace: Workspace {
            device_centre: DVec3::from_array(device_centre),
            scene_centre,
            scale,
        },
    })
}

fn ball(
    b: &BallToml,
    s: f64,
    offset: DVec3,
    span: impl Fn() -> std::ops::Range<usize>,
    key: &str,
    at: &dyn Fn(std::ops::Range<usize>, &str, String) -> Error,
) -> Result<(DVec3, f64), Error> {
    if !(coordinates_ok(&b.center) && coordinates_ok(&[b.radius])) {
        return Err(at(
            span(),
            key,
            format!("the ball's center and radius must be finite and at most {MAX_COORDINATE:e} in magnitude"),
        ));
    }
    let c = DVec3::from_array(b.center) * s - offset;
    let r = b.radius * s;
    if !(c.is_finite() && r.is_finite() && r > 0.0) {
        return Err(at(
            span(),
            key,
            "a ball needs a finite center and a positive radius".into(),
        ));
    }
    Ok((c, r))
}

/// The tets of `mesh` a `cuttable` key names: `"all"`, a physical volume group (its tets) or a
/// node group (the tets with every node in it), or a ball `{ center, radius }` (scene units;
/// the tets whose centroid is in it). Errors name the key.
fn cut_region(
    mesh: &crate::Mesh,
    t: &Spanned<TouchableToml>,
    s: f64,
    offset: DVec3,
    at: &dyn Fn(std::ops::Range<usize>, &str, String) -> Error,
) -> Result<crate::scene::CutRegion, Error> {
    let nt = mesh.tets.len();
    let mut tets = vec![false; nt];
    match t.get_ref() {
        TouchableToml::Name(n) if n == "all" => tets.fill(true),
        TouchableToml::Name(g) => {
            if let Some(ids) = mesh.tet_groups.get(g) {
                for &i in ids {
                    if let Some(x) = tets.get_mut(i as usize) {
                        *x = true;
                    }
                }
            } else if let Some(ids) = mesh.groups.get(g) {
                let mut in_group = vec![false; mesh.nodes.len()];
                for &v in ids {
                    if let Some(x) = in_group.get_mut(v as usize) {
                        *x = true;
                    }
                }
                for (k, tet) in mesh.tets.iter().enumerate() {
                    tets[k] = tet.iter().all(|&v| in_group[v as usize]);
                }
            } else {
                let names: Vec<String> = mesh
                    .tet_groups
                    .keys()
                    .chain(mesh.groups.keys())
                    .cloned()
                    .collect();
                return Err(at(
                    t.span(),
                    "cuttable",
                    format!("no group '{g}' in the mesh (groups: {})", names.join(", ")),
                ));
            }
        }
        TouchableToml::Ball(b) => {
            let (c, r) = ball(b, s, offset, || t.span(), "cuttable", at)?;
            for (k, tet) in mesh.tets.iter().enumerate() {
                let g = tet.iter().map(|&v| mesh.nodes[v as usize]).sum::<DVec3>() / 4.0;
                tets[k] = g.distance(c) <= r;
            }
        }
    }
    if !tets.iter().any(|&x| x) {
        return Err(at(
            t.span(),
            "cuttable",
            "the region holds no tet of the mesh".into(),
        ));
    }
    Ok(crate::scene::CutRegion::new(tets))
}

/// The cache file name of an object: `NAME-KEY.tfc` (name made file-safe) in `dir`.
pub use crate::cache::file_in as cache_file;

/// The compliance for `sel`, from the cache when valid; computed (and saved, if possible)
/// otherwise. `near_from` (a live session with one finger): an `L` of at least that many f64
/// bytes stays in the cache file and only the near blocks are held (see [`Hold::Live`]).
fn compute_cached(
    cache: Option<&Path>,
    name: &str,
    mesh: &crate::Mesh,
    sel: &Selection,
    compression: Option<&HOptions>,
    key: u64,
    near_from: Option<u64>,
) -> Result<Compliance, Error> {
    let Some(dir) = cache else {
        return Ok(match compression {
            Some(o) => Compliance::compute_hier(mesh, sel, o, &mut |_, _| {})?,
            None => Compliance::compute(mesh, sel)?,
        });
    };
    let path = cache_file(dir, name, key);
    let min_bytes = match crate::options::var("TOUCHFEM_HOST_L")
        .unwrap_or_default()
        .trim()
    {
        "dense" => None,
        "near" => near_from.map(|_| 0),
        _ => near_from,
    };
    let large =
        |rows: usize, cols: usize| min_bytes.is_some_and(|m| 72 * rows as u64 * cols as u64 >= m);
    let n = mesh.nodes.len();
    if let Ok(part) = crate::cache::Part::open(&path) {
        if large(part.head.l_rows as usize, part.cols.len()) {
            if let Ok(c) = crate::cache::load_near_part(part, key, n, &mesh.surface) {
                return Ok(c);
            }
        }
    }
    let (c, outcome) = crate::cache::load_or_compute_with(&path, mesh, sel, compression)?;
    match outcome {
        crate::cache::CacheOutcome::NotSaved(..) => {
            if let Some(m) = outcome.message() {
                log::warn!("{m}");
            }
        }
        crate::cache::CacheOutcome::Recomputed(_) if large(c.l_rows(), c.cols().len()) => {
            // Just saved: hold only the blocks from the file.
            drop(c);
            return Ok(crate::cache::load_near(&path, key, n, &mesh.surface)?);
        }
        _ => {}
    }
    Ok(c)
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    #[cfg_attr(test, test)]
    pub(crate) fn lines_are_counted_from_one() {
        assert_eq!(line_of("a\nb\nc", 0), 1);
        assert_eq!(line_of("a\nb\nc", 2), 2);
        assert_eq!(line_of("a\nb\nc", 4), 3);
    }
}
