"""Tracing backends: name -> class (see ``aobake.backends.base`` for the protocol).

The CLI's ``--backend`` choices come from ``BACKENDS``.
"""

from aobake.backends.embree import EmbreeBackend
from aobake.backends.reference import ReferenceBackend

#: backend name -> class built as cls(local vertices, faces, face_normals, step)
BACKENDS = {"embree": EmbreeBackend, "reference": ReferenceBackend}
