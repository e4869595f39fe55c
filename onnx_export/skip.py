"""The polynomial skip of forward_fast.onnx, c + L phi(Xn) [4, N], factored so that a few
GEMMs do the bulk of it: the skips are most of the rendering graph's cost.

Full skips (every monomial of degree 1..p, p >= 2): `skip_poly` writes each monomial as
mu * rho (a multiplier of degree q and the rest) and evaluates sum_mu mu (C_mu rho-vector);
`_skip_plan` picks the grouping of the multipliers that a small cost model ranks cheapest.
Explicit sparse monomials (trainer --skip-basis sparse): `sparse_skip` factors each into a
multiplier in (w, mu) and a base monomial in (r, u_r, u_t), built degree by degree from prefix
slices. Both give the same values as the plain monomial sum, to float32 rounding.
"""

from __future__ import annotations

import itertools

import numpy as np

from neurolens_addon.neural.modelfile import monomial_terms

from .builder import Graph

# The cost model that ranks skip plans, ns per ray: per multiply-add of a MatMul, per row of N
# written, and the fixed work per multiplier group and per piece. Fitted to onnxruntime on the
# development machine (docs/learned-graphs.md); it only has to rank the plans.
_NS_FMA, _NS_ROW, _NS_GROUP, _NS_PIECE = 0.022, 0.12, 1.5, 1.0


def _skip_split(t: tuple, q: int):
    """Monomial t (sorted variable indices) = mu * rho: mu its first q indices (() = 1 when t
    has fewer), rho the rest (all indices >= mu's last)."""
    return (t[:q], t[q:]) if len(t) >= q else ((), t)


def _skip_cost(d: int, p: int, q: int, cuts: tuple) -> tuple[float, list, list]:
    """Groups, pieces and an estimated cost in ns per ray of the factored skip with multiplier
    groups cut at variable indices `cuts` (see skip_poly), from the cost model below."""
    bounds = (0,) + cuts + (d,)
    band = lambda i: max(k for k in range(len(bounds) - 1) if bounds[k] <= i)
    terms = monomial_terms(d, p)
    mus = sorted({_skip_split(t, q)[0] for t in terms} | {()}, key=lambda m: (len(m), m))
    rhos = sorted({_skip_split(t, q)[1] for t in terms} | {()}, key=lambda r: (len(r), r))
    groups = [[m for m in mus if (band(m[-1]) if m else 0) == k] for k in range(len(bounds) - 1)]
    pieces = [[r for r in rhos if r and band(r[0]) == k] for k in range(len(bounds) - 1)]
    pieces[-1].append(())
    fma = writes = fixed = 0.0
    for k, grp in enumerate(groups):
        if not grp:
            continue
        rows = 4 * len(grp)
        used = [len(pc) for pc in pieces[k:] if pc]
        fma += rows * sum(used)
        writes += rows * (2 * len(used) - 1) + (2 * rows if len(grp) > 1 else 0)
        fixed += _NS_GROUP
    for pc in pieces:
        writes += 3 * len(pc)
        fixed += _NS_PIECE if pc else 0.0
    return _NS_FMA * fma + _NS_ROW * writes + fixed, groups, pieces


def _skip_plan(d: int, p: int):
    """(q, groups, pieces) of the cheapest factorisation (see skip_poly)."""
    q = 1 if p <= 3 else 2
    best = None
    for n in range(d):
        for cuts in itertools.combinations(range(1, d), n):
            cost, groups, pieces = _skip_cost(d, p, q, cuts)
            if best is None or cost < best[0] - 1e-9:
                best = (cost, groups, pieces)
    return q, best[1], best[2]


