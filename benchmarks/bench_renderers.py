"""Time to a per-pixel error: ``aobake view`` against Mitsuba 3 and Cycles' AO pass on the
same camera and the same pixels (issue 32 point 6).  A benchmark that prints a table, not a
test.

    python benchmarks/bench_renderers.py                       # still life, 160x90
    python benchmarks/bench_renderers.py --mesh M.obj --size 96x54 --budgets 16 64 256
    python benchmarks/bench_renderers.py --aobake joint positions:16 --tools aobake
    AOBAKE_BLENDER_PYTHON=/path/to/bpy/python python benchmarks/bench_renderers.py

The view: ``aobake view MESH --pixel-filter box`` (the mean AO over each pixel, what a
box-filtered renderer computes), exported with ``--export-camera`` / ``--export-mitsuba``
and rendered by each tool from those files (docs/renderers.md).  The reference is an aobake
view with many more rays (the joint estimator, by default, at another seed; cached in the
temporary directory); each row's error is the per-pixel RMSE against it over the pixels
every image covers fully, with the reference's own noise taken out: sqrt(max(0, mean(e^2)
- mean(se_ref^2))).  The errors are deterministic (fixed seeds): a rerun prints the same;
the seconds are indications, exact only on a quiet machine.

aobake's series (``--aobake``): ``joint`` (the default box estimator of the ray-traced
method, ``--box-sampling joint``: --rays AO rays per pixel, 4 from each of rays/4 positions,
positions and directions stratified together; aobake.targets.view_box), and for
comparison ``positions:S`` (``--box-sampling positions --pixel-samples S``: each position a
sample point with rays/S rays) and ``positions:rays`` (one AO ray per position, at most
256 positions).

Budgets are AO rays per pixel: aobake's ``--rays``, a renderer's samples per pixel (each
sample one primary ray and one AO ray: Mitsuba's direct integrator with one BSDF sample,
Cycles' AO pass; aobake's joint estimator casts one primary ray per 4 AO rays).  Times
are the tool's own: aobake's report (load, BVH, trace), Mitsuba's load_file + render (its
fastest CPU variant that runs here; the LLVM variant's first render also compiles its
kernels, timed apart), Cycles' render call inside Blender (BVH build and the Combined pass
it cannot skip, kept cheap: no bounces, a black world).  Process start-up and imports are
left out for all three.

aobake's budgets are the ones it casts: sobol's are R 2^k, so a budget with another odd factor
runs as that many replicates (``--replicates``: 384 = 3 x 128, 320 = 5 x 64).

Time to the target error: between the two budgets whose errors bracket it (log error
against log budget; quasi-Monte Carlo samplers fall faster than 1/sqrt(rays), so no slope
is assumed), seconds linear in the budget between them; past the largest budget,
extrapolated from it as 1/sqrt(rays) (said so in the table).  An interpolated budget is not
one aobake can cast, so its first budget run that reaches the target is printed too, as run.  An extrapolation is only
as good as that law: aobake's ``positions:S`` stops improving at the error of S positions
over the pixel's area (S = 16: about 0.010 on the still life at 160x90), which more rays
per position do not reduce.

The machine may be shared: each row records the other work on the cores meanwhile (the
busy time of every CPU from /proc/stat less this process's and its children's CPU time,
in cores) and is marked "not comparable" above 0.3 cores; CPU seconds are printed beside
wall seconds (less sensitive to others, though not immune: they share caches and clocks).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
BLENDER_SCRIPT = ROOT / "tests" / "blender_renderers.py"
#: other work (cores) above which a row is "not comparable"
LOAD_THRESHOLD = 0.3
#: the most positions per pixel of aobake's "positions:rays" series (a point each: memory)
MAX_POSITIONS = 256


# ---- the machine -----------------------------------------------------------------------------

def _busy_ticks() -> int:
    with open("/proc/stat") as f:
        fields = [int(x) for x in f.readline().split()[1:]]
    user, nice, system, _idle, _iowait, irq, softirq, steal = (fields + [0] * 8)[:8]
    return user + nice + system + irq + softirq + steal


def _own_cpu() -> float:
    me = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


class Load:
    """Other work on the machine over a block, in cores, and this process's CPU seconds."""

    def __enter__(self):
        self.ticks, self.cpu, self.wall = _busy_ticks(), _own_cpu(), time.perf_counter()
        return self

    def __exit__(self, *exc):
        wall = time.perf_counter() - self.wall
        busy = (_busy_ticks() - self.ticks) / os.sysconf("SC_CLK_TCK")
        self.cpu_s = _own_cpu() - self.cpu
        self.others = max(0.0, (busy - self.cpu_s) / wall) if wall > 0 else 0.0
        self.load1 = os.getloadavg()[0]
        return False


