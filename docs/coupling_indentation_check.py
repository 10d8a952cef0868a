"""Indentation of a block under a disk load: designs 7 and 8 of docs/hybrid_coupling.md
(4^3 Kuhn-split cells of edge 1, the top half particle zone at spacing 1/3, all of it
dynamic, covered vertices slaved by an affine fit, bottom clamped, lambda = 1, mu = 0.5),
the tets alone with the same point loads, and FEM references of 8^3..32^3 cells under
a uniform load on the same disk. Needs numpy and scipy; about six minutes:
`python3 docs/coupling_indentation_check.py 3 1.0` (spacing divisor, disk radius)."""
import itertools, sys, numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

def mesh(n_cells, h):
    nv = n_cells + 1
    vid = lambda i, j, k: (i * nv + j) * nv + k
    verts = np.array([[i, j, k] for i in range(nv) for j in range(nv) for k in range(nv)], float) * h
    perms = list(itertools.permutations(range(3))); e = np.eye(3, dtype=int); tets = []
    for ci in range(n_cells):
        for cj in range(n_cells):
            for ck in range(n_cells):
                b = np.array([ci, cj, ck])
                for (a, bb, c) in perms:
                    tets.append([vid(*v) for v in [b, b + e[a], b + e[a] + e[bb], b + 1]])
    tets = np.array(tets); X = verts[tets]
    Dm = np.stack([X[:, 1] - X[:, 0], X[:, 2] - X[:, 0], X[:, 3] - X[:, 0]], axis=2)
    Di = np.linalg.inv(Dm); g = np.zeros((len(tets), 4, 3)); g[:, 1:] = Di; g[:, 0] = -Di.sum(1)
    return verts, tets, g, np.abs(np.linalg.det(Dm)) / 6, perms

class Asm:
    def __init__(s, ndof, lam, mu):
        s.r, s.c, s.v, s.n, s.lam, s.mu = [], [], [], ndof, lam, mu
    def add(s, weight, entries):
        ids = np.array([i for i, _ in entries]); B = np.array([b for _, b in entries])
        lam, mu = s.lam, s.mu
        blk = weight * (lam * B[:, None, :, None] * B[None, :, None, :]
                        + mu * (B @ B.T)[:, :, None, None] * np.eye(3)
                        + mu * B[None, :, :, None] * B[:, None, None, :])
        for i in range(3):
            for j in range(3):
                s.r.append(np.repeat(3 * ids + i, len(ids))); s.c.append(np.tile(3 * ids + j, len(ids)))
                s.v.append(blk[:, :, i, j].reshape(-1))
    def mat(s):
        return sp.csr_matrix((np.concatenate(s.v), (np.concatenate(s.r), np.concatenate(s.c))), shape=(3 * s.n,) * 2)

def fe_stiffness(n_cells, L, lam, mu):
    """The all-tet block of n_cells^3 cells: its mesh and stiffness matrix."""
    h = L / n_cells
    verts, tets, g, Vt, perms = mesh(n_cells, h)
    A = Asm(len(verts), lam, mu)
    for t in range(len(tets)):
        A.add(Vt[t], [(tets[t, a], g[t, a]) for a in range(4)])
    return h, verts, tets, perms, A.mat()

def solve_clamped(K, f, clamped):
    """K u = f with the dofs `clamped` held at 0."""
    u = np.zeros_like(f); u[~clamped] = spsolve(K[~clamped][:, ~clamped].tocsc(), f[~clamped])
    return u

def fe_pressure(n_cells, L, lam, mu, radius, load):
    h, verts, tets, perms, K = fe_stiffness(n_cells, L, lam, mu)
    topv = np.nonzero((verts[:, 2] > L - 1e-9) & (np.linalg.norm(verts[:, :2] - L / 2, axis=1) < radius))[0]
    f = np.zeros(3 * len(verts)); f[3 * topv + 2] = load / len(topv)
    u = solve_clamped(K, f, np.repeat(verts[:, 2] < 1e-9, 3))
    return u[3 * topv + 2].mean()

