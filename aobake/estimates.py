"""What a method says at sample points (a shared type: methods make it, executors merge
it, targets and the report read it).

Each point's estimate depends on that point alone (its position, normal, size and
sample-stream id), so :func:`merge` of the estimates of any split of the points gives
the same arrays as one call on all of them: that is what lets an executor split a
bake over threads, processes or machines.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Estimates:
    """What a method says at n sample points.

    fields : name -> (n,) / (n, 3) float64 (names of ``aobake.quantities.FIELDS``),
    rays : (n,) int32 rays cast per point, or None for a method that casts none (it then
    reports no ``rays`` field and no stderr: it is deterministic),
    extras : name -> (n, ...) per-point arrays the method's record is made from (the ray
    offset used, kept ray distances, ``--tolerance``'s final counts); merged by index like
    the fields,
    dof : the degrees of freedom of a point's stderr (the fewest any point has: a target
    that pools points' errors, a lightmap's texel, needs it), or None without a stderr.
    """

    fields: dict
    rays: np.ndarray | None
    extras: dict = field(default_factory=dict)
    dof: int | None = None

    def __len__(self) -> int:
        first = next(iter(self.fields.values()), None)
        if first is not None:
            return len(first)
        return 0 if self.rays is None else len(self.rays)

    @property
    def rays_cast(self) -> int | None:
        """Rays traced in all (None for a method that casts none)."""
        return None if self.rays is None else int(self.rays.astype(np.int64).sum())


def merge(parts, n: int) -> Estimates:
    """One Estimates of n points from ``parts``: (index (k,) int64, Estimates of k points)
    pairs that cover 0..n-1 once.  Rows land by index, so the split and the order of the
    parts change nothing."""
    parts = list(parts)
    if not parts:
        raise ValueError("merge needs at least one part")
    first = parts[0][1]

    def like(array):
        return np.empty((n,) + array.shape[1:], dtype=array.dtype)

    fields = {name: like(a) for name, a in first.fields.items()}
    extras = {name: like(a) for name, a in first.extras.items()}
    rays = None if first.rays is None else like(first.rays)
    seen = np.zeros(n, dtype=np.int64)
    for index, part in parts:
        seen[index] += 1
        for name, array in part.fields.items():
            fields[name][index] = array
        for name, array in part.extras.items():
            extras[name][index] = array
        if rays is not None:
            rays[index] = part.rays
    if not (seen == 1).all():
        raise ValueError("merge: the parts must cover every point exactly once")
    dofs = {part.dof for _, part in parts}
    if len(dofs) != 1:  # a property of the method's settings, not of the points
        raise ValueError(f"merge: the parts disagree on their degrees of freedom {dofs}")
    return Estimates(fields, rays, extras, first.dof)
