#!/usr/bin/env python3
"""Generate meshes/phantom.msh: a palpation phantom, a soft block of tissue
with a stiff spherical nodule a few millimetres under its top surface (the
bundled mesh `phantom`, touched by the bundled scene `palpate`).

Usage:  pip install gmsh ; python3 scripts/make_palpate.py

Geometry (mm): the block [-30, 30] x [-20, 20] x [0, 20] (60 x 40 x 20 mm),
standing on z = 0; the nodule a ball of radius 5 mm (10 mm across) centred on
(0, 0, 12), so its top is 3 mm under the top face z = 20. The ball and the
block are fragmented so that the mesh conforms to the nodule's surface.

Output: MSH 4.1 binary with only the physical groups' elements:
  physical volume  "tissue" (the block minus the ball; linear tets)
  physical volume  "nodule" (the ball; linear tets)
  physical surface "fixed"  (the bottom face z = 0, triangles)
  physical surface "top"    (the top face z = 20, where the finger palpates)
The materials are not in the file: the scene gives them (scenes/palpate.toml).

Deterministic: single-threaded Gmsh with a fixed random seed.
"""
import os

import gmsh

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.environ.get("PHANTOM_OUT", os.path.join(HERE, "..", "meshes", "phantom.msh"))

LX, LY, LZ = 60.0, 40.0, 20.0  # block, mm
R = 5.0                        # nodule radius, mm
ZC = 12.0                      # nodule centre height, mm (top 3 mm under z = 20)
H_FINE = float(os.environ.get("PHANTOM_H", "2.2"))     # near the top face's middle strip
H_NODULE = float(os.environ.get("PHANTOM_HN", "1.5"))  # in the nodule
H_COARSE = float(os.environ.get("PHANTOM_HC", "5.0"))  # deep and far


def main():
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("General.NumThreads", 1)
    gmsh.option.setNumber("Mesh.RandomSeed", 1)
    gmsh.model.add("phantom")
    occ = gmsh.model.occ
    box = occ.addBox(-LX / 2, -LY / 2, 0.0, LX, LY, LZ)
    ball = occ.addSphere(0.0, 0.0, ZC, R)
    # The sphere's parametric poles on x, where they make no sliver at the top.
    occ.rotate([(3, ball)], 0.0, 0.0, ZC, 0, 1, 0, 1.5707963267948966)
    out, _ = occ.fragment([(3, box)], [(3, ball)])
    occ.synchronize()
    vols = [t for d, t in out if d == 3]
    # The nodule is the volume whose centre of mass is the ball's centre and whose volume is
    # the ball's; the tissue the other one.
    def mass(t):
        return occ.getMass(3, t)
    vols.sort(key=mass)
    nodule, tissue = vols[0], vols[1]
    bottom = [
        t
        for d, t in gmsh.model.getEntities(2)
        if abs(occ.getCenterOfMass(2, t)[2]) < 1e-9
    ]
    top = [
        t
        for d, t in gmsh.model.getEntities(2)
        if abs(occ.getCenterOfMass(2, t)[2] - LZ) < 1e-9
    ]
    assert len(bottom) == 1 and len(top) == 1, (bottom, top)
    gmsh.model.addPhysicalGroup(3, [tissue], name="tissue")
    gmsh.model.addPhysicalGroup(3, [nodule], name="nodule")
    gmsh.model.addPhysicalGroup(2, bottom, name="fixed")
    gmsh.model.addPhysicalGroup(2, top, name="top")

    # Fine near the top face's middle strip (where a finger presses), finer in the nodule, coarse
    # deep and far.
    f = gmsh.model.mesh.field
    box_f = f.add("Box")
    f.setNumber(box_f, "VIn", H_FINE)
    f.setNumber(box_f, "VOut", H_COARSE)
    f.setNumber(box_f, "XMin", -LX / 2)
    f.setNumber(box_f, "XMax", LX / 2)
    f.setNumber(box_f, "YMin", -10.0)
    f.setNumber(box_f, "YMax", 10.0)
    f.setNumber(box_f, "ZMin", ZC - R - 1.0)
    f.setNumber(box_f, "ZMax", LZ)
    f.setNumber(box_f, "Thickness", 8.0)
    ball_f = f.add("Ball")
    f.setNumber(ball_f, "VIn", H_NODULE)
    f.setNumber(ball_f, "VOut", H_COARSE)
    f.setNumber(ball_f, "XCenter", 0.0)
    f.setNumber(ball_f, "YCenter", 0.0)
    f.setNumber(ball_f, "ZCenter", ZC)
    f.setNumber(ball_f, "Radius", R + 0.5)
    f.setNumber(ball_f, "Thickness", 3.0)
    both = f.add("Min")
    f.setNumbers(both, "FieldsList", [box_f, ball_f])
    f.setAsBackgroundMesh(both)
    gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
    gmsh.option.setNumber("Mesh.Algorithm", 6)
    gmsh.option.setNumber("Mesh.Algorithm3D", 1)
    gmsh.option.setNumber("Mesh.Optimize", 1)
    gmsh.model.mesh.generate(3)

    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.option.setNumber("Mesh.Binary", 1)
    gmsh.option.setNumber("Mesh.SaveAll", 0)
    gmsh.write(OUT)
    n_nodes = len(gmsh.model.mesh.getNodes()[0])
    n_tets = {}
    for name, (d, t) in (("tissue", (3, tissue)), ("nodule", (3, nodule))):
        types, tags, _ = gmsh.model.mesh.getElements(d, t)
        n_tets[name] = sum(len(x) for x in tags)
    gmsh.finalize()
    print(f"{OUT}: {n_nodes} nodes, tets {n_tets}, {os.path.getsize(OUT)} bytes")


if __name__ == "__main__":
    main()
