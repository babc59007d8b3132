"""``hexgym bench``: the speed figures in one process.

- ``hexloading_steps_per_s`` / ``hopper_steps_per_s``: HexLoading-v0 (default backend: the native
  plugin when built) against Gymnasium's Hopper-v5, both made with ``gymnasium.make`` (so both carry
  Gymnasium's default wrappers), seeded, reset, then stepped with seeded random actions; only
  ``step`` calls are timed (a reset after an episode end is not). They are stepped in turn, ten
  blocks each, so a slower spell of the machine weighs on both. ``ratio`` is the first over the
  second (target >= 1.0).
- ``vector_steps_per_s``: environment steps (transitions) per second of
  ``gymnasium.make_vec("HexLoading-v0", num_envs=64)`` with random actions: the registered vector
  entry point when there is one, else Gymnasium's ``SyncVectorEnv`` (``vector_env`` names which ran).
- ``learned_realtime_factor_native`` (the default model, the circuit model, in the plugin; one thread;
  target >= 2,500x), ``paper_realtime_factor_native`` (the paper's tables), ``batch_realtime_factor_native``
  (64 rollouts on every core) and ``batch_speedup`` (over the same batch on one thread; target >= 1.8 on 2):
  simulated seconds per wall second of the machine model alone; ``circuit_cost_us`` splits a circuit period's
  microseconds into the circuit's steps and the joints' coupling at one state (:func:`circuit_cost_split`), and
  gives the rest of a step over Test 3 (MuJoCo's step, the plugin around the kernel, costlier periods);
  ``circuit_realtime_factor_python`` / ``learned_realtime_factor_python`` the Python models (the circuit model
  around the same native kernel; the paper tables).
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable
from pathlib import Path

import gymnasium as gym
import mujoco
import numpy as np

from hexgym.envs import ENV_ID  # importing hexgym registers it
from hexgym.files import write_json
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.mbl.schema import DEFAULT_TABLE_SET
from hexgym.model.base import LearnedModelBase
from hexgym.model.circuit_model import CircuitModel
from hexgym.model.commandlog import CommandLog
from hexgym.model.native_backend import NativeLearnedModel
from hexgym.model.plugin import CTRL_PER_SPOOL_M, native_available
from hexgym.model.python_backend import LearnedModel
from hexgym_lab.scenarios import scenarios

REFERENCE_ENV = "Hopper-v5"
VECTOR_ENVS = 64
BATCH_ROLLOUTS = 64


def steps_per_second(env_id: str, steps: int, seed: int = 0, **kwargs: object) -> float:
    """Random-action ``step`` calls per second of ``env_id`` made with ``kwargs`` (resets excluded from the timing)."""
    return interleaved_steps_per_second({env_id: (env_id, kwargs)}, steps, seed)[env_id]


def interleaved_steps_per_second(
    envs: dict[str, tuple[str, dict]], steps: int, seed: int = 0, rounds: int = 10
) -> dict[str, float]:
    """Random-action ``step`` calls per second of each named ``(env_id, make kwargs)``, stepped in turn in
    ``rounds`` blocks of ``steps / rounds`` steps each, so that a change of the machine's speed during the
    run (other processes, a VM's neighbours) weighs on all of them alike and their ratios stay fair."""
    if steps < 1 or rounds < 1:
        raise ValueError(f"steps and rounds must be >= 1, got {steps} and {rounds}")
    made = {name: gym.make(env_id, **kwargs) for name, (env_id, kwargs) in envs.items()}
    try:
        actions = {}
        for name, env in made.items():
            env.reset(seed=seed)
            env.action_space.seed(seed)
            actions[name] = [env.action_space.sample() for _ in range(steps)]
        elapsed = dict.fromkeys(made, 0.0)
        bounds = np.linspace(0, steps, min(rounds, steps) + 1).astype(int)
        for first, last in zip(bounds[:-1], bounds[1:], strict=True):
            for name, env in made.items():
                elapsed[name] += _timed_steps(env, actions[name][first:last])
        return {name: steps / seconds for name, seconds in elapsed.items()}
    finally:
        for env in made.values():
            env.close()


def _timed_steps(env: gym.Env, actions: list) -> float:
    """Wall seconds in ``env.step`` over ``actions`` (an episode's end resets, untimed)."""
    elapsed = 0.0
    for action in actions:
        start = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(action)
        elapsed += time.perf_counter() - start
        if terminated or truncated:
            env.reset()
    return elapsed


def _cores() -> int:
    """The CPUs this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


WARMUP_STEPS = 3  # untimed vector steps first: a fresh install compiles the task's functions on the first ones


def vector_steps_per_second(
    env_id: str = ENV_ID, num_envs: int = VECTOR_ENVS, vector_steps: int = 32, seed: int = 0
) -> tuple[float, str]:
    """Environment steps per second of ``gymnasium.make_vec(env_id, num_envs)`` under random actions,
    and the vector env's class name (only ``step`` calls are timed, after ``WARMUP_STEPS``; its autoreset is
    part of them)."""
    rates, kind = vector_benchmark(env_id, num_envs, vector_steps, seed, physics=False)
    return rates["vector_steps_per_s"], kind


def physics_bound_steps_per_second(num_envs: int = VECTOR_ENVS, vector_steps: int = 100, seed: int = 0) -> float:
    """Environment steps per second that the batch's physics alone allows: ``num_envs`` sites stepped a whole
    0.1 s step (its control periods in one ``Batch.step``) under random spools, no task logic. The vector env
    cannot beat this on the same cores: it is the physics' share of the speed target."""
    from hexgym.envs.vector import HexLoadingVectorEnv

    if num_envs < 1 or vector_steps < 1:
        raise ValueError(f"num_envs and vector_steps must be >= 1, got {num_envs} and {vector_steps}")
    envs = HexLoadingVectorEnv(num_envs, backend="native")
    try:
        envs.reset(seed=seed)
        rng = np.random.default_rng(seed)
        spools = rng.uniform(-1.0, 1.0, (vector_steps, num_envs, 4)) * p.SPOOL_STROKE * CTRL_PER_SPOOL_M
        elapsed = sum(envs.step_physics_only(row) for row in spools)
        return num_envs * vector_steps / elapsed
    finally:
        envs.close()


