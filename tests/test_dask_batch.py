"""``aobake batch --executor dask``: a library baked on a LocalCluster of 2 workers equals the
threads batch bit for bit; an asset whose work kills every worker it touches fails alone,
in bounded time; Ctrl-C stops the batch and its cluster cleanly (exit 130, the summary
written, no partial file, no process left).  Skipped where Dask is not installed.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

distributed = pytest.importorskip("distributed")


from test_batch import _by_mesh, _library, run_batch  # noqa: E402
from test_dask import dask_session  # noqa: E402,F401  (the shared cluster)

ROOT = Path(__file__).resolve().parents[1]


def _same_npz(a: Path, b: Path):
    with np.load(a) as x, np.load(b) as y:
        assert sorted(x.files) == sorted(y.files)
        for key in x.files:
            np.testing.assert_array_equal(x[key], y[key], err_msg=f"{a.name}: {key}")


@pytest.mark.slow
def test_library_on_dask_is_the_threads_library(tmp_path, dask_session):
    _library(tmp_path / "in")
    common = [tmp_path / "in", "--format", "npz", "--rays", "16", "-q", "ao", "-q",
              "bent_normal"]
    code, err, local = run_batch(*common, "--out-dir", tmp_path / "a")
    assert code == 1, err
    code, err, split = run_batch(*common, "--out-dir", tmp_path / "b", "--executor", "dask",
                                 "--workers", "2", "--chunk-points", "40")
    assert code == 1, err
    assert split["counts"] == local["counts"] == {"ok": 3, "skipped": 0, "failed": 1}
    assert split["executor"]["name"] == "dask"
    assert dask_session.stats, "the batch never reached the cluster"
    for name in ("box.npz", "ico.npz", "sub/torus.npz"):
        _same_npz(tmp_path / "a" / name, tmp_path / "b" / name)


class _KillFarAway(distributed.WorkerPlugin):
    """On every worker (restarted ones too): an item whose points lie beyond x = 4000 (the
    poison asset's) kills its worker process."""

    name = "aobake-test-kill-far-away"

    def setup(self, worker=None):
        from aobake.executors import worker as cache

        original = cache.run_item

        def run_item(item, *args, **kwargs):
            if len(item.points) and item.points[:, 0].min() > 4000:
                os.kill(os.getpid(), signal.SIGKILL)
            return original(item, *args, **kwargs)

        run_item.original = original
        cache.run_item = run_item

    def teardown(self, worker=None):
        from aobake.executors import worker as cache

        cache.run_item = getattr(cache.run_item, "original", cache.run_item)


@pytest.mark.slow
def test_an_asset_that_kills_its_workers_fails_alone(tmp_path, dask_session):
    """The poison asset comes first: its item kills 3 workers (allowed-failures 2), its
    asset fails with that message, and the restarted workers bake the rest."""
    import cloudpickle

    meshes = _library(tmp_path / "in")
    meshes["broken"].unlink()
    poison = trimesh.creation.box()
    poison.apply_translation([5000.0, 0.0, 0.0])
    poison.export(tmp_path / "in" / "a_poison.ply")  # first in the folder's order
    module = sys.modules[__name__]
    cloudpickle.register_pickle_by_value(module)
    client = dask_session.client
    client.register_plugin(_KillFarAway())
    start = time.monotonic()
    try:
        # the batch's own cluster() finds the session open and bakes on it
        code, err, summary = run_batch(tmp_path / "in", "--out-dir", tmp_path / "out",
                                       "--format", "ply", "--rays", "8", "--executor",
                                       "dask", "--chunk-points", "4")
    finally:
        client.unregister_worker_plugin(_KillFarAway.name)
        cloudpickle.unregister_pickle_by_value(module)
    assert time.monotonic() - start < 90
    assert code == 1, err
    records = _by_mesh(summary)
    assert records["a_poison.ply"]["status"] == "failed"
    # both of its items (points 0..3, 4..7) kill; the first to reach 3 deaths is named
    assert re.search(r"points [04]\.\.[37] of the bake killed every Dask worker that ran them "
                     r"\(3 workers; distributed\.scheduler\.allowed-failures = 2\)",
                     records["a_poison.ply"]["error"]), records["a_poison.ply"]["error"]
    assert [records[n]["status"] for n in ("box.ply", "ico.obj", "torus.stl")] == ["ok"] * 3
    assert not (tmp_path / "out" / "a_poison.ply").exists()
    client.wait_for_workers(2, timeout=60)


@pytest.mark.slow
def test_ctrl_c_stops_the_batch_and_its_cluster(tmp_path):
    """SIGINT to the whole process group (a terminal's Ctrl-C) while the second asset is
    on the cluster: exit 130 within seconds, the first asset's files and the summary
    written, nothing of the second, and every process of the cluster gone."""
    import psutil

    folder = tmp_path / "in"
    folder.mkdir()
    trimesh.creation.box().export(folder / "a.ply")
    trimesh.creation.torus(1.0, 0.4, major_sections=96, minor_sections=48).export(
        folder / "b.ply")
    out = tmp_path / "out"
    command = [sys.executable, "-c", "from aobake.cli.batch import main; main()",
               str(folder), "--out-dir", str(out), "--format", "npz", "--rays", "16384",
               "--executor", "dask", "--workers", "2", "--chunk-points", "64"]
    # 16384 rays: the torus takes ~5 s of tracing, so it is surely on the cluster when the
    # signal comes (with 4096, once occlusion went into packets, it could finish first)
    process = subprocess.Popen(command, cwd=ROOT, stderr=subprocess.PIPE, text=True,
                               start_new_session=True)
    lines, seen = [], threading.Event()

    def read():
        for line in process.stderr:
            lines.append(line)
            if "[1/2] ok" in line:
                seen.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        assert seen.wait(90), "".join(lines)
        parent = psutil.Process(process.pid)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and len(parent.children(recursive=True)) < 2:
            time.sleep(0.1)
        family = parent.children(recursive=True)
        assert len(family) >= 2, "the cluster's workers never started"
        time.sleep(1.0)  # the second asset's items on the workers
        clock = time.monotonic()
        os.killpg(process.pid, signal.SIGINT)
        code = process.wait(30)
        took = time.monotonic() - clock
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
    reader.join(5)
    text = "".join(lines)
    assert code == 130, text
    assert took < 20, took
    assert "interrupted" in text and "Traceback" not in text
    summary = json.loads((out / "batch-summary.json").read_text())
    assert summary["interrupted"] and summary["not_started"] == 1
    assert [r["status"] for r in summary["assets"]] == ["ok"]
    assert (out / "a.npz").is_file() and not (out / "b.npz").exists()
    assert not list(out.rglob("*aobake-unfinished*"))
    time.sleep(0.5)
    alive = [p.pid for p in family if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]
    assert not alive, f"processes left behind: {alive}"
