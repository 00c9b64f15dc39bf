#!/usr/bin/env python3
"""Generate an organ-like tetrahedral test mesh of a chosen size (for scaling runs).

A liver-like blob: two fused ellipsoids (about 160 x 100 x 70 mm) cut flat at z = 0; the flat
cut is the clamped face (physical surface "fixed"), the rest is free surface. Units: mm.

Usage:  pip install gmsh
        python3 scripts/make_organ.py H OUT.msh      # H: element size in mm
        python3 scripts/make_organ.py 46k OUT.msh    # presets: 17k, 46k, 100k
Node counts with Gmsh 4.15 (earlier Gmsh gave more per H): H = 3.15 -> 17 543, 3 -> 20 251,
2.3 -> 42 827, 2.25 -> 45 226 (preset 46k), 1.7 -> 100 666 (preset 100k, the hierarchical
L's large case: 17 471 surface and 13 692 free-surface nodes).
Large meshes belong under an ignored directory (out/, target-*), not in git.

Deterministic: single-threaded Gmsh with a fixed random seed. Output: MSH 4.1 binary.
"""
import math
import os
import sys

import gmsh


def main():
    presets = {"17k": 3.15, "46k": 2.25, "100k": 1.7}
    h = presets[sys.argv[1]] if sys.argv[1] in presets else float(sys.argv[1])
    out = sys.argv[2]
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("General.NumThreads", 1)
    gmsh.option.setNumber("Mesh.RandomSeed", 12345)
    gmsh.model.add("organ")
    occ = gmsh.model.occ
    a = occ.addSphere(0, 0, 0, 1.0)
    occ.dilate([(3, a)], 0, 0, 0, 80.0, 50.0, 38.0)
    occ.translate([(3, a)], 0.0, 0.0, 20.0)
    b = occ.addSphere(0, 0, 0, 1.0)
    occ.dilate([(3, b)], 0, 0, 0, 45.0, 35.0, 30.0)
    occ.rotate([(3, b)], 0, 0, 0, 0, 0, 1, math.radians(25.0))
    occ.translate([(3, b)], 45.0, 25.0, 30.0)
    out_v, _ = occ.fuse([(3, a)], [(3, b)])
    cutter = occ.addBox(-300, -300, -100, 600, 600, 100)
    out_v, _ = occ.cut(out_v, [(3, cutter)])
    occ.synchronize()
    occ.removeAllDuplicates()
    occ.synchronize()
    vols = gmsh.model.getEntities(3)
    assert len(vols) == 1, vols
    fixed = []
    for (_, s) in gmsh.model.getEntities(2):
        bb = gmsh.model.getBoundingBox(2, s)
        if abs(bb[2]) < 1e-3 and abs(bb[5]) < 1e-3:
            fixed.append(s)
    assert fixed, "no flat base"
    gmsh.model.addPhysicalGroup(2, fixed, name="fixed")
    gmsh.model.addPhysicalGroup(3, [vols[0][1]], name="body")
    gmsh.option.setNumber("Mesh.MeshSizeMin", h)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
    gmsh.option.setNumber("Mesh.Algorithm", 6)
    gmsh.option.setNumber("Mesh.Algorithm3D", 1)
    gmsh.option.setNumber("Mesh.Optimize", 1)
    gmsh.model.mesh.generate(3)
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.option.setNumber("Mesh.Binary", 1)
    gmsh.option.setNumber("Mesh.SaveAll", 0)
    d = os.path.dirname(out)
    if d:
        os.makedirs(d, exist_ok=True)
    gmsh.write(out)
    print("wrote", out, "nodes", len(gmsh.model.mesh.getNodes()[0]))
    gmsh.finalize()


if __name__ == "__main__":
    main()
