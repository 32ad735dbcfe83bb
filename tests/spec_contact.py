"""The contact part of the independent result checker, from the spec alone
(numpy only; docs/problem-format.md, "Contact"): the boundary, the gap
pairs (all of them, brute force), the IPC barrier's energy and gradient,
and the checks a contact result must pass."""

from __future__ import annotations

import numpy as np


def boundary(tri: np.ndarray, X: np.ndarray):
    """Boundary segments (m, 2) (P2 edges split at their midside node) and
    each boundary node's length weight, as a dict node -> w."""
    if tri.shape[1] == 6:
        corner = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
        mid = np.concatenate([tri[:, 3], tri[:, 4], tri[:, 5]])
    else:
        corner = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
        mid = None
    key = np.sort(corner, axis=1)
    _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    once = cnt[inv.ravel()] == 1
    if mid is None:
        segs = corner[once]
    else:
        a, b, m = corner[once, 0], corner[once, 1], mid[once]
        segs = np.concatenate([np.stack([a, m], 1), np.stack([m, b], 1)])
    weight: dict[int, float] = {}
    for i, j in segs:
        half = 0.5 * float(np.linalg.norm(X[j] - X[i]))
        weight[int(i)] = weight.get(int(i), 0.0) + half
        weight[int(j)] = weight.get(int(j), 0.0) + half
    return segs, weight


def barrier_ds(s, dhat2):
    """db/ds of b(s) = -(s - dhat2)^2 ln(s / dhat2), 0 beyond dhat2."""
    s = np.asarray(s, float)
    u = s - dhat2
    out = np.zeros_like(s)
    act = s < dhat2
    out[act] = -2 * u[act] * np.log(s[act] / dhat2) - u[act] ** 2 / s[act]
    return out


def _point_segment(p, a, b):
    """Squared distance and its gradient in (p, a, b) (envelope theorem)."""
    e = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, e) / np.einsum("ij,ij->i", e, e), 0.0, 1.0)
    r = p - (a + t[:, None] * e)
    s = np.einsum("ij,ij->i", r, r)
    return s, 2 * r, -2 * r * (1 - t)[:, None], -2 * r * t[:, None]


def contact_gradient(doc, x: np.ndarray) -> tuple[np.ndarray, float]:
    """grad_x E_contact (n_nodes, 2) at pose x and the smallest gap."""
    m = doc["model"]
    c = m["contact"]
    X = np.asarray(m["rest_nodes"], float)
    tri = np.asarray(m["triangles"], int)
    segs, weight = boundary(tri, X)
    nodes = np.array(sorted(weight))
    w = np.array([weight[n] for n in nodes])
    kappa, dh2 = c["stiffness"], c["distance"] ** 2
    g = np.zeros_like(x)
    gaps = [np.inf]
    if c["ground"] is not None:
        a = np.radians(c["ground"]["slope"])
        n = np.array([-np.sin(a), np.cos(a)])
        d = x[nodes] @ n - c["ground"]["height"] * np.cos(a)
        gaps.append(float(d.min()))
        np.add.at(g, nodes, (kappa * w * barrier_ds(d * d, dh2) * 2 * d)[:, None] * n)
    node_of = {int(k): i for i, k in enumerate(nodes)}
    for o in c["obstacles"]:
        V = np.asarray(o["outline"], float)
        E0, E1 = V, np.roll(V, -1, axis=0)
        ow = 0.5 * (np.linalg.norm(E1 - E0, axis=1) + np.roll(np.linalg.norm(E1 - E0, axis=1), 1))
        P, A, B = np.repeat(x[nodes], len(V), 0), np.tile(E0, (len(nodes), 1)), np.tile(E1, (len(nodes), 1))
        s, gp, _, _ = _point_segment(P, A, B)
        gaps.append(float(np.sqrt(s.min())))
        np.add.at(g, np.repeat(nodes, len(V)), (kappa * np.repeat(w, len(V)) * barrier_ds(s, dh2))[:, None] * gp)
        i, j = np.repeat(segs[:, 0], len(V)), np.repeat(segs[:, 1], len(V))
        s, _, ga, gb = _point_segment(np.tile(V, (len(segs), 1)), x[i], x[j])
        gaps.append(float(np.sqrt(s.min())))
        f = (kappa * np.tile(ow, len(segs)) * barrier_ds(s, dh2))[:, None]
        np.add.at(g, i, f * ga)
        np.add.at(g, j, f * gb)
    if c["self"]:
        nbr: dict[int, set] = {}
        for i, j in segs:
            nbr.setdefault(int(i), set()).add(int(j))
            nbr.setdefault(int(j), set()).add(int(i))
        for k in nodes:
            skip = {int(k)} | nbr[int(k)]
            keep = np.array([not ({int(i), int(j)} & skip) for i, j in segs])
            if not keep.any():
                continue
            si, sj = segs[keep, 0], segs[keep, 1]
            s, gp, ga, gb = _point_segment(np.repeat(x[[k]], keep.sum(), 0), x[si], x[sj])
            gaps.append(float(np.sqrt(s.min())))
            f = (kappa * w[node_of[int(k)]] * barrier_ds(s, dh2))[:, None]
            g[k] += (f * gp).sum(axis=0)
            np.add.at(g, si, f * ga)
            np.add.at(g, sj, f * gb)
    return g, float(min(gaps))


def check_contact(doc, x: np.ndarray, g_other: np.ndarray, rel: float = 1e-6) -> None:
    """A contact result: every gap positive; the reported normal forces are
    minus the barrier's gradient; the other terms' gradient equals the
    reported forces node by node (at a converged pose); friction forces in
    their cones."""
    block = doc["contact"]
    g_contact, gap = contact_gradient(doc, x)
    assert gap > 0, f"a gap <= 0 ({gap}) in a result"
    assert block["min_gap"] is None or abs(block["min_gap"] - gap) <= 1e-9 * max(1.0, gap) or \
        block["min_gap"] >= gap - 1e-12, f"min_gap {block['min_gap']} but the smallest gap is {gap}"
    normal = np.zeros_like(x)
    friction = np.zeros_like(x)
    mu = doc["model"]["contact"]["friction"]
    for entry in block["nodes"]:
        normal[entry["node"]] += entry["normal_force"]
        friction[entry["node"]] += entry["friction_force"]
        fn, ft = np.linalg.norm(entry["normal_force"]), np.linalg.norm(entry["friction_force"])
        assert ft <= mu * fn * (1 + 1e-3) + 1e-12 * max(fn, 1e-300), \
            f"node {entry['node']}: friction {ft} outside its cone (mu |f_n| = {mu * fn})"
    scale = max(float(np.abs(normal).max(initial=0.0)), 1e-300)
    assert np.abs(normal + g_contact).max() <= 1e-6 * scale + 1e-12 * np.abs(g_other).max(), \
        "the reported normal forces are not minus the barrier's gradient"
    total = normal + friction
    assert np.allclose(block["total_force"], total.sum(axis=0), rtol=1e-9, atol=1e-12 * scale), "total_force"
    if doc["converged"]:
        ref = max(float(np.abs(total).max(initial=0.0)), float(np.abs(g_other).max()), 1e-300)
        assert np.abs(g_other - total).max() <= rel * ref, \
            "the other terms' gradient does not equal the reported contact forces node by node"
