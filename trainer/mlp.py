"""The NeuroLens network and its training: Levenberg-Marquardt (batch mode, as in the paper)
and Adam.

One network:  y = W3 tanh(W2 tanh(W1 x + b1) + b2) + b3 + L phi(x)
(2 tanh hidden layers of width H, linear output), where phi(x) lists the monomials of x of
degree 1..p (p = `skip_degree`; p = 1 is a linear skip). The polynomial skip carries the smooth
low-order part of the map (Gaussian optics and the third-order aberrations), so the hidden
layers learn what is left. x and y are normalised: each
dimension standardised, then divided by its largest |value| so the data fill [-1, 1].

Levenberg-Marquardt minimises E = sum ||T - y||^2 (Eq. 2) by steps
    (J^T J + mu diag(J^T J)) delta = J^T r,
J the Jacobian of all outputs over all samples with respect to the parameters, computed in
closed form chunk by chunk (J^T J is P x P, never N x P in memory); mu shrinks after a step that
lowers E and grows otherwise.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import torch

from neurolens_addon.core.irf import MIRROR_COLUMN
from neurolens_addon.neural.modelfile import monomial_terms
from neurolens_addon.neural.reference import monomial_columns

torch.set_default_dtype(torch.float64)


def lstsq(A: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least-squares coefficients of A c = y. LAPACK's SVD solver can fail to converge on rare
    ill-conditioned design matrices; then solve the column-scaled normal equations with a tiny
    ridge (1e-12 of the largest diagonal entry) instead."""
    try:
        return np.linalg.lstsq(A, y, rcond=None)[0]
    except np.linalg.LinAlgError:
        scale = np.sqrt((A * A).sum(axis=0))
        scale = np.where(scale > 0, scale, 1.0)
        As = A / scale
        G = As.T @ As
        G[np.diag_indices_from(G)] += 1e-12 * float(np.diag(G).max())
        return np.linalg.solve(G, As.T @ y) / (scale[:, None] if y.ndim == 2 else scale)


def monomials(x, terms):
    """phi(x): one column per monomial (numpy or torch, (n, d) -> (n, len(terms))); a term's
    prefixes need not be listed (neural.reference.monomial_columns)."""
    if not len(terms):
        return np.zeros((x.shape[0], 0)) if isinstance(x, np.ndarray) else torch.zeros(x.shape[0], 0)
    cols = monomial_columns(x, terms)
    if isinstance(x, np.ndarray):
        return np.stack(cols, axis=1)
    return torch.stack(cols, dim=1)


# The rotational symmetry of a lens makes each stage's map mirror-symmetric in the radial
# frame: flipping u_t (input 2) flips x'_t and u'_t (outputs 1 and 3) and keeps x'_r, u'_r.
# (The cartesian frame of an anamorphic lens has no such symmetry: core.irf.StageFrame.mirror.)
MIRROR_INPUT = MIRROR_COLUMN
MIRROR_OUTPUTS = (1, 3)


def sparse_skip_terms(d_in: int, degree: int, w_column: int = 3) -> list[tuple[int, ...]]:
    """The skip's monomials in the stage inputs (base columns, w at `w_column`[, mu after it]:
    radial (r, u_r, u_t, w[, mu]), cartesian (x, y, u, v, w[, mu])) up to `degree`, keeping
    only those a lens needs (measured on the double Gauss, docs/learned-lenses.md): w at most
    linear (w is nearly a function of the directions), and the wavelength feature
    mu = (l0 / lambda)^2 at most squared and only in terms below the top degree (dispersion is
    a small, smooth correction)."""
    out = []
    for t in monomial_terms(d_in, degree):
        n_w, n_mu = t.count(w_column), t.count(w_column + 1)
        if n_w <= 1 and n_mu <= 2 and (n_mu == 0 or len(t) < degree):
            out.append(t)
    return out


def is_odd_term(t) -> bool:
    return t.count(MIRROR_INPUT) % 2 == 1