def vector_benchmark(
    env_id: str = ENV_ID,
    num_envs: int = VECTOR_ENVS,
    vector_steps: int = 1000,
    seed: int = 0,
    rounds: int = 10,
    physics: bool = True,
) -> tuple[dict[str, float], str]:
    """``vector_steps_per_s``: environment steps per second of ``gymnasium.make_vec(env_id, num_envs)`` under
    random actions (its autoreset included), and with ``physics`` (when the registered batched env runs)
    ``vector_physics_bound_steps_per_s``: the same sites' physics alone (:meth:`step_physics_only`: a whole
    step in one ``Batch.step``, no task logic). Both are timed in turn in ``rounds`` blocks, after
    ``WARMUP_STEPS`` untimed steps, so that the machine's drift weighs on both alike; ``vector_backend``:
    the batched env's backend (None for another vector env). Also returns the vector env's class name."""
    if num_envs < 1 or vector_steps < 1 or rounds < 1:
        raise ValueError(f"num_envs, vector_steps and rounds must be >= 1, got {num_envs}, {vector_steps}, {rounds}")
    envs = gym.make_vec(env_id, num_envs=num_envs)
    kind = type(envs).__name__
    backend = getattr(envs.unwrapped, "backend", None)  # the registered batched env's: "native" or "python"
    bound = None
    try:
        envs.reset(seed=seed)
        envs.action_space.seed(seed)
        for _ in range(WARMUP_STEPS):
            envs.step(envs.action_space.sample())
        actions = [envs.action_space.sample() for _ in range(vector_steps)]
        if physics and backend == "native":  # the batch (not Python machines)
            from hexgym.envs.vector import HexLoadingVectorEnv

            bound = HexLoadingVectorEnv(num_envs, backend="native")
            bound.reset(seed=seed)
            spools = np.asarray(actions, dtype=float) * p.SPOOL_STROKE * CTRL_PER_SPOOL_M
        elapsed = {"env": 0.0, "physics": 0.0}
        edges = np.linspace(0, vector_steps, min(rounds, vector_steps) + 1).astype(int)
        for first, last in zip(edges[:-1], edges[1:], strict=True):
            start = time.perf_counter()
            for action in actions[first:last]:
                envs.step(action)
            elapsed["env"] += time.perf_counter() - start
            if bound is not None:
                elapsed["physics"] += sum(bound.step_physics_only(row) for row in spools[first:last])
        rates: dict = {"vector_steps_per_s": num_envs * vector_steps / elapsed["env"], "vector_backend": backend}
        if bound is not None:
            rates["vector_physics_bound_steps_per_s"] = num_envs * vector_steps / elapsed["physics"]
        return rates, kind
    finally:
        envs.close()
        if bound is not None:
            bound.close()


