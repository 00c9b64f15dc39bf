#!/usr/bin/env python3
"""Render meshes/mouse.msh's boundary surface to meshes/mouse.png (matplotlib).
Pads ("fixed") in red; two views (3/4 view and from below)."""
import os
from collections import Counter

import gmsh
import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "meshes")
gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
gmsh.open(os.path.join(root, "mouse.msh"))
tags, xyz, _ = gmsh.model.mesh.getNodes()
pos = {int(t): xyz[3 * k:3 * k + 3] for k, t in enumerate(tags)}
_, _, tn = gmsh.model.mesh.getElements(3)
T = np.array(tn[0], dtype=np.int64).reshape(-1, 4)
fixed = set()
for (d, t) in gmsh.model.getPhysicalGroups(2):
    if gmsh.model.getPhysicalName(d, t) == "fixed":
        for e in gmsh.model.getEntitiesForPhysicalGroup(d, t):
            _, _, n = gmsh.model.mesh.getElements(2, e)
            for k in range(0, len(n[0]), 3):
                fixed.add(tuple(sorted(int(v) for v in n[0][k:k + 3])))
gmsh.finalize()

fc = Counter()
for t in T:
    for f in ((0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)):
        fc[tuple(sorted(int(t[i]) for i in f))] += 1
faces = [f for f, n in fc.items() if n == 1]
polys = [np.array([pos[v] for v in f]) for f in faces]
light = np.array([0.4, -0.5, 0.75]); light /= np.linalg.norm(light)
cols = []
for f, P in zip(faces, polys):
    n = np.cross(P[1] - P[0], P[2] - P[0]); n /= np.linalg.norm(n)
    s = 0.35 + 0.65 * abs(n @ light)
    cols.append((0.9 * s, 0.2 * s, 0.2 * s) if f in fixed else (0.75 * s, 0.72 * s, 0.68 * s))

fig = plt.figure(figsize=(12, 5.5))
for k, (elev, azim, title) in enumerate(((25, -60, "mouse.msh"), (-60, -60, "from below: fixed pads (red)"))):
    ax = fig.add_subplot(1, 2, k + 1, projection="3d")
    ax.add_collection3d(Poly3DCollection(polys, facecolors=cols, edgecolors=(0, 0, 0, 0.25), linewidths=0.2))
    ax.set_xlim(-65, 60); ax.set_ylim(-62.5, 62.5); ax.set_zlim(-20, 70)
    ax.set_box_aspect((125, 125, 90))
    ax.view_init(elev=elev, azim=azim)
    ax.set_title(title); ax.set_xlabel("x [mm]"); ax.set_ylabel("y"); ax.set_zlabel("z")
plt.tight_layout()
out = os.path.join(root, "mouse.png")
plt.savefig(out, dpi=90)
print("wrote", os.path.normpath(out), os.path.getsize(out), "bytes")
