#!/usr/bin/env python3
"""Generate meshes/mouse.msh: a tetrahedral soft "mouse" (the animal) standing
on four flat pads at z = 0, sized after Hirota & Kaneko's Table 1 model
(length ~120 mm, 1713 nodes, 1175 surface nodes, 2346 surface triangles,
6312 tetrahedra).

Usage:  pip install gmsh ; python3 scripts/make_mouse.py
        python3 scripts/check_mouse.py     # independent counts / checks (numpy)
        python3 scripts/render_mouse.py    # meshes/mouse.png (matplotlib)

The MOUSE_* environment variables override the tuned defaults (for
experiments only; the committed mesh uses the defaults); MOUSE_OUT names the
output file (the resolution ladder: `touchfem bench --ladder`).

Deterministic: single-threaded Gmsh with a fixed random seed.  Units: mm.
Output: MSH 4.1 ASCII with only the physical groups' elements:
  physical volume  "body"  (linear tets, element type 4)
  physical surface "fixed" (the four flat pad bottoms at z = 0, triangles)
"""
import math
import os

import gmsh

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.environ.get("MOUSE_OUT", os.path.join(HERE, "..", "meshes", "mouse.msh"))

# Mesh size parameters (mm), tuned so the counts land near Table 1.
H_SURF = float(os.environ.get("MOUSE_H", "4.4"))      # size on the surface
H_CORE = float(os.environ.get("MOUSE_HCORE", "4.8"))  # size deep inside
D_CORE = float(os.environ.get("MOUSE_DCORE", "12.0")) # distance to reach H_CORE
FOOT_A = float(os.environ.get("MOUSE_FA", "12.5"))
FOOT_B = float(os.environ.get("MOUSE_FB", "9.5"))
FOOT_C = float(os.environ.get("MOUSE_FC", "7.0"))
EAR_T = float(os.environ.get("MOUSE_EART", "5.0"))  # ear half-thickness


def build_geometry():
    occ = gmsh.model.occ
    parts = []
    # Body: ellipsoid, length 88 mm, width 46 mm, height 38 mm.
    # (unit spheres are turned so that their parametric poles, which give
    # poorly shaped surface triangles, end up hidden inside other parts)
    body = occ.addSphere(0, 0, 0, 1.0)
    occ.rotate([(3, body)], 0, 0, 0, 0, 1, 0, math.pi / 2)  # poles on x
    occ.dilate([(3, body)], 0, 0, 0, 44.0, 23.0, 19.0)
    occ.translate([(3, body)], -12.0, 0.0, 25.0)
    parts.append(body)
    # Head: smaller ellipsoid, snout toward +x, slightly raised.
    head = occ.addSphere(0, 0, 0, 1.0)
    occ.rotate([(3, head)], 0, 0, 0, 0, 1, 0, math.pi / 2)  # poles on x
    occ.dilate([(3, head)], 0, 0, 0, 22.0, 16.0, 14.0)
    occ.rotate([(3, head)], 0, 0, 0, 0, 1, 0, math.radians(12.0))  # nose dips
    occ.translate([(3, head)], 36.0, 0.0, 31.0)
    parts.append(head)
    # Ears: thick flattened ellipsoids on top/back of the head.
    for s in (+1, -1):
        ear = occ.addSphere(0, 0, 0, 1.0)
        occ.dilate([(3, ear)], 0, 0, 0, EAR_T, 10.0, 10.0)
        occ.rotate([(3, ear)], 0, 0, 0, 1, 0, 0, math.radians(-s * 30.0))
        occ.translate([(3, ear)], 28.0, s * 11.0, 42.0)
        parts.append(ear)
    # Legs: short cylinders from inside the body down to a foot pad; the
    # foot is a flattened ellipsoid centred on z = 0, so the cut at z = 0
    # leaves a flat elliptic pad.
    for (x, y) in ((22.0, 11.0), (22.0, -11.0), (-33.0, 12.0), (-33.0, -12.0)):
        # tapered leg leaning inward so that its top disc is buried in the body
        leg = occ.addCone(x, y, 1.0, 0.0, -0.6 * y, 22.0, 6.0, 4.0)
        parts.append(leg)
        foot = occ.addSphere(0, 0, 0, 1.0)
        occ.dilate([(3, foot)], 0, 0, 0, FOOT_A, FOOT_B, FOOT_C)
        occ.translate([(3, foot)], x + 2.0, y, 0.0)
        parts.append(foot)
    # Tail stub: thick tapered cone leaving the rump (kept thick on purpose).
    tail = occ.addCone(-50.0, 0.0, 24.0, -12.0, 0.0, -5.0, 6.0, 3.5)
    parts.append(tail)
    tail_tip = occ.addSphere(-62.0, 0.0, 19.0, 3.5)
    parts.append(tail_tip)

    out, _ = occ.fuse([(3, parts[0])], [(3, p) for p in parts[1:]])
    occ.synchronize()
    # the only planar faces must be the pad bottoms created by the cut below
    planes = [s for (_, s) in gmsh.model.getEntities(2)
              if gmsh.model.getType(2, s) == "Plane"]
    assert not planes, f"unexpected exposed planar faces {planes}"
    # Cut everything below z = 0.
    cutter = occ.addBox(-200, -200, -100, 400, 400, 100)
    out, _ = occ.cut(out, [(3, cutter)])
    occ.synchronize()
    occ.removeAllDuplicates()
    occ.synchronize()
    vols = gmsh.model.getEntities(3)
    assert len(vols) == 1, f"expected one volume, got {vols}"
    return vols[0][1]