# ---- the tools -------------------------------------------------------------------------------

def _covered(channels) -> np.ndarray:
    return np.asarray(channels["coverage"]) == 1.0


def series_options(series: str, budget: int) -> dict:
    """``bake_view``'s box options of an aobake series at ``budget`` rays per pixel:
    ``joint``, ``positions:S`` or ``positions:rays``."""
    if series == "joint":
        # sobol's budgets are R 2^k: a budget of another odd factor runs as that many
        # replicates (384 = 3 x 128), so every row is a budget aobake really casts
        odd = budget // (budget & -budget)
        return {"box_sampling": "joint", **({"replicates": odd} if odd > 1 else {})}
    kind, _, positions = series.partition(":")
    if kind != "positions" or not positions:
        raise SystemExit(f"--aobake {series!r}: joint, positions:S or positions:rays")
    count = min(budget, MAX_POSITIONS) if positions == "rays" else int(positions)
    return {"box_sampling": "positions", "pixel_samples": count}


def aobake_row(mesh, camera, budget, options: dict, threads, seed=0):
    import aobake

    with Load() as load:
        result = aobake.bake_view(str(mesh), camera=camera, rays=budget,
                                  pixel_filter="box", threads=threads, seed=seed, **options)
    footprint = result.report["camera"]["pixel_footprint"]
    return {"image": np.asarray(result.channels["ao"], dtype=np.float64),
            "full": _covered(result.channels), "seconds": result.report["wall_time_s"],
            "cpu_s": load.cpu_s, "others": load.others, "load1": load.load1,
            "note": f"{footprint['estimator']}: {footprint['positions']} positions, "
                    f"{result.report['rays_cast']} AO rays"}


def mitsuba_variant() -> tuple[str | None, str]:
    """The fastest CPU variant that renders here (probed in a child: an unusable libLLVM
    aborts the process), and why the faster one does not."""
    try:
        import mitsuba  # noqa: F401
    except ImportError:
        return None, "mitsuba is not installed (pip install 'aobake[mitsuba]')"
    probe = ("import mitsuba as mi; mi.set_variant('llvm_ad_rgb'); "
             "mi.render(mi.load_dict(mi.cornell_box()), spp=1)")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=600)
    if done.returncode == 0:
        return "llvm_ad_rgb", ""
    last = (done.stderr.strip().splitlines() or ["?"])[-1][:120]
    return "scalar_rgb", f"llvm_ad_rgb does not run ({last}): apt install libllvm19"


def mitsuba_rows(xml, budgets, threads, variant):
    import drjit as dr
    import mitsuba as mi

    mi.set_variant(variant)
    dr.set_thread_count(threads)
    rows = []
    for k, budget in enumerate(budgets):
        with Load() as load:
            clock = time.perf_counter()
            scene = mi.load_file(str(xml), spp=budget)
            image = np.array(mi.render(scene, seed=k))
            seconds = time.perf_counter() - clock
        note = variant
        if variant.startswith("llvm") and k == 0:
            # the first render compiles the kernels: time it again warm
            with Load() as load:
                clock = time.perf_counter()
                scene = mi.load_file(str(xml), spp=budget)
                image = np.array(mi.render(scene, seed=1000 + k))
                warm = time.perf_counter() - clock
            note += f", first render {seconds:.2f} s with its kernels' compile"
            seconds = warm
        rows.append({"budget": budget, "image": image[..., 0].astype(np.float64),
                     "full": image[..., 3] >= 1.0 - 1e-6, "seconds": seconds,
                     "cpu_s": load.cpu_s, "others": load.others, "load1": load.load1,
                     "note": note})
    return rows


def cycles_rows(glb, budgets, threads, work):
    from aobake.outputs import image as images

    python = os.environ.get("AOBAKE_BLENDER_PYTHON")
    rows = []
    for k, budget in enumerate(budgets):
        out = work / f"cycles_{budget}.exr"
        with Load() as load:
            done = subprocess.run([python, str(BLENDER_SCRIPT), "cycles", str(glb), str(out),
                                   "--samples", str(budget), "--seed", str(k + 1),
                                   "--threads", str(threads), "--bench"],
                                  capture_output=True, text=True, timeout=7200)
        result = json.loads(done.stdout.strip().splitlines()[-1])
        if not result.get("ok"):
            raise RuntimeError(f"Blender: {result}")
        table = images.read(result["out"][0])
        ao = np.asarray(table.columns["ViewLayer.Ambient Occlusion.R"], dtype=np.float64)
        alpha = np.asarray(table.columns["ViewLayer.Combined.A"])
        rows.append({"budget": budget, "image": ao, "full": alpha >= 1.0 - 1e-6,
                     "seconds": result["seconds"][0], "cpu_s": result["cpu_s"][0],
                     # the Blender child's own CPU is in load.cpu_s; others as measured
                     "others": load.others, "load1": load.load1,
                     "note": f"Blender {result['blender']}, CPU"})
    return rows


