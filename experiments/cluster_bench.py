"""Collection throughput on the local process pool and on Ray: ``python experiments/cluster_bench.py``.

The same collection (``--samples`` per group, ``--seed``, the production configuration with
``--episodes-per-chunk`` episodes a chunk) runs once per way, each in a new folder and timed from the
call to the data sets written, start-up and shut-down included (spawning the pool; starting Ray and
stopping it): ``pool1`` (one process), ``pool2`` (a pool of two), ``ray`` (a local Ray with this
machine's cores). Per way it prints the samples collected (both groups' counted tables), the wall
time, samples per minute, a digest of the data sets' samples (the same for every way), and
``efficiency``: the chunks' summed compute time over workers x wall time, the share of the workers'
time spent on chunks, and ``cpu_s``: the CPU seconds of this process and all its descendants (pool
workers; Ray's daemons and workers), sampled every 0.2 s, also by kind of process
(``cpu_s_by_process``: the driver, the pool's or Ray's workers, each of Ray's daemons), and the load
average (1 min) at the start and the end. On a machine shared with other work the wall times swing
with its load, and the chunks' compute times with them; ``--repeat`` alternates the ways to even the
load out. ``--json`` also writes the figures.
See docs/cluster.md for the measured figures.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from hexgym.files import write_json
from hexgym_lab.mbl.collect import CollectConfig, collect, load_dataset, samples_digest

WAYS = ("pool1", "pool2", "ray")


def _proc_stat(pid: int | str) -> tuple[int, int, float] | None:
    """(ppid, start ticks, CPU seconds) of a process from /proc (Linux), or None if it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text[text.rindex(")") + 2 :].split()  # after the command name, which may hold spaces
    ticks = os.sysconf("SC_CLK_TCK")
    return int(fields[1]), int(fields[19]), (int(fields[11]) + int(fields[12])) / ticks


class _TreeCPU:
    """CPU seconds of this process and its descendants, each process's last sample (a thread samples /proc)."""

    def __init__(self, period_s: float = 0.2) -> None:
        self._period = period_s
        self._seen: dict[tuple[int, int], float] = {}
        self._names: dict[tuple[int, int], str] = {}
        self._base = (_proc_stat(os.getpid()) or (0, 0, 0.0))[2]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _sample(self) -> None:
        stats = {int(p): st for p in os.listdir("/proc") if p.isdigit() and (st := _proc_stat(p)) is not None}
        tree, grown = {os.getpid()}, True
        while grown:
            new = {pid for pid, st in stats.items() if st[0] in tree} - tree
            tree |= new
            grown = bool(new)
        for pid in tree:
            if pid in stats:
                key = (pid, stats[pid][1])
                self._seen[key] = stats[pid][2]
                if self._names.get(key, "?") == "?" or "::" not in self._names[key]:  # Ray's retitle themselves
                    self._names[key] = _process_name(pid, self._names.get(key, "?"))

    def _run(self) -> None:
        while not self._stop.wait(self._period):
            self._sample()

    def stop(self) -> float:
        """Stop sampling; the CPU seconds used since the start."""
        self._stop.set()
        self._thread.join()
        self._sample()
        return sum(self._seen.values()) - self._base

    def by_name(self) -> dict[str, float]:
        """CPU seconds by kind of process (after :meth:`stop`), this process's since the start."""
        found: dict[str, float] = {}
        for key, seconds in self._seen.items():
            name = "driver" if key[0] == os.getpid() else self._names.get(key, "?")
            found[name] = found.get(name, 0.0) + seconds - (self._base if key[0] == os.getpid() else 0.0)
        return {k: round(v, 2) for k, v in sorted(found.items(), key=lambda kv: -kv[1])}


def _process_name(pid: int, known: str = "?") -> str:
    """A short name for a process: Ray's workers and daemons by role, pool workers, others by program
    (``known`` if it has ended)."""
    try:
        argv = [a for a in Path(f"/proc/{pid}/cmdline").read_text().split("\0") if a]
    except OSError:
        return known
    if not argv:
        return known
    if argv[0].startswith("ray::"):  # a Ray worker titles itself ray::IDLE or by its task; Ray's agents by role
        role = argv[0].split()[0]
        return role if role.endswith("Agent") else "ray::worker"
    for arg in argv[:3]:
        if "/ray/" in arg:
            inside = arg.rsplit("/ray/", 1)[1].removesuffix(".py")
            return "ray::worker" if inside.endswith("default_worker") else "ray:" + inside
    if "multiprocessing" in " ".join(argv):
        return "pool worker"
    return Path(argv[0]).name


