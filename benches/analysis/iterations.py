"""Why a tube-10k frame takes the iterations it takes (issue #8).

Reads the frames `examples/frame_dump` writes and, per frame, compares the solver's count with
what other methods need on the same energy, all in f64 here:

1. the spectrum of the Jacobi-preconditioned Gauss-Newton Hessian at the solution (its
   condition number sets linear CG's rate, (sqrt(k) - 1) / (sqrt(k) + 1) per iteration);
2. linear PCG on that Hessian from the warm start's residual, with the solver's scalar Jacobi
   preconditioner and with smoothed-aggregation AMG (pyamg);
3. the solver's method (nonlinear CG, Gauss-Newton curvature step, backtracking) on the true
   nonlinear energy, with Polak-Ribiere+ (the rule until session 6) and Hestenes-Stiefel capped
   by Fletcher-Reeves (since), each with the same two preconditioners;
4. Gauss-Newton with exact linear solves (outer iterations);
5. the lowest eigenvalues of the true (not Gauss-Newton) Hessian at the warm start and at the
   solution: negative ones mean compressed springs buckle there.

    cargo run --release --example frame_dump -- 10000 1,59 target/frame_dump
    python3 -m venv target/analysis-venv && target/analysis-venv/bin/pip install numpy scipy pyamg
    target/analysis-venv/bin/python benches/analysis/iterations.py target/frame_dump 1 59

Takes a minute or two per frame. Contacts are left out: use frames without any (the dump says
how many contacts a frame ended with).
"""

import sys

import numpy as np
import pyamg
import scipy.sparse as sp
import scipy.sparse.linalg as sla

DIR = sys.argv[1]
E = np.loadtxt(f"{DIR}/edges.txt")
I, J = E[:, 0].astype(int), E[:, 1].astype(int)
K, L = E[:, 2], E[:, 3]


def force(x, A):
    """Net force (minus the energy's gradient): springs and anchors."""
    e = x[I] - x[J]
    l = np.linalg.norm(e, axis=1)
    fs = (K * (l - L) / l)[:, None] * e
    f = np.zeros_like(x)
    np.add.at(f, I, -fs)
    np.add.at(f, J, fs)
    t, n, kn, kt = A[:, 0:3], A[:, 3:6], A[:, 6], A[:, 7]
    d = x - t
    dn = (d * n).sum(1)
    return f - kn[:, None] * dn[:, None] * n - kt[:, None] * (d - dn[:, None] * n)


def energy(x, A):
    l = np.linalg.norm(x[I] - x[J], axis=1)
    t, n, kn, kt = A[:, 0:3], A[:, 3:6], A[:, 6], A[:, 7]
    d = x - t
    dn = (d * n).sum(1)
    return 0.5 * (K * (l - L) ** 2).sum() + 0.5 * (kn * dn**2 + kt * ((d * d).sum(1) - dn**2)).sum()


def hessian(x, A, true=False):
    """Spring blocks k (u u^T + c (I - u u^T)), c = 1 - L/l: clamped at 0 (Gauss-Newton, as the
    solver's step) unless `true`; plus the anchors' blocks."""
    n = len(x)
    e = x[I] - x[J]
    l = np.linalg.norm(e, axis=1)
    u = e / l[:, None]
    c = 1 - L / l
    if not true:
        c = np.maximum(c, 0)
    uu = u[:, :, None] * u[:, None, :]
    B = K[:, None, None] * (uu * (1 - c)[:, None, None] + c[:, None, None] * np.eye(3)[None])
    nn = A[:, 3:6]
    Pn = nn[:, :, None] * nn[:, None, :]
    Ab = A[:, 6, None, None] * Pn + A[:, 7, None, None] * (np.eye(3)[None] - Pn)
    rows, cols, vals = [], [], []
    for a, b, blk, s in [(I, I, B, 1), (J, J, B, 1), (I, J, B, -1), (J, I, B, -1),
                         (np.arange(n), np.arange(n), Ab, 1)]:
        for p in range(3):
            for q in range(3):
                rows.append(3 * a + p)
                cols.append(3 * b + q)
                vals.append(s * blk[:, p, q])
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(3 * n, 3 * n))


def gn_curvature(x, d, A):
    e = x[I] - x[J]
    l = np.linalg.norm(e, axis=1)
    u = e / l[:, None]
    c = np.maximum(1 - L / l, 0)
    dd = d[I] - d[J]
    ud = (u * dd).sum(1)
    nn, kn, kt = A[:, 3:6], A[:, 6], A[:, 7]
    dn = (d * nn).sum(1)
    return (K * ((1 - c) * ud**2 + c * (dd * dd).sum(1))).sum() + (
        kn * dn**2 + kt * ((d * d).sum(1) - dn**2)).sum()


def linear_pcg(H, b, M, tol, maxit=3000):
    x, r = np.zeros_like(b), b.copy()
    z = M(r)
    d, rz = z.copy(), r @ z
    for it in range(maxit):
        if np.linalg.norm(r) <= tol:
            return it
        Hd = H @ d
        a = rz / (d @ Hd)
        x += a * d
        r -= a * Hd
        z = M(r)
        rz, rz_old = r @ z, rz
        d = z + (rz / rz_old) * d
    return maxit


