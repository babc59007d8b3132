"""Running independent tasks in parallel: a local process pool, or Ray on this machine or a cluster.

Collection chunks, validation logs, evaluation episodes and planning seeds are independent tasks
whose results do not depend on where they run (each is seeded by its own index). The callers map a
function over them with an :class:`Executor` from :func:`executor`:

- ``ray=None``: :class:`LocalPool`, a spawn-context process pool of ``workers`` processes (or this
  process alone for one worker), as hexgym always ran;
- ``ray="local"``: :class:`RayExecutor` on a Ray started here with the cores this process may use,
  its workers at this process's niceness, as the pool's (:data:`LOCAL_SYSTEM_CONFIG`);
  ``ray="HOST:PORT"`` (or ``"auto"``, ``"ray://HOST:PORT"``) joins a running cluster
  (``ray start --head`` on one machine, ``ray start --address HOST:PORT`` on the others).

A Ray task whose worker dies (a killed process, a lost node) is run again (``MAX_RETRIES``);
an exception raised by the task itself is not retried and reaches the caller. Before any task runs
on a cluster it joins, :func:`connect` checks every node: the address must answer within
``CONNECT_TIMEOUT_S``, and each node must import hexgym with the driver's versions of hexgym,
Python, Ray, MuJoCo and NumPy within ``PROBE_TIMEOUT_S``; otherwise one :class:`ClusterError` line
names the node and what is missing.

Ray is the optional extra ``hexgym[cluster]``; this module imports it only when asked to use it.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import pickle
import platform
import signal
import socket
import threading
import uuid
from collections.abc import Callable, Iterable, Iterator
from typing import Any

INSTALL_HINT = 'Ray is not installed: pip install "hexgym[cluster]" (Ray with RLlib) to use --ray'
MAX_RETRIES = 3  # reruns of a task whose worker process or node died
CONNECT_TIMEOUT_S = 5.0  # for the address to accept a TCP connection
PROBE_TIMEOUT_S = 30.0  # for every node to start a worker and import hexgym
_VERSIONED = ("hexgym", "python", "ray", "mujoco", "numpy")
# A Ray started here (``--ray`` alone): Ray runs its workers at niceness 15 by default, below every
# other process; the local pool's workers run at this process's niceness, and so do these. On a
# machine shared with other work, niceness 15 leaves the workers the cores' leftovers.
LOCAL_SYSTEM_CONFIG = {"worker_niceness": 0}
# `ray start` enables token authentication by default since Ray 2.59: a driver without the token is refused
_AUTH_HINT = " (if the cluster uses token authentication, set RAY_AUTH_MODE=token here; its token: ray get-auth-token)"


class ClusterError(RuntimeError):
    """A Ray cluster that cannot run hexgym's tasks (one line: the node or address and what is wrong)."""


class Executor:
    """Maps a function over independent items; see :class:`LocalPool` and :class:`RayExecutor`."""

    workers: int  # how many items run at once

    def map_unordered(self, function: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        """``function(item)`` for each item, yielded as each finishes."""
        raise NotImplementedError

    def map(self, function: Callable[[Any], Any], items: Iterable[Any]) -> list[Any]:
        """``function(item)`` for each item, in the items' order."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the worker processes (and a Ray this executor started)."""

    def __enter__(self) -> Executor:
        return self

    def abort(self) -> None:
        """Stop the workers now, their tasks unfinished (an error or Ctrl-C in the caller)."""
        self.close()

    def __exit__(self, *exc: object) -> None:
        if exc[0] is None:
            self.close()
        else:
            self.abort()


def ignore_interrupts(initializer: Callable[..., None] | None = None, *initargs: Any) -> None:
    """A worker process's start: Ctrl-C, which the terminal sends to every process of the command, is left to
    the parent (it stops the workers and ends in one line), then ``initializer(*initargs)``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if initializer is not None:
        initializer(*initargs)


@contextlib.contextmanager
def interrupts_held() -> Iterator[None]:
    """Start processes with Ctrl-C ignored from their first instruction (a fresh Python installs its Ctrl-C handler
    only where the signal is not ignored, so a Ctrl-C while it starts raises nothing there); this process holds a
    Ctrl-C that comes meanwhile and gets it when the block ends. Outside the main thread: nothing to do."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous_mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})  # held, not lost: Linux keeps a
    previous_handler = signal.signal(signal.SIGINT, signal.SIG_IGN)  # blocked signal pending even while ignored
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous_handler)
        signal.pthread_sigmask(signal.SIG_SETMASK, previous_mask)