def main():
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("General.NumThreads", 1)
    gmsh.option.setNumber("Mesh.RandomSeed", 12345)  # (no General.RandomSeed in 4.15)
    gmsh.model.add("mouse")
    vol = build_geometry()

    # Flat pad bottoms: surfaces whose bounding box lies in z = 0.
    fixed = []
    for (_, s) in gmsh.model.getEntities(2):
        bb = gmsh.model.getBoundingBox(2, s)
        if abs(bb[2]) < 1e-3 and abs(bb[5]) < 1e-3:
            fixed.append(s)
    assert len(fixed) == 4, f"expected four pads, got {fixed}"
    gmsh.model.addPhysicalGroup(2, fixed, name="fixed")
    gmsh.model.addPhysicalGroup(3, [vol], name="body")

    # Size field: H_SURF at the boundary, growing to H_CORE inside.
    surfs = [s for (_, s) in gmsh.model.getEntities(2)]
    f = gmsh.model.mesh.field
    dist = f.add("Distance")
    f.setNumbers(dist, "SurfacesList", surfs)
    f.setNumber(dist, "Sampling", 60)
    thr = f.add("Threshold")
    f.setNumber(thr, "InField", dist)
    f.setNumber(thr, "SizeMin", H_SURF)
    f.setNumber(thr, "SizeMax", H_CORE)
    f.setNumber(thr, "DistMin", 0.0)
    f.setNumber(thr, "DistMax", D_CORE)
    f.setAsBackgroundMesh(thr)
    gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
    gmsh.option.setNumber("Mesh.MeshSizeMin", 0.5 * H_SURF)
    gmsh.option.setNumber("Mesh.MeshSizeMax", H_CORE)

    gmsh.option.setNumber("Mesh.Algorithm", 6)     # Frontal-Delaunay 2D
    gmsh.option.setNumber("Mesh.Algorithm3D", 1)   # Delaunay 3D
    gmsh.option.setNumber("Mesh.ElementOrder", 1)
    gmsh.option.setNumber("Mesh.Optimize", 1)
    gmsh.option.setNumber("Mesh.OptimizeNetgen", 1)
    gmsh.option.setNumber("Mesh.OptimizeThreshold", 0.3)
    gmsh.model.mesh.generate(3)
    gmsh.model.mesh.optimize("", niter=3)  # default (Gmsh) tet optimiser
    gmsh.model.mesh.optimize("Netgen", niter=1)

    _, tets, _ = gmsh.model.mesh.getElements(3)
    tets = tets[0] if len(tets) else []
    q = gmsh.model.mesh.getElementQualities(tets, "gamma")
    print(f"tets {len(tets)}  gamma min {min(q):.3f} mean {sum(q)/len(q):.3f}")

    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.option.setNumber("Mesh.Binary", 0)
    gmsh.option.setNumber("Mesh.SaveAll", 0)
    os.makedirs(os.path.dirname(OUT), exist_ok=True)
    gmsh.write(OUT)
    print("wrote", os.path.normpath(OUT))
    gmsh.finalize()


if __name__ == "__main__":
    main()
