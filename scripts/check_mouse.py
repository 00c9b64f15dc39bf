#!/usr/bin/env python3
"""Independent check of meshes/mouse.msh (MSH 4.1 ASCII parsed by hand, no gmsh).

Prints: nodes used by tets, tets, boundary triangles, boundary nodes, free
boundary nodes (not in physical "fixed"), fixed nodes (+ per pad), connected
components, volume, orientation, bounding box, gamma quality, manifoldness.
"""
import math
import os
import sys
from collections import Counter, defaultdict

import numpy as np

path = sys.argv[1] if len(sys.argv) > 1 else os.path.join(
    os.path.dirname(os.path.abspath(__file__)), "..", "meshes", "mouse.msh")
lines = open(path).read().split("\n")
i = 0
phys_names = {}
ent_phys = {}  # (dim, tag) -> [phys tags]
nodes = {}
elems = []  # (dim, entity, type, [node tags])
while i < len(lines):
    l = lines[i].strip()
    if l == "$MeshFormat":
        assert lines[i + 1].split()[:2] == ["4.1", "0"], lines[i + 1]
    elif l == "$PhysicalNames":
        n = int(lines[i + 1])
        for k in range(n):
            d, t, name = lines[i + 2 + k].split(maxsplit=2)
            phys_names[(int(d), int(t))] = name.strip('"')
    elif l == "$Entities":
        cnt = list(map(int, lines[i + 1].split()))
        j = i + 2
        for d in range(4):
            for _ in range(cnt[d]):
                w = lines[j].split(); j += 1
                tag = int(w[0])
                k = 4 if d == 0 else 7
                np_ = int(w[k])
                ent_phys[(d, tag)] = [int(x) for x in w[k + 1:k + 1 + np_]]
    elif l == "$Nodes":
        nb, nn, _, _ = map(int, lines[i + 1].split())
        j = i + 2
        for _ in range(nb):
            d, t, par, m = map(int, lines[j].split()); j += 1
            tags = [int(lines[j + k]) for k in range(m)]; j += m
            for k in range(m):
                nodes[tags[k]] = tuple(map(float, lines[j + k].split()))
            j += m
        assert len(nodes) == nn
    elif l == "$Elements":
        nb, ne, _, _ = map(int, lines[i + 1].split())
        j = i + 2
        for _ in range(nb):
            d, t, ty, m = map(int, lines[j].split()); j += 1
            for k in range(m):
                w = list(map(int, lines[j + k].split()))
                elems.append((d, t, ty, w[1:]))
            j += m
        assert len(elems) == ne
    i += 1

types = Counter((e[0], e[2]) for e in elems)
print("element (dim,type) counts in file:", dict(types))
print("physical names:", phys_names)
fixed_tag = [t for (d, t), n in phys_names.items() if d == 2 and n == "fixed"][0]
body_tag = [t for (d, t), n in phys_names.items() if d == 3 and n == "body"][0]
tets = [e[3] for e in elems if e[2] == 4 and body_tag in ent_phys[(3, e[1])]]
assert all(e[2] in (2, 4) for e in elems), "only linear tris/tets expected"
fixed_tris = [(e[1], e[3]) for e in elems if e[2] == 2 and fixed_tag in ent_phys[(2, e[1])]]

used = sorted({v for t in tets for v in t})
idx = {v: k for k, v in enumerate(used)}
X = np.array([nodes[v] for v in used])
T = np.array([[idx[v] for v in t] for t in tets])
print(f"nodes in file: {len(nodes)}; nodes used by tets: {len(used)}")
print(f"tets: {len(T)}")

# orientation / volume
a, b, c, d = (X[T[:, k]] for k in range(4))
vol6 = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a)
print(f"positively oriented: {(vol6 > 0).sum()} / {len(T)}; degenerate(|V|<1e-9): {(abs(vol6) < 1e-9).sum()}")
print(f"total volume: {abs(vol6).sum() / 6:.1f} mm^3")

# boundary faces
fc = Counter()
for t in T:
    for f in ((0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)):
        fc[tuple(sorted(t[list(f)]))] += 1
assert max(fc.values()) <= 2, "face shared by >2 tets"
bfaces = [f for f, n in fc.items() if n == 1]
bnodes = {v for f in bfaces for v in f}
fixed_nodes = {idx[v] for _, tri in fixed_tris for v in tri}
assert fixed_nodes <= bnodes
fixed_face_set = {tuple(sorted(idx[v] for v in tri)) for _, tri in fixed_tris}
assert fixed_face_set <= set(bfaces), "fixed triangles are not tet boundary faces"
print(f"boundary triangles: {len(bfaces)}")
print(f"boundary nodes: {len(bnodes)}")
print(f"fixed nodes: {len(fixed_nodes)}; free surface nodes: {len(bnodes - fixed_nodes)}")
print(f"fixed triangles: {len(fixed_tris)}")
print(f"max |z| of fixed nodes: {max(abs(X[v, 2]) for v in fixed_nodes):.3g}; min z overall: {X[:, 2].min():.3g}")

