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
        results = [getattr(occluder, query)(origins, directions, tmax) for occluder in self.occluders]
        if QUERIES[query]:
            distance = results[0]
            for d in results[1:]:
                distance = np.minimum(distance, d)
            return np.isfinite(distance), distance
        occluded = results[0]
        for o in results[1:]:
            occluded = occluded | o
        return occluded, None
