#!/usr/bin/env python3
"""Generates the mesh fixtures in tests/data/ used by tests/mesh_io.rs.

Requires the Gmsh Python package (`pip install gmsh`, works headless). Run from the repository
root:  python3 scripts/gen_fixtures.py

Output (all coordinates in millimetres, a 30 x 30 x 30 mm box at the origin):
  box_v41.msh, box_v41_bin.msh, box_v22.msh, box_v22_bin.msh
      the same tet mesh in MSH 4.1 ASCII/binary and 2.2 ASCII/binary, with the physical groups
      "fixed" (surface z = 0), "body" (the volume) and an unnamed physical surface with tag 7
      (the top face z = 30), which loaders expose as group "7".
  box_points_v41.msh, box_points_v22.msh
      "fixed" is a physical group of the four bottom corner points (plus volume "body").
  box_curves_v41.msh, box_curves_v22.msh
      "fixed" is a physical group of the four bottom edges (plus volume "body").
  box.node, box.ele
      TetGen files written from the same mesh: 1-based, '#' comments, one node attribute, boundary
      markers (1 = on z = 0, 2 = other boundary node, 0 = interior) and one tet attribute.
  two_regions_v41.msh, two_regions_v41_bin.msh, two_regions_v22.msh, two_regions_v22_bin.msh
      a 30 x 20 x 10 mm block [0, 30] x [0, 20] x [0, 10] cut at x = 12 into two conforming
      physical volumes "soft" (x < 12) and "hard" (x > 12), "fixed" the bottom face z = 0 and a
      physical surface "top" (z = 10): for material regions. `python3 scripts/gen_fixtures.py
      regions` writes only these.
"""

import os
import sys

import gmsh

EDGE = 30.0
SIZE = 7.5  # target element size, mm: ~200 nodes, ~700 tets, every file < 200 KB

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, "..", "tests", "data")


def box_entities():
    """Returns (volume, bottom surface, top surface, bottom points, bottom curves) tags."""
    vol = gmsh.model.occ.addBox(0, 0, 0, EDGE, EDGE, EDGE)
    gmsh.model.occ.synchronize()
    eps = 1e-6
    bottom = gmsh.model.getEntitiesInBoundingBox(-eps, -eps, -eps, EDGE + eps, EDGE + eps, eps, 2)
    top = gmsh.model.getEntitiesInBoundingBox(-eps, -eps, EDGE - eps, EDGE + eps, EDGE + eps,
                                              EDGE + eps, 2)
    pts = gmsh.model.getEntitiesInBoundingBox(-eps, -eps, -eps, EDGE + eps, EDGE + eps, eps, 0)
    crv = gmsh.model.getEntitiesInBoundingBox(-eps, -eps, -eps, EDGE + eps, EDGE + eps, eps, 1)
    assert len(bottom) == 1 and len(top) == 1 and len(pts) == 4 and len(crv) == 4
    return vol, bottom[0][1], top[0][1], [t for _, t in pts], [t for _, t in crv]


def build(variant):
    gmsh.clear()
    gmsh.model.add("box_" + variant)
    vol, bottom, top, pts, crv = box_entities()
    if variant == "surface":
        gmsh.model.addPhysicalGroup(2, [bottom], name="fixed")
        gmsh.model.addPhysicalGroup(2, [top], tag=7)  # unnamed: exposed as group "7"
    elif variant == "points":
        gmsh.model.addPhysicalGroup(0, pts, name="fixed")
    elif variant == "curves":
        gmsh.model.addPhysicalGroup(1, crv, name="fixed")
    gmsh.model.addPhysicalGroup(3, [vol], name="body")
    gmsh.option.setNumber("Mesh.MeshSizeMin", SIZE)
    gmsh.option.setNumber("Mesh.MeshSizeMax", SIZE)
    gmsh.option.setNumber("Mesh.Algorithm3D", 1)  # Delaunay
    gmsh.option.setNumber("Mesh.RandomSeed", 1)
    gmsh.model.mesh.generate(3)


def save(name, version, binary):
    gmsh.option.setNumber("Mesh.MshFileVersion", version)
    gmsh.option.setNumber("Mesh.Binary", 1 if binary else 0)
    gmsh.option.setNumber("Mesh.SaveAll", 0)
    path = os.path.join(OUT, name)
    gmsh.write(path)
    print(f"{name}: {os.path.getsize(path)} bytes")


