"""Bake one file: plan the outputs, pick the target, refuse what cannot run, bake, write.

The one way a mesh file becomes output files: the main command, ``aobake view`` and
``aobake batch`` all call :func:`plan` and :meth:`Job.run` (or :func:`bake_file`, both in
one), so a rule about a request (``--keep-distances`` needs ``.npz``, ``--denoise`` an
``.exr`` lightmap, a method the target cannot serve, an output over an input) is written
once and holds for every command and for the library.

Everything decidable from the request is checked in :func:`plan`, before any file is
loaded: the settings (``BakeConfig``), the method against the target
(``aobake.capabilities``), the output paths against every file the bake reads
(``aobake.outputs.plan``), an ``--orm-from`` texture's size.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from aobake import capabilities
from aobake.settings import INPUT_FILES, BakeConfig
from aobake.errors import InputError, UsageError



@dataclass
class Job:
    """A checked request to bake ``mesh`` into ``outputs`` (``aobake.outputs.Outputs``).

    config : the validated BakeConfig; target : the ``TARGETS`` name that will run
    (``projected_texels`` / ``projected_vertices`` with ``--from``); method : the
    ``METHODS`` name; write : ``aobake.write``'s format options; view : the camera
    keywords of a view (camera, look, gltf, size, fov) or None; truths : a view of
    ``bake_view_truths``; run : ``aobake.run``'s keywords (threads, executor, ...).
    """

    mesh: object
    config: BakeConfig
    outputs: object
    target: str
    method: str
    write: dict = field(default_factory=dict)
    view: dict | None = None
    truths: bool = False
    run: dict = field(default_factory=dict)

    def _target(self):
        from aobake.targets import TARGETS

        if self.view is not None:
            return TARGETS["view"](self.view.get("camera"), look=self.view.get("look"),
                                   gltf=self.view.get("gltf"),
                                   size=self.view.get("size", (960, 540)),
                                   fov=self.view.get("fov", 40.0))
        if self.config.source is not None:  # high-to-low: MESH is the low mesh
            from aobake.api import projected_target

            return projected_target(self.config, self.outputs.target, self.mesh)
        return TARGETS[self.target]()

    def bake(self, progress=None):
        """The result of the bake (``BakeResult`` / ``TexelResult`` / ``ViewResult``)."""
        from aobake import api

        if self.truths:
            view = dict(self.view)
            return api.bake_view_truths(self.mesh, self.config, camera=view.pop("camera", None),
                                        look=view.pop("look", None), gltf=view.pop("gltf", None),
                                        size=view.pop("size", (960, 540)),
                                        fov=view.pop("fov", 40.0), method=self.method,
                                        **self.run)
        scene = self.config.source if self.config.source is not None else self.mesh
        unwrapping = None
        if self.target == "texels" and self.config.unwrap != "never":
            from aobake.targets.texels import unwrap as unwrapping

            unwrapping.prestart()  # its start overlaps the loading; ended if own UVs are baked
        try:
            return api.run(self.config, scene, self._target(), progress=progress,
                           method=self.method, **self.run)
        finally:
            if unwrapping is not None:
                unwrapping.discard_prestarted()

    def save(self, result) -> list[Path]:
        """Write ``result`` to the planned outputs (one transaction); the paths written."""
        from aobake.outputs import write

        o = self.outputs
        return write(result, o.out, mesh_out=o.mesh_out if o.mesh_out_given else None,
                     report=o.report, mesh=self.mesh, **self.write)

    def __call__(self, progress=None):
        """Bake and write: (result, paths written)."""
        result = self.bake(progress)
        return result, self.save(result)


def plan(mesh, out, config: BakeConfig | dict | None = None, *, target: str | None = None,
         method: str | None = None, view: dict | None = None, truths: bool = False,
         mesh_out=None, report=None, half: bool = False, bit_depth: int = 8,
         r_only: bool = False, orm: bool = False, orm_from=None, given=None, **run) -> Job:
    """Check a request to bake ``mesh`` into ``out`` before any work; the :class:`Job`.

    config : BakeConfig or its fields as a dict; target : 'vertices' | 'texels' | None
    (from ``out``'s extension); method : a ``METHODS`` name, or None: the one the config
    implies (``file`` with ``ao_from``, else ``rays``: ``capabilities.implied_method``);
    view : camera keywords for a view (``camera``, ``look``, ``gltf``, ``size``, ``fov``:
    ``bake_view``'s) or None;
    truths : bake ``bake_view_truths``; mesh_out, report, half, bit_depth, r_only, orm,
    orm_from : ``aobake.write``'s; given : the names of the settings given one by one
    (default: a dict config's keys; ``capabilities.check``); run : ``aobake.run``'s
    keywords.
    Raises InputError / OutputError naming the problem.
    """
    from aobake import outputs

    if given is None:
        given = tuple(config or ()) if config is None or isinstance(config, dict) else ()
    if config is None or isinstance(config, dict):
        config = BakeConfig(**(config or {}))
    elif not isinstance(config, BakeConfig):
        raise InputError(f"config must be a BakeConfig or a dict, got {type(config).__name__}")
    method = capabilities.implied_method(method, config)
    orm = orm or orm_from is not None
    reads = {flag: getattr(config, name) for name, flag in INPUT_FILES.items()
             if getattr(config, name) is not None}
    if orm_from is not None:
        reads["--orm-from"] = orm_from
    for flag, path in reads.items():
        if not Path(path).is_file():
            raise InputError(f"{path}: no such file ({flag})")
    kind = "view" if view is not None else target
    where = outputs.plan(out, kind, mesh=mesh, mesh_out=mesh_out, report=report,
                         quantities=config.quantities, inputs=reads, orm=orm,
                         keep_distances=config.keep_distances, denoise=config.denoise,
                         half=half, bit_depth=bit_depth, r_only=r_only)
    name = where.target
    if config.source is not None:
        if name not in ("vertices", "texels"):
            raise UsageError(f"--from bakes onto a low mesh's vertices or lightmap, not {name}")
        name = f"projected_{name}"
    capabilities.check(method, name, config, given)
    if orm_from is not None and config.texel_density is None:
        from aobake.outputs.orm import check_source

        check_source(orm_from, config.resolution)  # before the bake, not after
    write = dict(half=half, bit_depth=int(bit_depth), r_only=r_only, orm=orm,
                 orm_from=orm_from)
    if where.target == "view":
        write = dict(half=half, bit_depth=int(bit_depth))
    return Job(mesh, config, where, name, method, write, view, truths, run)


def bake_file(mesh, out, config: BakeConfig | dict | None = None, *, progress=None,
              **request):
    """Bake ``mesh`` into ``out`` as the command line does: :func:`plan`, bake, write.

    ``request`` : :func:`plan`'s keywords.  Returns (result, paths written, ``out`` first).
    """
    return plan(mesh, out, config, **request)(progress)
