"""``--tolerance E``: ask for an accuracy, not a ray count.

A two-stage design (Stein's two-stage procedure, adapted to bounded integrands):

1. **Pilot.** Every point casts ``rays`` rays (the ``--rays`` value) and gets its usual
   estimate, spread and interval.
2. **Final.** From the pilot's spread each point gets a ray count n, the smallest the
   sampler can cast (``aobake.samplers``: sobol rounds to 8 x 2^k) whose predicted interval
   reaches at most E from the estimate, capped at ``max_rays``; it then casts n *fresh*
   rays (an independent key stream, ``samplers.point_key(seed, 1)``), and only these make
   its estimate, stderr and interval.

Why this scheme: the final rays are independent of the pilot's, so given n they are an
ordinary fixed-count bake of n rays.  Whatever the pilot saw, the final estimate is
unbiased and its interval has exactly the coverage of a fixed-count interval (measured:
docs/conventions.md), at every true value, 0 and 1 included, for every sampler.  The
data-dependent stopping that makes naive rules fail (stop when the interval looks small:
the interval is small *because* the estimate is off) never touches the numbers reported.
The price: the pilot's rays are not reused.  A point whose pilot under-estimated its
spread can end its final stage wider than E: it then casts a *further* stage of fresh rays
(:func:`further`: at least twice its last count, from a key stream of its own, only these
rays in its estimate), and so on until it meets E or has cast ``max_rays``, when it is
counted as capped and its interval says how wide it is (never narrower than the truth
warrants).  Each stage is again a fixed-count bake given its count; the decision to stop
reads the last stage's own interval, a selection measured in ``tests/test_tolerance.py``
(the mean error stays within 0.1 E plus its noise).

The prediction: per-ray variance s2 = n_pilot se_pilot^2 (for QMC the effective one: its
variance falls faster than 1/n, so scaling by 1/n is conservative), raised to its one-sided
75% upper bound (Wilson-Hilferty chi-square quantile, dof of the pilot's spread) so that most
points meet E in one go.  Where the pilot saw no spread (every ray or replicate agreed: the
value may still be up to h0 = 1 - (1 - C)^(1/n) from 0 or 1) s2 is that of a 0/1 ray at
h0, h0 (1 - h0).  The predicted half-width is the interval construction's own,
sqrt((t se)^2 + h0^2) clipped to [0, 1] around the pilot's estimate.
"""

from __future__ import annotations

import logging
import math
from statistics import NormalDist

import numpy as np

from aobake import stats
from aobake.records import Estimates
from aobake.samplers import REPLICATES, sample_set

log = logging.getLogger(__name__)

#: one-sided level of the upper bound on the pilot's variance
VARIANCE_BOUND = 0.75
#: candidate ray counts per doubling (before the sampler's rounding)
STEPS_PER_DOUBLING = 4
#: the most further stages a point casts after its final stage (each at least doubles its
#: count, so 16 span any cap from a one-ray final stage)
MAX_STAGES = 16


def candidate_counts(sampler: str, max_rays: int, replicates: int = REPLICATES) -> np.ndarray:
    """(c,) int64 sorted distinct ray counts the sampler casts, from 1 to max_rays (the cap
    itself included, rounded down to a count the sampler casts)."""
    wanted = {1, max_rays}
    x = 1.0
    while x < max_rays:
        wanted.add(int(math.ceil(x)))
        x *= 2.0 ** (1.0 / STEPS_PER_DOUBLING)
    counts = sorted({sample_set(sampler, c, replicates).rays for c in wanted})
    capped = [c for c in counts if c <= max_rays]
    return np.array(capped or [sample_set(sampler, 1, replicates).rays], dtype=np.int64)


def _variance_factor(dof: float) -> float:
    """dof / chi2_{1 - VARIANCE_BOUND}(dof): the upper bound of a variance estimated with dof
    degrees of freedom (Wilson-Hilferty; 1 when there is no spread to bound)."""
    if dof < 1:
        return 1.0
    z = NormalDist().inv_cdf(1.0 - VARIANCE_BOUND)
    a = 2.0 / (9.0 * dof)
    return 1.0 / max(1.0 - a + z * math.sqrt(a), 0.05) ** 3


