"""The fast approximations scored against the ray-traced truth (issue 22, section 3).

    python benchmarks/bench_approximations.py [--meshes still_life,bunny] [--points N]
        [--truth-rays 2048] [--multi-rays 1024] [--threads 2] [--hemicube-points 1000]
        [--parts rays,discs,hemicube,depthmaps,multibounce]
        [--work /tmp/aobake_approx] [--json PATH] [--plot docs/img/approx_error_vs_time.png]
        [--views docs/img/approx_views.png] [--quick] [--merge RUN.json ...]

Points: per mesh, ``--points`` points (default: as many as the mesh has vertices, the size
of a per-vertex bake) drawn uniformly by area on its triangles with a fixed seed, at their
triangles' normals and sizes (surface points rather than vertices: the still life's slabs
are separate patches whose rim vertices lie in their neighbours' planes, where AO is not
defined and methods disagree by up to 1; ``bench_hemicube.query_points`` says more).

Truth: ``aobake.bake_points(..., rays=--truth-rays, seed=1001, quantities=(ao, indirect),
albedo=0.5)`` at those points, written to an NPZ.  Every candidate is written to an NPZ
too and scored with ``aobake.compare.compare`` (docs/compare.md): RMSE, bias (candidate
minus truth), max error, ``rmse_in_reference_se`` (the RMSE in units of the truth's own rms
stderr) and ``rmse_without_reference_noise`` (the candidate's own error against the exact
values, its noise included: the truth's noise taken out; compare's ``excess_rmse`` also
takes out the noise a candidate states, which for a rays bake is the whole point of the
curve).

Candidates:
- ``rays`` at 4 .. 1024 rays (seed 1): the baseline curve, for ``ao`` and ``indirect``;
- ``discs`` per kappa (1, 2, 4, 8) and per pass (pass 1 alone, pass 2, the CD's 0.6/0.4
  weighting of the two), and its indirect light per kappa (2, 4, 8; brute force where the
  mesh has at most 25,000 elements) and per pass (1, 2; 3 at kappa 4);
- ``hemicube`` per resolution (16, 32, 64) when ``"hemicube" in aobake.methods.METHODS`` and
  an EGL context can be made, on ``--hemicube-points`` of the points (a fixed subset: it
  costs milliseconds per point), scored against the truth at those points; its time is
  the fixed cost (a call on 8 points: the GL child's start, the mesh's upload) plus the
  drawing of the subset scaled to all the points;
- ``depthmaps`` per direction count K (16, 64, 256, 1024) at its default resolution and bias
  when ``"depthmaps" in aobake.methods.METHODS`` and a GL 4.3 context can be made, on all
  the points (its cost is K x (triangles + points): the whole call is timed);
- the GTAO multi-bounce fit (Jimenez et al. 2016) ``a' = max(a, ((a A + B) a + C) a)``,
  A = 2.0404 rho - 0.3324, B = -4.7951 rho + 0.6417, C = 2.7552 rho + 0.6903, applied to the
  truth's own AO, against the ray-traced multi-bounce "visibility" ``ao + indirect`` with
  ``--bounces 8`` (rho = 0.5 and 0.8; ``--multi-rays`` rays, seed 1002): GTAO's convention
  counts the light bounced onto a point as visibility.  Beside it: plain AO (no fit) and the
  discs' own ``ao + indirect`` with 8 bounces.  The reference's stderr there is
  sqrt(se_ao^2 + se_indirect^2), an upper bound (a ray adds to one or the other, never both,
  so the two estimates are negatively correlated).

Time: wall-clock seconds of the whole estimate on ``--threads`` threads, the scene already
loaded (``rays``: ``bake_points``, so its BVH and the tracing; ``discs``: prepare (elements,
tree, the elements' passes) and the estimate; ``hemicube``: as above).  ``--parts`` runs
some of rays, discs, hemicube, multibounce (all by default).  The machine is shared (2
cores, other jobs running): absolute times are pessimistic and varied by up to 3.5x
between runs (``--merge`` keeps each row's least); errors are deterministic
(approximations) or seeded.

``--views``: ``aobake view`` of the still life (256 x 144, a camera close to the objects):
the truth (1024 rays per pixel), 16 rays, discs, hemicube (R = 32), their errors, and
indirect light (truth, discs, error), side by side in one PNG.  ``--merge`` runs nothing:
it prints the tables of saved runs and makes ``--plot`` from them.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import aobake  # noqa: E402
from aobake.compare import compare  # noqa: E402
from aobake.settings import BakeConfig  # noqa: E402
from aobake.methods import METHODS  # noqa: E402
from aobake.methods.discs import DiscsMethod, DiscsOptions  # noqa: E402
from aobake.scene import load_scene  # noqa: E402
from aobake.records import SamplePoints  # noqa: E402
from aobake.trace import DEFAULT_CHUNK_RAYS  # noqa: E402
from aobake.vectors import defined  # noqa: E402

MESHES = {
    "still_life": ROOT / "assets" / "still_life.obj",
    "bunny": ROOT.parent / "shared" / "meshes" / "stanford-bunny.obj",
    "ogre": ROOT.parent / "shared" / "meshes" / "ogre.obj",
}
RAY_COUNTS = (4, 8, 16, 32, 64, 128, 256, 512, 1024)
KAPPAS = (1.0, 2.0, 4.0, 8.0)
INDIRECT_KAPPAS = (2.0, 4.0, 8.0)
RESOLUTIONS = (16, 32, 64)
DEPTHMAP_DIRECTIONS = (16, 64, 256, 1024)
ALBEDOS = (0.5, 0.8)
#: the most elements for which brute force (O(n^2)) is run
BRUTE_ELEMENTS = 25000
ALBEDO = 0.5


def gtao_multibounce(ao: np.ndarray, albedo: float) -> np.ndarray:
    """Jimenez et al. 2016 (GTAO), section 5: the cubic fit of multi-bounce visibility to
    AO and albedo, never below the AO itself.  ao (n,) in [0, 1] -> (n,)."""
    a = 2.0404 * albedo - 0.3324
    b = -4.7951 * albedo + 0.6417
    c = 2.7552 * albedo + 0.6903
    return np.maximum(ao, ((ao * a + b) * ao + c) * ao)


def query_points(scene, n: int, seed: int = 1):
    """n points drawn uniformly by area on the scene's triangles (seeded), with their
    triangles' normals and sizes (sqrt of twice the area)."""
    areas = scene.areas()
    rng = np.random.default_rng(seed)
    face = rng.choice(len(areas), size=n, p=areas / areas.sum())
    u = rng.random((n, 2))
    flip = u.sum(axis=1) > 1
    u[flip] = 1 - u[flip]
    corners = scene.vertices[scene.faces[face]]
    points = corners[:, 0] + u[:, :1] * (corners[:, 1] - corners[:, 0]) \
        + u[:, 1:] * (corners[:, 2] - corners[:, 0])
    normals = scene.face_normals[face]
    keep = defined(normals)
    return points[keep], normals[keep], np.sqrt(2 * areas[face])[keep]


