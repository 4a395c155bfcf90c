"""``--executor dask`` on a LocalCluster of 2 worker processes: the same bits as the local
bake for every split (vertices, --tolerance, a lightmap, a view), the cost model's split,
a worker killed mid-item, the cluster's sockets on the loopback interface only.  (An item
that kills every worker it touches: ``tests/test_dask_batch.py``.)

One cluster serves these tests and the batch's (``aobake.executors.dask.cluster``: the
LocalCluster a bake starts, TLS where ``cryptography`` is installed).  Skipped where Dask is
not installed (CI installs it: the ``test`` extra).
"""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

import aobake  # noqa: E402
from aobake.executors import dask as dask_executor  # noqa: E402
from aobake.executors import worker  # noqa: E402

from analytic import combine, floor_and_ceiling, polygon, quad  # noqa: E402


@pytest.fixture(scope="session")
def dask_session():
    """One LocalCluster of 2 workers for the Dask tests (``tests/test_dask_batch.py`` too),
    as ``--executor dask --workers 2`` starts it (by the first bake that needs it); every
    ``--executor dask`` bake while it is open runs on it."""
    with dask_executor.cluster(workers=2) as opened:
        yield opened


@pytest.fixture
def session(dask_session):
    return dask_session


def _scene():
    return combine(floor_and_ceiling(0.5, 2.0), polygon([0.5, 0.3, 0.2], 0.3, 24),
                   quad([-1.0, 0.0, 0.25], 0.2, 0.2, flip=True))


def _torus(sections=24):
    import trimesh

    return trimesh.creation.torus(1.0, 0.4, major_sections=sections,
                                  minor_sections=sections // 2)


def _values(result):
    if hasattr(result, "channels"):
        return dict(result.channels)
    return {**result.values, "rays": result.rays, **result.kept}


def _same(a, b):
    a, b = _values(a), _values(b)
    assert a.keys() == b.keys()
    for name in a:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)


