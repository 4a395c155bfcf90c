"""What a timing was taken on, and how busy the machine was meanwhile (Linux).

A timing means something only next to the CPU it came from and the work that shared the
cores with it.  This module gives both, for the benchmarks that print speed figures:

* :func:`cpu` -- the CPU model (``/proc/cpuinfo`` "model name"), the vector extensions the
  kernel reports (``avx2``, ``avx512f``, ...), the logical CPUs, and this Embree build's
  native packet widths when aobake's binding is there.
* :class:`Load` -- the CPU seconds *other* work used over an interval: the busy time of
  every core from ``/proc/stat`` (user + nice + system + irq + softirq + steal) minus the
  CPU time of this process and the children it waited for (``getrusage``), divided by the
  wall time.  The result is in cores: 0.0 an otherwise idle machine, 1.0 one core taken
  by someone else.  Steal counts as other work (another guest had the core).  The
  one-minute load average is recorded beside it, but not used to judge: it lags by a
  minute and counts the benchmark's own processes.

``/proc/stat`` ticks at USER_HZ (100/s) and ``getrusage`` is exact, so over an interval of
t seconds the estimate is good to about 0.02 / t cores per CPU: a threshold of 0.3 cores
is well clear of it for any interval of half a second or more.
"""

from __future__ import annotations

import os
import resource
import time

#: other work, in cores, above which a timing is marked "not comparable (load)"
LOAD_THRESHOLD = 0.3
#: seconds of the quiet samples taken before and after each timed row
SAMPLE_S = 0.5

#: the vector extensions reported (as /proc/cpuinfo names them)
VECTOR_FLAGS = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512vl", "avx512bw",
                "avx512dq")


def cpu() -> dict:
    """{'model', 'logical_cpus', 'vector'}: the model name and the vector extensions of the
    first processor in /proc/cpuinfo (all cores of one machine report the same)."""
    model, flags = None, set()
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                key, _, value = line.partition(":")
                key = key.strip()
                if key == "model name" and model is None:
                    model = value.strip()
                elif key == "flags" and not flags:
                    flags = set(value.split())
                if model is not None and flags:
                    break
    except OSError:
        pass
    return {"model": model or "unknown", "logical_cpus": os.cpu_count(),
            "vector": [f for f in VECTOR_FLAGS if f in flags]}


def _busy_ticks() -> int:
    """Busy ticks of all CPUs since boot (the 'cpu' line of /proc/stat)."""
    with open("/proc/stat", encoding="ascii") as f:
        fields = f.readline().split()
    # cpu user nice system idle iowait irq softirq steal guest guest_nice
    user, nice, system, _idle, _iowait, irq, softirq, steal = (int(x) for x in fields[1:9])
    # guest time is already inside user (and guest_nice inside nice): not added again
    return user + nice + system + irq + softirq + steal


def _own_cpu_s() -> float:
    """CPU seconds of this process and every child it has waited for."""
    total = 0.0
    for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN):
        r = resource.getrusage(who)
        total += r.ru_utime + r.ru_stime
    return total


class Load:
    """Other work over an interval: ``with Load() as load: ...`` then ``load.others``
    (cores), ``load.wall_s``, ``load.loadavg`` (the 1-minute average at the start and the
    end).  Time spent by children not waited for before the block ends is counted as
    other work (so wait for them inside it)."""

    _hz = os.sysconf("SC_CLK_TCK")

    def __enter__(self):
        self._la0 = os.getloadavg()[0]
        self._own0, self._busy0 = _own_cpu_s(), _busy_ticks()
        self._t0 = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.wall_s = time.perf_counter() - self._t0
        busy = (_busy_ticks() - self._busy0) / self._hz
        self.own_s = _own_cpu_s() - self._own0
        self.others = max(0.0, busy - self.own_s) / self.wall_s if self.wall_s > 0 else 0.0
        self.loadavg = (self._la0, os.getloadavg()[0])
        return False

    def record(self) -> dict:
        return {"others_cores": round(self.others, 3), "wall_s": round(self.wall_s, 3),
                "own_cpu_s": round(self.own_s, 3),
                "loadavg_1min": [round(x, 2) for x in self.loadavg]}


def quiet_sample(seconds: float = SAMPLE_S) -> dict:
    """Other work while this process sleeps for ``seconds``: Load.record() of the sleep."""
    with Load() as load:
        time.sleep(seconds)
    return load.record()


def wait_for_quiet(limit_s: float, threshold: float = LOAD_THRESHOLD, log=None,
                   settle: int = 2) -> dict:
    """Sample until other work was at most ``threshold`` cores in ``settle`` samples in a
    row (a quiet second, not a gap between two of someone's processes), for at most
    ``limit_s`` seconds; returns the last sample (its ``others_cores`` may still be above)."""
    deadline = time.monotonic() + limit_s
    quiet, told = 0, False
    while True:
        sample = quiet_sample()
        quiet = quiet + 1 if sample["others_cores"] <= threshold else 0
        if quiet >= settle or time.monotonic() >= deadline:
            return sample
        if quiet == 0:
            if log and not told:
                log(f"  (waiting up to {limit_s:.0f} s for other work below {threshold} "
                    f"cores: {sample['others_cores']:.2f} now)")
                told = True
            time.sleep(2.0)


def watched(args, run, log, label: str):
    """Run one row (``run()``: a fresh process to its end) under the load watch.

    ``args``: the benchmark's ``retries``, ``wait`` and ``threshold``; ``run()`` returns a
    dict with the row's ``seconds`` (or ``bake_s``).  Returns (result, load): load has the
    other work before / during / after in cores (``Load``, ``quiet_sample``),
    ``comparable`` (neither before nor during above --threshold: the row's own measurement
    of other work is the direct one, the sample before catches a load that its own work
    squeezed out; after is recorded only) and ``attempts`` (every try's seconds and load;
    a try under load is run again, up to --retries times, after waiting up to --wait s for
    a quiet machine).  bench_peers.py and bench_renderers_lightmap.py time their rows so."""
    attempts = []
    for attempt in range(args.retries + 1):
        before = wait_for_quiet(args.wait, args.threshold, log)
        with Load() as during:
            res = run()
        after = quiet_sample()
        load = {"before": before, "during": during.record(), "after": after}
        others = [load[k]["others_cores"] for k in ("before", "during", "after")]
        # before and during decide; after is kept as a sign of load that began late in it
        load["comparable"] = max(others[:2]) <= args.threshold
        attempts.append({"seconds": res["seconds"] if "seconds" in res else res["bake_s"],
                         **{k: load[k] for k in ("before", "during", "after")}})
        if load["comparable"]:
            break
        log(f"  {label}: not comparable (load): other work "
            + " / ".join(f"{o:.2f}" for o in others) + " cores before / during / after"
            + ("; again" if attempt < args.retries else "; kept, marked"))
    load["attempts"] = attempts
    return res, load