def hemicube_available() -> tuple[bool, str]:
    if "hemicube" not in METHODS:
        return False, "no hemicube method registered"
    from aobake.methods.hemicube import available

    return available()


class Bench:
    def __init__(self, name, path, args):
        self.name, self.args = name, args
        self.work = Path(args.work) / name
        self.work.mkdir(parents=True, exist_ok=True)
        self.scene = load_scene(str(path))
        n = args.points or len(self.scene.vertices)
        self.points, self.normals, self.sizes = query_points(self.scene, n)
        self.rows = []

    def bake(self, **options):
        """(result, seconds) of bake_points at the points."""
        clock = time.perf_counter()
        result = aobake.bake_points(self.scene, self.points, self.normals,
                                    point_sizes=self.sizes, threads=self.args.threads,
                                    **options)
        return result, time.perf_counter() - clock

    def score(self, reference, family, setting, quantity, values, seconds, stderr=None,
              note=""):
        """Write the candidate's values and score them with aobake compare."""
        path = self.work / f"cand_{family}_{setting}_{quantity}.npz".replace(" ", "_")
        arrays = {"ao": np.asarray(values, dtype=np.float64)}
        if stderr is not None:
            arrays["ao_stderr"] = stderr
        np.savez(path, **arrays)
        m = compare(reference, path, quantity="ao")
        row = {"mesh": self.name, "family": family, "setting": setting, "quantity": quantity,
               "n": m["n"], "seconds": seconds, "rmse": m["rmse"], "bias": m["bias"],
               "max_error": m["max_error"], "rmse_in_se": m["rmse_in_reference_se"],
               "excess_rmse": m["rmse_without_reference_noise"], "note": note}
        self.rows.append(row)
        return row

    def reference(self, tag, values, stderr, index=None):
        """An NPZ of reference values (key ``ao`` whatever the quantity: compare reads it)."""
        path = self.work / f"ref_{tag}.npz"
        if index is not None:
            values, stderr = values[index], stderr[index]
        np.savez(path, ao=values, ao_stderr=stderr)
        return path

    def run(self):
        args = self.args
        n = len(self.points)
        print(f"\n== {self.name}: {n} points, {len(self.scene.vertices)} vertices, "
              f"{len(self.scene.faces)} triangles", flush=True)
        truth, t_truth = self.bake(rays=args.truth_rays, seed=1001,
                                   quantities=("ao", "indirect"), albedo=ALBEDO)
        print(f"truth: {args.truth_rays} rays, {t_truth:.1f} s; rms stderr ao "
              f"{np.sqrt(np.mean(truth.ao_stderr ** 2)):.4f}, indirect "
              f"{np.sqrt(np.mean(truth.indirect_stderr ** 2)):.4f}; means ao "
              f"{truth.ao.mean():.4f}, indirect {truth.indirect.mean():.4f}", flush=True)
        self.truth_seconds = t_truth
        ref = {"ao": self.reference("ao", truth.ao, truth.ao_stderr),
               "indirect": self.reference("indirect", truth.indirect, truth.indirect_stderr)}
        parts = args.parts.split(",")
        if "rays" in parts:
            self.rays(ref)
        if "discs" in parts:
            self.discs(ref)
        if "hemicube" in parts:
            self.hemicube(truth)
        if "depthmaps" in parts:
            self.depthmaps(ref)
        if "multibounce" in parts:
            self.multibounce(truth)
        return self.rows

    def rays(self, ref):
        for quantity in ("ao", "indirect"):
            for rays in RAY_COUNTS:
                result, seconds = self.bake(rays=rays, seed=1, quantities=(quantity,),
                                            albedo=ALBEDO)
                self.score(ref[quantity], "rays", f"{rays}", quantity,
                           getattr(result, quantity), seconds)
            print(f"rays {quantity}: done", flush=True)

    def _discs(self, quantities, albedo=ALBEDO, bounces=1, **options):
        """(estimates, seconds, method) of the disc method at the points."""
        config = BakeConfig(quantities=quantities, albedo=albedo, bounces=bounces)
        clock = time.perf_counter()
        method = DiscsMethod.prepare(self.scene, config, None, 0,
                                     options=DiscsOptions(**options))
        est = method.estimate(SamplePoints(self.points, self.normals,
                                           np.arange(len(self.points), dtype=np.int64)),
                              self.args.threads, DEFAULT_CHUNK_RAYS)
        return est, time.perf_counter() - clock, method

    def discs(self, ref):
        for kappa in KAPPAS:
            est, seconds, _ = self._discs(("ao",), discs_kappa=kappa, discs_passes=1)
            self.score(ref["ao"], "discs", f"kappa {kappa:g} pass 1", "ao", est.fields["ao"],
                       seconds)
            est, seconds, _ = self._discs(("ao",), discs_kappa=kappa)
            passes = est.extras["discs_passes"]
            self.score(ref["ao"], "discs", f"kappa {kappa:g} pass 2", "ao", passes[:, 1],
                       seconds)
            self.score(ref["ao"], "discs", f"kappa {kappa:g} weighted", "ao",
                       est.fields["ao"], seconds, note="0.6 pass 2 + 0.4 pass 1 (default)")
            print(f"discs ao kappa {kappa:g}: {seconds:.1f} s", flush=True)
        settings = [(f"kappa {k:g}", dict(discs_kappa=k)) for k in INDIRECT_KAPPAS]
        if len(self.scene.vertices) <= BRUTE_ELEMENTS:
            settings.append(("brute", dict(discs_traversal="brute")))
        for label, options in settings:
            est, seconds, _ = self._discs(("indirect",), **options)
            passes = est.extras["discs_indirect_passes"]
            self.score(ref["indirect"], "discs", f"{label} pass 1", "indirect", passes[:, 0],
                       seconds)
            self.score(ref["indirect"], "discs", f"{label} pass 2", "indirect",
                       est.fields["indirect"], seconds, note="default")
            print(f"discs indirect {label}: {seconds:.1f} s", flush=True)
        est, seconds, _ = self._discs(("indirect",), discs_indirect_passes=3)
        passes = est.extras["discs_indirect_passes"]
        self.score(ref["indirect"], "discs", "kappa 4 pass 3", "indirect", passes[:, 2],
                   seconds)
        self.score(ref["indirect"], "discs", "kappa 4 passes 2+3", "indirect",
                   0.5 * (passes[:, 1] + passes[:, 2]), seconds, note="0.5 each")

    def hemicube(self, truth):
        ok, why = hemicube_available()
        self.hemicube_status = why
        if not ok:
            print(f"hemicube skipped: {why}", flush=True)
            return
        n = len(self.points)
        k = min(self.args.hemicube_points, n)
        index = np.sort(np.random.default_rng(7).choice(n, size=k, replace=False))
        ref = self.reference("ao_hemicube_subset", truth.ao, truth.ao_stderr, index)

        def run(where, resolution):
            clock = time.perf_counter()
            result = aobake.bake_points(self.scene, self.points[where], self.normals[where],
                                        point_sizes=self.sizes[where],
                                        threads=self.args.threads, method="hemicube",
                                        hemicube_resolution=resolution)
            return result, time.perf_counter() - clock

        for resolution in RESOLUTIONS:
            # the fixed cost (the GL child's start, the mesh's upload) from a call on 8
            # points; the drawing scales with the points
            _, fixed = run(index[:8], resolution)
            result, seconds = run(index, resolution)
            whole = fixed + max(0.0, seconds - fixed) * n / k
            self.score(ref, "hemicube", f"R {resolution}", "ao", result.ao, whole,
                       note=f"{k} of the points; time {fixed:.2f} s + drawing x {n / k:.1f}")
            print(f"hemicube R {resolution}: {seconds:.1f} s for {k} points ({fixed:.1f} s "
                  f"for 8); {whole:.1f} s for {n}", flush=True)

    def depthmaps(self, ref):
        if "depthmaps" not in METHODS:
            print("depthmaps skipped: not registered", flush=True)
            return
        from aobake.methods.depthmaps import available

        ok, why = available()
        if not ok:
            print(f"depthmaps skipped: {why}", flush=True)
            return
        for k in DEPTHMAP_DIRECTIONS:
            result, seconds = self.bake(method="depthmaps", depthmaps_directions=k)
            self.score(ref["ao"], "depthmaps", f"K {k}", "ao", result.ao, seconds,
                       note="N 1024, b 1 (the defaults)")
            print(f"depthmaps K {k}: {seconds:.1f} s", flush=True)

    def multibounce(self, truth):
        for albedo in ALBEDOS:
            multi, seconds = self.bake(rays=self.args.multi_rays, seed=1002,
                                       quantities=("ao", "indirect"), albedo=albedo,
                                       bounces=8)
            se = np.sqrt(multi.ao_stderr ** 2 + multi.indirect_stderr ** 2)
            ref = self.reference(f"multibounce_{albedo:g}", multi.ao + multi.indirect, se)
            tag = f"rho {albedo:g}"
            self.score(ref, "gtao", f"{tag} plain ao", "ao+indirect8", truth.ao,
                       self.truth_seconds, note="the truth's AO, no fit")
            self.score(ref, "gtao", f"{tag} fit", "ao+indirect8",
                       gtao_multibounce(truth.ao, albedo), self.truth_seconds,
                       note="fit applied to the truth's AO")
            est, t_discs, _ = self._discs(("ao", "indirect"), albedo=albedo, bounces=8)
            self.score(ref, "discs", f"{tag} ao+indirect 8 bounces", "ao+indirect8",
                       est.fields["ao"] + est.fields["indirect"], t_discs)
            self.score(ref, "gtao", f"{tag} fit of discs ao", "ao+indirect8",
                       gtao_multibounce(est.fields["ao"], albedo), t_discs)
            print(f"multi-bounce truth rho {albedo:g}: {seconds:.1f} s; mean ao + indirect "
                  f"{(multi.ao + multi.indirect).mean():.4f}", flush=True)