def _reach(mean, half) -> np.ndarray:
    """How far the interval clip(mean -+ half, 0, 1) reaches from mean."""
    return np.maximum(mean - np.clip(mean - half, 0.0, 1.0), np.clip(mean + half, 0.0, 1.0) - mean)


def rays_needed(pilot: dict, names, n_pilot: int, pilot_dof: float, sampler: str,
                tolerance: float, confidence: float, max_rays: int,
                replicates: int = REPLICATES):
    """Final ray count of each point from its pilot.

    pilot : field name -> (k,) float64 pilot values/stderrs, names : the scalar quantities
    that must meet E (value field, error field) pairs.  Returns (n (k,) int64,
    capped (k,) bool: even max_rays is predicted too few).
    """
    counts = candidate_counts(sampler, max_rays, replicates)
    sets = [sample_set(sampler, int(c), replicates) for c in counts]
    dof = np.array([s.groups - 1 if not s.iid else s.rays - 1 for s in sets], dtype=np.float64)
    t = np.asarray(stats.t_quantile(confidence, np.maximum(dof, 1.0)), dtype=np.float64)
    h0 = stats.rule_of_three(counts, confidence)
    factor = _variance_factor(pilot_dof)
    k = len(next(iter(pilot.values())))
    index = np.zeros(k, dtype=np.int64)
    capped = np.zeros(k, dtype=bool)
    h0_pilot = float(stats.rule_of_three(n_pilot, confidence))
    for value, error in names:
        mean, se = pilot[value], pilot[error]
        no_spread = se == 1.0 / n_pilot  # error_bars' stand-in: every ray or replicate agreed
        s2 = np.where(no_spread, h0_pilot * (1.0 - h0_pilot), n_pilot * np.square(se) * factor)
        # (k, c) predicted reach of the final interval at each candidate count
        half = np.sqrt(np.square(t[None, :]) * s2[:, None] / counts[None, :]
                       + np.square(h0)[None, :])
        ok = _reach(mean[:, None], half) <= tolerance
        first = np.where(ok.any(axis=1), ok.argmax(axis=1), len(counts) - 1)
        capped |= ~ok.any(axis=1)
        index = np.maximum(index, first)
    return counts[index], capped


