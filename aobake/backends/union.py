"""Several occluders traced as one: a ray is occluded if any blocks it, its distance the nearest."""

from __future__ import annotations

import numpy as np

#: the four queries of a backend, and whether each returns distances
QUERIES = {"occluded": False, "distance": True, "front_occluded": False, "front_distance": True}


def query_name(need_distance: bool, backfaces: str) -> str:
    """The query a bake needs: distances only for obscurance, front faces only for 'ignore'."""
    return ("front_" if backfaces == "ignore" else "") + ("distance" if need_distance else "occluded")


class Union:
    """occluders : list of backends / occluders answering the same queries."""

    def __init__(self, occluders: list):
        self.occluders = list(occluders)

    def trace(self, query: str, origins, directions, tmax):
        """(occluded (n,) bool, distance (n,) float32 | None) of ``query`` over all occluders."""
        if not QUERIES[query]:
            return self._occluded(query, origins, directions, tmax), None
        results = [getattr(occluder, query)(origins, directions, tmax) for occluder in self.occluders]
        distance = results[0]
        for d in results[1:]:
            distance = np.minimum(distance, d)
        return np.isfinite(distance), distance

    def _occluded(self, query, origins, directions, tmax) -> np.ndarray:
        """(n,) bool any member blocks the ray; a ``selective`` member (a dear one: alpha
        cutouts) is asked only about the rays the members before it left open."""
        occluded = None
        for occluder in self.occluders:
            if occluded is not None and getattr(occluder, "selective", False):
                open_rays = np.flatnonzero(~occluded)
                if len(open_rays):
                    occluded = occluded.copy()  # a member's own array: never written to
                    limit = np.asarray(tmax)
                    limit = limit[open_rays] if limit.ndim else limit
                    occluded[open_rays] = getattr(occluder, query)(
                        origins[open_rays], directions[open_rays], limit)
                continue
            blocked = getattr(occluder, query)(origins, directions, tmax)
            occluded = blocked if occluded is None else (occluded | blocked)
        return occluded