def merge(paths) -> tuple[list, list]:
    """Rows of several runs' JSON files: each row's errors from the last file that has it,
    its seconds the least over the files (wall-clock on a shared machine: the least is the
    one least disturbed by other jobs).  Returns (rows, meshes in first-seen order)."""
    rows, seconds, meshes = {}, {}, []
    for path in paths:
        for row in json.loads(Path(path).read_text())["rows"]:
            key = (row["mesh"], row["family"], row["setting"], row["quantity"])
            rows[key] = dict(row)
            seconds[key] = min(seconds.get(key, math.inf), row["seconds"])
            if row["mesh"] not in meshes:
                meshes.append(row["mesh"])
    for key, row in rows.items():
        row["seconds"] = seconds[key]

    def order(row):  # per mesh; the ray counts in order first, the rest as they came
        rays = row["family"] == "rays"
        return (meshes.index(row["mesh"]), not rays, int(row["setting"]) if rays else 0)

    return sorted(rows.values(), key=order), meshes


def table(rows, compact: bool = False) -> str:
    """A markdown table of rows (``compact``: without the mesh and quantity columns)."""
    lead = ("method", "setting") if compact else ("mesh", "method", "setting", "quantity")
    head = "| " + " | ".join(lead) + " | s | RMSE | bias | max | RMSE / truth se | excess RMSE |"
    lines = [head, "|" + "---|" * len(lead) + "---:|" * 6]
    for r in rows:
        cells = (r["family"], r["setting"]) if compact else (r["mesh"], r["family"],
                                                             r["setting"], r["quantity"])
        lines.append(f"| {' | '.join(cells)} | {r['seconds']:.2f} | {r['rmse']:.4f} | "
                     f"{r['bias']:+.4f} | {r['max_error']:.3f} | {r['rmse_in_se']:.1f} | "
                     f"{r['excess_rmse']:.4f} |")
    return "\n".join(lines)


