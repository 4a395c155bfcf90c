"""Tracing backends: name -> class (see ``aobake.backends.base`` for the protocol).

The CLI's ``--backend`` choices come from ``BACKENDS``.  ``warp`` is always a choice; its
module imports Warp only when a backend is built, and building one where the ``warp`` extra
is not installed is an InputError naming it (``unavailable(name)`` says so beforehand).
"""

from aobake.backends.embree import EmbreeBackend
from aobake.backends.reference import ReferenceBackend
from aobake.backends.warp import WarpBackend

#: backend name -> class built as cls(local vertices, faces, face_normals, step)
BACKENDS = {"embree": EmbreeBackend, "reference": ReferenceBackend, "warp": WarpBackend}

def unavailable(name: str) -> str | None:
    """Why backend ``name`` cannot run on this machine (the message to show), or None if it
    can, from the class's own ``unavailable()`` where it has one (a missing optional extra:
    ``warp``); the check imports nothing heavy, so it can run before any work."""
    check = getattr(BACKENDS[name], "unavailable", None)
    return None if check is None else check()
