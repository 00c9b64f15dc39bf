//! `poke --cut X1,Y1,Z1:X2,Y2,Z2 --depth D`: the blade separates the object along its path
//! first (snap and split, the exact low-rank update of `L`, no recompute), then a point finger
//! pokes the separated object, with the paper's force unless `--exact` is given.

use glam::DVec3;

use touchfem_core::contact::{GodObject, Surface};
use touchfem_core::cut::{point_poke, point_poke_paper, BladeQuad, Cut, SplitReport};

use crate::args::{check_motion, check_tool, extent_m, PokeArgs};
use crate::error::Error;

/// Runs `poke` with `--cut` (`seg`, mesh units) and `--depth` (mesh units).
pub(crate) fn poke_cut(a: &PokeArgs, seg: (DVec3, DVec3), depth: f64) -> Result<(), Error> {
    let refuse = |flag: &str| {
        Err(Error::Input(format!(
            "--cut: {flag} is not combined with a cut yet (a point finger)"
        )))
    };
    if a.sphere.is_some() {
        return refuse("--sphere");
    }
    if a.friction.is_some() {
        return refuse("--friction");
    }
    if a.slide.is_some() {
        return refuse("--slide");
    }
    if a.png.is_some() {
        return refuse("--png");
    }
    if a.cache.is_some() {
        return refuse("--cache");
    }
    let (mesh, unit) = a.load.load(&a.mesh)?;
    let s = unit.to_metres();
    let blade = touchfem_core::contact::Tool::Blade { depth_m: depth * s };
    check_tool("--depth", depth, blade, &[extent_m(&mesh)])?;
    check_motion("--push", a.push, &mesh, unit)?;
    let uncut = Surface::new(&mesh);
    let (_, p1) = uncut.closest_global(seg.0 * s);
    let (_, p2) = uncut.closest_global(seg.1 * s);
    let mut cut = Cut::new(&mesh)?;
    // A blade whose two points meet on the surface (or that hangs along its path) cuts
    // nothing.
    let rep = match BladeQuad::on_surface(&uncut, seg.0 * s, seg.1 * s, depth * s) {
        Ok(quad) => cut.split(&mesh, &[quad])?,
        Err(_) => SplitReport::default(),
    };
    // The finger: the god-object on the separated rest surface (the cut's faces touchable
    // too), pushed in `steps` ticks.
    let open = cut.separated_mesh(&mesh);
    if open.surface.is_empty() {
        return Err(Error::Input("--cut: nothing of the object is left".into()));
    }
    let surface = Surface::new(&open);
    let (at, push) = (a.at * s, a.push * s);
    let (tri, p0) = surface.closest_global(at);
    let mut god = GodObject::touching(tri);
    let steps = a.steps.max(1);
    let mut contact = None;
    for k in 1..=steps {
        contact = god.update(&surface, p0 + push * (k as f64 / steps as f64));
    }
    let n = open.nodes.len();
    let poked = contact.and_then(|c| {
        if a.exact {
            point_poke(&cut, c.nodes, c.alpha, c.displacement())
        } else {
            // The compliance a clamped or pinned contact node is given (only then worked
            // out: a solve for the surface's free nodes).
            let held = (0..3).any(|k| c.alpha[k] != 0.0 && cut.holds_still(c.nodes[k]));
            let clamp = if held {
                cut.clamp_compliance(&open.surface_nodes)
            } else {
                0.0
            };
            point_poke_paper(&cut, c.nodes, c.alpha, c.displacement(), clamp)
        }
    });
    let (feedback, forces, u) = poked.unwrap_or((DVec3::ZERO, Vec::new(), vec![DVec3::ZERO; n]));
    let max_u = u.iter().map(|v| v.length()).fold(0.0, f64::max);
    let mut f = vec![DVec3::ZERO; n];
    for &(v, fv) in &forces {
        f[v as usize] += fv;
    }
    if let Some(path) = &a.vtu {
        crate::vtu::write_vtu(path, &open, &u, &f, &f)?;
    }
    let tets_removed = cut.removed().iter().filter(|&&r| r).count();
    let model = if a.exact {
        "exact model"
    } else {
        "paper model"
    };
    let contact_nodes: Vec<u32> = forces.iter().map(|p| p.0).collect();
    if a.json {
        let v = serde_json::json!({
            "force": feedback.to_array(),
            "max_displacement": max_u,
            "tets_removed": tets_removed,
            "nodes_split": rep.nodes_split,
            "nodes_snapped": rep.nodes_snapped,
            "slivers": rep.slivers,
            "sliver_volume": rep.sliver_volume,
            "correction_rank": rep.cut.rank,
            "pieces_removed": rep.cut.pieces_removed,
            "nodes_pinned": cut.pinned().iter().filter(|&&p| p).count(),
            "contact_nodes": contact_nodes,
            "touch_point": p0.to_array(),
            "blade": { "from": p1.to_array(), "to": p2.to_array(), "depth_m": depth * s },
            "units": {
                "force": "N",
                "max_displacement": "m",
                "positions": "m",
                "sliver_volume": "m^3"
            }
        });
        println!("{v}");
    } else {
        println!(
            "cut: {} nodes split, {} snapped, {} slivers dropped ({:.4} mm³), {} tets removed ({} piece(s) cut off), correction rank {}",
            rep.nodes_split,
            rep.nodes_snapped,
            rep.slivers,
            rep.sliver_volume * 1e9,
            tets_removed,
            rep.cut.pieces_removed,
            rep.cut.rank
        );
        println!(
            "force on the finger: [{:.6}, {:.6}, {:.6}] N (|F| = {:.6} N, {model})",
            feedback.x,
            feedback.y,
            feedback.z,
            feedback.length()
        );
        println!("max displacement: {:.4} mm", max_u * 1e3);
    }
    Ok(())
}
