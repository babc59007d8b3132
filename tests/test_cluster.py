"""Parallel tasks (:mod:`hexgym.parallel`): the local pool and Ray give the same results; a killed Ray worker's
task is redone; a bad cluster is refused in one line within seconds. Ray tests are skipped without Ray."""

from __future__ import annotations

import json
import operator
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from hexgym.parallel import LocalPool, executor
from hexgym_lab.cli import build_parser
from hexgym_lab.mbl.collect import CollectConfig, chunk_path, collect, samples_digest

ROOT = Path(__file__).resolve().parent.parent
TINY = CollectConfig(
    table_set="paper", segments_per_episode=3, episodes_per_chunk=1, hold_s=(0.7, 0.8), windows_per_segment=1
)
SEED = 6


@pytest.fixture(scope="module")
def ray_session():
    """One local Ray (2 CPUs) for the module's Ray tests; hexgym's executors join it."""
    ray = pytest.importorskip("ray")
    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="ERROR")
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def pool_data(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A small collection in the local process pool (one worker: the reference for every other way)."""
    out = tmp_path_factory.mktemp("pool")
    return collect(out, samples_per_group=12, seed=SEED, workers=1, progress=False, config=TINY)


@pytest.mark.parametrize("workers", [1, 2])
def test_local_pool_maps_in_order_and_unordered(workers: int) -> None:
    with LocalPool(workers) as pool:
        assert pool.map(operator.neg, range(5)) == [0, -1, -2, -3, -4]
        assert sorted(pool.map_unordered(abs, [-3, 1, -2])) == [1, 2, 3]
    with pytest.raises(ValueError, match="workers"):
        LocalPool(0)


def test_ray_option_on_every_parallel_command() -> None:
    parser = build_parser()
    for argv in (["collect"], ["validate", "--suite", "1"], ["evaluate"], ["plan", "--task", "dump", "--seeds", "0-1"]):
        assert parser.parse_args(argv).ray is None
        assert parser.parse_args([*argv, "--ray"]).ray == "local"
        assert parser.parse_args([*argv, "--ray", "10.0.0.1:6379"]).ray == "10.0.0.1:6379"
    args = parser.parse_args(["train", "--framework", "rllib", "--num-env-runners", "3", "--ray", "auto"])
    assert (args.framework, args.num_env_runners, args.ray) == ("rllib", 3, "auto")


def _hexgym(*argv: str, code: str = "") -> subprocess.CompletedProcess:
    """``hexgym ARGV`` in a fresh interpreter (``code`` run first), with a time limit."""
    script = f"import sys\n{code}\nfrom hexgym_lab.cli import main\nsys.exit(main({list(argv)!r}))"
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, cwd=ROOT)


def test_hexgym_and_its_cli_do_not_import_ray() -> None:
    code = (
        "import sys, hexgym, gymnasium, hexgym.parallel, hexgym_lab.cli, hexgym_lab.agents.evaluate\n"
        "gymnasium.make('HexLoading-v0').reset(seed=0)\n"
        "hexgym_lab.cli.build_parser()\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] == 'ray'))"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert run.returncode == 0 and run.stdout.strip() == "[]", run.stdout + run.stderr


def test_without_ray_the_ray_option_says_what_to_install(tmp_path: Path) -> None:
    run = _hexgym("collect", "--out", str(tmp_path), "--samples", "4", "--ray", code="sys.modules['ray'] = None")
    assert run.returncode == 2
    assert run.stderr.count("\n") == 1 and 'pip install "hexgym[cluster]"' in run.stderr, run.stderr
    assert not list(tmp_path.rglob("*.npz"))


def test_unreachable_address_is_one_line_within_seconds(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    t0 = time.perf_counter()
    run = _hexgym("collect", "--out", str(tmp_path), "--samples", "4", "--ray", "127.0.0.1:9")
    assert time.perf_counter() - t0 < 30
    assert run.returncode == 2 and run.stderr.count("\n") == 1, run.stderr
    assert "no Ray cluster at 127.0.0.1:9" in run.stderr


def test_ray_collection_equals_the_local_pool(ray_session, pool_data: dict[str, Path], tmp_path: Path) -> None:
    paths = collect(tmp_path, samples_per_group=12, seed=SEED, progress=False, config=TINY, ray="local")
    assert samples_digest(paths) == samples_digest(pool_data)
    assert ray_session.is_initialized()  # a Ray this process was connected to stays up


def _parent(pid: int | str) -> int:
    """The parent pid of a process (from /proc)."""
    text = Path(f"/proc/{pid}/stat").read_text()
    return int(text[text.rindex(")") + 2 :].split()[1])


def _stored_chunks(out: Path) -> list[Path]:
    """The collection's stored chunks, not the hidden temporary files a chunk is written to before its rename."""
    return sorted((out / "chunks").glob("[!.]*.npz"))


def _worker_running_a_task() -> int | None:
    """The pid of a worker of this process's Ray (a child of its raylet, which is this process's child)
    that is running one of hexgym's tasks (its title ``ray::_call``), if any: never another Ray's."""
    for entry in Path("/proc").iterdir():
        try:
            if entry.name.isdigit() and (entry / "cmdline").read_bytes().startswith(b"ray::_call"):
                if _parent(_parent(entry.name)) == os.getpid():
                    return int(entry.name)
        except (OSError, ValueError, IndexError):  # ended while listed
            continue
    return None


@pytest.mark.skipif(not Path("/proc/self/cmdline").exists(), reason="finds the worker through /proc")
def test_a_killed_worker_loses_no_finished_chunk(ray_session, pool_data: dict[str, Path], tmp_path: Path) -> None:
    result: dict[str, object] = {}
    run = threading.Thread(target=lambda: result.update(paths=collect(
        tmp_path, samples_per_group=12, seed=SEED, progress=False, config=TINY, ray="local")))  # fmt: skip
    run.start()
    deadline, killed, before = time.time() + 120, None, {}
    while killed is None and run.is_alive() and time.time() < deadline:
        pid = _worker_running_a_task()
        if pid is not None and _stored_chunks(tmp_path):  # mid-run: a chunk is already stored
            before = {p: p.stat().st_mtime_ns for p in _stored_chunks(tmp_path)}
            os.kill(pid, signal.SIGKILL)
            killed = pid
        time.sleep(0.02)
    run.join(timeout=300)
    assert killed is not None, "no Ray worker was caught running a chunk"
    assert samples_digest(result["paths"]) == samples_digest(pool_data)  # the killed task was run again
    assert all(p.stat().st_mtime_ns == t for p, t in before.items())  # finished chunks kept, not redone


def test_a_ray_collection_interrupted_resumes_in_the_pool(ray_session, pool_data, tmp_path: Path) -> None:
    kwargs = {"samples_per_group": 12, "seed": SEED, "progress": False, "config": TINY}
    assert collect(tmp_path, **kwargs, ray="local", max_chunks=2) == {}
    first = chunk_path(tmp_path, "boom_bucket", 0).read_bytes()
    resumed = collect(tmp_path, **kwargs, workers=2)
    assert chunk_path(tmp_path, "boom_bucket", 0).read_bytes() == first
    assert samples_digest(resumed) == samples_digest(pool_data)


def test_ray_validation_suite_and_figure_equal_the_pool(ray_session, tmp_path: Path) -> None:
    from hexgym_lab.validate import run_validation

    kwargs = {"suite": 2, "suite_seed": 5, "suite_only": True, "suite_duration_s": 4.0}
    # two processes: one log per fresh model, as on Ray (one process replaying both logs on one model
    # differs in the last digits)
    pool = run_validation(tmp_path / "pool", workers=2, **kwargs)
    on_ray = run_validation(tmp_path / "ray", ray="local", **kwargs)
    assert json.dumps(on_ray, sort_keys=True) == json.dumps(pool, sort_keys=True)
    figure = [(tmp_path / way / "suite_worst.png").read_bytes() for way in ("pool", "ray")]
    assert figure[0] == figure[1]


def test_ray_evaluation_equals_one_process(ray_session) -> None:
    from hexgym_lab.agents.evaluate import evaluate

    kwargs = {"episodes": 2, "seed": 3, "env_kwargs": {"time_limit": 3.0}}
    assert evaluate("scripted", ray="local", **kwargs) == evaluate("scripted", **kwargs)


# Stand-ins for badly installed nodes: run in each worker process before any task (Ray's setup hook).
FAKE_NODES = """
import sys


def old_hexgym():
    import hexgym

    hexgym.__version__ = "0.0.1"


class _Hide:
    def find_spec(self, name, path=None, target=None):
        if name == "hexgym" or name.startswith("hexgym."):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)


def no_hexgym():
    sys.meta_path.insert(0, _Hide())
    for name in [m for m in sys.modules if m == "hexgym" or m.startswith("hexgym.")]:
        del sys.modules[name]
"""


def _join(address: str, hook: str | None, hooks_dir: Path) -> str:
    """Join the cluster at ``address`` from a new driver whose workers run ``hook``: 'ok' or the error line."""
    env = {"env_vars": {"PYTHONPATH": str(hooks_dir)}, "worker_process_setup_hook": hook} if hook else None
    code = (
        "from hexgym.parallel import ClusterError, connect\n"
        f"try:\n    connect({address!r}, runtime_env={env!r})\n    print('ok')\n"
        "except ClusterError as exc:\n    print(exc)\n"
    )
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120).stdout.strip()


