"""An independent checker of result files, written from the spec alone.

It uses numpy only and does not import plush_opt: it rebuilds E(x; c) and
O(x) from the result's ``model`` section with hand-written formulas, and
checks that the reported pose is a certified equilibrium.
"""

from __future__ import annotations

import json

import numpy as np

from spec_contact import check_contact, contact_gradient

REQUIRED = ("format", "problem", "method", "converged", "status", "contractions", "nodes",
            "objective", "residual_norm", "min_hessian_eigenvalue", "timing", "model")


def _elements(model):
    """Rest nodes, element node lists (3 or 6 per row) and Dm of the corners."""
    X = np.asarray(model["rest_nodes"], float)
    tri = np.asarray(model["triangles"], int)
    assert tri.shape[1] == (6 if model.get("element", "P1") == "P2" else 3), "triangle rows"
    Dm = np.stack([X[tri[:, 1]] - X[tri[:, 0]], X[tri[:, 2]] - X[tri[:, 0]]], axis=2)
    return X, tri, Dm


def via_weights(t, n_nodes):
    """Dense (n_via, n_nodes) weights of a tendon's via points: its
    ``points`` (finite attachments) if given, else one node each."""
    points = t.get("points") or [{"nodes": [v], "weights": [1.0]} for v in t["nodes"]]
    W = np.zeros((len(points), n_nodes))
    for k, p in enumerate(points):
        np.add.at(W[k], np.asarray(p["nodes"], int), np.asarray(p["weights"], float))
    return W


def tendon_energy(G, K, eps):
    G = np.asarray(G, float)
    return np.where(G <= -eps, 0.0,
                    np.where(G < eps, K * (G + eps) ** 3 / (6 * eps), K * G**2 + K * eps**2 / 3))


def tendon_tension(G, K, eps):
    G = np.asarray(G, float)
    return np.where(G <= -eps, 0.0, np.where(G < eps, K * (G + eps) ** 2 / (2 * eps), 2 * K * G))


def _p2_shapes(l1, l2, l3):
    """The six P2 shape functions and their l-derivatives (6 x 3) at a point."""
    N = np.array([l1 * (2 * l1 - 1), l2 * (2 * l2 - 1), l3 * (2 * l3 - 1),
                  4 * l1 * l2, 4 * l2 * l3, 4 * l3 * l1])
    dN = np.array([[4 * l1 - 1, 0, 0], [0, 4 * l2 - 1, 0], [0, 0, 4 * l3 - 1],
                   [4 * l2, 4 * l1, 0], [0, 4 * l3, 4 * l2], [4 * l3, 0, 4 * l1]])
    return N, dN


P2_POINTS = [(2 / 3, 1 / 6, 1 / 6), (1 / 6, 2 / 3, 1 / 6), (1 / 6, 1 / 6, 2 / 3)]


def _psi_and_piola(F, mu, lam):
    J = np.linalg.det(F)
    lnJ = np.log(J)
    psi = mu / 2 * (np.einsum("eij,eij->e", F, F) - 2) - mu * lnJ + lam / 2 * lnJ**2
    FinvT = np.linalg.inv(F).transpose(0, 2, 1)
    return psi, mu * (F - FinvT) + lam * lnJ[:, None, None] * FinvT


def _p2_elastic(x, tri, A, Dinv, mu, lam, th):
    """E_plush and its gradient for 6-node triangles, 3-point rule."""
    gl = np.stack([-(Dinv[:, 0] + Dinv[:, 1]), Dinv[:, 0], Dinv[:, 1]], axis=1)   # grad l_j
    E, g = 0.0, np.zeros_like(x)
    for lq in P2_POINTS:
        gradN = np.einsum("ij,ejd->eid", _p2_shapes(*lq)[1], gl)                   # (e, 6, 2)
        F = np.einsum("eia,eib->eab", x[tri], gradN)
        if np.any(np.linalg.det(F) <= 0):
            return np.inf, None
        psi, P = _psi_and_piola(F, mu, lam)
        E += float(np.sum(th * A * psi / 3))
        np.add.at(g, tri, (th * A / 3)[:, None, None] * np.einsum("eab,eib->eia", P, gradN))
    return E, g