def skip_lstsq(x: np.ndarray, y: np.ndarray, terms, mirror: bool) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares skip (L [O, T], constant [O]) of y ~ c + L phi(x). With `mirror` (inputs
    and outputs normalised with zero mean on the mirrored axes) the even outputs use only
    monomials even in u_t plus the constant, the odd outputs only odd monomials: the symmetry
    holds exactly and each fit has about half the unknowns."""
    phi = monomials(x, terms)
    L = np.zeros((y.shape[1], len(terms)))
    c = np.zeros(y.shape[1])
    groups = [(list(range(y.shape[1])), list(range(len(terms))), True)]
    if mirror:
        odd = [j for j, t in enumerate(terms) if is_odd_term(t)]
        even = [j for j, t in enumerate(terms) if not is_odd_term(t)]
        outs_odd = list(MIRROR_OUTPUTS)
        outs_even = [o for o in range(y.shape[1]) if o not in MIRROR_OUTPUTS]
        groups = [(outs_even, even, True), (outs_odd, odd, False)]
    for outs, cols, const in groups:
        A = phi[:, cols]
        if const:
            A = np.concatenate([A, np.ones((x.shape[0], 1))], axis=1)
        coef = lstsq(A, y[:, outs])
        L[np.ix_(outs, cols)] = coef[:len(cols)].T
        if const:
            c[outs] = coef[-1]
    return L, c


@dataclass
class Normaliser:
    mean: np.ndarray
    scale: np.ndarray

    @staticmethod
    def fit(a: np.ndarray, zero_mean=()) -> "Normaliser":
        """Standardise, then scale so the data fill [-1, 1]; columns in `zero_mean` keep their
        origin (mean 0), so a symmetry about 0 survives normalisation."""
        m = a.mean(axis=0)
        m[list(zero_mean)] = 0.0
        sd = a.std(axis=0)
        sd = np.where(sd > 0, sd, 1.0)
        z = (a - m) / sd
        peak = np.abs(z).max(axis=0)
        return Normaliser(m, sd * np.where(peak > 0, peak, 1.0))

    def apply(self, a):
        return (a - self.mean) / self.scale

    def invert(self, a):
        return a * self.scale + self.mean

    def as_dict(self):
        return {"mean": self.mean.tolist(), "scale": self.scale.tolist()}

    @staticmethod
    def from_dict(d):
        return Normaliser(np.asarray(d["mean"], float), np.asarray(d["scale"], float))


@dataclass
class MLP:
    """Parameters of one network (numpy float64)."""

    W1: np.ndarray
    b1: np.ndarray
    W2: np.ndarray
    b2: np.ndarray
    W3: np.ndarray
    b3: np.ndarray
    L: np.ndarray
    skip_degree: int = 1
    skip_terms: list | None = None      # explicit monomials; None: all of degree 1..skip_degree

    @property
    def terms(self):
        if self.skip_terms is not None:
            return [tuple(t) for t in self.skip_terms]
        return monomial_terms(self.W1.shape[1], self.skip_degree)

    @property
    def hidden(self) -> int:
        return self.W1.shape[0]

    @property
    def n_params(self) -> int:
        return sum(a.size for a in self.arrays())

    def arrays(self):
        return (self.W1, self.b1, self.W2, self.b2, self.W3, self.b3, self.L)

    def flat(self) -> np.ndarray:
        return np.concatenate([a.ravel() for a in self.arrays()])

    @staticmethod
    def shapes(d_in: int, hidden: int, d_out: int, skip_degree: int = 1):
        n_terms = len(monomial_terms(d_in, skip_degree))
        return [(hidden, d_in), (hidden,), (hidden, hidden), (hidden,), (d_out, hidden),
                (d_out,), (d_out, n_terms)]

    @staticmethod
    def from_flat(theta: np.ndarray, d_in: int, hidden: int, d_out: int,
                  skip_degree: int = 1) -> "MLP":
        out, k = [], 0
        for shp in MLP.shapes(d_in, hidden, d_out, skip_degree):
            n = int(np.prod(shp))
            out.append(np.asarray(theta[k:k + n]).reshape(shp).copy())
            k += n
        return MLP(*out, skip_degree=skip_degree)

    def forward(self, x: np.ndarray) -> np.ndarray:
        h1 = np.tanh(x @ self.W1.T + self.b1)
        h2 = np.tanh(h1 @ self.W2.T + self.b2)
        return h2 @ self.W3.T + self.b3 + monomials(x, self.terms) @ self.L.T

    def as_dict(self):
        d = {k: v.tolist() for k, v in zip(("W1", "b1", "W2", "b2", "W3", "b3", "L"),
                                           self.arrays())}
        d["skip_degree"] = self.skip_degree
        if self.skip_terms is not None:
            d["skip_terms"] = [list(t) for t in self.skip_terms]
        return d

    @staticmethod
    def from_dict(d):
        terms = d.get("skip_terms")
        return MLP(*(np.asarray(d[k], float) for k in ("W1", "b1", "W2", "b2", "W3", "b3", "L")),
                   skip_degree=int(d.get("skip_degree", 1)),
                   skip_terms=None if terms is None else [tuple(t) for t in terms])


def init_mlp(x: np.ndarray, y: np.ndarray, hidden: int, rng: np.random.Generator,
             skip_degree: int = 1) -> MLP:
    """Random hidden layers (uniform, scaled by fan-in) and the output started at the
    least-squares polynomial fit, so training begins from the polynomial map."""
    d_in, d_out = x.shape[1], y.shape[1]
    W1 = rng.uniform(-1, 1, (hidden, d_in)) * (2.0 / math.sqrt(d_in))
    b1 = rng.uniform(-1, 1, hidden)
    W2 = rng.uniform(-1, 1, (hidden, hidden)) * (2.0 / math.sqrt(hidden))
    b2 = rng.uniform(-1, 1, hidden)
    terms = monomial_terms(d_in, skip_degree)
    A = np.concatenate([monomials(x, terms), np.ones((x.shape[0], 1))], axis=1)
    coef = lstsq(A, y)
    L, b3 = coef[:-1].T.copy(), coef[-1].copy()
    # The output layer starts well below what the skip leaves, so training starts from the
    # polynomial's error, not above it.
    resid = y - A @ coef
    W3 = rng.uniform(-1, 1, (d_out, hidden)) * (1e-2 * float(resid.std()) / hidden + 1e-12)
    return MLP(W1, b1, W2, b2, W3, b3, L, skip_degree)


def fit_member(x: np.ndarray, y: np.ndarray, hidden: int, skip_degree: int,
               rng: np.random.Generator, *, method: str = "lm", lm_iterations: int = 40,
               adam_epochs: int = 150, time_budget_s: float = 30.0,
               skip_terms=None, mirror: bool = False) -> MLP:
    """One ensemble member: the polynomial skip by least squares (its exact optimum), then the
    hidden layers trained on what the polynomial leaves (LM or Adam), merged into one network.
    `skip_terms` (default: every monomial of degree 1..skip_degree) and `mirror` as in
    skip_lstsq."""
    terms = monomial_terms(x.shape[1], skip_degree) if skip_terms is None else skip_terms
    L, b_poly = skip_lstsq(x, y, terms, mirror)
    resid = y - (monomials(x, terms) @ L.T + b_poly)
    # The network learns the residual scaled to unit spread: LM does not care, but Adam's
    # step sizes are absolute and would swamp a 1e-4 residual.
    rs = np.where(resid.std(axis=0) > 0, resid.std(axis=0), 1.0)
    target = resid / rs
    net = init_mlp(x, target, hidden, rng, skip_degree=0)
    if method == "lm":
        net, _ = train_lm(net, x, target, max_iter=lm_iterations, time_budget_s=time_budget_s)
    else:
        net, _ = train_adam(net, x, target, epochs=adam_epochs, time_budget_s=time_budget_s,
                            seed=int(rng.integers(1 << 30)))
    return MLP(net.W1, net.b1, net.W2, net.b2, net.W3 * rs[:, None], net.b3 * rs + b_poly, L,
               skip_degree if skip_terms is None else max((len(t) for t in terms), default=1),
               None if skip_terms is None else [tuple(t) for t in terms])


def _jacobian_chunk(theta, x, phi, d_in, hidden, d_out, skip_degree):
    """Outputs y (n, O) and dy/dtheta (n, O, P) for one chunk, in closed form."""
    shp = MLP.shapes(d_in, hidden, d_out, skip_degree)
    sizes = [int(np.prod(s)) for s in shp]
    parts = torch.split(theta, sizes)
    W1, b1, W2, b2, W3, b3, L = (p.reshape(s) for p, s in zip(parts, shp))
    h1 = torch.tanh(x @ W1.T + b1)
    h2 = torch.tanh(h1 @ W2.T + b2)
    y = h2 @ W3.T + b3 + phi @ L.T
    n = x.shape[0]
    g2 = 1.0 - h2 * h2
    g1 = 1.0 - h1 * h1
    D2 = W3[None, :, :] * g2[:, None, :]                   # (n, O, H): dy_k / d(pre-act 2)_j
    D1 = (D2 @ W2) * g1[:, None, :]                        # (n, O, H): dy_k / d(pre-act 1)_i
    eye = torch.eye(d_out)
    J = torch.cat([
        (D1[:, :, :, None] * x[:, None, None, :]).reshape(n, d_out, -1),      # W1
        D1,                                                                    # b1
        (D2[:, :, :, None] * h1[:, None, None, :]).reshape(n, d_out, -1),     # W2
        D2,                                                                    # b2
        (eye[None, :, :, None] * h2[:, None, None, :]).reshape(n, d_out, -1), # W3
        eye[None].expand(n, d_out, d_out),                                     # b3
        (eye[None, :, :, None] * phi[:, None, None, :]).reshape(n, d_out, -1),  # L
    ], dim=2)
    return y, J


def _loss(theta, x, y, d_in, hidden, d_out, skip_degree, chunk=65536):
    tot = 0.0
    with torch.no_grad():
        net = MLP.from_flat(theta.numpy(), d_in, hidden, d_out, skip_degree)
        for i in range(0, x.shape[0], chunk):
            r = y[i:i + chunk].numpy() - net.forward(x[i:i + chunk].numpy())
            tot += float((r * r).sum())
    return tot


def train_lm(net: MLP, x: np.ndarray, y: np.ndarray, *, max_iter: int = 200,
             time_budget_s: float = 60.0, chunk: int = 4096, tol: float = 1e-10,
             progress=None) -> tuple[MLP, list[float]]:
    """Levenberg-Marquardt in batch mode; returns the trained net and its loss history."""
    d_in, d_out, hidden, p = x.shape[1], y.shape[1], net.hidden, net.skip_degree
    xt, yt = torch.from_numpy(np.ascontiguousarray(x)), torch.from_numpy(np.ascontiguousarray(y))
    phit = torch.from_numpy(np.ascontiguousarray(monomials(x, net.terms)))
    theta = torch.from_numpy(net.flat())
    mu = 1e-3
    loss = _loss(theta, xt, yt, d_in, hidden, d_out, p)
    history = [loss]
    t0 = time.perf_counter()
    for it in range(max_iter):
        P = theta.numel()
        JtJ = torch.zeros(P, P)
        Jtr = torch.zeros(P)
        for i in range(0, xt.shape[0], chunk):
            yp, J = _jacobian_chunk(theta, xt[i:i + chunk], phit[i:i + chunk], d_in, hidden,
                                    d_out, p)
            Jf = J.reshape(-1, P)
            r = (yt[i:i + chunk] - yp).reshape(-1)
            JtJ.addmm_(Jf.T, Jf)
            Jtr.addmv_(Jf.T, r)
        # Marquardt scaling, floored so parameters with little curvature (hidden weights seen
        # through a near-zero output layer) cannot take huge steps into tanh saturation.
        diag = torch.diagonal(JtJ).clone()
        diag = diag.clamp_min(1e-2 * float(diag.mean()) + 1e-12)
        improved = False
        for _ in range(12):
            A = JtJ + torch.diag(mu * diag)
            try:
                Lc = torch.linalg.cholesky(A)
                step = torch.cholesky_solve(Jtr[:, None], Lc)[:, 0]
            except RuntimeError:
                mu *= 10.0
                continue
            cand = theta + step
            new_loss = _loss(cand, xt, yt, d_in, hidden, d_out, p)
            if new_loss < loss:
                theta = cand
                rel = (loss - new_loss) / max(loss, 1e-300)
                loss = new_loss
                mu = max(mu / 3.0, 1e-12)
                improved = True
                break
            mu *= 4.0
        history.append(loss)
        if progress:
            progress(it, loss)
        if not improved or rel < tol or time.perf_counter() - t0 > time_budget_s:
            break
    return MLP.from_flat(theta.numpy(), d_in, hidden, d_out, p), history


def train_adam(net: MLP, x: np.ndarray, y: np.ndarray, *, epochs: int = 200,
               batch: int = 4096, lr: float = 3e-3, time_budget_s: float = 60.0,
               seed: int = 0) -> tuple[MLP, list[float]]:
    """Adam on minibatches with a cosine learning-rate decay; same network and loss."""
    d_in, d_out, hidden, p = x.shape[1], y.shape[1], net.hidden, net.skip_degree
    g = torch.Generator().manual_seed(seed)
    theta = torch.nn.Parameter(torch.from_numpy(net.flat()))
    opt = torch.optim.Adam([theta], lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, epochs)
    xt, yt = torch.from_numpy(x), torch.from_numpy(y)
    phit = torch.from_numpy(monomials(x, net.terms))
    history = []
    t0 = time.perf_counter()
    for ep in range(epochs):
        perm = torch.randperm(xt.shape[0], generator=g)
        for i in range(0, xt.shape[0], batch):
            idx = perm[i:i + batch]
            yp, _ = _forward_torch(theta, xt[idx], phit[idx], d_in, hidden, d_out, p)
            lossb = ((yt[idx] - yp) ** 2).sum(dim=1).mean()
            opt.zero_grad()
            lossb.backward()
            opt.step()
        sched.step()
        history.append(_loss(theta.detach(), xt, yt, d_in, hidden, d_out, p))
        if time.perf_counter() - t0 > time_budget_s:
            break
    return MLP.from_flat(theta.detach().numpy(), d_in, hidden, d_out, p), history


def _forward_torch(theta, x, phi, d_in, hidden, d_out, skip_degree):
    shp = MLP.shapes(d_in, hidden, d_out, skip_degree)
    parts = torch.split(theta, [int(np.prod(s)) for s in shp])
    W1, b1, W2, b2, W3, b3, L = (p.reshape(s) for p, s in zip(parts, shp))
    h1 = torch.tanh(x @ W1.T + b1)
    h2 = torch.tanh(h1 @ W2.T + b2)
    return h2 @ W3.T + b3 + phi @ L.T, (h1, h2)