def mujoco_step_profile(steps: int = 500, seed: int = 0) -> dict[str, float]:
    """MuJoCo's timers over ``steps`` random steps of one native HexLoadingEnv: wall s per ``mj_step`` and the
    shares of the plugin's actuation (its table lookups) and of collision detection in it."""
    from hexgym.envs.loading import HexLoadingEnv

    env = HexLoadingEnv(backend="native")
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(rng.uniform(-1.0, 1.0, 4))
        if terminated or truncated:
            env.reset()
    timer, kind = env.physics.data.timer, mujoco.mjtTimer
    step = timer[kind.mjTIMER_STEP]
    return {
        "step_s": step.duration / max(step.number, 1),
        "actuation_share": timer[kind.mjTIMER_ACTUATION].duration / step.duration,
        "collision_share": timer[kind.mjTIMER_POS_COLLISION].duration / step.duration,
    }


def warm_up(steps: int = 80, seed: int = 0) -> float:
    """Run the scripted loader into the pile for ``steps`` untimed steps, so that every compiled function of the
    loading task (:mod:`hexgym.envs.task`) is compiled or loaded from numba's cache before anything is timed;
    returns its wall seconds (on a fresh install, the first-call compile time)."""
    from hexgym.agents.scripted import ScriptedLoader
    from hexgym.envs.loading import HexLoadingEnv

    start = time.perf_counter()
    env, loader = HexLoadingEnv(), ScriptedLoader()
    env.reset(seed=seed)
    for _ in range(steps):  # it cuts the pile from about step 50
        env.step(loader.act(env))
    env.close()
    return time.perf_counter() - start