def plot(rows, path, meshes):
    """Error (RMSE with the truth's own noise taken out: compare's
    ``rmse_without_reference_noise``, stored here as ``excess_rmse``) against seconds,
    per mesh (rows) for ao and indirect (columns); the ray-traced curve on every panel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    quantities = ("ao", "indirect")
    fig, axes = plt.subplots(len(meshes), 2, figsize=(11, 4.2 * len(meshes)), squeeze=False)

    def shown(r):  # the defaults per kappa (and brute force); hemicube, depthmaps per setting
        if r["family"] == "discs":
            default_indirect = r["quantity"] == "indirect" and r["setting"] in (
                "kappa 2 pass 2", "kappa 4 pass 2", "kappa 8 pass 2", "brute pass 2")
            return r["setting"].endswith("weighted") or default_indirect
        return r["family"] in ("hemicube", "depthmaps")

    style = {"discs": ("s", "tab:orange"), "hemicube": ("^", "tab:green"),
             "depthmaps": ("D", "tab:purple")}
    for i, mesh in enumerate(meshes):
        for j, quantity in enumerate(quantities):
            ax = axes[i][j]
            mine = [r for r in rows if r["mesh"] == mesh and r["quantity"] == quantity]
            rays = [r for r in mine if r["family"] == "rays"]
            ax.plot([r["seconds"] for r in rays], [r["excess_rmse"] for r in rays], "o-",
                    color="tab:blue", label="rays (4 .. 1024 per point)")
            for r in rays:
                ax.annotate(r["setting"], (r["seconds"], r["excess_rmse"]), fontsize=7,
                            xytext=(3, 3), textcoords="offset points", color="tab:blue")
            for family, (marker, colour) in style.items():
                pts = [r for r in mine if r["family"] == family and shown(r)]
                if not pts:
                    continue
                ax.plot([r["seconds"] for r in pts], [r["excess_rmse"] for r in pts], marker,
                        color=colour, linestyle="none", label=family)
                for r in pts:
                    label = r["setting"].replace(" weighted", "").replace(" pass 2", "")
                    ax.annotate(label, (r["seconds"], r["excess_rmse"]), fontsize=7,
                                xytext=(3, -9), textcoords="offset points", color=colour)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel("seconds for all the points (2 shared cores)")
            ax.set_ylabel(f"{quantity}: RMSE against the truth (its noise removed)")
            ax.set_title(f"{mesh}: {quantity}")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    print(f"wrote {path}")


def views(path, threads, hemicube_ok):
    """Truth, methods and errors of the still life's default view, composed with PIL."""
    from PIL import Image, ImageDraw

    mesh = str(MESHES["still_life"])
    size = (256, 144)
    look = dict(look_from=(1.25, 1.0, 1.6), look_at=(0.0, 0.12, 0.0))  # the objects, close
    clock = time.perf_counter()
    truth = aobake.bake_view(mesh, rays=1024, seed=11, quantities=("ao", "indirect"),
                             size=size, look=look, threads=threads)
    print(f"view truth: {time.perf_counter() - clock:.1f} s", flush=True)
    covered = truth.covered
    panels = {"truth (1024 rays)": truth.channels["ao"]}
    candidates = {"rays (16)": dict(rays=16, seed=12),
                  "discs": dict(method="discs", quantities=("ao", "indirect"))}
    if hemicube_ok:
        candidates["hemicube (R 32)"] = dict(method="hemicube", hemicube_resolution=32)
    results = {}
    for label, options in candidates.items():
        clock = time.perf_counter()
        results[label] = aobake.bake_view(mesh, size=size, look=look, threads=threads,
                                          **options)
        print(f"view {label}: {time.perf_counter() - clock:.1f} s", flush=True)
        panels[label] = results[label].channels["ao"]
    scale = 0.25  # error maps: +-0.25 saturates

    def grey(values, gain=1.0):
        v = np.clip(np.where(covered, values * gain, 0.0), 0, 1)
        img = (v * 255).round().astype(np.uint8)
        rgb = np.stack([img] * 3, axis=-1)
        rgb[~covered] = (40, 40, 60)
        return Image.fromarray(rgb)

    def error(values, quantity="ao"):
        return diverging(np.clip(np.where(covered, values - truth.channels[quantity], 0.0)
                                 / scale, -1, 1))

    def diverging(e):
        r = np.where(e > 0, 1.0, 1.0 + e)
        b = np.where(e < 0, 1.0, 1.0 - e)
        g = 1.0 - np.abs(e)
        rgb = (np.stack([r, g, b], axis=-1) * 255).round().astype(np.uint8)
        rgb[~covered] = (40, 40, 60)
        return Image.fromarray(rgb)

    gain = 4.0  # indirect light is small: shown x4
    rows = [[(label, grey(values)) for label, values in panels.items()],
            [("", None)] + [(f"{label} - truth", error(results[label].channels["ao"]))
                            for label in candidates],
            [(f"indirect truth (x{gain:g})", grey(truth.channels["indirect"], gain)),
             (f"indirect discs (x{gain:g})", grey(results["discs"].channels["indirect"], gain)),
             ("indirect discs - truth", error(results["discs"].channels["indirect"],
                                              "indirect"))]]
    w, h = size
    label_h = 16
    cols = max(len(r) for r in rows)
    sheet = Image.new("RGB", (cols * w, len(rows) * (h + label_h) + 20), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for i, row in enumerate(rows):
        for j, (label, image) in enumerate(row):
            x, y = j * w, i * (h + label_h)
            if image is not None:
                sheet.paste(image, (x, y + label_h))
            draw.text((x + 4, y + 2), label, fill=(0, 0, 0))
    draw.text((4, len(rows) * (h + label_h) + 4),
              f"error maps: blue = darker than the truth, red = lighter, full colour at "
              f"+-{scale:g}; still_life.obj from {look['look_from']}, {w}x{h}", fill=(0, 0, 0))
    sheet.save(path)
    print(f"wrote {path}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--meshes", default="still_life,bunny")
    parser.add_argument("--points", type=int, default=0,
                        help="points per mesh (0: as many as its vertices)")
    parser.add_argument("--truth-rays", type=int, default=2048)
    parser.add_argument("--multi-rays", type=int, default=1024)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--hemicube-points", type=int, default=1000)
    parser.add_argument("--parts", default="rays,discs,hemicube,depthmaps,multibounce")
    parser.add_argument("--work", default="/tmp/aobake_approx")
    parser.add_argument("--json")
    parser.add_argument("--plot")
    parser.add_argument("--views")
    parser.add_argument("--merge", nargs="+", metavar="JSON",
                        help="no bake: print the tables of these runs' rows (least seconds "
                             "of each) and write --plot / --json from them")
    parser.add_argument("--quick", action="store_true",
                        help="1000 points, 256-ray truths: a smoke run")
    args = parser.parse_args(argv)
    if args.quick:
        args.points, args.truth_rays, args.multi_rays = 1000, 256, 128
        args.hemicube_points = 200
    if args.merge:
        rows, meshes = merge(args.merge)
        for mesh in meshes:
            for quantity in ("ao", "indirect", "ao+indirect8"):
                mine = [r for r in rows if r["mesh"] == mesh and r["quantity"] == quantity]
                if mine:
                    print(f"\n{mesh}, {quantity}\n\n{table(mine, compact=True)}")
        if args.json:
            Path(args.json).write_text(json.dumps({"merged": args.merge, "rows": rows},
                                                  indent=1))
        if args.plot:
            plot(rows, args.plot, meshes)
        return
    load = os.getloadavg()
    print(f"load average at start: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} "
          f"({os.cpu_count()} cores)")
    meshes = [m for m in args.meshes.split(",") if m]
    rows, status = [], {}
    for name in meshes:
        bench = Bench(name, MESHES[name], args)
        rows += bench.run()
        status[name] = getattr(bench, "hemicube_status", None)
        print(table(bench.rows), flush=True)
    load = os.getloadavg()
    print(f"load average at end: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"args": vars(args), "rows": rows,
                                               "hemicube": status}, indent=1))
    if args.plot:
        plot(rows, args.plot, meshes)
    if args.views:
        views(args.views, args.threads, hemicube_available()[0])


if __name__ == "__main__":
    main()