class LocalPool(Executor):
    """``workers`` spawned processes (this process alone for one), each set up once by ``initializer``."""

    def __init__(
        self, workers: int = 1, initializer: Callable[..., None] | None = None, initargs: tuple[Any, ...] = ()
    ) -> None:
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.workers, self._initializer, self._initargs = workers, initializer, initargs
        self._pool: Any = None
        self._initialized = False

    def _prepare(self, n: int) -> Any:
        """The pool for ``n`` items, or None to run them here (one worker or one item)."""
        if self.workers == 1 or n <= 1:
            if self._initializer is not None and not self._initialized:
                self._initializer(*self._initargs)
                self._initialized = True
            return None
        if self._pool is None:
            context = multiprocessing.get_context("spawn")  # fork would copy MuJoCo and thread state
            with interrupts_held():
                self._pool = context.Pool(min(self.workers, n), ignore_interrupts, (self._initializer, *self._initargs))
        return self._pool

    def map_unordered(self, function: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        items = list(items)
        pool = self._prepare(len(items))
        if pool is None:
            yield from map(function, items)
            return
        try:
            yield from pool.imap_unordered(function, items)
        except BaseException:  # Ctrl-C or an error: the workers stop now, not after their tasks
            self.abort()
            raise

    def map(self, function: Callable[[Any], Any], items: Iterable[Any]) -> list[Any]:
        items = list(items)
        pool = self._prepare(len(items))
        if pool is None:
            return list(map(function, items))
        try:
            return pool.map(function, items)
        except BaseException:
            self.abort()
            raise

    def close(self) -> None:
        if self._pool is not None:
            self._pool.close()
            self._pool.join()
            self._pool = None

    def abort(self) -> None:
        if self._pool is not None:
            self._pool.terminate()
            self._pool.join()
            self._pool = None


# Per worker process: the set-ups already run there (by executor token), so each runs once.
_SET_UP: set[str] = set()


def _call(function: Callable[[Any], Any], initializer: Any, initargs: tuple[Any, ...], token: str, item: Any) -> Any:
    """A Ray task's body: this process's set-up once per executor, then ``function(item)``.

    Ray hands NumPy arrays over read-only (zero-copy from its object store); a pickled copy gives the
    function writable ones, as a process pool does."""
    if initializer is not None and token not in _SET_UP:
        initializer(*pickle.loads(pickle.dumps(initargs)))
        _SET_UP.add(token)
    return function(pickle.loads(pickle.dumps(item)))


class RayExecutor(Executor):
    """Tasks on Ray: ``address`` "local" (a Ray started here), "auto", "HOST:PORT" or "ray://HOST:PORT".

    If this process is already connected to Ray, that connection is used (and left open). Each task
    asks for ``cpus_per_task`` cores; ``initializer(*initargs)`` runs once in each worker process
    that runs a task (``initargs`` are sent to the cluster once).
    """

    def __init__(
        self,
        address: str = "local",
        initializer: Callable[..., None] | None = None,
        initargs: tuple[Any, ...] = (),
        cpus_per_task: float = 1.0,
    ) -> None:
        ray = import_ray()
        self._started = connect(address)
        self._ray = ray
        self._remote = ray.remote(_call).options(num_cpus=cpus_per_task, max_retries=MAX_RETRIES)
        self._initializer = initializer
        self._initargs_ref = ray.put(initargs) if initializer is not None else None
        self._token = uuid.uuid4().hex
        node_cpus = [n.get("Resources", {}).get("CPU", 0.0) for n in ray.nodes() if n.get("Alive")]
        if cpus_per_task > max(node_cpus, default=0.0):
            self.close()
            raise ClusterError(
                f"each task needs {cpus_per_task:g} cores, the largest Ray node has {max(node_cpus, default=0.0):g}"
            )
        self.workers = max(1, int(sum(node_cpus) // max(cpus_per_task, 1e-9)))

    def _submit(self, function: Callable[[Any], Any], items: Iterable[Any]) -> list[Any]:
        return [self._remote.remote(function, self._initializer, self._initargs_ref, self._token, i) for i in items]

    def map_unordered(self, function: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        pending = self._submit(function, items)
        try:
            while pending:
                done, pending = self._ray.wait(pending, num_returns=1)
                yield self._ray.get(done[0])
        finally:
            for ref in pending:  # the caller stopped (an error, Ctrl-C): do not leave work running
                self._ray.cancel(ref, force=True)

    def map(self, function: Callable[[Any], Any], items: Iterable[Any]) -> list[Any]:
        refs = self._submit(function, items)
        try:
            return self._ray.get(refs)
        except BaseException:  # Ctrl-C or a task's error: the other tasks stop, not run on in the cluster
            for ref in refs:
                self._ray.cancel(ref, force=True)
            raise

    def close(self) -> None:
        if self._started and self._ray.is_initialized():
            self._ray.shutdown()
            self._started = False


def executor(
    workers: int = 1,
    ray: str | None = None,
    initializer: Callable[..., None] | None = None,
    initargs: tuple[Any, ...] = (),
    cpus_per_task: float = 1.0,
) -> Executor:
    """A :class:`RayExecutor` on ``ray`` (an address or "local"), else a :class:`LocalPool` of ``workers``."""
    if ray:
        return RayExecutor(ray, initializer, initargs, cpus_per_task)
    return LocalPool(workers, initializer, initargs)


def import_ray() -> Any:
    """The ``ray`` module, or a :class:`ClusterError` saying in one line what to install."""
    try:
        import ray
    except ImportError:
        raise ClusterError(INSTALL_HINT) from None
    return ray


def _check_reachable(address: str) -> None:
    """Refuse within ``CONNECT_TIMEOUT_S`` an address nothing listens on (ray.init would retry for a minute)."""
    if address in ("auto", "local"):
        return
    host_port = address.removeprefix("ray://").rstrip("/")
    host, _, port = host_port.rpartition(":")
    if not host or not port.isdigit():
        raise ClusterError(f"Ray address {address!r} is not HOST:PORT, ray://HOST:PORT, 'auto' or 'local'")
    try:
        connection = socket.create_connection((host, int(port)), timeout=CONNECT_TIMEOUT_S)
    except OSError as exc:
        raise ClusterError(
            f"no Ray cluster at {address}: {exc.strerror or exc or 'no answer'} within {CONNECT_TIMEOUT_S:g} s "
            "(start one with `ray start --head`, or give --ray local)"
        ) from None
    with connection:
        if not _answers_grpc(connection):  # ray.init would wait on it for minutes
            raise ClusterError(
                f"{address} answers but is no Ray cluster: no gRPC reply within {CONNECT_TIMEOUT_S:g} s (a Ray head's "
                "address is HOST:6379, its client server's ray://HOST:10001)"
            )


_HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])  # + an empty SETTINGS


def _answers_grpc(connection: socket.socket) -> bool:
    """Whether the server on ``connection`` speaks HTTP/2 as every Ray endpoint (gRPC) does: it answers the
    client preface with a SETTINGS frame within ``CONNECT_TIMEOUT_S``."""
    try:
        connection.settimeout(CONNECT_TIMEOUT_S)
        connection.sendall(_HTTP2_PREFACE)
        header = b""
        while len(header) < 9:
            chunk = connection.recv(9 - len(header))
            if not chunk:
                return False
            header += chunk
    except OSError:
        return False
    return header[3] == 4  # the frame's type: SETTINGS


def connect(address: str = "local", runtime_env: dict[str, Any] | None = None) -> bool:
    """Connect this process to Ray at ``address`` and check its nodes (:func:`check_nodes`).

    "local" starts a Ray here, which is not probed: its workers run this interpreter in this
    process's environment and working directory.

    Returns whether a Ray was started or joined here (the caller then shuts it down); False when
    this process was already connected. ``runtime_env``: Ray's runtime environment for this job's
    workers (e.g. ``{"env_vars": ...}``).
    """
    ray = import_ray()
    if ray.is_initialized():
        return False
    _check_reachable(address)
    kwargs: dict[str, Any] = {"include_dashboard": False, "logging_level": "ERROR", "runtime_env": runtime_env}
    kwargs["address"] = address  # "local": a new Ray here, even when `ray start` runs one on this machine
    if address == "local":
        kwargs["num_cpus"] = available_cores()
        kwargs["_system_config"] = LOCAL_SYSTEM_CONFIG
    try:
        ray.init(**kwargs)
    except Exception as exc:  # Ray's own version check, a refused client connection, a missing token
        auth = "" if os.environ.get("RAY_AUTH_MODE") else _AUTH_HINT
        text = " ".join(str(exc).split())[:300]
        raise ClusterError(f"cannot join the Ray cluster at {address}: {text}{auth}") from None
    if address == "local":  # its workers run this interpreter in this environment: nothing to probe
        return True
    try:
        check_nodes()
    except BaseException:
        ray.shutdown()
        raise
    return True


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity where the system tells it, else all)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0)) or 1
    return os.cpu_count() or 1