def energy_and_gradient(doc, x):
    """E and grad_x E, (n_nodes, 2), from the spec's formulas."""
    m = doc["model"]
    X, tri, Dm = _elements(m)
    mat = m["material"]
    mu, lam, th = mat["mu"], mat["lambda"], mat["thickness"]
    A = np.linalg.det(Dm) / 2
    Dinv = np.linalg.inv(Dm)
    if tri.shape[1] == 6:
        E, g = _p2_elastic(x, tri, A, Dinv, mu, lam, th)
        if g is None:
            return E, None
        return _other_terms(doc, m, X, tri, A, x, E, g)
    ds = np.stack([x[tri[:, 1]] - x[tri[:, 0]], x[tri[:, 2]] - x[tri[:, 0]]], axis=2)
    F = ds @ Dinv
    J = np.linalg.det(F)
    if np.any(J <= 0):
        return np.inf, None
    lnJ = np.log(J)
    psi = mu / 2 * (np.einsum("eij,eij->e", F, F) - 2) - mu * lnJ + lam / 2 * lnJ**2
    E = float(np.sum(th * A * psi))
    FinvT = np.linalg.inv(F).transpose(0, 2, 1)
    P = mu * (F - FinvT) + lam * lnJ[:, None, None] * FinvT      # first Piola-Kirchhoff
    Hm = (th * A)[:, None, None] * P @ Dinv.transpose(0, 2, 1)   # forces on nodes b, c
    g = np.zeros_like(x)
    np.add.at(g, tri[:, 1], Hm[:, :, 0])
    np.add.at(g, tri[:, 2], Hm[:, :, 1])
    np.add.at(g, tri[:, 0], -Hm[:, :, 0] - Hm[:, :, 1])
    return _other_terms(doc, m, X, tri, A, x, E, g)


def _other_terms(doc, m, X, tri, A, x, E, g):
    """Pins, tendons and gravity added to the elastic E and g."""
    mat = m["material"]
    th = mat["thickness"]
    pins = m["pins"]
    kp = pins["stiffness"]
    pn = np.asarray(pins["nodes"], int)
    E += kp / 2 * float(np.sum((x[pn] - X[pn]) ** 2))
    np.add.at(g, pn, kp * (x[pn] - X[pn]))
    K, eps = m["tendons"]["stiffness"], m["tendons"]["smoothing"]
    for t in m["tendons"]["list"]:
        W = via_weights(t, len(x))
        P = W @ x                                  # the (weighted) via points
        seg = P[1:] - P[:-1]
        seglen = np.linalg.norm(seg, axis=1)
        rest = t["assembly_length"] - doc["contractions"][t["winch"]]
        if t.get("friction", 0.0) > 0 and "segment_rest_lengths" in t:
            # friction at via points: segment j is phi_j U(G_j / phi_j),
            # phi_j = r_j / (a - c), G_j = |seg_j| - r_j, with the r_j held
            # (a frictionless tendon is one spring: its segments' rest
            # lengths follow its length, so only their sum is fixed)
            phi = np.asarray(t["segment_rest_lengths"], float) / rest
            z = (seglen - phi * rest) / phi
            E += float(np.sum(phi * tendon_energy(z, K, eps)))
            T = tendon_tension(z, K, eps)
        else:
            G = seglen.sum() - rest
            E += float(tendon_energy(G, K, eps))
            T = tendon_tension(G, K, eps)
        unit = seg / seglen[:, None] * np.reshape(T, (-1, 1))
        gP = np.zeros_like(P)
        gP[1:] += unit
        gP[:-1] -= unit
        g += W.T @ gP
    if m["gravity"] is not None:
        gv = np.asarray(m["gravity"], float)
        w = mat["density"] * th * A / 3
        carry = tri[:, 3:] if tri.shape[1] == 6 else tri      # P2: the midside nodes carry it all
        E -= float(np.sum(w[:, None] * x[carry].sum(axis=1) @ gv))
        np.add.at(g, carry.ravel(), -np.repeat(w, 3)[:, None] * gv[None, :])
    return E, g


