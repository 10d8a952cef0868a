"""Static affine patch test of coupling design 7 (docs/hybrid_coupling.md):
E = sum_t (1-phi_t) V_t Psi(F_t) + sum_{p in S} V_p Psi(Fbar_p + D_p(delta)),
Fbar_p = F of p's host tet, delta_q = x_q - sum_a w_qa x_a (0 on followers),
D_p(delta) = sum_q (delta_q - delta_p) (x) c_pq, c_pq = G_p^T V_q gradW(X_q - X_p).
Under an affine state every F = A, so the residual at dof a is P g_a with g_a a
geometric vector; this script computes g at every vertex and dynamic particle
(`run`), then the linearised stiffness of design 7 and of design 8 (the Bregman
form, `bregman=True`) with and without the covered vertices slaved (`stiffness_check`).
Needs numpy only; `python3 docs/coupling_design7_check.py` takes about three minutes."""
import itertools, sys
import numpy as np

def kuhn_block(n_cells, per_cell, h=1.0):
    """A cube of n_cells^3 cells of edge h, each split into 6 Kuhn tets, and a lattice at
    spacing h/per_cell over it: vertices, tets, shape-function gradients, tet volumes, the
    lattice's indices and positions, each point's host tet, barycentric weights and host
    vertices, and the permutation of axes naming each Kuhn tet."""
    dx = h / per_cell
    nv = n_cells + 1
    vid = lambda i, j, k: (i * nv + j) * nv + k
    verts = np.array([[i, j, k] for i in range(nv) for j in range(nv) for k in range(nv)], float) * h
    # Kuhn tets: for permutation (a,b,c) of axes, [0, e_a, e_a+e_b, 1]
    perms = list(itertools.permutations(range(3)))
    e = np.eye(3, dtype=int)
    tets = []
    for ci in range(n_cells):
        for cj in range(n_cells):
            for ck in range(n_cells):
                base = np.array([ci, cj, ck])
                for (a, b, c) in perms:
                    corners = [base, base + e[a], base + e[a] + e[b], base + 1]
                    tets.append([vid(*v) for v in corners])
    tets = np.array(tets)
    nt = len(tets)
    X = verts[tets]  # nt x 4 x 3
    Dm = np.stack([X[:, 1] - X[:, 0], X[:, 2] - X[:, 0], X[:, 3] - X[:, 0]], axis=2)  # columns
    Dinv = np.linalg.inv(Dm)
    gradN = np.zeros((nt, 4, 3))
    gradN[:, 1:, :] = Dinv  # rows of Dm^-1 are grad N_1..3
    gradN[:, 0, :] = -Dinv.sum(axis=1)
    Vt = np.abs(np.linalg.det(Dm)) / 6.0
    # lattice over the whole block
    m = n_cells * per_cell
    idx = np.array(np.meshgrid(np.arange(m), np.arange(m), np.arange(m), indexing="ij")).reshape(3, -1).T
    P = (idx + 0.5) * dx
    cube = np.minimum((P // h).astype(int), n_cells - 1)
    r = P / h - cube
    order = np.argsort(-r, axis=1, kind="stable")  # a: largest, b, c
    perm_id = {p: i for i, p in enumerate(perms)}
    pid = np.array([perm_id[tuple(o)] for o in order])
    host = ((cube[:, 0] * n_cells + cube[:, 1]) * n_cells + cube[:, 2]) * 6 + pid
    rs = np.take_along_axis(r, order, axis=1)
    w = np.stack([1 - rs[:, 0], rs[:, 0] - rs[:, 1], rs[:, 1] - rs[:, 2], rs[:, 2]], axis=1)
    hv = tets[host]  # host vertices
    return verts, tets, gradN, Vt, m, idx, P, host, w, hv, perms


def block_setup(n_cells, per_cell, zone_from, h=1.0):
    """The Kuhn block at lattice spacing dx = h/per_cell, its kernel support R = 2.4 dx and
    smoothing length R/2, and which particles are dynamic (above z = zone_from h)."""
    dx = h / per_cell
    R = 2.4 * dx
    block = kuhn_block(n_cells, per_cell, h)
    P = block[6]
    return h, dx, R, 0.5 * R, block, P[:, 2] > zone_from * h


def run(n_cells, per_cell, ghosts, zone_from, uniform=False):
    h, dx, R, hk, block, dynamic = block_setup(n_cells, per_cell, zone_from)
    verts, tets, gradN, Vt, m, idx, P, host, w, hv, perms = block
    nt = len(tets)
    part = np.ones(len(P), bool) if ghosts else dynamic.copy()
    # volumes per tet
    counts = np.bincount(host[part], minlength=nt)
    Vp = np.where(part, Vt[host] / np.maximum(counts[host], 1), 0.0)
    if uniform:
        Vp = np.where(part, dx**3, 0.0)
    phi = np.bincount(host[part], weights=Vp[part], minlength=nt) / Vt
    # neighbour offsets
    k = int(np.ceil(R / dx))
    offs = [np.array(o) for o in itertools.product(range(-k, k + 1), repeat=3)
            if 0 < np.linalg.norm(o) * dx < R]
    lin = lambda ijk: (ijk[:, 0] * m + ijk[:, 1]) * m + ijk[:, 2]
    pairs_p, pairs_q = [], []
    for o in offs:
        q = idx + o
        ok = np.all((q >= 0) & (q < m), axis=1)
        pi = np.nonzero(ok)[0]
        qi = lin(q[ok])
        keep = part[pi] & part[qi]
        pairs_p.append(pi[keep]); pairs_q.append(qi[keep])
    pp = np.concatenate(pairs_p); qq = np.concatenate(pairs_q)
    d = P[qq] - P[pp]
    rr = np.linalg.norm(d, axis=1)
    qk = rr / hk
    t = 1 - 0.5 * qk
    gw = d * (-105.0 / (16 * np.pi * hk**5) * t**3)[:, None]
    wv = gw * Vp[qq][:, None]
    M = np.zeros((len(P), 3, 3))
    np.add.at(M, pp, d[:, :, None] * wv[:, None, :])
    G = np.zeros_like(M)
    G[part] = np.linalg.inv(M[part])
    c = np.einsum("nji,nj->ni", G[pp], wv)  # G^T wv
    gv = np.zeros((len(verts), 3)); gp = np.zeros((len(P), 3))
    # FE part: sum_t V_t gradN (tets or the quadrature of their particles)
    np.add.at(gv, tets.reshape(-1), (Vt[:, None, None] * gradN).reshape(-1, 3))
    term = Vp[pp][:, None] * c
    dq = dynamic[qq]; dp = dynamic[pp]
    np.add.at(gp, qq[dq], term[dq])
    for a in range(4):
        np.add.at(gv, hv[qq[dq], a], -w[qq[dq], a][:, None] * term[dq])
    np.add.at(gp, pp[dp], -term[dp])
    for a in range(4):
        np.add.at(gv, hv[pp[dp], a], w[pp[dp], a][:, None] * term[dp])
    # sets
    L = n_cells * h
    onb = np.any((verts < 1e-9) | (verts > L - 1e-9), axis=1)
    scale = np.linalg.norm(gv[onb], axis=1).max()
    dist_surface_v = np.minimum(verts, L - verts).min(axis=1)
    dist_surface_p = np.minimum(P, L - P).min(axis=1)
    inter = (~onb) & (np.abs(verts[:, 2] - zone_from * h) < 1e-9)
    deep_v = (~onb) & (dist_surface_v >= 2 * h - 1e-9)
    nrm = lambda a: np.linalg.norm(a, axis=1).max() / scale if len(a) else float("nan")
    total = gv.sum(axis=0) + gp.sum(axis=0)
    res = dict(
        interface_all=nrm(gv[inter]), n_interface=int(inter.sum()),
        interface_deep=nrm(gv[inter & deep_v]), n_interface_deep=int((inter & deep_v).sum()),
        interior_vertices=nrm(gv[~onb]),
        deep_vertices=nrm(gv[deep_v]),
        particles_2R=nrm(gp[dynamic & (dist_surface_p > 2 * R)]),
        n_particles_2R=int((dynamic & (dist_surface_p > 2 * R)).sum()),
        particles_all=nrm(gp[dynamic]),
        phi_min=float(phi[counts>0].min()), phi_max=float(phi.max()), empty=int((counts==0).sum()),
        translation=np.linalg.norm(total) / scale,
    )
    return res

def stiffness_check(n_cells=4, per_cell=3, zone_from=2, lam=1.0, mu=0.5, bregman=False):
    """Linearised stiffness of design 7 (uniform volumes, lattice continued into the core):
    eigenvalues of K over all vertices and dynamic particles, and of T^T K T where every
    vertex that hosts only dynamic particles is slaved to them (x_v = sum_p s_vp x_p, an
    affine-reproducing linear fit)."""
    h, dx, R, hk, block, dynamic = block_setup(n_cells, per_cell, zone_from)
    verts, tets, gradN, Vt, m, idx, P, host, w, hv, perms = block
    nt = len(tets)
    n = len(P)
    V = dx**3
    counts = np.bincount(host, minlength=nt)
    phi = counts * V / Vt
    k = int(np.ceil(R / dx))
    offs = [np.array(o) for o in itertools.product(range(-k, k + 1), repeat=3) if 0 < np.linalg.norm(o) * dx < R]
    nbr = [[] for _ in range(n)]
    lin = lambda ijk: (ijk[0] * m + ijk[1]) * m + ijk[2]
    for p in range(n):
        for o in offs:
            q = idx[p] + o
            if np.all((q >= 0) & (q < m)):
                nbr[p].append(lin(q))
    c = {}
    for p in range(n):
        M = np.zeros((3, 3)); gws = []
        for q in nbr[p]:
            d = P[q] - P[p]; qk = np.linalg.norm(d) / hk; t = 1 - 0.5 * qk
            gw = d * (-105.0 / (16 * np.pi * hk**5) * t**3) * V
            M += np.outer(d, gw); gws.append(gw)
        G = np.linalg.inv(M)
        c[p] = [G.T @ gw for gw in gws]
    dyn_index = -np.ones(n, int); dyn_index[dynamic] = np.arange(dynamic.sum())
    nvtx = len(verts); ndof = nvtx + int(dynamic.sum())
    dof_p = lambda q: nvtx + dyn_index[q]
    K = np.zeros((3 * ndof, 3 * ndof))

    def add(weight, entries):
        for (i, bi) in entries:
            for (j, bj) in entries:
                blk = weight * (lam * np.outer(bi, bj) + mu * np.dot(bi, bj) * np.eye(3) + mu * np.outer(bj, bi))
                K[3 * i:3 * i + 3, 3 * j:3 * j + 3] += blk

    for t in range(nt):
        weight = 1.0 if bregman else 1 - phi[t]
        if abs(weight) > 0:
            add(weight * Vt[t], [(tets[t, a], gradN[t, a]) for a in range(4)])
    for p in range(n):
        ent = {}
        def put(i, b):
            ent[i] = ent.get(i, 0) + b
        if not bregman:
            for a in range(4):
                put(hv[p, a], gradN[host[p], a])
        csum = np.zeros(3)
        for q, cq in zip(nbr[p], c[p]):
            csum += cq
            if dynamic[q]:
                put(dof_p(q), cq)
                for a in range(4):
                    put(hv[q, a], -w[q, a] * cq)
        if dynamic[p]:
            put(dof_p(p), -csum)
            for a in range(4):
                put(hv[p, a], w[p, a] * csum)
        add(V, list(ent.items()))
    ev_full = np.linalg.eigvalsh(K)
    # vertices hosting only dynamic particles
    hosts_follower = np.zeros(nvtx, bool)
    for p in np.nonzero(~dynamic)[0]:
        hosts_follower[hv[p][w[p] > 0]] = True
    slaved = ~hosts_follower
    free_v = np.nonzero(~slaved)[0]
    red = {v: i for i, v in enumerate(free_v)}
    nred = len(free_v) + int(dynamic.sum())
    T = np.zeros((3 * ndof, 3 * nred))
    for v in free_v:
        T[3 * v:3 * v + 3, 3 * red[v]:3 * red[v] + 3] = np.eye(3)
    for q in np.nonzero(dynamic)[0]:
        i, j = dof_p(q), len(free_v) + dyn_index[q]
        T[3 * i:3 * i + 3, 3 * j:3 * j + 3] = np.eye(3)
    dyn = np.nonzero(dynamic)[0]
    for v in np.nonzero(slaved)[0]:
        d = P[dyn] - verts[v]; rr = np.linalg.norm(d, axis=1)
        near = rr < 1.2 * h
        qk = rr[near] / (0.6 * h); t = np.clip(1 - 0.5 * qk, 0, None)
        ww = t**4 * (2 * qk + 1)
        Bm = np.hstack([np.ones((near.sum(), 1)), d[near]])
        A = (Bm * ww[:, None]).T @ Bm
        s = ww * (Bm @ np.linalg.solve(A, np.array([1.0, 0, 0, 0])))
        for q, sq in zip(dyn[near], s):
            j = len(free_v) + dyn_index[q]
            T[3 * v:3 * v + 3, 3 * j:3 * j + 3] += sq * np.eye(3)
    ev_red = np.linalg.eigvalsh(T.T @ K @ T)
    for name, ev in (("all vertices free", ev_full), ("covered vertices slaved", ev_red)):
        top = ev.max()
        print(f"{name}: {len(ev)} dofs, most negative {ev.min() / top:.2e} of the largest, "
              f"{int((ev < -1e-9 * top).sum())} negative, {int((np.abs(ev) <= 1e-9 * top).sum())} zero")
    # energies of u = (z^2, 0, 0): the exact continuum value, and the design's with every
    # dof at the exact field (slaved vertices at their fit)
    L = n_cells * h
    exact = 2 * mu * L * L * L**3 / 3
    ured = np.zeros(3 * nred)
    for v in free_v:
        ured[3 * red[v]] = verts[v, 2] ** 2
    for q in dyn:
        ured[3 * (len(free_v) + dyn_index[q])] = P[q, 2] ** 2
    u = T @ ured
    e_design = 0.5 * u @ K @ u
    ufe = np.zeros(3 * ndof)
    ufe[0:3 * nvtx:3] = verts[:, 2] ** 2
    Kfe = np.zeros((3 * nvtx, 3 * nvtx))
    for t in range(nt):
        for a in range(4):
            for b in range(4):
                ba, bb = gradN[t, a], gradN[t, b]
                Kfe[3 * tets[t, a]:3 * tets[t, a] + 3, 3 * tets[t, b]:3 * tets[t, b] + 3] += Vt[t] * (
                    lam * np.outer(ba, bb) + mu * np.dot(ba, bb) * np.eye(3) + mu * np.outer(bb, ba))
    e_fe = 0.5 * ufe[:3 * nvtx] @ Kfe @ ufe[:3 * nvtx]
    print(f"u = (z^2, 0, 0): energy / exact: design {e_design / exact:.4f}, the tets alone {e_fe / exact:.4f}")
    # static shear under a body force along x, bottom face clamped: the top's mean u_x
    # against the tets alone (zone mass on the dynamic particles, core mass lumped)
    rho_g = 1.0
    f = np.zeros(3 * ndof)
    core = np.array([np.all(verts[tt, 2] <= zone_from * h + 1e-9) for tt in tets])
    for t in np.nonzero(core)[0]:
        for a in range(4):
            f[3 * tets[t, a]] += rho_g * Vt[t] / 4
    fz = np.zeros(3 * nvtx)
    for t in range(nt):
        for a in range(4):
            fz[3 * tets[t, a]] += rho_g * Vt[t] / 4
    for q in dyn:
        f[3 * dof_p(q)] += rho_g * V
    fr = T.T @ f
    clamp = np.zeros(3 * nred, bool)
    for v in free_v:
        if verts[v, 2] < 1e-9:
            clamp[3 * red[v]:3 * red[v] + 3] = True
    Kr = T.T @ K @ T
    ur = np.zeros(3 * nred)
    ur[~clamp] = np.linalg.solve(Kr[np.ix_(~clamp, ~clamp)], fr[~clamp])
    top_p = dyn[P[dyn, 2] > L - dx]
    ux_design = np.mean([ur[3 * (len(free_v) + dyn_index[q])] for q in top_p])
    cl = np.zeros(3 * nvtx, bool)
    for v in range(nvtx):
        if verts[v, 2] < 1e-9:
            cl[3 * v:3 * v + 3] = True
    ufe = np.zeros(3 * nvtx)
    ufe[~cl] = np.linalg.solve(Kfe[np.ix_(~cl, ~cl)], fz[~cl])
    top_v = np.nonzero(verts[:, 2] > L - 1e-9)[0]
    ux_fe = np.mean(ufe[3 * top_v])
    print(f"shear under gravity along x: mean top u_x, design {ux_design:.4e}, tets alone {ux_fe:.4e} (ratio {ux_design / ux_fe:.3f})")
    print(f"tet weights 1 - phi: {1 - phi.max():.2f} .. {1 - phi.min():.2f}; slaved vertices {int(slaved.sum())}")


if __name__ == "__main__":
    for n_cells, per_cell, zone in [(6, 4, 3), (6, 5, 3), (6, 8, 3), (6, 5, 2.5)]:
        for ghosts, uniform in ((False, False), (False, True), (True, False), (True, True)):
            r = run(n_cells, per_cell, ghosts, zone, uniform)
            print(f"cells {n_cells} dx=h/{per_cell} zone z>{zone} ghosts={ghosts} uniformV={uniform}: " +
                  ", ".join(f"{k} {v:.2e}" if isinstance(v, float) else f"{k} {v}" for k, v in r.items()))
            sys.stdout.flush()
    for bregman in (False, True):
        print(f"design {8 if bregman else 7}:")
        stiffness_check(bregman=bregman)