def skip_poly(g: Graph, f: dict, Xn: str, ones: str, d: int) -> str:
    """c + L phi(Xn) [4, N] for skip degree p >= 2, factored so that one MatMul does the bulk:
    every monomial t = mu * rho (_skip_split: mu of degree q = 1 (p <= 3) or 2, or mu = 1),
    so  sum_t L_t t = sum_mu mu * (C_mu rho-vector), with C_mu [4, #rho] gathered from L.
    Multipliers mu are grouped by their last variable index; group k needs only rho over
    variables >= its smallest such index, so the rho monomials are cut into pieces by their
    smallest index and group k multiplies pieces k, k+1, ... (a Gemm chain accumulating G_k
    [4 |group|, N], rows j |group| + m); then sum_m mu_m G_k[j, m] is one broadcast Mul and a
    [1, |group|] MatMul of ones. The cuts minimise _skip_cost (d = 5, p = 4: groups of 4 and 12
    multipliers, [16, 21] and [48, 10] MatMuls, 816 FMA a ray instead of 4 x 126 monomials
    through an M = 4 Gemm; p = 5: three groups). Monomials come from the rows of Xe = [Xn; 1]: P2 =
    all products of two Xe rows (1, x_i, x_i x_j), and a piece holding rho of degree k >= 3 as
    S[rho[:-1]] * Xe[rho[-1]] (Gather, Gather, Mul) with S = all monomials of degree < k."""
    p, L = f["p"], f["L"]
    q, groups, pieces = _skip_plan(d, p)
    pos = {t: i for i, t in enumerate(monomial_terms(d, p))}
    one = d
    Xe = g.concat([Xn, ones], 0)                                              # [d + 1, N]
    pad = lambda t, n: tuple(t) + (one,) * (n - len(t))
    maxdeg = max(len(r) for pc in pieces for r in pc)
    P2 = P2_rows = None
    if q == 2 or maxdeg >= 2:
        P2_terms = ([()] + [(i,) for i in range(d)]
                    + [t for t in monomial_terms(d, 2) if len(t) == 2])
        P2 = g.mul(g.gather(Xe, [pad(t, 2)[0] for t in P2_terms]),
                   g.gather(Xe, [pad(t, 2)[1] for t in P2_terms]))
        P2_rows = {t: i for i, t in enumerate(P2_terms)}
    below = {3: (P2, P2_rows)}           # k -> (tensor of every monomial of degree < k, rows)

    def source(k):
        if k not in below:
            prev, rows = source(k - 1)
            new = [t for t in monomial_terms(d, k - 1) if len(t) == k - 1]
            both = g.concat([prev, rows_of(new)], 0)
            below[k] = (both, {**rows, **{t: len(rows) + i for i, t in enumerate(new)}})
        return below[k]

    def rows_of(terms):
        """A tensor whose rows are the monomials `terms` (0 ops when it is Xe or P2 itself)."""
        if all(len(t) <= 1 for t in terms):
            idx = [t[0] if t else one for t in terms]
            return Xe if idx == list(range(d + 1)) else g.gather(Xe, idx)
        if all(len(t) <= 2 for t in terms):
            idx = [P2_rows[t] for t in terms]
            return P2 if idx == list(range(len(P2_rows))) else g.gather(P2, idx)
        S, S_rows = source(max(len(t) for t in terms))
        return g.mul(g.gather(S, [S_rows[t[:-1]] for t in terms]),
                     g.gather(Xe, [t[-1] if t else one for t in terms]))

    piece_t = [rows_of(pc) if pc else None for pc in pieces]
    poly = None
    for k, grp in enumerate(groups):
        if not grp:
            continue
        M = len(grp)
        mi = {m: i for i, m in enumerate(grp)}
        C = [np.zeros((4, M, len(pc))) for pc in pieces]
        ri = [{r: i for i, r in enumerate(pc)} for pc in pieces]
        where = {r: kk for kk, pc in enumerate(pieces) for r in pc}
        for t in monomial_terms(d, p):
            mu, rho = _skip_split(t, q)
            if mu in mi:
                C[where[rho]][:, mi[mu], ri[where[rho]][rho]] += L[:, pos[t]]
        if () in mi:                                          # mu = 1, rho = 1: the constant
            C[where[()]][:, mi[()], ri[where[()]][()]] += f["c"]
        G = None
        for kk in range(len(pieces) - 1, k - 1, -1):
            if piece_t[kk] is None:
                continue
            Ck = g.const(C[kk].reshape(4 * M, -1))
            G = g.mm(Ck, piece_t[kk]) if G is None else g.op("Gemm", Ck, piece_t[kk], G)
        if M == 1:
            term = G if grp[0] == () else g.mul(G, rows_of(grp))
        else:
            prod = g.mul(g.reshape(G, [4, -1]), g.reshape(rows_of(grp), [1, -1]))
            term = g.reshape(g.mm(g.const(np.ones((1, M))), g.reshape(prod, [4, M, -1])), [4, -1])
        poly = term if poly is None else g.add(poly, term)
    return poly