def run_bench(steps: int = 2000, seed: int = 0, seconds: float = 2.0) -> dict:
    """All figures (see the module docstring); ``steps`` random steps per single environment (and ``steps / 2``
    steps of the vector env of 64), ``seconds`` of wall time per real-time factor."""
    if not seconds > 0:
        raise ValueError(f"seconds must be > 0, got {seconds}")
    warm_up_s = warm_up(seed=seed)
    rates = interleaved_steps_per_second(
        {"loading": (ENV_ID, {}), "hopper": (REFERENCE_ENV, {}), "python": (ENV_ID, {"backend": "python"})},
        steps, seed,
    )  # fmt: skip
    loading, hopper, python = rates["loading"], rates["hopper"], rates["python"]
    vector_rates, vector_env = vector_benchmark(vector_steps=max(1, steps // 2), seed=seed)
    vector, bound = vector_rates["vector_steps_per_s"], vector_rates.get("vector_physics_bound_steps_per_s")
    result = {
        "steps": steps,
        "hexloading_steps_per_s": loading,
        "hexloading_backend": "native" if native_available() else "python",
        "hopper_steps_per_s": hopper,
        "ratio": loading / hopper,
        "hexloading_python_steps_per_s": python,  # backend="python": the machine model in Python
        "ratio_python": python / hopper,
        "vector_steps_per_s": vector,
        "vector_envs": VECTOR_ENVS,
        "vector_env": vector_env,
        "vector_backend": vector_rates["vector_backend"],
        "vector_ratio": vector / hopper,
        # what the batch's physics alone allows the vector env (no task logic): the ceiling of vector_steps_per_s
        "vector_physics_bound_steps_per_s": bound,
        "vector_physics_share": vector / bound if bound else None,  # target >= 0.7
        "hexloading_sim_seconds_per_s": loading * 0.1,  # one step is 0.1 s of simulated time
        "warm_up_s": warm_up_s,  # untimed scripted steps first: on a fresh install, the task's compile time
        **native_benchmark(seconds=seconds),  # learned_realtime_factor_python / _native (one thread)
    }
    if native_available():
        one = batch_benchmark(BATCH_ROLLOUTS, nthread=1, seconds=seconds)["batch_realtime_factor_native"]
        result.update(batch_benchmark(BATCH_ROLLOUTS, seconds=seconds), batch_rollouts=BATCH_ROLLOUTS)
        result["batch_realtime_factor_native_1thread"] = one
        result["batch_speedup"] = result["batch_realtime_factor_native"] / one  # target >= 1.8 on 2 threads
        # what the batch made of each core it got: with other processes on the cores it got fewer
        result["batch_realtime_factor_per_core"] = result["batch_realtime_factor_native"] / result["batch_cores_used"]
        # where one native mj_step of the loading site spends its time (MuJoCo's timers)
        result["native_step_profile"] = mujoco_step_profile(seed=seed)
    result.update(
        machine=platform.processor() or platform.machine(),
        cpus=os.cpu_count(),
        python=platform.python_version(),
        numpy=np.__version__,
    )
    return result


def print_bench(result: dict, json_path: str | Path | None = None) -> None:
    """Print the figures; with ``json_path`` also write them as JSON (atomically)."""
    r = result
    print(f"{ENV_ID}: {r['hexloading_steps_per_s']:.0f} steps/s ({r['steps']} random steps, {r['hexloading_backend']})")
    print(f"{REFERENCE_ENV}:     {r['hopper_steps_per_s']:.0f} steps/s")
    print(f"ratio:         {r['ratio']:.3f} (target >= 1.0)")
    print(
        f"{ENV_ID}, backend='python': {r['hexloading_python_steps_per_s']:.0f} steps/s, ratio {r['ratio_python']:.3f}"
    )
    vector = f"vector ({r['vector_envs']} envs, {r['vector_env']}, backend {r['vector_backend']})"
    print(f"{vector}: {r['vector_steps_per_s']:.0f} env steps/s, ratio {r['vector_ratio']:.3f}")
    if r["vector_physics_bound_steps_per_s"] is not None:
        bound = r["vector_physics_bound_steps_per_s"]
        ratio = bound / r["hopper_steps_per_s"]
        print(f"  its physics alone (no task logic): {bound:.0f} env steps/s, ratio {ratio:.3f}")
        print(f"  vector / physics alone: {r['vector_steps_per_s'] / bound:.3f} (target >= 0.7)")
    for key in ("learned_realtime_factor_python", "circuit_realtime_factor_python", "learned_realtime_factor_native",
                "paper_realtime_factor_native"):  # fmt: skip
        print(f"{key}: {result.get(key, float('nan')):.0f}x real time (one thread)")
    if "circuit_cost_us" in result:
        c = result["circuit_cost_us"]
        print(
            f"circuit model's 25 ms period: {c['period']:.1f} us in the kernel ({c['circuit']:.1f} circuit steps, "
            f"{c['joints']:.1f} joints) at one state; per step over Test 3 {c['rest_of_step']:.1f} us more (MuJoCo, "
            "the plugin, the log's costlier periods)"
        )
    if "batch_realtime_factor_native" in result:
        print(
            f"batch_realtime_factor_native: {result['batch_realtime_factor_native']:.0f}x real time"
            f" ({result['batch_rollouts']} rollouts, {result['batch_threads']} threads,"
            f" {result['batch_cores_used']:.2f} cores used: {result['batch_realtime_factor_per_core']:.0f}x per core)"
        )
        print(
            f"  one thread: {result['batch_realtime_factor_native_1thread']:.0f}x real time; speed-up "
            f"{result['batch_speedup']:.2f} (target >= 1.8 on 2 threads)"
        )
    if json_path is not None:
        from hexgym_lab.progress import wrote

        wrote(write_json(json_path, result), "the figures")


def _timed_with_cores(run: Callable[[], float], seconds: float) -> tuple[float, float]:
    """Simulated seconds per wall second of ``run`` (which returns the seconds it simulated), repeated
    for at least ``seconds`` of wall time, and the cores the process got meanwhile (CPU / wall seconds)."""
    simulated, wall, cpu = 0.0, 0.0, 0.0
    while wall < seconds:
        t0, c0 = time.perf_counter(), time.process_time()
        simulated += run()
        wall += time.perf_counter() - t0
        cpu += time.process_time() - c0
    return simulated / wall, cpu / wall


def _timed(run: Callable[[], float], seconds: float) -> float:
    """Simulated seconds per wall second of ``run`` (see :func:`_timed_with_cores`)."""
    return _timed_with_cores(run, seconds)[0]


def _test3() -> tuple[CommandLog, np.ndarray]:
    return scenarios()["test3"]


def _test3_controls(model: LearnedModelBase) -> np.ndarray:
    """Test 3's spools (mm), one row per control period of ``model`` (one step of the lean machine)."""
    log, _ = _test3()
    n = int(round(log.duration / model.control_period))
    return np.array([log.spools_at((k + 1e-9) * model.control_period) for k in range(n)])


def native_rollout_realtime_factor(seconds: float = 3.0, table_set: str = DEFAULT_TABLE_SET) -> float:
    """The native model's own speed (``table_set``'s): ``hexgym validate``'s Test 3 spools as ``mujoco.rollout``'s
    open-loop controls, one thread, in simulated seconds per wall second (needs the plugin)."""
    from mujoco import rollout

    _, pose = _test3()
    native = NativeLearnedModel(table_set=table_set)
    m, d = native.physics.model, native.physics.data
    control = _test3_controls(native)[None]  # mm
    n = control.shape[1]
    state_kind = mujoco.mjtState.mjSTATE_FULLPHYSICS
    native.reset(pose)
    x0 = np.empty(mujoco.mj_stateSize(m, state_kind))
    mujoco.mj_getState(m, d, x0, state_kind)
    states = np.empty((1, n, x0.size))
    rollout_data = mujoco.MjData(m)

    def run_rollout() -> float:
        rollout.rollout(m, rollout_data, x0[None], control, initial_warmstart=None, state=states)
        return n * native.control_period

    return _timed(run_rollout, seconds)


def batch_realtime_factor_native(
    nbatch: int = 64, nthread: int | None = None, seconds: float = 3.0, seed: int = 0
) -> float:
    """Simulated seconds of ``nbatch`` native rollouts per wall second, ``nthread`` threads (default:
    every core) of ``mujoco.rollout`` (needs the plugin); see :func:`batch_benchmark`."""
    return batch_benchmark(nbatch, nthread, seconds, seed)["batch_realtime_factor_native"]


def batch_benchmark(nbatch: int = 64, nthread: int | None = None, seconds: float = 3.0, seed: int = 0) -> dict:
    """``batch_realtime_factor_native``: simulated seconds of ``nbatch`` native rollouts per wall
    second on ``nthread`` threads (default: one per CPU this process may use) of ``mujoco.rollout`` (needs the plugin);
    ``batch_cores_used``: the cores the process got meanwhile (CPU / wall seconds: below ``nthread``
    when other processes share the cores, and the first figure is then that much short).

    Each rollout is the whole of ``hexgym validate``'s Test 3 spools (48 s), started at a different point of the
    log (a seeded cyclic shift) from Test 3's start pose moved by up to ±0.1 rad per joint, so the
    rollouts differ (as a batch of environments would) but have the same length.
    """
    from mujoco import rollout

    if nbatch < 1:
        raise ValueError(f"nbatch must be >= 1, got {nbatch}")
    nthread = _cores() if nthread is None else nthread
    if nthread < 1:
        raise ValueError(f"nthread must be >= 1, got {nthread}")
    _, pose = _test3()
    native = NativeLearnedModel()
    m, d = native.physics.model, native.physics.data
    control = _test3_controls(native)
    rng = np.random.default_rng(seed)
    state_kind = mujoco.mjtState.mjSTATE_FULLPHYSICS
    x0 = np.empty((nbatch, mujoco.mj_stateSize(m, state_kind)))
    controls = np.empty((nbatch, *control.shape))
    ranges = np.array([kinematics.joint_range(n) if n != "swing" else (-np.inf, np.inf) for n in kinematics.JOINTS])
    for b in range(nbatch):
        native.reset(np.clip(pose + rng.uniform(-0.1, 0.1, 4), ranges[:, 0] + 0.02, ranges[:, 1] - 0.02))
        mujoco.mj_getState(m, d, x0[b], state_kind)
        controls[b] = np.roll(control, -int(rng.integers(len(control))), axis=0)
    states = np.empty((nbatch, len(control), x0.shape[1]))
    datas = [mujoco.MjData(m) for _ in range(nthread)]
    simulated = nbatch * len(control) * native.control_period
    with rollout.Rollout(nthread=nthread) as pool:

        def run_batch() -> float:
            pool.rollout(m, datas, x0, controls, initial_warmstart=None, state=states)
            return simulated

        factor, cores = _timed_with_cores(run_batch, seconds)
    return {"batch_realtime_factor_native": factor, "batch_cores_used": cores, "batch_threads": nthread}


def native_benchmark(seconds: float = 3.0) -> dict[str, float]:
    """Real-time factors of the learned models on one thread: simulated time / wall time.

    All replay the 50 s loading-cycle command log of ``hexgym validate`` (test3) from its start
    pose, repeated for at least ``seconds`` of wall time each:

    - ``learned_realtime_factor_native``: the default model (the circuit model) in the plugin,
      :func:`native_rollout_realtime_factor`, its own speed; ``paper_realtime_factor_native`` the paper's tables
      the same way;
    - ``learned_realtime_factor_native_python_loop``: :class:`NativeLearnedModel`, one ``step`` per control period
      from Python (what an environment stepping every period gets);
    - ``circuit_realtime_factor_python``: :class:`CircuitModel` (the Python model around the same native kernel),
      one ``step`` per control period; ``learned_realtime_factor_python`` the paper tables' :class:`LearnedModel`;
    - ``circuit_cost_us``: where a native circuit period's time goes (:func:`circuit_cost_split`).
    """
    _, pose = _test3()

    def per_period(model: LearnedModelBase) -> Callable[[], float]:
        spools = _test3_controls(model) * 1e-3
        model.reset(pose)
        model.step(spools[0])  # untimed: the first period loads what the model needs

        def run() -> float:
            model.reset(pose)
            for u in spools:
                model.step(u)
            return len(spools) * model.control_period

        return run

    out = {
        "learned_realtime_factor_python": _timed(per_period(LearnedModel(table_set="paper")), seconds),
        "circuit_realtime_factor_python": _timed(per_period(CircuitModel()), seconds),
    }
    if not native_available():
        return out
    out["learned_realtime_factor_native"] = native_rollout_realtime_factor(seconds)
    out["paper_realtime_factor_native"] = native_rollout_realtime_factor(seconds, table_set="paper")
    out["learned_realtime_factor_native_python_loop"] = _timed(per_period(NativeLearnedModel()), seconds)
    split = circuit_cost_split()
    # the rest of a step over the whole log: MuJoCo's step, the plugin around the kernel, and the periods elsewhere in
    # the log that cost the kernel more than this one (split steps at stroke ends and pressure jumps)
    split["rest_of_step"] = 25e3 / out["learned_realtime_factor_native"] - split["period"]
    out["circuit_cost_us"] = split
    return out


def circuit_cost_split(periods: int = 20_000) -> dict[str, float]:
    """Microseconds of one native circuit period by part, at Test 3's state 2 s in (swing, boom and bucket moving),
    timed inside the library (no call overhead): ``period`` the whole period, ``circuit`` its five circuit steps
    alone, ``joints`` the rest (the joints' implicit solve, the oil's forces, the stroke ends)."""
    _, pose = _test3()
    model = CircuitModel()
    model.reset(pose)
    for u in (_test3_controls(model) * 1e-3)[:80]:
        model.step(u)
    arms, mass, load = model._period_start()
    kernel, h = model._kernel, model.control_period / model.substeps
    kernel.control_period(model.spools_m, model.state, model.rates, model.physics.cylinder_extensions(),
                          arms, mass, load, h, model.substeps)  # fmt: skip
    period = kernel.period_ns(h, model.substeps, periods) * 1e-3
    circuit = kernel.period_ns(h, model.substeps, periods, steps_only=True) * 1e-3
    return {"period": period, "circuit": circuit, "joints": period - circuit}