def fe_only(n_cells, L, lam, mu, load_pts, load):
    h, verts, tets, perms, K = fe_stiffness(n_cells, L, lam, mu)
    f = np.zeros(3 * len(verts))
    hostw = [(hv, w) for _, hv, w in locate(load_pts, n_cells, h, tets, perms)]
    for (hv, w) in hostw:
        for a in range(4):
            f[3 * hv[a] + 2] += w[a] * load / len(load_pts)
    u = solve_clamped(K, f, np.repeat(verts[:, 2] < 1e-9, 3))
    # displacement under the load: interpolated at the load points
    uz = np.mean([sum(w[a] * u[3 * hv[a] + 2] for a in range(4)) for hv, w in hostw])
    return uz

def locate(pts, n_cells, h, tets, perms):
    """Per point: its host Kuhn tet, that tet's vertices and the barycentric weights."""
    out = []
    perm_id = {p: i for i, p in enumerate(perms)}
    for P in pts:
        cube = np.minimum((P // h).astype(int), n_cells - 1); r = P / h - cube
        o = np.argsort(-r, kind="stable"); rs = r[o]
        t = ((cube[0] * n_cells + cube[1]) * n_cells + cube[2]) * 6 + perm_id[tuple(o)]
        out.append((t, tets[t], np.array([1 - rs[0], rs[0] - rs[1], rs[1] - rs[2], rs[2]])))
    return out

def hybrid(mode, n_cells, per_cell, L, lam, mu, zone_from, load_radius, load):
    h = L / n_cells; dx = h / per_cell; R = 2.4 * dx; hk = 0.5 * R
    verts, tets, gN, Vt, perms = mesh(n_cells, h); nt = len(tets)
    m = n_cells * per_cell
    idx = np.array(np.meshgrid(np.arange(m), np.arange(m), np.arange(m), indexing="ij")).reshape(3, -1).T
    P = (idx + 0.5) * dx
    n = len(P)
    # the lattice covers the core too (followers there); the zone's particles are dynamic
    dynamic = P[:, 2] > zone_from * h
    hw = locate(P, n_cells, h, tets, perms)
    host = np.array([t for t, _, _ in hw])
    hv = np.array([a for _, a, _ in hw]); w = np.array([b for _, _, b in hw])
    V = dx**3
    lookup = -np.ones(m**3, int); lookup[(idx[:, 0] * m + idx[:, 1]) * m + idx[:, 2]] = np.arange(n)
    k = int(np.ceil(R / dx))
    offs = [np.array(o) for o in itertools.product(range(-k, k + 1), repeat=3) if 0 < np.linalg.norm(o) * dx < R]
    nbr = [[] for _ in range(n)]
    for o in offs:
        q = idx + o
        ok = np.all((q >= 0) & (q < m), axis=1)
        qi = np.full(n, -1); qi[ok] = lookup[(q[ok, 0] * m + q[ok, 1]) * m + q[ok, 2]]
        for p in np.nonzero(qi >= 0)[0]:
            nbr[p].append(qi[p])
    c = []
    for p in range(n):
        qs = np.array(nbr[p]); d = P[qs] - P[p]; qk = np.linalg.norm(d, axis=1) / hk; t = 1 - 0.5 * qk
        gw = d * (-105.0 / (16 * np.pi * hk**5) * t**3)[:, None] * V
        M = d.T @ gw
        c.append(gw @ np.linalg.inv(M))  # rows: G^T gw
    dyn_index = -np.ones(n, int); dyn_index[dynamic] = np.arange(dynamic.sum())
    nvtx = len(verts); ndof = nvtx + int(dynamic.sum())
    dofp = lambda q: nvtx + dyn_index[q]
    A = Asm(ndof, lam, mu)
    counts = np.bincount(host, minlength=nt)
    tw = 1 - counts * V / Vt if mode == "design7" else np.ones(nt)
    for t in range(nt):
        if tw[t] != 0:
            A.add(tw[t] * Vt[t], [(tets[t, a], gN[t, a]) for a in range(4)])
    for p in range(n):
        ent = {}
        def put(i, b):
            ent[i] = ent.get(i, 0) + b
        if mode == "design7":
            for a in range(4):
                put(hv[p, a], gN[host[p], a])
        csum = c[p].sum(0)
        for q, cq in zip(nbr[p], c[p]):
            if dynamic[q]:
                put(dofp(q), cq)
                for a in range(4):
                    put(hv[q, a], -w[q, a] * cq)
        if dynamic[p]:
            put(dofp(p), -csum)
            for a in range(4):
                put(hv[p, a], w[p, a] * csum)
        if ent:
            A.add(V, list(ent.items()))
    K = A.mat()
    # slaving of the vertices that host only dynamic particles
    hosts_follower = np.zeros(nvtx, bool)
    for p in np.nonzero(~dynamic)[0]:
        hosts_follower[hv[p][w[p] > 0]] = True
    slaved = ~hosts_follower
    free_v = np.nonzero(~slaved)[0]; red = {v: i for i, v in enumerate(free_v)}
    nred = len(free_v) + int(dynamic.sum())
    rows, cols, vals = [], [], []
    def T_add(i, j, s):
        for d in range(3):
            rows.append(3 * i + d); cols.append(3 * j + d); vals.append(s)
    for v in free_v:
        T_add(v, red[v], 1.0)
    dyn = np.nonzero(dynamic)[0]
    for q in dyn:
        T_add(dofp(q), len(free_v) + dyn_index[q], 1.0)
    for v in np.nonzero(slaved)[0]:
        d = P[dyn] - verts[v]; rr = np.linalg.norm(d, axis=1); near = rr < 1.2 * h
        qk = rr[near] / (0.6 * h); t = np.clip(1 - 0.5 * qk, 0, None); ww = t**4 * (2 * qk + 1)
        Bm = np.hstack([np.ones((near.sum(), 1)), d[near]]); Am = (Bm * ww[:, None]).T @ Bm
        s = ww * (Bm @ np.linalg.solve(Am, np.array([1.0, 0, 0, 0])))
        for q, sq in zip(dyn[near], s):
            T_add(v, len(free_v) + dyn_index[q], sq)
    T = sp.csr_matrix((vals, (rows, cols)), shape=(3 * ndof, 3 * nred))
    Kr = (T.T @ K @ T).tocsr()
    f = np.zeros(3 * nred)
    centre = np.array([L / 2, L / 2])
    top = dyn[(P[dyn, 2] > L - dx) & (np.linalg.norm(P[dyn, :2] - centre, axis=1) < load_radius)]
    for q in top:
        f[3 * (len(free_v) + dyn_index[q]) + 2] += load / len(top)
    cl = np.zeros(3 * nred, bool)
    for v in free_v:
        if verts[v, 2] < 1e-9:
            cl[3 * red[v]:3 * red[v] + 3] = True
    u = solve_clamped(Kr, f, cl)
    uz = np.mean([u[3 * (len(free_v) + dyn_index[q]) + 2] for q in top])
    return uz, P[top], int(slaved.sum())

if __name__ == "__main__":
    L, lam, mu = 4.0, 1.0, 0.5
    n_cells, per_cell = 4, int(sys.argv[1]) if len(sys.argv) > 1 else 3
    rad = float(sys.argv[2]) if len(sys.argv) > 2 else 1.0
    for mode in ("design7", "design8"):
        uz, pts, ns = hybrid(mode, n_cells, per_cell, L, lam, mu, 2, rad, -1.0)
        print(f"{mode}: indentation {uz:.4e} ({len(pts)} loaded particles, {ns} slaved vertices)"); sys.stdout.flush()
    print(f"the tets alone (4^3 cells), the load at the particles' points: {fe_only(4, L, lam, mu, pts, -1.0):.4e}")
    for nf in (8, 16, 24, 32):
        print(f"FEM {nf}^3 cells, uniform load on the disk: {fe_pressure(nf, L, lam, mu, rad, -1.0):.4e}"); sys.stdout.flush()