def run_way(way: str, samples: int, seed: int, config: CollectConfig) -> dict[str, Any]:
    """One timed collection ``way`` (see the module docstring) in a temporary folder: its figures."""
    workers = {"pool1": 1, "pool2": 2}.get(way, 2)
    ray = "local" if way == "ray" else None
    with tempfile.TemporaryDirectory(prefix=f"hexgym-bench-{way}-") as out:
        load_start = os.getloadavg()[0]
        cpu = _TreeCPU()
        t0 = time.perf_counter()
        paths = collect(out, samples_per_group=samples, seed=seed, workers=workers, progress=False,
                        config=config, ray=ray)  # fmt: skip
        wall = time.perf_counter() - t0
        cpu_s = cpu.stop()
        by_process = cpu.by_name()
        counted = {table: len(load_dataset(path)["y"]) for table, path in paths.items()}
        stats = [load_dataset(path)["meta"]["stats"] for table, path in paths.items() if table in ("boom", "stick")]
        chunk_s = sum(s["chunk_wall_seconds"] for s in stats)
        total = counted["boom"] + counted["stick"]  # each group's counted table
        return {
            "way": way, "samples": total, "wall_s": round(wall, 2), "samples_per_min": round(60.0 * total / wall, 1),
            "chunk_compute_s": round(chunk_s, 1), "efficiency": round(chunk_s / (workers * wall), 3),
            "cpu_s": round(cpu_s, 1), "load_avg_1min": [round(load_start, 2), round(os.getloadavg()[0], 2)],
            "digest": samples_digest(paths)[:16], "cpu_s_by_process": by_process,
        }  # fmt: skip


def ray_fixed_cost() -> dict[str, float]:
    """Seconds to start a local Ray (:func:`hexgym.parallel.connect`), and to shut it down."""
    from hexgym.parallel import executor

    t0 = time.perf_counter()
    pool = executor(ray="local")
    t1 = time.perf_counter()
    pool.close()
    return {"start_s": round(t1 - t0, 2), "shutdown_s": round(time.perf_counter() - t1, 2)}


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark ways in order and print one line each (and the Ray overhead and the scaling)."""
    parser = argparse.ArgumentParser(prog="python experiments/cluster_bench.py", description=__doc__.split("\n")[0])
    parser.add_argument("--samples", type=int, default=200, help="samples per group (default: 200)")
    parser.add_argument("--seed", type=int, default=0, help="collection seed (default: 0)")
    parser.add_argument("--episodes-per-chunk", type=int, default=2, help="episodes per chunk (default: 2)")
    parser.add_argument("--ways", default=",".join(WAYS), help=f"comma-separated, of {WAYS} (default: all)")
    parser.add_argument("--repeat", type=int, default=1, help="rounds over the ways (default: 1)")
    parser.add_argument("--ray-fixed-cost", action="store_true", help="also time a local Ray's start and shutdown")
    parser.add_argument("--json", default=None, help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    ways = [w for w in args.ways.split(",") if w]
    if not ways or set(ways) - set(WAYS):
        parser.error(f"--ways must name some of {WAYS}, got {args.ways!r}")
    config = CollectConfig(episodes_per_chunk=args.episodes_per_chunk)
    print(f"collection of {args.samples} samples per group, seed {args.seed}, {args.episodes_per_chunk} episodes "
          f"a chunk, {os.cpu_count()} cores", flush=True)  # fmt: skip
    runs: dict[str, list[dict[str, Any]]] = {way: [] for way in ways}
    for _ in range(max(1, args.repeat)):
        for way in ways:
            runs[way].append(run_way(way, args.samples, args.seed, config))
            print(json.dumps(runs[way][-1]), flush=True)
    if args.ray_fixed_cost:
        runs["ray_fixed_cost"] = [ray_fixed_cost() for _ in range(max(1, args.repeat))]
        print(json.dumps(runs["ray_fixed_cost"]), flush=True)
    digests = {r["digest"] for way in ways for r in runs[way]}
    keys = ("wall_s", "samples_per_min", "efficiency", "cpu_s")
    median = {way: {k: float(np.median([r[k] for r in runs[way]])) for k in keys} for way in ways}
    summary: dict[str, Any] = {"runs": runs, "median": median, "same_data": len(digests) == 1}
    if "pool2" in median and "ray" in median:
        summary["ray_overhead_wall"] = round(median["ray"]["wall_s"] / median["pool2"]["wall_s"] - 1.0, 4)
        summary["ray_overhead_efficiency"] = round(median["pool2"]["efficiency"] / median["ray"]["efficiency"] - 1, 4)
        summary["ray_overhead_cpu"] = round(median["ray"]["cpu_s"] / median["pool2"]["cpu_s"] - 1.0, 4)
    if "pool1" in median and "pool2" in median:
        summary["speedup_2_vs_1"] = round(median["pool2"]["samples_per_min"] / median["pool1"]["samples_per_min"], 3)
        efficiency = 2 * median["pool2"]["efficiency"] / median["pool1"]["efficiency"]
        summary["speedup_2_vs_1_efficiency"] = round(efficiency, 3)
    print(json.dumps({k: v for k, v in summary.items() if k != "runs"}))
    if args.json:
        write_json(args.json, summary | {"samples_per_group": args.samples, "seed": args.seed})
    return 0 if summary["same_data"] else 1


if __name__ == "__main__":
    sys.exit(main())