# ---- the table -------------------------------------------------------------------------------

def reference(mesh, camera, rays, series, threads, cache: Path):
    """aobake's view with ``rays`` per pixel, ``series`` sampled (cached by mesh, camera
    and settings)."""
    import aobake

    options = series_options(series, rays)
    key = hashlib.sha256(json.dumps([str(mesh), Path(mesh).stat().st_size,
                                     camera.world_to_view().tolist(), camera.fov_y,
                                     camera.width, camera.height, rays, options, 987654321,
                                     aobake.__version__]).encode()).hexdigest()[:12]
    path = cache / f"aobake_renderers_ref_{key}.npz"
    if path.is_file():
        data = np.load(path)
        return data["ao"], data["se"], data["full"]
    result = aobake.bake_view(str(mesh), camera=camera, rays=rays, pixel_filter="box",
                              threads=threads, seed=987654321, **options)
    ao = np.asarray(result.channels["ao"], dtype=np.float64)
    se = np.asarray(result.channels["ao_stderr"], dtype=np.float64)
    full = _covered(result.channels)
    np.savez(path, ao=ao, se=se, full=full)
    return ao, se, full


def error(row, ref, ref_se, mask) -> float:
    """Per-pixel RMSE against the reference over ``mask``, its noise taken out."""
    e = row["image"].reshape(ref.shape)[mask] - ref[mask]
    return math.sqrt(max(0.0, float(np.mean(e ** 2) - np.mean(ref_se[mask] ** 2))))