def nonlinear_cg(x, A, M, tol, rule, maxit=1000):
    """The solver's method in f64: step slope / Gauss-Newton curvature, halved until the energy
    falls; `rule` "pr" (Polak-Ribiere+, the solver's until session 6) or "hsfr"
    (Hestenes-Stiefel capped by Fletcher-Reeves, the solver's since)."""
    r = force(x, A)
    z = M(r)
    d, rz, e0 = z.copy(), (r * z).sum(), energy(x, A)
    for it in range(maxit):
        if np.linalg.norm(r) <= tol:
            return it
        slope = (r * d).sum()
        a = slope / gn_curvature(x, d, A)
        while energy(x + a * d, A) >= e0:
            a *= 0.5
            if a < 1e-30:
                return f"stalled at {it}"
        x = x + a * d
        e0 = energy(x, A)
        r_new = force(x, A)
        z_new = M(r_new)
        rz_new = (r_new * z_new).sum()
        if rule == "pr":
            beta = max((rz_new - (z_new * r).sum()) / rz, 0.0)
        else:
            slope_change = slope - (r_new * d).sum()
            beta = (max(min((rz_new - (z_new * r).sum()) / slope_change, rz_new / rz), 0.0)
                    if slope_change > 0 else 0.0)
        d, r, rz = z_new + beta * d, r_new, rz_new
    return f"budget {maxit}"


def gauss_newton(x, A, tol, maxit=200):
    e0 = energy(x, A)
    for it in range(maxit):
        r = force(x, A)
        if np.linalg.norm(r) <= tol:
            return it
        dx = sla.spsolve(hessian(x, A).tocsc(), r.ravel()).reshape(-1, 3)
        a = 1.0
        while energy(x + a * dx, A) >= e0 and a > 1e-12:
            a *= 0.5
        x = x + a * dx
        e0 = energy(x, A)
    return f"budget {maxit}"


def lowest_true(x, A, w):
    """The lowest eigenvalues of the Jacobi-preconditioned true Hessian (as the largest of
    `2 - H`: the preconditioned spectrum lies under 2) and how many vertices the lowest mode
    spans (participation ratio)."""
    s = np.sqrt(np.repeat(w, 3))
    Hs = (sp.diags(s) @ hessian(x, A, true=True) @ sp.diags(s)).tocsr()
    flipped = sla.LinearOperator(Hs.shape, matvec=lambda v: 2.0 * v - Hs @ v, dtype=float)
    ev, V = sla.eigsh(flipped, k=3, which="LA", tol=1e-8)
    v = V[:, np.argmax(ev)].reshape(-1, 3)
    m2 = (v * v).sum(1)
    return np.sort(2.0 - ev), m2.sum() ** 2 / (m2**2).sum()


def amg(H, n):
    B = np.zeros((3 * n, 3))
    for c in range(3):
        B[c::3, c] = 1
    P = pyamg.smoothed_aggregation_solver(H.tocsr(), B=B, max_coarse=300).aspreconditioner()
    return lambda r: (P @ r.ravel()).reshape(r.shape)


for frame in sys.argv[2:]:
    A = np.loadtxt(f"{DIR}/f{frame}_anchors.txt")
    x0 = np.loadtxt(f"{DIR}/f{frame}_x0.txt")
    x1 = np.loadtxt(f"{DIR}/f{frame}_x1.txt")
    its, _, _, scale, tolerance = np.loadtxt(f"{DIR}/f{frame}_meta.txt")
    n, tol = len(x0), tolerance * scale
    # The solver's preconditioner: 1 / (sum of spring stiffness + max anchor stiffness).
    diag = np.maximum(A[:, 6], A[:, 7])
    np.add.at(diag, I, K)
    np.add.at(diag, J, K)
    w = 1 / diag
    jacobi = lambda r: w[:, None] * r if r.ndim == 2 else np.repeat(w, 3) * r
    r0 = force(x0, A)
    print(f"frame {frame}: solver {int(its)} iterations; |r| = {np.linalg.norm(r0) / tol:.0f} "
          f"tolerances at the warm start, {np.linalg.norm(force(x1, A)) / tol:.2f} at the end")
    H = hessian(x1, A)
    s = np.sqrt(np.repeat(w, 3))
    Hs = sp.diags(s) @ H @ sp.diags(s)
    lmax = sla.eigsh(Hs, k=1, which="LA", return_eigenvectors=False)[0]
    lmin = sla.eigsh(Hs.tocsc(), k=1, sigma=0, which="LM", return_eigenvectors=False)[0]
    kappa = lmax / lmin
    rate = (np.sqrt(kappa) - 1) / (np.sqrt(kappa) + 1)
    print(f"  Jacobi-preconditioned Gauss-Newton Hessian at the solution: condition {kappa:.0f}, "
          f"linear CG rate {rate:.3f} per iteration")
    M_amg = amg(H, n)
    print(f"  linear PCG from the warm start's residual: Jacobi {linear_pcg(H, r0.ravel(), jacobi, tol)}, "
          f"smoothed-aggregation AMG {linear_pcg(H, r0.ravel(), lambda r: M_amg(r), tol)} iterations")
    M0 = amg(hessian(x0, A), n)
    for rule in ["pr", "hsfr"]:
        print(f"  nonlinear CG ({rule}, f64): Jacobi {nonlinear_cg(x0, A, jacobi, tol, rule)}, "
              f"AMG {nonlinear_cg(x0, A, M0, tol, rule)} iterations")
    print(f"  Gauss-Newton with exact solves: {gauss_newton(x0, A, tol)} outer iterations")
    for name, x in [("warm start", x0), ("solution", x1)]:
        ev, part = lowest_true(x, A, w)
        strain = np.linalg.norm(x[I] - x[J], axis=1) / L - 1
        print(f"  true Hessian at the {name}: lowest preconditioned eigenvalues "
              f"{np.array2string(ev, precision=5)}, lowest mode over ~{part:.0f} vertices; "
              f"{(strain < -1e-3).sum()} of {len(L)} springs compressed (min strain {strain.min():.3f})")