def objective(doc, x):
    m = doc["model"]
    tri = np.asarray(m["triangles"], int)
    O = 0.0
    for t in m["targets"]:
        b = np.asarray(t["barycentric"], float)
        weights = _p2_shapes(*b)[0] if tri.shape[1] == 6 else b
        y = weights @ x[tri[t["triangle"]]]
        O += 0.5 * t["weight"] * float(np.sum((y - np.asarray(t["to"], float)) ** 2))
    return O


def check_result(doc_or_path, rel_residual=1e-6, hessian_step=1e-5):
    """Raise AssertionError with a reason if the result breaks the spec."""
    doc = doc_or_path
    if not isinstance(doc, dict):
        with open(doc_or_path) as fh:
            doc = json.load(fh)
    for key in REQUIRED:
        assert key in doc, f"missing key {key!r}"
    assert doc["format"] == "plush-opt-result/1", doc["format"]
    assert doc["method"] in ("forward", "reparam", "bilevel"), doc["method"]
    for key in ("total_s", "solve_s", "iterations"):
        assert key in doc["timing"], f"timing.{key} missing"
    m = doc["model"]
    X, tri, Dm = _elements(m)
    assert np.all(np.linalg.det(Dm) > 0), "triangles are not counter-clockwise in rest_nodes"
    x = np.asarray(doc["nodes"], float)
    assert x.shape == X.shape, "nodes and rest_nodes differ in shape"
    for t in m["tendons"]["list"]:
        W = via_weights(t, len(X))
        a = np.linalg.norm(np.diff(W @ X, axis=0), axis=1).sum() + t.get("assembly_offset", 0.0)
        if "points" in t:
            assert len(t["points"]) == len(t["nodes"]), f"points of {t['name']}"
            assert np.allclose(W.sum(axis=1), 1, rtol=0, atol=1e-12), f"weights of {t['name']}"
        assert abs(a - t["assembly_length"]) <= 1e-9 * max(a, 1), f"assembly_length of {t['name']}"
        assert t["winch"] in doc["contractions"], f"tendon {t['name']}: unknown winch"
        if "segment_rest_lengths" in t:
            _check_segments(doc, t, x, len(t["nodes"]) - 1)
    for w in m["winches"]:
        lo, hi = w["bounds"]
        c = doc["contractions"][w["name"]]
        assert lo <= c <= hi, f"winch {w['name']}: contraction {c} outside [{lo}, {hi}]"
    for t in m["targets"]:
        b = np.asarray(t["barycentric"], float)
        assert abs(b.sum() - 1) < 1e-9 and np.all(b >= -1e-9), "barycentric weights"

    E, g = energy_and_gradient(doc, x)
    assert np.isfinite(E), "pose not admissible (some J <= 0)"
    contact = m.get("contact")
    if contact is not None:
        check_contact(doc, x, g)
        friction = np.zeros_like(x)
        for entry in doc["contact"]["nodes"]:
            friction[entry["node"]] += entry["friction_force"]
        g = g + contact_gradient(doc, x)[0] - friction
    rnorm = float(np.linalg.norm(g))
    assert abs(rnorm - doc["residual_norm"]) <= 1e-6 * max(1.0, np.abs(g).max() * 10) + 1e-9, \
        f"residual_norm {doc['residual_norm']} but the spec's gradient has norm {rnorm}"
    O = 0.0 if doc["method"] == "forward" else objective(doc, x)   # spec: 0 for forward
    assert abs(O - doc["objective"]) <= 1e-9 * max(1.0, abs(O)), f"objective {doc['objective']} != {O}"

    if doc["converged"] and contact is not None and contact["friction"] > 0:
        return doc      # the friction's lag is the solver's history: balance and cones checked above
    if doc["converged"]:
        # residual small against the forces in balance
        scale = max(np.linalg.norm(_internal_force_scale(doc, x)), 1e-300)
        assert rnorm <= rel_residual * scale, f"residual {rnorm} not small against force scale {scale}"
        # Hessian by central differences of the gradient: positive definite
        n = x.size
        H = np.empty((n, n))
        flat = x.reshape(-1)
        size = np.ptp(X, axis=0).max()
        h = hessian_step * size
        for i in range(n):
            xp = flat.copy()
            xp[i] += h
            xm = flat.copy()
            xm[i] -= h
            H[:, i] = (_full_gradient(doc, xp.reshape(-1, 2)).reshape(-1)
                       - _full_gradient(doc, xm.reshape(-1, 2)).reshape(-1)) / (2 * h)
        H = (H + H.T) / 2
        free = doc.get("contact", {}).get("free_motions", [])
        if free:
            # positive definite on the motions the contact does not leave free
            Q = _complement(_rigid(x, free))
            lam_min = float(np.linalg.eigvalsh(Q.T @ H @ Q)[0])
            assert lam_min > 0, f"Hessian not positive definite off the free motions ({lam_min})"
            return doc
        lam_min = float(np.linalg.eigvalsh(H)[0])
        assert lam_min > 0, f"Hessian not positive definite (smallest eigenvalue {lam_min})"
        reported = doc["min_hessian_eigenvalue"]
        assert reported is not None and abs(reported - lam_min) <= 1e-3 * abs(lam_min) + 1e-6 * np.abs(H).max(), \
            f"min_hessian_eigenvalue {reported} but finite differences give {lam_min}"
    return doc