def time_to(rows, target, key="seconds"):
    """(budget, seconds, how) at which ``rows`` reach RMSE ``target``: interpolated between
    the two rows that bracket it (log rmse against log budget, row[key] (wall "seconds" or
    "cpu_s") linear in budget);
    past the last row, extrapolated as rmse ~ 1/sqrt(budget) and seconds ~ budget from it
    (how = 'extrapolated'); at or below the first row's budget, that row."""
    rows = sorted(rows, key=lambda r: r["budget"])
    for i, row in enumerate(rows):
        if row["rmse"] <= target:
            if i == 0:
                return row["budget"], row[key], "first row"
            a, b = rows[i - 1], row
            x = ((math.log(a["rmse"]) - math.log(target))
                 / (math.log(a["rmse"]) - math.log(max(b["rmse"], 1e-12))))
            budget = math.exp(math.log(a["budget"])
                              + x * (math.log(b["budget"]) - math.log(a["budget"])))
            fraction = (budget - a["budget"]) / (b["budget"] - a["budget"])
            return budget, a[key] + fraction * (b[key] - a[key]), "interpolated"
    last = rows[-1]
    budget = last["budget"] * (last["rmse"] / target) ** 2
    how = "extrapolated"
    if len(rows) > 1:  # a series whose error has stopped falling: the law does not hold
        before = rows[-2]
        if last["rmse"] > before["rmse"] * (before["budget"] / last["budget"]) ** 0.25:
            how = (f"extrapolated, but its error stalls ({before['rmse']:.4f} -> "
                   f"{last['rmse']:.4f}): it may not get there")
    return budget, last[key] * budget / last["budget"], how


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mesh", type=Path, default=ROOT / "assets" / "still_life.obj")
    parser.add_argument("--size", default="160x90")
    parser.add_argument("--budgets", type=int, nargs="+", default=[16, 64, 256, 1024])
    parser.add_argument("--aobake", nargs="+", default=["joint"],
                        help="aobake's series: joint (the default box estimator), "
                             "positions:S (S positions, rays/S rays each) or positions:rays "
                             "(one AO ray per position, at most 256)")
    parser.add_argument("--reference-rays", type=int, default=16384)
    parser.add_argument("--reference", default="joint",
                        help="the reference's sampling, as an --aobake series")
    parser.add_argument("--target", type=float, nargs="+", default=[0.01, 0.005],
                        help="per-pixel RMSEs to reach (default 0.01 and 0.005)")
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--tools", nargs="+", default=["aobake", "mitsuba", "cycles"])
    parser.add_argument("--json", type=Path, help="also write the rows here")
    args = parser.parse_args(argv)

    from aobake import camera as cameras
    from aobake.outputs import camera_export

    import aobake

    width, height = cameras.parse_size(args.size)
    work = Path(tempfile.mkdtemp(prefix="aobake_bench_renderers_"))
    # the default view of the mesh, as aobake view frames it: one view for every tool
    probe = aobake.bake_view(str(args.mesh), size=(width, height), rays=1,
                             pixel_filter="box")
    camera = probe.camera
    camera_export.export_view(probe, str(args.mesh), gltf=work / "view.glb",
                              mitsuba=work / "view.xml")
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} logical "
          f"CPUs, {args.threads} threads each; load average {os.getloadavg()[0]:.2f}")
    print(f"view: {args.mesh.name} {width}x{height}, box filter; reference: aobake "
          f"{args.reference_rays} rays per pixel, {args.reference} (cached)")
    clock = time.perf_counter()
    ref, ref_se, ref_full = reference(args.mesh, camera, args.reference_rays,
                                      args.reference, args.threads,
                                      Path(tempfile.gettempdir()))
    print(f"reference ready in {time.perf_counter() - clock:.1f} s; its noise rms "
          f"{math.sqrt(np.mean(ref_se[ref_full] ** 2)):.5f}")

    tools = {}
    if "aobake" in args.tools:
        for series in args.aobake:
            rows = []
            for budget in args.budgets:
                row = aobake_row(args.mesh, camera, budget, series_options(series, budget),
                                 args.threads)
                row["budget"] = budget
                rows.append(row)
            tools[f"aobake view ({series})"] = rows
    skipped = []
    if "mitsuba" in args.tools:
        variant, why = mitsuba_variant()
        if variant is None:
            skipped.append(f"Mitsuba 3: {why}")
        else:
            if why:
                skipped.append(f"Mitsuba 3 {why} (scalar_rgb timed instead)")
            tools[f"Mitsuba 3 ({variant})"] = mitsuba_rows(work / "view.xml", args.budgets,
                                                           args.threads, variant)
    if "cycles" in args.tools:
        if not os.environ.get("AOBAKE_BLENDER_PYTHON"):
            skipped.append("Cycles: AOBAKE_BLENDER_PYTHON (a Python with bpy) not set")
        else:
            tools["Cycles AO pass"] = cycles_rows(work / "view.glb", args.budgets,
                                                  args.threads, work)

    mask = ref_full.copy()
    for rows in tools.values():
        for row in rows:
            mask &= row["full"].reshape(ref.shape)
    print(f"pixels compared: {int(mask.sum())} (covered fully by every image)\n")
    header = (f"{'tool':28} {'rays/px':>8} {'wall s':>8} {'cpu s':>8} {'rmse':>8} "
              f"{'others':>7}  comparable")
    print(header)
    print("-" * len(header))
    summary = []
    for name, rows in tools.items():
        for row in rows:
            row["rmse"] = error(row, ref, ref_se, mask)
            comparable = row["others"] <= LOAD_THRESHOLD
            row["comparable"] = comparable
            print(f"{name:28} {row['budget']:8d} {row['seconds']:8.3f} {row['cpu_s']:8.2f} "
                  f"{row['rmse']:8.5f} {row['others']:7.2f}  "
                  f"{'yes' if comparable else 'NO (load)'}  {row['note']}")
        for target in args.target:
            budget, seconds, how = time_to(rows, target)
            cpu = time_to(rows, target, "cpu_s")[1]
            summary.append((target, name, budget, seconds, cpu, how,
                            all(r["comparable"] for r in rows)))
    for target in args.target:
        print(f"\ntime to per-pixel RMSE {target}:")
        for at, name, budget, seconds, cpu, how, comparable in summary:
            if at != target:
                continue
            print(f"  {name:28} {budget:9.0f} rays/px  {seconds:8.2f} s wall  {cpu:8.2f} s "
                  f"cpu  {how}{'' if comparable else '   (not comparable: load)'}")
        # aobake cannot cast an interpolated budget (sobol: R 2^k): its first row that
        # reaches the target, as run, beside the interpolation every tool gets
        for name, rows in tools.items():
            reached = [r for r in sorted(rows, key=lambda r: r["budget"]) if r["rmse"] <= target]
            if name.startswith("aobake") and reached:
                row = reached[0]
                print(f"  {name + ', as run':28} {row['budget']:9d} rays/px  "
                      f"{row['seconds']:8.2f} s wall  {row['cpu_s']:8.2f} s cpu  "
                      f"the first budget run that reaches it (RMSE {row['rmse']:.5f})")
    for line in skipped:
        print(f"skipped: {line}")
    if args.json:
        out = {name: [{k: v for k, v in r.items() if k not in ("image", "full")}
                      for r in rows] for name, rows in tools.items()}
        args.json.write_text(json.dumps({"rows": out, "skipped": skipped,
                                         "target": args.target, "summary": summary},
                                        indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
