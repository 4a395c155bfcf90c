"""Values from a per-vertex bake file (``--method file --ao-from ao.ply``): how a user looks
at a bake, or moves a vertex bake into a lightmap.

No estimate is made: the file's per-vertex values (every scalar ``-q`` quantity it holds:
``ao``, ``obscurance``) are interpolated at each sample point with the barycentric
coordinates of the point on its triangle, which the target gives (``SamplePoints.faces``,
``.bary``: camera pixels and lightmap texels have them).  The file must be a bake of the
same mesh: the same vertices, in the same order (checked by count and by position).
Deterministic, no rays and no stderr: the file's own errors are not carried through an
interpolation (read them from the file).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from aobake.errors import InputError
from aobake.settings.file import FileOptions  # noqa: F401  (the method's settings)
from aobake.records import Estimates
from aobake.vectors import defined


class FileMethod:
    """Per-vertex values of a bake file, interpolated on the surface."""

    name = "file"
    casts_rays = False

    def __init__(self, path: Path, values: dict, faces: np.ndarray):
        """path : the bake file, values : quantity -> (v,) float64 per vertex, faces :
        (f, 3) int64 the scene's triangles."""
        self.path, self.values, self._faces = path, values, faces

    @classmethod
    def prepare(cls, scene, config, occluders, rays_per_point: int,
                compiled: bool | None = None) -> "FileMethod":
        from aobake.outputs import read

        if config.ao_from is None:
            raise InputError("--method file needs --ao-from FILE (a per-vertex bake of the "
                             "mesh)")
        path = Path(config.ao_from)
        wanted = [q for q in config.quantities if q in ("ao", "obscurance")]
        if not wanted:
            raise InputError(f"{path}: --method file reads ao or obscurance; got -q "
                             f"{', '.join(config.quantities)}")
        values = {}
        for quantity in wanted:
            read_values = read(path, quantity, role="reference")
            if read_values.target != "vertices":
                raise InputError(f"{path}: not a per-vertex bake (.npz, .ply, .glb)")
            value = np.asarray(read_values.value, dtype=np.float64)
            if value.shape != (len(scene.vertices),):
                raise InputError(f"{path}: {value.shape[0]} vertices, the mesh "
                                 f"{scene.source} has {len(scene.vertices)}: not a bake of "
                                 "this mesh")
            positions = read_values.positions
            if positions is not None:
                # float32 files (GLB) hold positions to float32's precision
                tol = 4 * np.finfo(np.float32).eps * max(scene.diagonal, 1e-300) + \
                    4 * np.finfo(np.float32).eps * float(np.abs(scene.vertices).max())
                far = float(np.abs(positions - scene.vertices).max())
                if not far <= tol:
                    raise InputError(f"{path}: its vertices are not the mesh's (they differ by "
                                     f"up to {far:.3g}): not a bake of {scene.source}")
            if not np.isfinite(value).all():
                raise InputError(f"{path}: {quantity} holds non-finite values")
            values[quantity] = value
        return cls(path, values, scene.faces)

    def estimate(self, points, threads: int, chunk_rays: int, progress=None) -> Estimates:
        """points : SamplePoints with ``faces`` (n,) int64 and ``bary`` (n, 3) float64."""
        if points.faces is None or points.bary is None:
            raise InputError(f"{self.path}: --method file interpolates on triangles; this "
                             "target gives no triangle per point (use a view or a lightmap)")
        return self.interpolate(points.faces, points.bary, points.normals)

    def interpolate(self, faces: np.ndarray, bary: np.ndarray, normals: np.ndarray) -> Estimates:
        """The values at barycentric ``bary`` (n, 3) of triangles ``faces`` (n,) of the
        scene; 0 where the normal is zero (no point there) or the face is -1 (no triangle:
        the ground plane holds no file values)."""
        fields = {}
        ok = defined(normals) & (faces >= 0)  # -1: a point on no triangle (the ground plane)
        corners = self._faces[np.maximum(faces, 0)]
        for name, value in self.values.items():
            out = np.einsum("nc,nc->n", bary, value[corners])
            fields[name] = np.where(ok, out, 0.0)
        return Estimates(fields, None, {})

    def record(self, estimates: Estimates) -> dict:
        return {"parameters": {"method": self.name, "ao_from": str(self.path),
                               "quantities": sorted(self.values),
                               "interpolation": "barycentric, of the file's per-vertex values"}}

    def error_quantities(self) -> list:
        return []

    def kernel_stages(self) -> dict:
        return {}