def estimate(tracer, points, normals, ids, threads, chunk_rays, progress, sizes):
    """The two stages for all points (as ``Tracer.estimate``).

    Returns Estimates: the fields of the final stage, rays (n,) int32 cast in all (pilot +
    final), and the extras of the final stage plus ``final_rays`` (n,) int64 and ``capped``
    (n,) bool, from which :func:`summary` makes the report's section (each point's
    stages depend on that point alone: any split of the points gives the same rows).
    """
    config = tracer.config
    tolerance, max_rays = config.tolerance, config.max_rays
    total = len(points)

    def staged(offset):
        if progress is None:
            return None
        return lambda done, count: progress(min(total, (offset + done) // 2), total)

    first = tracer.estimate(points, normals, ids, threads, chunk_rays, staged(0), sizes=sizes)
    pilot, pilot_rays = first.fields, first.rays
    traced = np.flatnonzero(pilot_rays > 0)
    n_pilot = tracer.samples.rays
    pilot_dof = tracer.samples.rays - 1 if tracer.samples.iid else tracer.samples.groups - 1
    names = [(q.value.name, q.error.name) for q in tracer.quantities if q.interval]
    out = tracer.no_information(normals)
    extras = {name: np.zeros_like(array) for name, array in first.extras.items()}
    if "ray_distances" in extras:
        extras.pop("ray_distances")  # refused up front: one stage's distances would mislead
    rays = pilot_rays.copy()
    final_rays = np.zeros(total, dtype=np.int64)
    capped = np.zeros(total, dtype=bool)
    if len(traced) and names:
        need, capped_t = rays_needed({k: v[traced] for k, v in pilot.items()
                                      if v.ndim == 1}, names, n_pilot, pilot_dof,
                                     config.sampler, tolerance, config.confidence, max_rays,
                                     config.replicates)
        capped[traced] = capped_t
        done = 0
        for n in np.unique(need):
            sel = traced[need == n]
            stage = tracer.with_rays(int(n), stage=1)
            final = stage.estimate(points[sel], normals[sel], ids[sel], threads, chunk_rays,
                                   staged(total + done),
                                   sizes=None if sizes is None else sizes[sel])
            done += len(sel)
            for name, array in final.fields.items():
                out[name][sel] = array
            for name, array in extras.items():
                array[sel] = final.extras[name]
            rays[sel] += final.rays[:]
            final_rays[sel] = final.rays
        further(tracer, points, normals, ids, sizes, threads, chunk_rays, names, traced, out,
                extras, rays, final_rays, capped)
    elif len(traced):  # only bent normals: nothing to meet, the pilot is the bake
        out, final_rays[traced] = pilot, pilot_rays[traced]
        extras = {name: first.extras[name] for name in extras}
    extras.update(final_rays=final_rays, capped=capped)
    # points end with different counts: the fewest degrees of freedom a final stage can have
    return Estimates(out, rays, extras, min_final_dof(config))


def _reach_of(out: dict, tracer, names, sel) -> np.ndarray:
    """(k,) float64 the widest reach of the intervals of points ``sel`` over ``names``."""
    reach = np.zeros(len(sel))
    for value, _ in names:
        q = next(q for q in tracer.quantities if q.value.name == value)
        low, high = out[q.interval[0].name][sel], out[q.interval[1].name][sel]
        v = out[value][sel]
        reach = np.maximum(reach, np.maximum(v - low, high - v))
    return reach


def further(tracer, points, normals, ids, sizes, threads, chunk_rays, names, traced, out,
            extras, rays, final_rays, capped) -> None:
    """Further fresh stages for the points a final stage left wider than E, in place.

    A point whose last stage ends wider than E casts another stage of fresh rays (key
    stream ``stage``, 2, 3, ...): at least twice its last count, more if its last stage's
    spread predicts more (the same rule as from the pilot, with that stage's count and
    degrees of freedom), capped at ``max_rays``; only the new stage's rays make its
    estimate, so given its count it is again an ordinary fixed-count bake.  The stages go
    on until every point meets E or has cast the cap (then it is *capped*: "missed" no
    longer happens), or MAX_STAGES.
    """
    config = tracer.config
    counts = candidate_counts(config.sampler, config.max_rays, config.replicates)
    cap = int(counts[-1])
    for stage_number in range(2, MAX_STAGES + 2):
        reach = _reach_of(out, tracer, names, traced)
        wide = traced[(reach > config.tolerance) & (final_rays[traced] < cap)]
        if not len(wide):
            break
        target = np.zeros(len(wide), dtype=np.int64)
        for last in np.unique(final_rays[wide]):
            group = final_rays[wide] == last
            sel = wide[group]
            last_set = sample_set(config.sampler, int(last), config.replicates)
            dof = last_set.rays - 1 if last_set.iid else last_set.groups - 1
            need, _ = rays_needed({k: v[sel] for k, v in out.items() if v.ndim == 1}, names,
                                  int(last), dof, config.sampler, config.tolerance,
                                  config.confidence, config.max_rays, config.replicates)
            doubled = counts[np.minimum(np.searchsorted(counts, 2 * int(last)),
                                        len(counts) - 1)]
            target[group] = np.maximum(need, doubled)
        for n in np.unique(target):
            sel = wide[target == n]
            stage = tracer.with_rays(int(n), stage=stage_number)
            final = stage.estimate(points[sel], normals[sel], ids[sel], threads, chunk_rays,
                                   None, sizes=None if sizes is None else sizes[sel])
            for name, array in final.fields.items():
                out[name][sel] = array
            for name, array in extras.items():
                array[sel] = final.extras[name]
            rays[sel] += final.rays
            final_rays[sel] = final.rays
    # capped: even the cap was predicted too few, or the stages reached it still wide
    reach = _reach_of(out, tracer, names, traced)
    capped[traced] |= (reach > config.tolerance) & (final_rays[traced] >= cap)


def estimate_blocks(tracer, plan, threads, chunk_rays, progress, folds) -> Estimates:
    """:func:`estimate` of a plan whose sizes are made a block of points at a time
    (``records.BlockSizes``: a set's instances), a block at a time: each block's stages run
    on its points alone (every point's stages depend on that point alone: the same rows as
    one call on all of them) and its rows land in the result (``records.Merged``) with the
    extras ``folds`` takes (the ray offsets, and the final counts into a :class:`Tally`),
    so nothing is held for every point besides the results."""
    from aobake.records import Merged

    points, normals, ids, sizes = plan.points, plan.normals, plan.ids, plan.sizes
    n = len(points)
    result = Merged(n, folds)
    bounds = sizes.bounds
    for k in range(len(bounds) - 1):
        b0, b1 = int(bounds[k]), int(bounds[k + 1])
        if b1 == b0:
            continue
        step = None if progress is None else (lambda done, count, b0=b0: progress(b0 + done, n))
        result.add(b0, b1, estimate(tracer, points[b0:b1], normals[b0:b1], ids[b0:b1], threads,
                                    chunk_rays, step, sizes.block(k)))
    return result.result()


class Tally:
    """What the report's ``tolerance`` section reads of the points, counted a part at a
    time (``add``, a ``records.Merged`` fold of the extras ``final_rays`` and ``capped``),
    never an array per point: the points met, missed and capped, the widest reach, the rays
    in all, and how many points ended at each count (final and in all): the counts take a
    few distinct values, so their min, median and max are exact from the histograms."""

    def __init__(self, tracer):
        self.tracer = tracer
        self.met = self.missed = self.capped = self.traced = self.rays_total = 0
        self.worst = None
        self.final: dict = {}  # final count -> points (traced ones)
        self.cast: dict = {}  # rays in all -> points (traced ones)

    def add(self, start: int, stop: int, part) -> None:
        """Count ``part``'s points (an Estimates of :func:`estimate`)."""
        self.count(part.fields, part.rays, part.extras["final_rays"], part.extras["capped"])

    def count(self, out: dict, rays, final_rays, capped) -> None:
        """Count points of (k,) ``rays``, ``final_rays``, ``capped`` with their fields
        ``out`` (name -> (k, ...))."""
        tracer, tolerance = self.tracer, self.tracer.config.tolerance
        names = [(q.value.name, q.error.name) for q in tracer.quantities if q.interval]
        reach = np.zeros(len(rays))
        for value, _ in names:
            q = next(q for q in tracer.quantities if q.value.name == value)
            low, high = out[q.interval[0].name], out[q.interval[1].name]
            reach = np.maximum(reach, np.maximum(out[value] - low, high - out[value]))
        traced = rays > 0
        met = (reach <= tolerance) & traced
        self.met += int(np.count_nonzero(met))
        self.missed += int(np.count_nonzero(~met & ~capped & traced))
        self.capped += int(np.count_nonzero(~met & capped & traced))
        self.rays_total += int(rays.astype(np.int64).sum())
        if traced.any():
            worst = float(reach[traced].max())
            self.worst = worst if self.worst is None else max(self.worst, worst)
            self.traced += int(np.count_nonzero(traced))
            for histogram, values in ((self.final, final_rays[traced]),
                                      (self.cast, rays[traced])):
                kinds, counts = np.unique(values, return_counts=True)
                for value, count in zip(kinds.tolist(), counts.tolist()):
                    histogram[value] = histogram.get(value, 0) + count

    def result(self) -> "Tally":
        return self

    @classmethod
    def of(cls, tracer, estimates, block: int = 1 << 16) -> "Tally":
        """The tally of merged Estimates whose extras are the (n,) arrays, a block of points
        at a time."""
        tally = cls(tracer)
        out, rays = estimates.fields, estimates.rays
        final_rays, capped = estimates.extras["final_rays"], estimates.extras["capped"]
        for a in range(0, len(rays), block):
            rows = slice(a, a + block)
            tally.count({name: array[rows] for name, array in out.items()}, rays[rows],
                        final_rays[rows], capped[rows])
        return tally


def summary(tracer, estimates) -> dict:
    """The report's ``tolerance`` section from the merged estimates of :func:`estimate` (their
    extras ``final_rays`` and ``capped`` as arrays, or a :class:`Tally` of them)."""
    config = tracer.config
    tolerance, max_rays = config.tolerance, config.max_rays
    tally = estimates.extras["final_rays"]
    if not isinstance(tally, Tally):
        tally = Tally.of(tracer, estimates)
    worst = tally.worst if tally.traced else 0.0
    fixed = max(tally.final) * tally.traced if tally.traced else 0
    section = {
        "tolerance": tolerance,
        "scheme": "a pilot of rays, then fresh rays chosen from its spread, and further "
                  "fresh stages (each at least doubling) for points still wider than the "
                  "tolerance, up to max_rays (aobake.adaptive); only the last stage's rays "
                  "are in the estimate",
        "max_rays": max_rays,
        "pilot_rays_per_point": tracer.samples.rays,
        # Three disjoint counts of the traced points: met E; else capped (even --max-rays
        # was predicted too few); else missed (the pilot under-estimated the spread).
        "points_met": tally.met,
        "points_missed": tally.missed,
        "points_capped": tally.capped,
        "worst_reach": worst,
        "rays_total": tally.rays_total,
        # the last stage's count: the rays in each point's estimate
        "final_rays": _spread(tally.final),
        # every ray a point cast after the pilot (all its stages: a point whose final stage
        # was its third cast the two before it too), and with the pilot
        "rays_after_pilot": _spread(tally.cast, -tracer.samples.rays),
        "rays_per_point": _spread(tally.cast),
        # A fixed count reaching the same worst case: every point at the largest final count
        # (the count the worst point needed), and no pilot.
        "fixed_budget_rays": fixed,
    }
    section["saving_vs_fixed"] = (fixed / section["rays_total"]) if section["rays_total"] \
        else None
    return section


def _spread(histogram: dict, shift: int = 0) -> dict:
    """{"min", "median", "max"} of per-point ray counts plus ``shift``, from ``histogram``
    (count -> points; zeros for no point): np.min's, np.median's and np.max's values of the
    counts' array."""
    if not histogram:
        return {"min": 0, "median": 0.0, "max": 0}
    values = sorted(histogram)
    total = sum(histogram.values())

    def kth(k):  # the k-th smallest count (0-based)
        for value in values:
            k -= histogram[value]
            if k < 0:
                return value
        raise IndexError(k)

    middle = [kth(total // 2)] if total % 2 else [kth(total // 2 - 1), kth(total // 2)]
    median = float(np.median(np.array(middle, dtype=np.int64) + shift))
    return {"min": int(values[0] + shift), "median": median, "max": int(values[-1] + shift)}


def min_final_dof(config) -> int:
    """The fewest degrees of freedom a final stage's stderr can have (texels pool their
    samples' errors with one dof): the smallest count that can meet E must at least have
    its rule-of-three h0 <= E, so no final count is below it (or it is the cap)."""
    counts = candidate_counts(config.sampler, config.max_rays, config.replicates)
    h0 = stats.rule_of_three(counts, config.confidence)
    possible = counts[h0 <= config.tolerance]
    c = int(possible[0]) if len(possible) else int(counts[-1])
    s = sample_set(config.sampler, c, config.replicates)
    return s.rays - 1 if s.iid else s.groups - 1
