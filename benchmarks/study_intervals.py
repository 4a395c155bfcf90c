"""Simulation study: confidence intervals and standard errors for per-point AO estimates.

    python benchmarks/study_intervals.py [--trials 2048] [--quick]

One surface point per trial, every trial with its own independent randomisation; all
trials of a case are simulated at once with numpy (single-threaded, ~2-3 minutes).
Prints markdown tables (coverage of the 95% interval, RMS(error)/RMS(stderr), zero-stderr
fraction, interval width, RMSE) for the samplers random / stratified / sobol_cp /
sobol_owen at 16..4096 rays, R = 8/16/32 replicates, over three integrand families with
closed-form (or 1-D quadrature) exact values, plus an exact (enumerated) worst case over a
dense grid of elevation-only thresholds, and a final recommendation.
Standalone: needs only numpy and scipy (it does not import aobake).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from scipy import integrate, optimize, special, stats

Z = stats.norm.ppf(0.975)
H0 = -math.log(0.05)          # 2.996: P(no hit among n rays) = 0.05 at p = H0 / n
NS = (16, 64, 256, 1024, 4096)
RS = (8, 16, 32)
TWO32 = float(1 << 32)


# --------------------------------------------------------------------------- exact values
def disc_form_factor(a, x0, h=1.0):
    """Closed form: differential floor element (normal +z) to a parallel disc of radius a,
    height h, centre offset x0 (derived by Nusselt projection; checked by quadrature below)."""
    s = h * h + x0 * x0
    return 0.5 * (1.0 - (s - a * a) / math.sqrt((s + a * a) ** 2 - 4.0 * a * a * x0 * x0))


def disc_form_factor_quad(a, x0, h=1.0):
    """F = (1/2pi) int dpsi [h^2/(rho_-^2+h^2) - h^2/(rho_+^2+h^2)], rho_-+ the polar chord
    of the disc (projected on the floor) at azimuth psi: a smooth 1-D integral."""
    def g(psi):
        b = x0 * math.cos(psi)
        disc = b * b - (x0 * x0 - a * a)
        if disc <= 0:
            return 0.0
        r1, r2 = max(b - math.sqrt(disc), 0.0), b + math.sqrt(disc)
        if r2 <= 0:
            return 0.0
        return h * h / (r1 * r1 + h * h) - h * h / (r2 * r2 + h * h)
    if x0 <= a:
        val = integrate.quad(g, 0, math.pi, epsabs=1e-13, epsrel=1e-12, limit=400)[0]
    else:
        val = integrate.quad(g, 0, math.asin(a / x0), epsabs=1e-13, epsrel=1e-12, limit=400)[0]
    return val / math.pi


def obscurance_exact(tau, h, dmax):
    """E f over the cosine measure (u0 uniform, z = sqrt(1-u0)): int_0^1 f(z) 2z dz."""
    def f(z):
        L = h / z if z > 0 else math.inf
        return 1.0 - math.exp(-tau * L) if L <= dmax else 1.0
    zc = h / dmax if math.isfinite(dmax) else 0.0
    pts = [zc] if 0 < zc < 1 else None
    return integrate.quad(lambda z: f(z) * 2 * z, 0, 1, points=pts, epsabs=1e-14, epsrel=1e-13,
                          limit=400)[0]


def build_cases():
    cases = []
    # elevation-only: escape iff u0 > c, AO = 1 - c
    for c in (0.9999, 0.999, 0.99, 0.96, 0.7, 0.5 + math.sqrt(2) * 1e-3, 0.37, 1 / 3, 0.3, 0.04,
              0.01, 0.001, 0.0001):
        cases.append(dict(fam="elev", kind="bin", c=c, exact=1.0 - c, label=f"elev c={c:.4g}"))
    # coaxial disc (elevation-only through the geometric path)
    for ao in (1e-4, 1e-2, 0.5, 0.99, 0.9999):
        F = 1 - ao
        a = math.sqrt(F / (1 - F))
        cases.append(dict(fam="coax", kind="bin", a=a, x0=0.0, exact=1 - disc_form_factor(a, 0.0),
                          label=f"coax AO={ao:g}"))
    # offset disc: 2-D visibility boundary in u-space
    for ao in (1e-4, 1e-3, 1e-2, 0.2, 0.5, 0.7, 0.9, 0.99, 0.999, 0.9999):
        F = 1 - ao
        if F >= 0.5:   # huge near disc, point under it off-centre: x0 = a/2
            a = optimize.brentq(lambda a: disc_form_factor(a, 0.5 * a) - F, 1e-3, 1e7, xtol=1e-14,
                                rtol=1e-15)
            x0 = 0.5 * a
        else:          # disc centred 45 deg off zenith, small and far for AO -> 1
            x0 = 1.0
            a = optimize.brentq(lambda a: disc_form_factor(a, 1.0) - F, 1e-8, 1e3, xtol=1e-15,
                                rtol=1e-15)
        cases.append(dict(fam="disc", kind="bin", a=a, x0=x0, exact=1 - disc_form_factor(a, x0),
                          label=f"disc AO={ao:g}"))
    # obscurance-like [0,1]-valued: infinite ceiling at h = 1, f = 1 - exp(-tau L) if L <= D
    for tau, dmax in ((1.0, 3.0), (0.05, math.inf), (1.0, 1.0005), (0.002, math.inf)):
        ex = obscurance_exact(tau, 1.0, dmax)
        cases.append(dict(fam="obsc", kind="real", tau=tau, dmax=dmax, exact=ex,
                          label=f"obsc tau={tau:g} D={dmax:g}"))
    for cs in cases:
        v = cs["exact"]
        if cs["fam"] == "obsc":
            cs["group"] = "OBS"
        elif v < 0.05 or v > 0.95:
            cs["group"] = "EDGE"
        elif cs["fam"] == "disc":
            cs["group"] = "I2D"
        else:
            cs["group"] = "ELV"
    return cases


# --------------------------------------------------------------------------- samplers
def _rev16_table():
    t = np.arange(65536, dtype=np.uint32)
    r = np.zeros_like(t)
    for b in range(16):
        r |= ((t >> b) & 1) << (15 - b)
    return r


REV16 = _rev16_table()


def rev32(x):
    return (REV16[x & 0xFFFF] << np.uint32(16)) | REV16[x >> np.uint32(16)]


def laine_karras(x, seed):
    x = x + seed
    x ^= x * np.uint32(0x6C50B47C)
    x ^= x * np.uint32(0xB82F1E52)
    x ^= x * np.uint32(0xC7AFE638)
    x ^= x * np.uint32(0x8D22F6E6)
    return x


def sobol_ints(m):
    """(m, 2) uint32: first m 2-D Sobol points in Gray-code order (as aobake.samplers.sobol_2d)."""
    v1 = np.array([1 << (31 - k) for k in range(32)], dtype=np.uint64)
    v2 = np.empty(32, dtype=np.uint64)
    v2[0] = 1 << 31
    for k in range(1, 32):
        v2[k] = v2[k - 1] ^ (v2[k - 1] >> np.uint64(1))
    idx = np.arange(m, dtype=np.uint64)
    g = idx ^ (idx >> np.uint64(1))
    x = np.zeros(m, dtype=np.uint64)
    y = np.zeros(m, dtype=np.uint64)
    for k in range(32):
        bit = (g >> np.uint64(k)) & np.uint64(1)
        x ^= bit * v1[k]
        y ^= bit * v2[k]
    return np.stack([x, y], axis=1).astype(np.uint32)


class Sampler:
    """gen(rng, tb) -> u (tb, G, m, 2) float64 in [0,1); G replicates of m rays."""

    def __init__(self, name, n, R=1, mode="ceil"):
        self.name, self.n_req = name, n
        if name == "random":
            self.G, self.m = 1, n
        else:
            G = max(1, min(R, n))
            m = -(-n // G)
            if mode == "pow2":
                m = 1 << (m - 1).bit_length()
            elif mode == "pow2down":
                m = max(1, 1 << (m.bit_length() - 1))
            self.G, self.m = G, m
        self.rays = self.G * self.m
        if name in ("sobol_cp", "sobol_owen"):
            ints = sobol_ints(self.m)
            self.base = ints.astype(np.float64) / TWO32
            self.rev = rev32(ints)
        if name == "stratified":
            m = self.m
            self.nx = max(d for d in range(1, int(math.isqrt(m)) + 1) if m % d == 0)
            self.ny = m // self.nx
            j = np.arange(m)
            self.cell = np.stack([j % self.nx, j // self.nx], axis=1).astype(np.float64)

    def gen(self, rng, tb):
        G, m = self.G, self.m
        if self.name == "random":
            return rng.random((tb, 1, m, 2))
        if self.name == "stratified":
            u = (self.cell + rng.random((tb, G, m, 2))) / np.array([self.nx, self.ny], float)
            return np.minimum(u, np.nextafter(1.0, 0.0))
        if self.name == "sobol_cp":
            u = self.base + rng.random((tb, G, 1, 2))
            return u - np.floor(u)
        seeds = rng.integers(0, 1 << 32, size=(tb, G, 1, 2), dtype=np.uint32)
        x = rev32(laine_karras(self.rev[None, None], seeds))
        return x.astype(np.float64) / TWO32


# --------------------------------------------------------------------------- simulation
def simulate(sampler, cases, trials, seed):
    """Per case: group sums (T, G) and sum of squares over all rays (T,)."""
    G, m = sampler.G, sampler.m
    rng = np.random.default_rng(seed)
    tb = max(1, min(trials, (1 << 19) // sampler.rays))
    gs = [np.empty((trials, G)) for _ in cases]
    ssq = [np.empty(trials) for _ in cases]
    t0 = 0
    while t0 < trials:
        b = min(tb, trials - t0)
        u = sampler.gen(rng, b)
        u0, u1 = u[..., 0], u[..., 1]
        z = np.sqrt(1.0 - u0)
        r = np.sqrt(u0)
        phi = 2 * np.pi * u1
        X = r * np.cos(phi) / z        # hit point on the plane z = 1 (h = 1)
        Y = r * np.sin(phi) / z
        Y2 = Y * Y
        for i, cs in enumerate(cases):
            if cs["fam"] == "elev":
                f = u0 > cs["c"]
            elif cs["fam"] in ("coax", "disc"):
                d = X - cs["x0"]
                f = (d * d + Y2) >= cs["a"] ** 2
            else:
                L = 1.0 / z
                f = np.where(L <= cs["dmax"], -np.expm1(-cs["tau"] * L), 1.0)
            if f.dtype == bool:
                s = np.count_nonzero(f, axis=2).astype(np.float64)
                gs[i][t0:t0 + b] = s
                ssq[i][t0:t0 + b] = s.sum(axis=1)
            else:
                gs[i][t0:t0 + b] = f.sum(axis=2)
                ssq[i][t0:t0 + b] = np.square(f).sum(axis=(1, 2))
        t0 += b
    return gs, ssq


def design_stats(sampler, gs, ssq):
    """-> mu (C, T), SS (C, T) sum of squared deviations of the group means, G, m."""
    n = sampler.rays
    if sampler.name == "random":   # n i.i.d. rays = n groups of 1
        mu = np.stack([g[:, 0] / n for g in gs])
        sq = np.stack(ssq)
        SS = np.maximum(sq - n * mu * mu, 0.0)
        return mu, SS, n, 1
    m = sampler.m
    Y = np.stack(gs) / m
    mu = Y.mean(axis=2)
    SS = np.square(Y - mu[..., None]).sum(axis=2)
    return mu, SS, sampler.G, m


# --------------------------------------------------------------------------- constructions
def wilson(x, N, zc):
    den = N + zc * zc
    ctr = (x + zc * zc / 2) / den
    hw = zc * np.sqrt(np.maximum(x * (N - x) / N, 0.0) + zc * zc / 4) / den
    return np.clip(ctr - hw, 0, 1), np.clip(ctr + hw, 0, 1)


def jeff_sd(k, n):
    a, b = k + 0.5, n - k + 0.5
    return np.sqrt(a * b / ((a + b) ** 2 * (a + b + 1)))


CONS_ALL = ["z (current)", "t", "t|1/n", "t|1/(m√R)", "t|Jeff(n)", "t|3/n", "t|Wilson0",
            "prior κ=1", "prior κ=2", "Wilson-deff|3/n", "Jeffreys-deff|3/n",
            "pooled Wilson", "Wilson", "Jeffreys", "Agresti-Coull", "emp-Bernstein"]
QMC_ONLY = {"t|1/(m√R)", "pooled Wilson"}
IID_ONLY = {"Wilson", "Jeffreys", "Agresti-Coull", "emp-Bernstein"}


def constructions(mu, SS, G, m, n, iid, names=None):
    """-> {name: (stderr, lo, hi)}; mu, SS arrays of any shape."""
    out = {}
    want = (lambda nm: names is None or nm in names)
    t = stats.t.ppf(0.975, G - 1)
    se_raw = np.sqrt(SS / (G * (G - 1)))
    k = mu * n

    def sym(se, mult):
        return se, np.clip(mu - mult * se, 0, 1), np.clip(mu + mult * se, 0, 1)

    if want("z (current)"):
        out["z (current)"] = sym(se_raw, Z)
    if want("t"):
        out["t"] = sym(se_raw, t)
    if want("t|1/n"):
        out["t|1/n"] = sym(np.maximum(se_raw, 1.0 / n), t)
    if not iid and want("t|1/(m√R)"):
        out["t|1/(m√R)"] = sym(np.maximum(se_raw, 1.0 / (m * math.sqrt(G))), t)
    if want("t|Jeff(n)"):
        out["t|Jeff(n)"] = sym(np.maximum(se_raw, jeff_sd(k, n)), t)
    se3 = np.maximum(se_raw, H0 / (n * t))
    if want("t|3/n"):
        out["t|3/n"] = sym(se3, t)
    if want("t|Wilson0"):
        wl, wh = wilson(k, n, Z)
        zero = se_raw == 0
        _, lo, hi = sym(se_raw, t)
        out["t|Wilson0"] = (np.where(zero, (wh - wl) / (2 * Z), se_raw), np.where(zero, wl, lo),
                            np.where(zero, wh, hi))
    for kap in (1, 2):
        if want(f"prior κ={kap}"):
            out[f"prior κ={kap}"] = sym(np.sqrt((SS + kap / (m * m)) / (G * (G - 1))), t)
    inter = (mu > 0) & (mu < 1)
    if want("Wilson-deff|3/n") or want("Jeffreys-deff|3/n"):
        neff = np.where(inter, mu * (1 - mu) / np.where(inter, se3, 1.0) ** 2, n)
        x = mu * neff
    if want("Wilson-deff|3/n"):
        lo, hi = wilson(x, neff, np.where(inter, t, Z))
        out["Wilson-deff|3/n"] = (se3, lo, hi)
    if want("Jeffreys-deff|3/n"):
        alo = np.where(inter, stats.norm.cdf(-t), 0.025)
        lo = np.where(mu <= 0, 0.0, special.betaincinv(x + 0.5, neff - x + 0.5, alo))
        hi = np.where(mu >= 1, 1.0, special.betaincinv(x + 0.5, neff - x + 0.5, 1 - alo))
        out["Jeffreys-deff|3/n"] = (se3, lo, hi)
    pt = (k + 0.5) / (n + 1)
    if not iid and want("pooled Wilson"):
        out["pooled Wilson"] = (np.sqrt(pt * (1 - pt) / n),) + wilson(k, n, Z)
    if iid:
        if want("Wilson"):
            out["Wilson"] = (np.sqrt(pt * (1 - pt) / n),) + wilson(k, n, Z)
        if want("Jeffreys"):
            lo = np.where(k <= 0, 0.0, special.betaincinv(k + 0.5, n - k + 0.5, 0.025))
            hi = np.where(k >= n, 1.0, special.betaincinv(k + 0.5, n - k + 0.5, 0.975))
            out["Jeffreys"] = (jeff_sd(k, n), lo, hi)
        if want("Agresti-Coull"):
            nt = n + Z * Z
            p2 = (k + Z * Z / 2) / nt
            se = np.sqrt(p2 * (1 - p2) / nt)
            out["Agresti-Coull"] = (se, np.clip(p2 - Z * se, 0, 1), np.clip(p2 + Z * se, 0, 1))
        if want("emp-Bernstein"):   # Maurer & Pontil 2009, delta = 0.05
            V = SS / (n - 1)
            lg = math.log(2 / 0.05)
            hw = np.sqrt(2 * V * lg / n) + 7 * lg / (3 * (n - 1))
            out["emp-Bernstein"] = (se_raw, np.clip(mu - hw, 0, 1), np.clip(mu + hw, 0, 1))
    return out


def metrics(exact, mu, cons):
    """exact (C,), mu (C, T) -> {name: dict of (C,) arrays}."""
    err = mu - exact[:, None]
    mse = np.mean(err * err, axis=1)
    res = {}
    for nm, (se, lo, hi) in cons.items():
        cov = np.mean((lo <= exact[:, None] + 1e-13) & (hi >= exact[:, None] - 1e-13), axis=1)
        mse_se = np.mean(se * se, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            cal = np.sqrt(mse / mse_se)
        res[nm] = dict(cov=cov, cal=cal, zero=np.mean(se == 0, axis=1),
                       hw=np.mean((hi - lo) / 2, axis=1), rmse=np.sqrt(mse))
    return res


# --------------------------------------------------------------------------- exact 1-D step
def exact_step_tables(names, ngrid=4001, strat_trials=1500, strat_grid=121, seed=7):
    """Worst coverage over a dense grid of elevation-only AO values p in [1e-4, 1-1e-4].

    random: K ~ Bin(n, p) exactly.  sobol_cp / sobol_owen with m = 2^k: the m dim-0 points
    are one per stratum of width 1/m, so each replicate count is floor(m p) + Bernoulli(q),
    q = frac(m p): J ~ Bin(R, q) replicates take the upper value (enumerated exactly).
    stratified: count = ny * floor(nx p) + Bin(ny, frac(nx p)) per replicate (Monte Carlo).
    """
    lg = np.logspace(-4, math.log10(0.05), ngrid // 4)
    p = np.unique(np.concatenate([lg, np.linspace(0.05, 0.95, ngrid // 2), 1 - lg]))
    out = {}   # (model, R) -> {name: (worst cov, p at worst, n at worst)}
    def upd(key, nm, cov, n):
        i = int(np.argmin(cov))
        cur = out.setdefault(key, {}).get(nm)
        if cur is None or cov[i] < cur[0]:
            out[key][nm] = (float(cov[i]), float(p[i]), n)
    for n in NS:
        # random
        kk = np.arange(n + 1, dtype=np.float64)
        mu = kk / n
        cons = constructions(mu, n * mu * (1 - mu), n, 1, n, True, names)
        pmf = stats.binom.pmf(kk[None, :], n, p[:, None])
        for nm, (_, lo, hi) in cons.items():
            cv = (lo[None, :] <= p[:, None] + 1e-13) & (hi[None, :] >= p[:, None] - 1e-13)
            upd(("random", 1), nm, (pmf * cv).sum(axis=1), n)
        for R in RS:
            G = min(R, n)
            m = -(-n // G)
            k0 = np.floor(m * p)
            q = m * p - k0
            J = np.arange(G + 1, dtype=np.float64)
            mu = (k0[:, None] + J[None, :] / G) / m
            SS = np.broadcast_to(J * (G - J) / G / (m * m), mu.shape)
            cons = constructions(mu, SS, G, m, G * m, False, names)
            pmf = stats.binom.pmf(J[None, :], G, q[:, None])
            for nm, (_, lo, hi) in cons.items():
                cv = (lo <= p[:, None] + 1e-13) & (hi >= p[:, None] - 1e-13)
                upd(("sobol (cp=owen)", R), nm, (pmf * cv).sum(axis=1), n)
    rng = np.random.default_rng(seed)
    ps = np.unique(np.concatenate([np.logspace(-4, math.log10(0.05), strat_grid // 3),
                                   np.linspace(0.05, 0.95, strat_grid // 3),
                                   1 - np.logspace(-4, math.log10(0.05), strat_grid // 3)]))
    for n in NS:
        for R in RS:
            G = min(R, n)
            m = -(-n // G)
            nx = max(d for d in range(1, int(math.isqrt(m)) + 1) if m % d == 0)
            ny = m // nx
            k0 = np.floor(nx * ps)
            q = nx * ps - k0
            B = rng.binomial(ny, q[:, None, None], size=(len(ps), strat_trials, G))
            Y = (ny * k0[:, None, None] + B) / m
            mu = Y.mean(axis=2)
            SS = np.square(Y - mu[..., None]).sum(axis=2)
            cons = constructions(mu, SS, G, m, G * m, False, names)
            for nm, (_, lo, hi) in cons.items():
                cov = np.mean((lo <= ps[:, None] + 1e-13) & (hi >= ps[:, None] - 1e-13), axis=1)
                i = int(np.argmin(cov))
                cur = out.setdefault(("stratified (MC)", R), {}).get(nm)
                if cur is None or cov[i] < cur[0]:
                    out[("stratified (MC)", R)][nm] = (float(cov[i]), float(ps[i]), n)
    return out


# --------------------------------------------------------------------------- reporting
def fmt_pct(x):
    return "  -  " if x is None or not np.isfinite(x) else f"{100 * x:.1f}"


def gmean(x):
    x = np.asarray(x, float)
    x = x[np.isfinite(x) & (x > 0)]
    return float(np.exp(np.mean(np.log(x)))) if len(x) else float("nan")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=2048)
    ap.add_argument("--quick", action="store_true", help="fewer trials (smoke test)")
    args = ap.parse_args()
    T = 256 if args.quick else args.trials
    t_start = time.time()
    cases = build_cases()
    exact = np.array([c["exact"] for c in cases])
    groups = np.array([c["group"] for c in cases])
    labels = [c["label"] for c in cases]
    qerr = max(abs(disc_form_factor(c["a"], c["x0"]) - disc_form_factor_quad(c["a"], c["x0"]))
               for c in cases if c["fam"] in ("disc", "coax"))

    configs = [("random", 1)] + [(s, R) for s in ("sobol_cp", "sobol_owen", "stratified")
                                 for R in RS]
    short = {"random": "rand", "sobol_cp": "cp", "sobol_owen": "ow", "stratified": "st"}
    col = {cfg: (short[cfg[0]] + (str(cfg[1]) if cfg[0] != "random" else "")) for cfg in configs}
    # results[cfg][n] = metrics dict
    results = {}
    for ci, cfg in enumerate(configs):
        results[cfg] = {}
        for ni, n in enumerate(NS):
            smp = Sampler(cfg[0], n, cfg[1])
            gs, ssq = simulate(smp, cases, T, seed=1000 * ci + ni)
            mu, SS, G, m = design_stats(smp, gs, ssq)
            cons = constructions(mu, SS, G, m, smp.rays, cfg[0] == "random")
            results[cfg][n] = metrics(exact, mu, cons)
    t_sim = time.time() - t_start

    cov_se = math.sqrt(0.95 * 0.05 / T)
    print("# aobake interval study\n")
    print(f"{T} trials per (sampler, R, n, case) (1 s.e. of a coverage near 95%: "
          f"{100 * cov_se:.2f} points); n = {NS}; R = min(R, n), m = ceil(n/R) (all powers of 2).")
    print(f"{len(cases)} cases: elevation-only u0 > c ({sum(c['fam'] == 'elev' for c in cases)}), "
          f"coaxial disc ({sum(c['fam'] == 'coax' for c in cases)}), offset disc "
          f"({sum(c['fam'] == 'disc' for c in cases)}), obscurance ({sum(c['fam'] == 'obsc' for c in cases)}); "
          f"groups: I2D = offset disc AO in [0.05,0.95], ELV = elevation-only interior, "
          f"EDGE = AO < 0.05 or > 0.95, OBS = [0,1]-valued.")
    print(f"Disc exact AO: closed form F = (1 - (h²+x0²-a²)/sqrt((h²+x0²+a²)² - 4a²x0²))/2; "
          f"max |closed form - 1-D quadrature| = {qerr:.1e}. Obscurance exact: 1-D quad (scipy).")
    print(f"Interval level 95%; t = t_(G-1) quantile (G = R replicates, or n rays for random); "
          f"'|x' = stderr floored at x; '3/n': stderr >= {H0:.3f}/(n t) (half-width >= 3/n); "
          f"'Wilson0': Wilson(n rays) when stderr = 0; 'prior κ': SS + κ/m² added to the "
          f"replicate sum of squares; '-deff': Wilson/Jeffreys on n_eff = p(1-p)/se² "
          f"(se floored as in '3/n'; Wilson(n) at p = 0 or 1).\n")

    def cons_rows(cfgs):
        return [nm for nm in CONS_ALL if any(nm in results[c][NS[0]] for c in cfgs)]

    def agg(cfg, nm, key, mask, red):
        vals = []
        for n in NS:
            r = results[cfg][n].get(nm)
            if r is None:
                return None
            vals.append(r[key][mask])
        v = np.concatenate(vals)
        return red(v)

    allmask = np.ones(len(cases), bool)
    # -------- Table 1: worst coverage
    print("## 1. Worst-case coverage (%) of the 95% interval over all 32 cases x 5 ray counts\n")
    hdr = "| construction | " + " | ".join(col[c] for c in configs) + " |"
    print(hdr)
    print("|" + "---|" * (len(configs) + 1))
    for nm in cons_rows(configs):
        row = [fmt_pct(agg(c, nm, "cov", allmask, np.min)) if nm in results[c][NS[0]] else "  ·  "
               for c in configs]
        print(f"| {nm} | " + " | ".join(row) + " |")
    print()

    # -------- Table 2: worst coverage by group for the key constructions
    key_cons = ["z (current)", "t", "t|1/n", "t|1/(m√R)", "t|3/n", "t|Wilson0", "prior κ=2",
                "Wilson-deff|3/n", "Jeffreys-deff|3/n", "Wilson", "Jeffreys"]
    gnames = ["I2D", "ELV", "EDGE", "OBS"]
    print("## 2. Worst-case coverage (%) by group: I2D / ELV / EDGE / OBS\n")
    print(hdr)
    print("|" + "---|" * (len(configs) + 1))
    for nm in key_cons:
        row = []
        for c in configs:
            if nm not in results[c][NS[0]]:
                row.append("·")
                continue
            row.append("/".join(f"{100 * agg(c, nm, 'cov', groups == g, np.min):.0f}"
                                for g in gnames))
        print(f"| {nm} | " + " | ".join(row) + " |")
    print()

    # -------- Table 3: width index
    def width_index(cfg, nm, mask):
        v = []
        for n in NS:
            r = results[cfg][n].get(nm)
            if r is None:
                return None
            ok = mask & (r["rmse"] > 0)
            v.append(r["hw"][ok] / (Z * r["rmse"][ok]))
        return gmean(np.concatenate(v))

    print("## 3. Width index: geometric mean over cases x n of half-width / (1.96 RMSE) "
          "(1 = ideal normal interval); all cases / I2D\n")
    print(hdr)
    print("|" + "---|" * (len(configs) + 1))
    for nm in cons_rows(configs):
        row = []
        for c in configs:
            if nm not in results[c][NS[0]]:
                row.append("·")
                continue
            row.append(f"{width_index(c, nm, allmask):.2f}/{width_index(c, nm, groups == 'I2D'):.2f}")
        print(f"| {nm} | " + " | ".join(row) + " |")
    print()

    # -------- Table 4: calibration
    print("## 4. RMS(error)/RMS(stderr), min-max over n: I2D cases | ELV+EDGE+OBS cases "
          "(target 0.9-1.1)\n")
    cal_cons = ["t", "t|1/n", "t|1/(m√R)", "t|3/n", "prior κ=1", "prior κ=2", "Wilson",
                "Jeffreys"]
    print(hdr)
    print("|" + "---|" * (len(configs) + 1))
    for nm in cal_cons:
        row = []
        for c in configs:
            if nm not in results[c][NS[0]]:
                row.append("·")
                continue
            a = agg(c, nm, "cal", groups == "I2D", lambda v: (np.nanmin(v), np.nanmax(v)))
            b = agg(c, nm, "cal", groups != "I2D",
                    lambda v: (np.nanmin(v[np.isfinite(v)]), np.nanmax(v[np.isfinite(v)])))
            row.append(f"{a[0]:.2f}-{a[1]:.2f} \\| {b[0]:.2f}-{b[1]:.2f}")
        print(f"| {nm} | " + " | ".join(row) + " |")
    print()

    # -------- Table 5: zero stderr and current product
    print("## 5. Raw design stderr (replicate sd/sqrt(R), or sd/sqrt(n)): fraction of exactly-zero "
          "stderr (max over cases, where) and coverage of the current 'mean ± 1.96 se'\n")
    print("| sampler | max P(se=0) | at | ... and error there: frac(err≠0) proxy RMSE | "
          "cov z: I2D min | ELV min | EDGE min |")
    print("|---|---|---|---|---|---|---|")
    for c in configs:
        best = (-1, None, None)
        for n in NS:
            r = results[c][n]["z (current)"]
            i = int(np.argmax(r["zero"] * (r["rmse"] > 0)))
            if r["zero"][i] > best[0]:
                best = (r["zero"][i], f"{labels[i]}, n={n}", r["rmse"][i])
        covs = [agg(c, "z (current)", "cov", groups == g, np.min) for g in ("I2D", "ELV", "EDGE")]
        print(f"| {col[c]} | {100 * best[0]:.1f}% | {best[1]} | {best[2]:.1e} | "
              + " | ".join(fmt_pct(v) for v in covs) + " |")
    print()

    # -------- choose best construction per config
    print("## 6. Best construction per sampler: coverage >= 93% in every case and n "
          "(simulation), narrowest width index\n")
    print("| sampler | best | worst cov ± se (case, n) | width all/I2D | calib I2D | "
          "2nd best (width) |")
    print("|---|---|---|---|---|---|")
    choice = {}
    for c in configs:
        cand = []
        for nm in cons_rows([c]):
            if nm not in results[c][NS[0]] or nm in ("pooled Wilson", "emp-Bernstein",
                                                      "t|Jeff(n)"):
                continue
            w = agg(c, nm, "cov", allmask, np.min)
            if w >= 0.93:
                cand.append((width_index(c, nm, allmask), nm))
        cand.sort()
        if not cand:
            print(f"| {col[c]} | none | | | | |")
            continue
        nm = cand[0][1]
        choice[c] = nm
        worst = (2, None)
        for n in NS:
            cv = results[c][n][nm]["cov"]
            i = int(np.argmin(cv))
            if cv[i] < worst[0]:
                worst = (cv[i], f"{labels[i]}, n={n}")
        a = agg(c, nm, "cal", groups == "I2D", lambda v: (np.nanmin(v), np.nanmax(v)))
        sec = f"{cand[1][1]} ({cand[1][0]:.2f})" if len(cand) > 1 else "-"
        print(f"| {col[c]} | {nm} | {100 * worst[0]:.1f} ± {100 * cov_se:.1f} ({worst[1]}) | "
              f"{cand[0][0]:.2f}/{width_index(c, nm, groups == 'I2D'):.2f} | "
              f"{a[0]:.2f}-{a[1]:.2f} | {sec} |")
    print()

    # -------- Table 7: exact dense-grid elevation-only worst case
    ex_names = ["t", "t|1/n", "t|1/(m√R)", "t|3/n", "t|Wilson0", "prior κ=1", "prior κ=2",
                "Wilson-deff|3/n", "Jeffreys-deff|3/n", "Wilson", "Jeffreys", "Agresti-Coull"]
    t1 = time.time()
    ex = exact_step_tables(set(ex_names))
    t_ex = time.time() - t1
    models = [("random", 1)] + [("sobol (cp=owen)", R) for R in RS] + \
             [("stratified (MC)", R) for R in RS]
    mcol = {("random", 1): "rand"}
    mcol.update({("sobol (cp=owen)", R): f"sob{R}" for R in RS})
    mcol.update({("stratified (MC)", R): f"st{R}" for R in RS})
    print("## 7. Elevation-only (escape iff u0 > c), worst coverage (%) over a dense grid of "
          "AO in [1e-4, 1-1e-4] and all n — exact enumeration (random: binomial; sobol_cp and "
          "sobol_owen with m = 2^k: J ~ Bin(R, frac(m AO))), stratified by Monte Carlo "
          "(1500 trials x 121 AO values)\n")
    print("| construction | " + " | ".join(mcol[k] for k in models) + " | worst at (sob16) |")
    print("|" + "---|" * (len(models) + 2))
    for nm in ex_names:
        row, where = [], ""
        for k in models:
            v = ex.get(k, {}).get(nm)
            row.append(fmt_pct(v[0]) if v else "·")
            if k == ("sobol (cp=owen)", 16) and v:
                where = f"AO={v[1]:.4g}, n={v[2]}"
        print(f"| {nm} | " + " | ".join(row) + f" | {where} |")
    print()

    # -------- Table 8: RMSE on the disc family
    print("## 8. RMSE relative to random (geometric mean over cases; < 1 = more accurate), "
          "disc family (coaxial + offset)\n")
    dint = np.array([c["fam"] in ("disc", "coax") and c["group"] != "EDGE" for c in cases])
    dall = np.array([c["fam"] in ("disc", "coax") for c in cases])
    d05 = labels.index("disc AO=0.5")
    print("| sampler | n=64 interior | n=64 all | n=256 interior | n=256 all | n=1024 interior "
          "| n=1024 all | RMSE offset AO=0.5 @64/256/1024 |")
    print("|---|---|---|---|---|---|---|---|")
    for c in configs:
        row = []
        for n in (64, 256, 1024):
            r = results[c][n]["t"]["rmse"]
            r0 = results[("random", 1)][n]["t"]["rmse"]
            row.append(f"{gmean(r[dint] / r0[dint]):.3f}")
            row.append(f"{gmean(r[dall] / r0[dall]):.3f}")
        ab = "/".join(f"{results[c][n]['t']['rmse'][d05]:.2e}" for n in (64, 256, 1024))
        print(f"| {col[c]} | " + " | ".join(row) + f" | {ab} |")
    print()

    # -------- Table 9: R = 8 vs 16 (and 32) summary for chosen constructions
    print("## 9. R comparison with each sampler's chosen construction: mean half-width "
          "relative to R=8 (geo-mean over cases x n), RMSE relative to R=8\n")
    print("| sampler | R=8 cons | hw R=16/R=8 | hw R=32/R=8 | RMSE R=16/R=8 | RMSE R=32/R=8 |")
    print("|---|---|---|---|---|---|")
    for s in ("sobol_cp", "sobol_owen", "stratified"):
        nm8 = choice.get((s, 8))
        out = []
        for R in (16, 32):
            nmR = choice.get((s, R))
            if nm8 is None or nmR is None:
                out.append(("-", "-"))
                continue
            hw = [results[(s, R)][n][nmR]["hw"] / results[(s, 8)][n][nm8]["hw"] for n in NS]
            rm = [results[(s, R)][n]["t"]["rmse"] / results[(s, 8)][n]["t"]["rmse"] for n in NS]
            out.append((f"{gmean(np.concatenate(hw)):.3f} ({nmR})", f"{gmean(np.concatenate(rm)):.3f}"))
        print(f"| {s} | {nm8} | {out[0][0]} | {out[1][0]} | {out[0][1]} | {out[1][1]} |")
    print()

    # -------- Table 10: [0,1]-valued integrand
    print("## 10. [0,1]-valued obscurance integrand: worst coverage % / calibration range over "
          "the 4 OBS cases x 5 n / max P(se=0)\n")
    ob_cons = ["t", "t|Wilson0", "t|3/n", "prior κ=2", "Wilson-deff|3/n", "Wilson",
               "emp-Bernstein"]
    ob_cfg = [("random", 1), ("sobol_cp", 16), ("sobol_owen", 16), ("stratified", 16)]
    print("| construction | " + " | ".join(col[c] for c in ob_cfg) + " |")
    print("|" + "---|" * (len(ob_cfg) + 1))
    om = groups == "OBS"
    for nm in ob_cons:
        row = []
        for c in ob_cfg:
            if nm not in results[c][NS[0]]:
                row.append("·")
                continue
            cv = agg(c, nm, "cov", om, np.min)
            cl = agg(c, nm, "cal", om, lambda v: (np.nanmin(v), np.nanmax(v)))
            zf = agg(c, nm, "zero", om, np.max)
            row.append(f"{100 * cv:.1f} / {cl[0]:.2f}-{cl[1]:.2f} / {100 * zf:.0f}%")
        print(f"| {nm} | " + " | ".join(row) + " |")
    print()

    # -------- Table 11: pow2 vs prefix
    print("## 11. sobol_owen / sobol_cp, R = 8, n not a multiple of 8·2^k: m = ceil(n/R) prefix vs "
          "m rounded up to 2^k (more rays) or down (fewer). Variance x rays / AO(1-AO) "
          "(1 = random; geo-mean over I2D+ELV cases); min coverage of 'Wilson-deff|3/n' over "
          "all cases\n")
    t2 = time.time()
    n_list = (24, 100, 400, 1500)
    print("| sampler, m | " + " | ".join(f"n={n}: rays, eff, cov" for n in n_list) + " |")
    print("|" + "---|" * (len(n_list) + 1))
    Tp = max(T // 2, 256)
    imask = (groups == "I2D") | (groups == "ELV")
    for s in ("sobol_owen", "sobol_cp"):
        for mode in ("ceil", "pow2", "pow2down"):
            row = []
            for ni, n in enumerate(n_list):
                smp = Sampler(s, n, 8, mode)
                gs, ssq = simulate(smp, cases, Tp, seed=77 + ni)
                mu, SS, G, m = design_stats(smp, gs, ssq)
                cons = constructions(mu, SS, G, m, smp.rays, False, {"t", "Wilson-deff|3/n"})
                mt = metrics(exact, mu, cons)
                eff = mt["t"]["rmse"] ** 2 * smp.rays / (exact * (1 - exact))
                row.append(f"{smp.rays}, {gmean(eff[imask]):.3f}, "
                           f"{100 * mt['Wilson-deff|3/n']['cov'].min():.1f}")
            print(f"| {s}, {mode} | " + " | ".join(row) + " |")
    print(f"\n({Tp} trials per cell.)\n")
    t_p2 = time.time() - t2

    # -------- recommendation
    print("## 12. Recommendation (computed from the tables above)\n")
    for c in configs:
        nm = choice.get(c)
        if nm is None:
            continue
        w = agg(c, nm, "cov", allmask, np.min)
        print(f"- {col[c]}: {nm} (worst simulated coverage {100 * w:.1f}%, width index "
              f"{width_index(c, nm, allmask):.2f})")
    uni = "Wilson-deff|3/n"
    ok = [c for c in configs if agg(c, uni, "cov", allmask, np.min) >= 0.93]
    print(f"- one construction for all: '{uni}' meets >= 93% in "
          f"{len(ok)}/{len(configs)} configurations: "
          + ", ".join(f"{col[c]} {100 * agg(c, uni, 'cov', allmask, np.min):.1f}" for c in configs))
    print(f"\n(runtime: simulation {t_sim:.0f} s, exact tables {t_ex:.0f} s, pow2 study "
          f"{t_p2:.0f} s, total {time.time() - t_start:.0f} s)")


if __name__ == "__main__":
    main()