def _full_gradient(doc, x):
    """grad_x E with contact (without friction, which carries history)."""
    g = energy_and_gradient(doc, x)[1]
    if doc["model"].get("contact") is not None:
        g = g + contact_gradient(doc, x)[0]
    return g


def _rigid(x, names):
    """(n_dofs, k) the named rigid motions of pose x (flat, interleaved)."""
    cols = []
    for name in names:
        v = np.zeros_like(x)
        if name == "translation in x":
            v[:, 0] = 1
        elif name == "translation in y":
            v[:, 1] = 1
        elif name.startswith("translation along ("):
            v[:] = [float(t) for t in name[len("translation along ("):-1].split(",")]
        else:                       # a rotation about the centroid
            d = x - x.mean(axis=0)
            v[:, 0], v[:, 1] = -d[:, 1], d[:, 0]
        cols.append(v.reshape(-1))
    return np.stack(cols, axis=1)


def _complement(V):
    """An orthonormal basis of the complement of V's columns."""
    q, _ = np.linalg.qr(np.hstack([V, np.eye(V.shape[0])]))
    return q[:, V.shape[1]:]


def _check_segments(doc, t, x, n_segments):
    """Segment rest lengths sum to a - c and the recorded tensions are
    U'(G_j / phi_j) of them at the nodes."""
    r = np.asarray(t["segment_rest_lengths"], float)
    T = np.asarray(t["segment_tensions"], float)
    assert r.shape == T.shape == (n_segments,), f"tendon {t['name']}: one rest length and tension per segment"
    rest = t["assembly_length"] - doc["contractions"][t["winch"]]
    assert np.all(r > 0) and abs(r.sum() - rest) <= 1e-8 * rest, \
        f"tendon {t['name']}: segment rest lengths sum to {r.sum()}, not a - c = {rest}"
    seglen = np.linalg.norm(np.diff(via_weights(t, len(x)) @ x, axis=0), axis=1)
    K, eps = doc["model"]["tendons"]["stiffness"], doc["model"]["tendons"]["smoothing"]
    phi = r / rest
    want = tendon_tension((seglen - r) / phi, K, eps)
    assert np.allclose(T, want, rtol=1e-6, atol=1e-9 * max(1.0, np.abs(want).max())), \
        f"tendon {t['name']}: segment_tensions {T} but the rest lengths give {want}"


def _internal_force_scale(doc, x):
    """Pin forces and contact forces: at equilibrium they balance everything else."""
    m = doc["model"]
    X = np.asarray(m["rest_nodes"], float)
    pn = np.asarray(m["pins"]["nodes"], int)
    forces = m["pins"]["stiffness"] * (x[pn] - X[pn])
    if m.get("contact") is not None:
        forces = np.concatenate([forces.reshape(-1, 2)] + [np.reshape(e["normal_force"], (1, 2))
                                                          for e in doc["contact"]["nodes"]])
    return forces