def test_nodes_report_versions_and_a_bad_install_is_named(ray_session, tmp_path: Path) -> None:
    from hexgym.parallel import check_nodes, versions

    assert list(check_nodes().values()) == [versions()]
    (tmp_path / "fake_nodes.py").write_text(FAKE_NODES)
    address = ray_session.get_runtime_context().gcs_address
    assert _join(address, None, tmp_path) == "ok"
    t0 = time.perf_counter()
    line = _join(address, "fake_nodes.old_hexgym", tmp_path)
    assert re.fullmatch(r"Ray node \S+ runs other versions than this driver: hexgym 0\.0\.1 \(here \S+\)", line), line
    line = _join(address, "fake_nodes.no_hexgym", tmp_path)
    assert re.fullmatch(
        r'Ray node \S+ cannot import hexgym: install it there \(pip install "hexgym\[cluster\]"\)', line
    )
    assert time.perf_counter() - t0 < 60  # seconds each, not a hang


def test_a_ray_started_here_runs_its_workers_as_the_pool_would() -> None:
    """``--ray`` alone: as many workers as this process's cores, at this process's niceness (not Ray's 15)."""
    pytest.importorskip("ray")
    code = (
        "import os\nfrom hexgym.parallel import available_cores, executor\n"
        "with executor(ray='local') as pool:\n"
        "    print(pool.workers == available_cores(), sorted(set(pool.map(os.nice, [0] * 4))))"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert run.stdout.strip() == f"True [{os.nice(0)}]", run.stdout + run.stderr[-2000:]


def test_executor_refuses_tasks_larger_than_any_node(ray_session) -> None:
    from hexgym.parallel import ClusterError

    with pytest.raises(ClusterError, match="needs 64 cores"):
        executor(ray="local", cpus_per_task=64)


@pytest.mark.slow
def test_ray_planning_sweep_equals_the_sequential_one(ray_session) -> None:
    from hexgym_lab.plan import run_plan

    def figures(result: dict) -> list[dict]:
        return [{k: v for k, v in r.items() if not k.endswith("wall_s")} for r in result["per_seed"]]

    kwargs = {"budget": 40, "nthread": 1}
    assert figures(run_plan("dump", [0, 1], ray="local", **kwargs)) == figures(run_plan("dump", [0, 1], **kwargs))


def _ray_daemons() -> int:
    """How many Ray GCS servers run on this machine (one per local Ray)."""
    count = 0
    for entry in Path("/proc").iterdir():
        try:
            count += entry.name.isdigit() and b"gcs_server" in (entry / "cmdline").read_bytes().split(b"\0")[0]
        except OSError:
            continue
    return count


@pytest.mark.slow  # ~25 s: a Ray started and stopped in a second driver
def test_an_interrupted_ray_driver_keeps_its_chunks_and_resumes(ray_session, pool_data, tmp_path: Path) -> None:
    """Ctrl-C to ``hexgym collect --ray``: status 130, the stored chunks kept, its Ray shut down; it resumes."""
    daemons = _ray_daemons()
    argv = ["collect", "--out", str(tmp_path), "--samples", "12", "--seed", str(SEED), "--ray"]
    code = (
        "import sys\nimport hexgym_lab.mbl.collect as c\nfrom tests.test_cluster import TINY\n"
        "real = c.CollectConfig\n"  # the command's own config becomes TINY; configs read back from chunks stay
        "c.CollectConfig = lambda table_set=None, **kw: real(table_set=table_set, **kw) if kw else TINY\n"
        "from hexgym_lab.cli import main\n"
        f"sys.exit(main({argv!r}))"
    )
    driver = subprocess.Popen([sys.executable, "-c", code], cwd=ROOT, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while not _stored_chunks(tmp_path) and driver.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    driver.send_signal(signal.SIGINT)
    _, err = driver.communicate(timeout=60)
    # 130 and "interrupted"; now and then Ray's core worker dies of the signal first (status 1, its trace)
    assert driver.returncode == 130 and "interrupted" in err or driver.returncode == 1, err
    stored = _stored_chunks(tmp_path)
    assert stored and not (tmp_path / "boom.npz").exists()
    assert _ray_daemons() == daemons  # the Ray it started is gone
    kwargs = {"samples_per_group": 12, "seed": SEED, "progress": False, "config": TINY}
    assert samples_digest(collect(tmp_path, **kwargs, workers=2)) == samples_digest(pool_data)