CASES = {
    "fixed": dict(rays=24, quantities=("ao", "obscurance", "bent_normal"), max_distance="40%"),
    "tolerance": dict(rays=16, tolerance=0.08, max_rays=128, quantities=("ao", "obscurance")),
    "keep": dict(rays=8, quantities=("obscurance",), keep_distances=True),
}


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.slow
def test_vertex_bake_on_dask_is_the_local_bake(session, case):
    mesh, options = _scene(), CASES[case]
    local = aobake.bake(mesh, seed=3, threads=1, **options)
    split = aobake.bake(mesh, seed=3, executor="dask", chunk_points=13, **options)
    _same(local, split)
    assert local.report["parameters"] == split.report["parameters"]
    assert local.report.get("tolerance") == split.report.get("tolerance")
    assert split.report["executor"]["name"] == "dask"
    stats = session.stats[-1]
    assert stats["items"] == -(-len(local.rays) // 13) and stats["pilot_points"] == 0


@pytest.mark.slow
def test_lightmap_and_view_on_dask_are_the_local_ones(session):
    mesh = _torus()
    options = dict(rays=8, resolution=32, seed=5, quantities=("ao", "bent_normal"))
    _same(aobake.bake_texels(mesh, threads=1, **options),
          aobake.bake_texels(mesh, executor="dask", chunk_points=97, **options))
    view = dict(rays=8, seed=2, size=(40, 30))
    _same(aobake.bake_view(mesh, threads=1, **view),
          aobake.bake_view(mesh, executor="dask", chunk_points=151, **view))


@pytest.mark.slow
def test_cost_model_splits_the_rest_after_the_pilot(session, monkeypatch):
    """Without --chunk-points: the first points are estimated here (the pilot, kept), the
    rest in items of about ITEM_SECONDS of a worker, each worker getting work.  The model's
    times are scaled down 20x, so a bake of ~0.1 s of tracing goes through all of it."""
    for name, value in (("ITEM_SECONDS", 0.05), ("MIN_ITEM_SECONDS", 0.02),
                        ("PILOT_SECONDS", 0.005)):
        monkeypatch.setattr(dask_executor, name, value)
    mesh = _torus(48)  # 1152 vertices x 512 rays
    local = aobake.bake(mesh, rays=512, seed=1)
    before = len(session.stats)
    split = aobake.bake(mesh, rays=512, seed=1, executor="dask", threads=1)
    _same(local, split)
    assert len(session.stats) == before + 1, "the bake never reached the cluster"
    stats = session.stats[-1]
    assert 0 < stats["pilot_points"] < stats["points"]
    assert stats["items"] >= 2
    # every worker forgot the job when the bake ended
    assert not any(session.client.run(_cached_jobs).values())


def _cached_jobs():
    return list(worker._CACHE)


def test_a_bake_the_pilot_finishes_never_reaches_the_cluster(session):
    before = len(session.stats)
    mesh = _scene()
    _same(aobake.bake(mesh, rays=8, seed=1, threads=1),
          aobake.bake(mesh, rays=8, seed=1, executor="dask"))
    assert len(session.stats) == before


def test_cut_items_are_base_items():
    """The executor's own cutting (items of any sizes) equals ``executors.base.items`` on
    every field of a WorkItem: a per-point field added there must be cut here too."""
    from dataclasses import fields

    from aobake.executors.base import Job, items
    from aobake.records import SamplePoints

    n = 10
    plan = SamplePoints(np.random.default_rng(0).random((n, 3)), np.ones((n, 3)),
                        np.arange(n, dtype=np.int64), sizes=np.full(n, 0.1),
                        faces=np.arange(n), bary=np.full((n, 3), 1 / 3))
    job = Job(None, None, "rays", 8, True, "k")
    whole = items(job, plan, n)[0]
    for want in items(job, plan, 3):
        got = dask_executor._cut(whole, want.start, want.stop)
        for f in fields(want):
            a, b = getattr(want, f.name), getattr(got, f.name)
            if isinstance(a, np.ndarray):
                np.testing.assert_array_equal(a, b, err_msg=f.name)
            else:
                assert a == b, f.name


def test_split_sizes_items_from_the_cost_model():
    # 1e-3 s per point on one thread: 1000 points a second per worker thread
    ranges = dask_executor.split(100_000, 100, 1e-3, workers=2, threads=1)
    sizes = [b - a for a, b in ranges]
    assert ranges[0][0] == 100 and ranges[-1][1] == 100_000
    assert max(sizes) == 1000  # ITEM_SECONDS of one worker
    # little work: split for balance (2 per worker), never below MIN_ITEM_SECONDS
    assert [b - a for a, b in dask_executor.split(2100, 100, 1e-3, 2, 1)] == [500] * 4
    assert len(dask_executor.split(700, 100, 1e-3, 4, 1)) == 2
    # a worker with 4 threads takes items 4x larger
    assert max(b - a for a, b in dask_executor.split(100_000, 0, 1e-3, 2, 4)) == 4000


@pytest.mark.slow
def test_local_cluster_listens_on_loopback_only_without_dashboard(session):
    import psutil

    session.client  # started if no test before needed it
    me = psutil.Process()
    listening = [(p.pid, c.laddr) for p in [me] + me.children(recursive=True)
                 for c in p.net_connections(kind="inet") if c.status == psutil.CONN_LISTEN]
    assert listening, "no listening socket found"
    assert all(addr.ip == "127.0.0.1" for _, addr in listening), listening
    assert 8787 not in {addr.port for _, addr in listening}  # no dashboard on its port
    assert session.address.startswith("tls://127.0.0.1:") == session.tls
    assert session.tls or not _has_cryptography()


def _has_cryptography():
    try:
        import cryptography  # noqa: F401
    except ImportError:
        return False
    return True


@pytest.mark.slow
def test_worker_killed_mid_item_loses_nothing(session):
    """The test kills a worker's process while it traces an item: the scheduler re-runs the
    item elsewhere (the nanny restarts the worker) and the bits are the local bake's."""
    mesh = _torus(48)
    # 8 items of 150 points x 8192 rays, ~0.1 s of tracing each (2048 rays left too short
    # a window once occlusion went into packets: the bake could end before the killer looked)
    options = dict(rays=8192, seed=4)
    local = aobake.bake(mesh, threads=1, **options)
    client = session.client
    pids = client.run(os.getpid)
    killed = []

    def kill_one_busy_worker():
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not killed:
            busy = [a for a, keys in client.processing().items()
                    if any(str(k).startswith("aobake-item") for k in keys)]
            if busy:
                time.sleep(0.03)  # mid-item: each carries ~0.1 s of tracing
                os.kill(pids[busy[0]], signal.SIGKILL)
                killed.append(pids[busy[0]])
                return
            time.sleep(0.01)

    killer = threading.Thread(target=kill_one_busy_worker)
    killer.start()
    try:
        split = aobake.bake(mesh, executor="dask", chunk_points=150, **options)
    finally:
        killer.join()
    assert killed, "no worker was seen tracing"
    _same(local, split)
    client.wait_for_workers(2, timeout=60)  # the nanny restarted it
    assert killed[0] not in client.run(os.getpid).values()


@pytest.mark.slow
def test_a_scheduler_is_reached_with_dasks_tls_settings(session, monkeypatch):
    """A remote scheduler (here the session's own TLS cluster, by its address) is reached
    with the credentials of Dask's configuration (``distributed.comm.tls.*``: what a user
    sets in ~/.config/dask or DASK_DISTRIBUTED__COMM__TLS__* variables); without them the
    connection is refused with one clear message."""
    import dask

    session.client  # started if no test before needed it
    if not session.tls:
        pytest.skip("cryptography is not installed: the local cluster is plain TCP")
    monkeypatch.setattr(dask_executor, "CONNECT_SECONDS", 5.0)
    with pytest.raises(dask_executor.ClusterError, match="cannot reach the Dask scheduler"):
        with dask_executor.cluster(session.address) as stranger:
            stranger.client
    credentials = session.cluster.security
    settings = {"distributed.comm.require-encryption": True,
                "distributed.comm.tls.ca-file": credentials.tls_ca_file,
                "distributed.comm.tls.client.cert": credentials.tls_client_cert,
                "distributed.comm.tls.client.key": credentials.tls_client_key}
    mesh = _scene()
    with dask.config.set(settings), dask_executor.cluster(session.address) as remote:
        assert remote is not session
        split = aobake.bake(mesh, rays=8, seed=1, executor="dask", chunk_points=9)
        assert remote.tls and remote.cluster is None and len(remote.stats) == 1
    _same(aobake.bake(mesh, rays=8, seed=1, threads=1), split)


def test_the_dask_executor_releases_what_the_method_started_here(session, monkeypatch):
    """As every executor: what the method holds for estimating in this process (``close``:
    the hemicube's GL child started ahead) is released before the items go to the
    cluster, and when the estimate returns (issue 35)."""
    from aobake.methods.discs import DiscsMethod

    closed = []
    monkeypatch.setattr(DiscsMethod, "close", lambda self: closed.append(self),
                        raising=False)
    aobake.bake(_scene(), method="discs", executor="dask", chunk_points=9)
    assert len(closed) >= 1
