"""What occludes what: faces selected by the names the input gives them.

Names (``Scene.names``): OBJ ``o`` (kind ``object``), ``g`` (``group``) and ``usemtl``
(``material``); glTF and the other formats read through trimesh: the scene-graph node
(``node``), its mesh (``mesh``) and its material (``material``).  A pattern is a glob
(``fnmatch``, case-sensitive: ``*``, ``?``, ``[abc]``), matched against every kind of name,
or against one kind with a prefix: ``material:glass*``, ``object:floor``.  A face is
selected when one of its names matches.  Faces with no name of a kind are never matched
by that kind (``*`` selects the named faces only).

Three roles (:class:`Selection`):

* ``exclude``: neither baked nor occluding.  The faces are removed from the scene before
  anything is built (every method and target then never sees them; their vertices, now
  unused, are not baked), so an excluded object changes nothing: the bake equals the
  bake of the file without it.
* ``receive_only``: baked, casting nothing (``Scene.occluding``: the occluders are built
  from the other faces alone).  Only methods that trace through the scene's occluders
  honour it (``rays``; a high-to-low projection).
* ``occluder_only``: casting, not baked (its points get a zero normal: no rays; its texels
  are not covered and are filled from their neighbours, its vertices get the
  no-information value).  In a high-to-low bake it is a face of the source the cage rays
  pass through.

``exclude`` wins over the others; a face both ``receive_only`` and ``occluder_only`` is
refused (it would do nothing: say ``exclude``).  A pattern that matches no name is refused
with the names the file has.  The report's ``groups`` lists every name with the faces it
holds in each role.
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass, field, replace

import numpy as np

from aobake.errors import InputError

#: the roles, as the CLI names them
ROLES = ("exclude", "receive_only", "occluder_only")
#: the kinds of names a pattern may be restricted to with a "kind:" prefix
KINDS = ("object", "group", "node", "mesh", "material")


@dataclass(frozen=True)
class Selection:
    """Glob patterns per role (tuples of str)."""

    exclude: tuple = ()
    receive_only: tuple = ()
    occluder_only: tuple = ()

    def __bool__(self) -> bool:
        return any(getattr(self, role) for role in ROLES)


@dataclass
class Applied:
    """A selection applied to a scene.

    scene : the scene to bake (excluded faces removed, ``occluding`` set when some faces
    are receive-only), receiving : (f',) bool its faces that are baked (not occluder-only),
    kept : (f',) int64 the input face of each of its faces, record : the report's
    ``groups``.
    """

    scene: object
    receiving: np.ndarray
    kept: np.ndarray
    record: dict = field(default_factory=dict)


def _split(pattern: str) -> tuple[tuple, str]:
    kind, sep, glob = pattern.partition(":")
    if sep and kind in KINDS:
        return (kind,), glob
    return KINDS, pattern


def match(scene, pattern: str) -> np.ndarray:
    """(f,) bool the faces of ``scene`` one of whose names matches ``pattern``."""
    kinds, glob = _split(pattern)
    selected = np.zeros(len(scene.faces), dtype=bool)
    for kind in kinds:
        if kind not in (scene.names or {}):
            continue
        names, index = scene.names[kind]
        hits = np.array([fnmatch.fnmatchcase(name, glob) for name in names] + [False])
        selected |= hits[index]  # index -1 (no name) reads the trailing False
    return selected


#: names listed per kind in a "matches no face's name" message (then how many more)
LISTED = 20


def _available(scene, pattern: str | None = None) -> str:
    """What a "matches no face's name" message says the file has: every kind's names (the
    first ``LISTED`` of each, and how many more), and for ``pattern``: a ``kind:`` prefix
    that is no kind, a kind the file gives no names, names that differ only in case."""
    names = {kind: given for kind, (given, _) in (scene.names or {}).items() if given}
    notes = []
    if pattern is not None:
        kind, sep, glob = pattern.partition(":")
        if sep and kind not in KINDS and kind.isidentifier():
            notes.append(f"{kind!r} is not a kind of name: the kinds are {', '.join(KINDS)}")
        elif sep and kind in KINDS and names and kind not in names:
            notes.append(f"it gives no face a {kind} name")
        kinds, glob = _split(pattern)
        near = sorted({name for k in kinds for name in names.get(k, ())
                       if fnmatch.fnmatchcase(name.lower(), glob.lower())})
        if near:  # the glob is case-sensitive
            notes.append(f"names are matched case-sensitively; ignoring case it would match "
                         f"{', '.join(map(repr, near[:5]))}{' ...' if len(near) > 5 else ''}")
    if not names:
        listed = "it names no object, group, node, mesh or material"
    else:
        parts = []
        for kind, given in names.items():
            more = len(given) - LISTED
            parts.append(f"{kind} {', '.join(repr(n) for n in given[:LISTED])}"
                         f"{f' and {more} more' if more > 0 else ''}")
        listed = "its names: " + "; ".join(parts)
    return "; ".join(notes + [listed])


def apply(scene, selection: Selection) -> Applied:
    """``selection`` applied to ``scene`` (see the module docstring); InputError for a
    pattern that matches nothing, a face both receive-only and occluder-only, or a
    selection that leaves nothing to bake."""
    masks = {}
    for role in ROLES:
        mask = np.zeros(len(scene.faces), dtype=bool)
        for pattern in getattr(selection, role):
            if not isinstance(pattern, str) or not pattern:
                raise InputError(f"--{role.replace('_', '-')} takes a name pattern, got "
                                 f"{pattern!r}")
            hit = match(scene, pattern)
            if not hit.any():
                raise InputError(f"{scene.source}: --{role.replace('_', '-')} {pattern!r} "
                                 f"matches no face's name ({_available(scene, pattern)})")
            mask |= hit
        masks[role] = mask
    exclude = masks["exclude"]
    receive_only = masks["receive_only"] & ~exclude
    occluder_only = masks["occluder_only"] & ~exclude
    both = receive_only & occluder_only
    if both.any():
        raise InputError(f"{scene.source}: {int(both.sum())} faces are both receive-only and "
                         "occluder-only (they would neither cast nor be baked: --exclude them)")
    kept = np.flatnonzero(~exclude)
    if not len(kept):
        raise InputError(f"{scene.source}: --exclude leaves no face")
    receiving = ~occluder_only[kept]
    if not receiving.any():
        raise InputError(f"{scene.source}: every face left is occluder-only: nothing to bake")
    if receive_only[kept].all():
        raise InputError(f"{scene.source}: every face left is receive-only: nothing occludes")
    out = _subset(scene, kept) if exclude.any() else scene
    if receive_only.any():
        out = replace(out, occluding=~receive_only[kept])
    record = _record(scene, selection, exclude, receive_only, occluder_only)
    return Applied(out, receiving, kept, record)


def _subset(scene, kept: np.ndarray):
    """``scene`` with only the faces ``kept``, made as loading a file of those faces would
    make it (normals and areas computed in the frame of the faces kept, so a bake of it
    equals, bit for bit, the bake of the file without the others when its vertex normals
    are computed; file normals are renormalised); vertices no kept face uses have no normal
    (they are not baked).  The input's warnings and repair record are kept as they were."""
    from aobake.scene import make_scene

    faces = scene.faces[kept]
    names = None if scene.names is None else {
        kind: (names, index[kept]) for kind, (names, index) in scene.names.items()}
    given = scene.normals_source == "file"
    out = make_scene(scene.vertices, faces, scene.vertex_normals if given else None,
                     scene.normals_source, uv=scene.uv,
                     faces_uv=None if scene.faces_uv is None else scene.faces_uv[kept],
                     source=scene.source, materials=scene.materials,
                     face_material=None if scene.face_material is None
                     else scene.face_material[kept], fix_normals="off", names=names)
    used = np.zeros(len(scene.vertices), dtype=bool)
    used[faces.ravel()] = True
    normals = np.where(used[:, None], out.vertex_normals, 0.0)
    return replace(out, vertex_normals=normals, warnings=list(scene.warnings),
                   repair=scene.repair)


def _record(scene, selection, exclude, receive_only, occluder_only) -> dict:
    """The report's ``groups``: the patterns, the face counts per role, and every name with
    its faces in each role."""
    roles = {"excluded": exclude, "receive_only": receive_only, "occluder_only": occluder_only}
    names = []
    for kind, (given, index) in (scene.names or {}).items():
        for i, name in enumerate(given):
            faces = index == i
            entry = {"kind": kind, "name": name, "faces": int(faces.sum())}
            entry.update({role: int(np.count_nonzero(faces & mask))
                          for role, mask in roles.items()})
            entry["baked_and_occluding"] = entry["faces"] - sum(entry[r] for r in roles)
            names.append(entry)
    counts = {"total": int(len(scene.faces))}
    counts.update({role: int(mask.sum()) for role, mask in roles.items()})
    counts["baked"] = counts["total"] - counts["excluded"] - counts["occluder_only"]
    counts["occluding"] = counts["total"] - counts["excluded"] - counts["receive_only"]
    return {"patterns": {role: list(getattr(selection, role)) for role in ROLES},
            "rule": "glob on object/group/node/mesh/material names ('kind:' restricts); "
                    "exclude wins",
            "faces": counts, "names": names}


#: the kinds of names ``--bake`` chooses an OBJ's faces by (``aobake.instances.subset``)
BAKE_KINDS = ("object", "group")


def bake_faces(scene, patterns) -> np.ndarray:
    """(f,) bool the faces of a flat scene (an OBJ) that ``--bake`` ``patterns`` name: a face
    is baked when its object or its group name matches a glob (``object:`` or ``group:``
    restricts it to one kind).  InputError for a pattern of another kind or one that matches
    no face's name (with the names the file has)."""
    chosen = np.zeros(len(scene.faces), dtype=bool)
    for pattern in patterns:
        kind, sep, _ = pattern.partition(":")
        if sep and kind in KINDS and kind not in BAKE_KINDS:
            raise InputError(f"{scene.source}: --bake {pattern!r}: an OBJ's faces are baked "
                             f"by their object or group name ('object:NAME', 'group:NAME'), "
                             f"not by {kind} (--exclude and the other roles take {kind} "
                             "names)")
        hit = match(scene, pattern if sep and kind in BAKE_KINDS else f"object:{pattern}")
        if not (sep and kind in BAKE_KINDS):
            hit |= match(scene, f"group:{pattern}")
        if not hit.any():
            raise InputError(f"{scene.source}: --bake {pattern!r} matches no object or group "
                             f"({_available(scene, pattern)})")
        chosen |= hit
    return chosen


class GroupedTarget:
    """``inner`` (any target) baking only the receiving faces of an :class:`Applied`
    selection: points on occluder-only faces get a zero normal (not traced); a high-to-low
    target projects onto the receiving faces of the source.  Its report gains ``groups``."""

    def __init__(self, inner, applied: Applied):
        self.inner, self.applied = inner, applied
        self.name = inner.name

    def check(self, config) -> None:
        if getattr(self.inner, "check", None):
            self.inner.check(config)

    def rays_per_point(self, config) -> int:
        return self.inner.rays_per_point(config)

    def sample(self, scene, config, occluders, threads, timings, warnings, phase=None):
        receiving = self.applied.receiving
        everything = receiving.all() and scene.occluding is None
        if hasattr(self.inner, "receivers"):  # a high-to-low target: where cage rays land
            if not everything:
                self.inner.receivers = _receivers(scene, config, receiving)
            return self.inner.sample(scene, config, occluders, threads, timings, warnings,
                                     phase)
        plan = self.inner.sample(scene, config, occluders, threads, timings, warnings, phase)
        if receiving.all():
            return plan
        if plan.faces is not None:
            off = plan.faces >= 0
            off[off] = ~receiving[plan.faces[off]]
        elif self.inner.name == "vertices":  # point ids are vertex indices
            baked = np.zeros(len(scene.vertices), dtype=bool)
            baked[scene.faces[receiving].ravel()] = True
            off = ~baked[plan.ids]
        else:
            raise InputError(f"--occluder-only needs a target whose points know their face "
                             f"(not {self.inner.name})")
        normals = plan.normals.copy()
        normals[off] = 0.0
        return replace(plan, normals=normals)

    def finish(self, scene, config, plan, estimates, timings, warnings):
        done = self.inner.finish(scene, config, plan, estimates, timings, warnings)
        report = dict(done.report)
        report["groups"] = self.applied.record
        return replace(done, report=report)


def _receivers(scene, config, receiving: np.ndarray):
    """A builder of the occluders a high-to-low projection lands on: the receiving faces
    (receive-only ones included), no ground plane."""
    from aobake import occluders as stage

    def build(_built):
        flat = replace(config, ground_plane=False)
        return stage.build(replace(scene, occluding=receiving), flat)
    return build


def dark_warning(estimates, source) -> str | None:
    """A warning when no baked point sees anything (AO, or obscurance, is 0 at every point
    that cast rays): an occluder setup that covers everything (a ground plane or an
    occluder-only shell around the bake, faces turned inward) rather than a result."""
    fields, rays = estimates.fields, estimates.rays
    for name in ("ao", "obscurance"):
        if name not in fields:
            continue
        # a block of points at a time (no (n,) mask, no copy of the values)
        values, block, baked, seen = fields[name], 1 << 16, 0, False
        for start in range(0, len(values), block):
            part = values[start:start + block]
            if rays is not None:
                part = part[rays[start:start + block] > 0]
            baked += len(part)
            seen = seen or bool(np.any(part > 0))
        if baked and not seen:
            return (f"{source}: {name} is 0 at every one of the {baked} points baked: "
                    "every ray is blocked (check --receive-only / --occluder-only, the ground "
                    "plane, and faces turned inward)")
    return None