def write_tetgen(stem):
    """Writes the current model's tet mesh as TetGen .node/.ele (1-based, with markers)."""
    tags, coords, _ = gmsh.model.mesh.getNodes()
    xyz = {int(t): coords[3 * i:3 * i + 3] for i, t in enumerate(tags)}
    etypes, etags, enodes = gmsh.model.mesh.getElements(3)
    assert list(etypes) == [4], etypes
    tets = [[int(n) for n in enodes[0][4 * i:4 * i + 4]] for i in range(len(etags[0]))]
    # Boundary nodes: nodes of tet faces used by exactly one tet.
    faces = {}
    for t in tets:
        for f in ((t[1], t[2], t[3]), (t[0], t[2], t[3]), (t[0], t[1], t[3]), (t[0], t[1], t[2])):
            k = tuple(sorted(f))
            faces[k] = faces.get(k, 0) + 1
    boundary = {n for f, c in faces.items() if c == 1 for n in f}
    order = sorted(xyz)  # gmsh tags, renumbered 1..n in this order
    index = {t: i + 1 for i, t in enumerate(order)}
    with open(os.path.join(OUT, stem + ".node"), "w") as f:
        f.write("# box 30 mm, written by scripts/gen_fixtures.py from the Gmsh mesh\n")
        f.write("# <points> <dim> <attributes> <boundary markers>\n")
        f.write(f"{len(order)} 3 1 1\n")
        for t in order:
            x, y, z = xyz[t]
            mark = (1 if z == 0.0 else 2) if t in boundary else 0
            f.write(f"{index[t]} {x!r} {y!r} {z!r} {float(t)!r} {mark}\n")
        f.write("# end\n")
    with open(os.path.join(OUT, stem + ".ele"), "w") as f:
        f.write("# <tets> <nodes per tet> <attributes>\n")
        f.write(f"{len(tets)} 4 1\n")
        for i, t in enumerate(tets):
            a, b, c, d = (index[n] for n in t)
            f.write(f"  {i + 1}  {a} {b} {c} {d}  1\n")
    for ext in (".node", ".ele"):
        print(f"{stem}{ext}: {os.path.getsize(os.path.join(OUT, stem + ext))} bytes")


def build_regions():
    """Two boxes side by side, fragmented so that the mesh conforms to their shared face."""
    gmsh.clear()
    gmsh.model.add("two_regions")
    occ = gmsh.model.occ
    a = occ.addBox(0, 0, 0, 12, 20, 10)
    b = occ.addBox(12, 0, 0, 18, 20, 10)
    occ.fragment([(3, a)], [(3, b)])
    occ.synchronize()
    eps = 1e-6
    soft = gmsh.model.getEntitiesInBoundingBox(-eps, -eps, -eps, 12 + eps, 20 + eps, 10 + eps, 3)
    hard = gmsh.model.getEntitiesInBoundingBox(12 - eps, -eps, -eps, 30 + eps, 20 + eps, 10 + eps, 3)
    bottom = gmsh.model.getEntitiesInBoundingBox(-eps, -eps, -eps, 30 + eps, 20 + eps, eps, 2)
    top = gmsh.model.getEntitiesInBoundingBox(-eps, -eps, 10 - eps, 30 + eps, 20 + eps, 10 + eps, 2)
    assert len(soft) == 1 and len(hard) == 1 and len(bottom) == 2 and len(top) == 2
    gmsh.model.addPhysicalGroup(3, [soft[0][1]], name="soft")
    gmsh.model.addPhysicalGroup(3, [hard[0][1]], name="hard")
    gmsh.model.addPhysicalGroup(2, [t for _, t in bottom], name="fixed")
    gmsh.model.addPhysicalGroup(2, [t for _, t in top], name="top")
    gmsh.option.setNumber("Mesh.MeshSizeMin", 5.0)
    gmsh.option.setNumber("Mesh.MeshSizeMax", 5.0)
    gmsh.option.setNumber("Mesh.Algorithm3D", 1)
    gmsh.option.setNumber("Mesh.RandomSeed", 1)
    gmsh.model.mesh.generate(3)


def main():
    os.makedirs(OUT, exist_ok=True)
    gmsh.initialize(sys.argv[:1])
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("General.NumThreads", 1)
    build_regions()
    save("two_regions_v41.msh", 4.1, False)
    save("two_regions_v41_bin.msh", 4.1, True)
    save("two_regions_v22.msh", 2.2, False)
    save("two_regions_v22_bin.msh", 2.2, True)
    if sys.argv[1:] == ["regions"]:
        gmsh.finalize()
        return
    build("surface")
    save("box_v41.msh", 4.1, False)
    save("box_v41_bin.msh", 4.1, True)
    save("box_v22.msh", 2.2, False)
    save("box_v22_bin.msh", 2.2, True)
    write_tetgen("box")
    for variant in ("points", "curves"):
        build(variant)
        save(f"box_{variant}_v41.msh", 4.1, False)
        save(f"box_{variant}_v22.msh", 2.2, False)
    gmsh.finalize()


if __name__ == "__main__":
    main()