def versions() -> dict[str, str]:
    """This process's versions of what must match across the cluster, and its node's address."""
    import mujoco
    import numpy

    import hexgym

    ray = import_ray()
    return {
        "hexgym": hexgym.__version__,
        "python": platform.python_version(),
        "ray": ray.__version__,
        "mujoco": mujoco.__version__,
        "numpy": numpy.__version__,
        "node": ray.util.get_node_ip_address(),
    }


def check_nodes(timeout_s: float = PROBE_TIMEOUT_S) -> dict[str, dict]:
    """Run a probe on every alive node; returns its :func:`versions` by node address.

    Raises :class:`ClusterError` naming the first node that cannot import hexgym, runs other
    versions than this process, or does not answer within ``timeout_s``.
    """
    ray = import_ray()
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    mine = versions()
    nodes = [n for n in ray.nodes() if n.get("Alive")]
    probe = ray.remote(versions)
    refs = {
        n["NodeManagerAddress"]: probe.options(
            num_cpus=0,
            max_retries=0,
            scheduling_strategy=NodeAffinitySchedulingStrategy(n["NodeID"], soft=False),
        ).remote()
        for n in nodes
    }
    ready, _ = ray.wait(list(refs.values()), num_returns=len(refs), timeout=timeout_s)
    found: dict[str, dict] = {}
    for node, ref in refs.items():
        if ref not in ready:
            ray.cancel(ref, force=True)
            raise ClusterError(f"Ray node {node} did not answer hexgym's probe within {timeout_s:g} s")
        try:
            theirs = ray.get(ref)
        except Exception as exc:
            cause = getattr(exc, "cause", None) or exc
            text = " ".join(str(cause).split())
            if "hexgym" in text and ("No module named" in text or "ModuleNotFound" in text):
                raise ClusterError(
                    f'Ray node {node} cannot import hexgym: install it there (pip install "hexgym[cluster]")'
                ) from None
            raise ClusterError(f"Ray node {node} failed hexgym's probe: {type(cause).__name__}: {text[:200]}") from None
        wrong = [f"{k} {theirs.get(k)} (here {mine[k]})" for k in _VERSIONED if theirs.get(k) != mine[k]]
        if wrong:
            raise ClusterError(f"Ray node {node} runs other versions than this driver: {', '.join(wrong)}")
        found[node] = theirs
    return found