BASE_INPUTS = 3        # r, u_r, u_t: the skip's full polynomial part; w and mu multiply it
#                        (the frame's `base`: 4, x, y, u, v, in the cartesian frame)


def _split_term(t: tuple, base: int = BASE_INPUTS) -> tuple[tuple, tuple]:
    """Monomial t = multiplier (its w and mu factors) * base (its base-column factors)."""
    return tuple(i for i in t if i >= base), tuple(i for i in t if i < base)


def _base_blocks(p: int, base: int = BASE_INPUTS) -> list[list[tuple]]:
    """Every monomial in the base columns of degree k = 0..p, block k ordered so that the block
    k + 1 is  concat_i (the first n_i rows of block k) * x_i  with n_i = its monomials whose
    last index is <= i (a prefix, since block k is ordered by last index)."""
    blocks = [[()]]
    for _ in range(p):
        blocks.append([t + (i,) for i in range(base) for t in blocks[-1]
                       if not t or t[-1] <= i])
    return blocks


def sparse_skip(g: Graph, f: dict, Xn: str, base: int = BASE_INPUTS) -> str:
    """c + L phi(Xn) [4, N] for explicit skip monomials, factored as
        sum_t L_t t = sum_m m * (C_m b),
    m over the multipliers (products of w and mu: 1, w, mu, mu^2, w mu, ... as the terms
    need), b every monomial of the `base` columns ((r, u_r, u_t), or (x, y, u, v)) up to the
    top degree (_base_blocks: per degree `base` prefix Slices and broadcast Muls and a Concat,
    no Gather), C_m gathered from L.
    One Gemm per degree accumulates G [4 K, N] (rows j K + m, M = 4 K = 24 for the sparse
    basis keeps the GEMM efficient), then Y = sum_m M_m G_m is a broadcast Mul and a [1, K]
    MatMul of ones."""
    terms, L = f["terms"], f["L"]
    mults = sorted({_split_term(t, base)[0] for t in terms} | {()}, key=lambda m: (len(m), m))
    K = len(mults)
    mi = {m: i for i, m in enumerate(mults)}
    p = max(len(_split_term(t, base)[1]) for t in terms)
    blocks = _base_blocks(p, base)
    where = {b: (k, i) for k, blk in enumerate(blocks) for i, b in enumerate(blk)}
    C = [np.zeros((4, K, len(blk))) for blk in blocks]
    for j, t in enumerate(terms):
        m, b = _split_term(t, base)
        k, i = where[b]
        C[k][:, mi[m], i] += L[:, j]
    C[0][:, mi[()], 0] += f["c"]
    rows = [g.op("Slice", Xn, g.ints([i]), g.ints([i + 1]), g.ints([0])) for i in range(base)]
    G = g.const(C[0].reshape(4 * K, 1))
    prev = None
    for k in range(1, p + 1):
        if k == 1:
            Bk = g.op("Slice", Xn, g.ints([0]), g.ints([base]), g.ints([0]))
        else:
            pieces = []
            for i in range(base):
                n_i = sum(1 for t in blocks[k - 1] if t[-1] <= i)
                src = prev if n_i == len(blocks[k - 1]) else g.op(
                    "Slice", prev, g.ints([0]), g.ints([n_i]), g.ints([0]))
                pieces.append(g.mul(src, rows[i]))
            Bk = g.concat(pieces, 0)
        G = g.op("Gemm", g.const(C[k].reshape(4 * K, -1)), Bk, G)
        prev = Bk
    if K == 1:
        return G
    mrow = {}

    def multiplier(m):
        if m not in mrow:
            x = g.op("Slice", Xn, g.ints([m[-1]]), g.ints([m[-1] + 1]), g.ints([0]))
            mrow[m] = x if len(m) == 1 else g.mul(multiplier(m[:-1]), x)
        return mrow[m]
    for m in mults[1:]:
        multiplier(m)
    Mk = g.concat([g.op("Expand", g.const(np.ones((1, 1))), g.op("Shape", rows[0]))
                   if m == () else mrow[m] for m in mults], 0)                 # [K, N]
    prod = g.mul(g.reshape(G, [4, K, -1]), g.reshape(Mk, [1, K, -1]))
    return g.reshape(g.mm(g.const(np.ones((1, K))), prod), [4, -1])