# per pad
pads = defaultdict(set)
for ent, tri in fixed_tris:
    pads[ent] |= {idx[v] for v in tri}
for ent, ns in sorted(pads.items()):
    P = X[sorted(ns)]
    rank = np.linalg.matrix_rank(P - P.mean(0), tol=1e-6)
    print(f"  pad surface {ent}: {len(ns)} nodes, centre ({P[:,0].mean():.1f}, {P[:,1].mean():.1f}), affine rank {rank}")
print(f"pads: {len(pads)}")

# manifold boundary
ec = Counter()
for f in bfaces:
    for e in ((f[0], f[1]), (f[0], f[2]), (f[1], f[2])):
        ec[tuple(sorted(e))] += 1
print(f"closed 2-manifold edges (each boundary edge in exactly 2 triangles): {all(n == 2 for n in ec.values())}")
# vertex manifoldness: boundary-triangle fan around each vertex is a single cycle
vt = defaultdict(list)
for f in bfaces:
    for v in f:
        vt[v].append(f)
bad_v = 0
for v, fs in vt.items():
    adj = defaultdict(set)
    for f in fs:
        o = [w for w in f if w != v]
        adj[o[0]].add(o[1]); adj[o[1]].add(o[0])
    start = next(iter(adj)); seen = {start}; st = [start]
    while st:
        u = st.pop()
        for w in adj[u]:
            if w not in seen:
                seen.add(w); st.append(w)
    if len(seen) != len(adj):
        bad_v += 1
print(f"non-manifold boundary vertices: {bad_v}")
V, E, F = len(bnodes), len(ec), len(bfaces)
chi = V - E + F
print(f"boundary Euler characteristic V-E+F = {chi} (2 = sphere, genus {(2 - chi) // 2})")

# connected components (tets sharing a face)
parent = list(range(len(T)))
def find(x):
    while parent[x] != x:
        parent[x] = parent[parent[x]]; x = parent[x]
    return x
owner = {}
for k, t in enumerate(T):
    for f in ((0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)):
        key = tuple(sorted(t[list(f)]))
        if key in owner:
            parent[find(k)] = find(owner[key])
        else:
            owner[key] = k
print(f"connected components (face-adjacency): {len({find(k) for k in range(len(T))})}")

lo, hi = X.min(0), X.max(0)
print(f"bbox: x [{lo[0]:.2f}, {hi[0]:.2f}]  y [{lo[1]:.2f}, {hi[1]:.2f}]  z [{lo[2]:.2f}, {hi[2]:.2f}]  "
      f"size {hi[0]-lo[0]:.1f} x {hi[1]-lo[1]:.1f} x {hi[2]-lo[2]:.1f} mm")

# gamma quality = 3 * inradius / circumradius (Gmsh's "gamma"), computed here.
def gamma(p):
    A, B, C, D = p
    V = abs(np.dot(np.cross(B - A, C - A), D - A)) / 6
    S = sum(np.linalg.norm(np.cross(q - p0, r - p0)) / 2 for p0, q, r in ((A, B, C), (A, B, D), (A, C, D), (B, C, D)))
    r_in = 3 * V / S
    # circumradius
    M = 2 * np.array([B - A, C - A, D - A])
    rhs = np.array([B @ B - A @ A, C @ C - A @ A, D @ D - A @ A])
    cc = np.linalg.solve(M, rhs)
    return 3 * r_in / np.linalg.norm(cc - A)
g = np.array([gamma(X[t]) for t in T])
print(f"gamma (3 r_in / r_circ): min {g.min():.3f}  mean {g.mean():.3f}  "
      f"<0.1: {(g < 0.1).sum()}  <0.2: {(g < 0.2).sum()}  <0.3: {(g < 0.3).sum()}")
# dihedral angles
mins, maxs = [], []
for t in T:
    P = X[t]
    angs = []
    for (i0, i1) in ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)):
        o = [k for k in range(4) if k not in (i0, i1)]
        e = P[i1] - P[i0]
        n1 = np.cross(e, P[o[0]] - P[i0]); n2 = np.cross(e, P[o[1]] - P[i0])
        cosv = np.dot(n1, n2) / np.linalg.norm(n1) / np.linalg.norm(n2)
        angs.append(math.degrees(math.acos(max(-1, min(1, cosv)))))
    mins.append(min(angs)); maxs.append(max(angs))
print(f"dihedral angles: min {min(mins):.1f} deg, max {max(maxs):.1f} deg")
print(f"file size: {os.path.getsize(path)} bytes")
worst = np.argsort(g)[:8]
print("worst tets (gamma, centroid):", [(round(float(g[k]), 3), tuple(np.round(X[T[k]].mean(0), 1))) for k in worst])
