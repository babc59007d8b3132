"""The native learned model: the ``hexgym.mbl`` MuJoCo plugin (``native/``) and its Python face.

``import hexgym`` loads the plugin library the package build compiled (``hexgym/_mbl_plugin*.so``,
see ``setup.py``) with ``mujoco.mj_loadPluginLibrary``; models that name the plugin (the lean
``assets/cat325_mbl.xml``, the full ``assets/cat325_mbl_full.xml``, or one from
:func:`hexgym.model.plugin_mjcf.mbl_model_xml`) then compile in this process. The plugin does in C++,
inside ``mj_step``, what :class:`hexgym.model.python_backend.LearnedModel` does in Python each control period
(loads, stall, tables, swing integration, servo targets), from the same table files, so the two
give the same trajectories (``tests/test_native.py``).

:class:`NativeLearnedModel` has LearnedModel's interface (``reset``, ``step``, ``observe``,
``physics``, ``cylinder_loads``, ``spools_m``, ``timestep``); :func:`make_learned_model` picks a
backend. Without the library (no compiler at install time, or a MuJoCo other than the one it was
built against) ``backend="auto"`` uses the Python model and says why once.
"""

from __future__ import annotations

import ctypes
import functools
import math
import os
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np

from hexgym.hydraulics.circuit import validate_spools
from hexgym.machine import kinematics
from hexgym.machine.assets import AssetError, asset_path
from hexgym.machine.physics import ExcavatorPhysics, contiguous_index
from hexgym.model.commandlog import CommandLog
from hexgym.model.python_backend import LearnedModel, trajectory_row

PLUGIN_NAME = "hexgym.mbl"
BACKENDS = ("auto", "python", "native")
_PACKAGE_DIR = Path(__file__).resolve().parents[1]  # the plugin library is built into the hexgym package
_STATE_SIZE = 10  # native/mbl_plugin.cc kStateSize
# The plugin's config keys in its declared order (native/mbl_plugin.cc kAttributes)
CONFIG_KEYS = (
    "tables",
    "boom_triangle",
    "stick_triangle",
    "bucket_four_bar",
    "retracted_length",
    "stroke",
    "end_margin",
    "push_limit",
    "pull_limit",
    "swing_torque_limit",
    "dead_band",
    "swing_rest_rate",
    "rate_range",
    "control_period",
)
_ACCELERATION, _PHASE = 4, 5  # plugin state slots


class NativePluginError(RuntimeError):
    """The native plugin library is missing or cannot be used in this process."""


def plugin_library() -> Path | None:
    """The built plugin library inside the package, or None."""
    found = sorted(_PACKAGE_DIR.glob("_mbl_plugin*.so"))
    return found[0] if found else None


@functools.cache
def load_plugin() -> str:
    """Load the plugin library once; returns "" when it is registered, else why it is not."""
    library = plugin_library()
    if library is None:
        return f"the native plugin was not built (no {_PACKAGE_DIR}/_mbl_plugin*.so; see the build output of pip)"
    try:
        mujoco.mj_loadPluginLibrary(str(library))
        return _library_error(library)
    except (OSError, AttributeError, mujoco.FatalError) as exc:
        return f"the native plugin {library} cannot be loaded: {exc}"


def _library_error(library: Path) -> str:
    """The library's own verdict (e.g. a MuJoCo version mismatch); dlopen returns the loaded copy."""
    lib = ctypes.CDLL(str(library))
    lib.hexgym_mbl_load_error.restype = ctypes.c_char_p
    return (lib.hexgym_mbl_load_error() or b"").decode()


def native_available() -> bool:
    """Whether models using the ``hexgym.mbl`` plugin can be compiled in this process."""
    return load_plugin() == ""


def require_plugin() -> None:
    """Raise :class:`NativePluginError` with the reason if the plugin cannot be used."""
    reason = load_plugin()
    if reason:
        raise NativePluginError(f"{reason}; use backend='python'")


def load_mbl_model(
    tables_dir: str | Path | None = None, control_period: float | None = None, full: bool = False
) -> mujoco.MjModel:
    """The lean machine driven by the plugin (the packaged ``cat325_mbl.xml``, or one generated for
    other tables or another control period); ``full``: the full machine (``cat325_mbl_full.xml``).

    Table files the plugin cannot use fail the compile with a message naming the file and the
    problem: ValueError (AssetError for the packaged model).
    """
    require_plugin()
    if tables_dir is None and control_period is None:
        path = asset_path("cat325_mbl_full.xml" if full else "cat325_mbl.xml")
        try:
            return mujoco.MjModel.from_xml_path(str(path))
        except ValueError as exc:
            raise AssetError(f"cannot load model {path}: {exc}") from exc
    from hexgym.model.plugin_mjcf import mbl_model_xml

    if tables_dir is not None and not Path(tables_dir).is_dir():
        raise FileNotFoundError(f"MBL table directory {tables_dir} does not exist")
    spec = mujoco.MjSpec.from_string(mbl_model_xml(tables_dir, control_period, full=full))
    spec.meshdir = str(asset_path("cat325_lean.xml").parent / "meshes")
    return spec.compile()


def plugin_config_values(model: mujoco.MjModel, instance: int = 0) -> dict[str, str]:
    """The config of a ``hexgym.mbl`` instance as compiled (unset keys are "")."""
    start = int(model.plugin_attradr[instance])
    raw = np.asarray(model.plugin_attr[start:]).tobytes()
    values = raw.split(b"\0")[: len(CONFIG_KEYS)]
    return {k: v.decode() for k, v in zip(CONFIG_KEYS, values, strict=True)}


class NativeLearnedModel:
    """The learned machine model run by the native plugin (same interface as LearnedModel).

    Args:
        tables_dir: directory of the four ``.npz`` tables (default: the packaged ones).
        model: a compiled model whose four actuators are ``hexgym.mbl`` plugin actuators
            (default: :func:`load_mbl_model`).
        control_period: seconds between table queries, at least one step (default: one step);
            with ``model`` it must be the model's configured period.

    The model's servos may be the lean machine's velocity servos or the full machine's
    integrated-velocity servos (``load_mbl_model(full=True)``). A period that is no whole number
    of steps (the full machine's 25 ms at 2 ms steps) is kept on average: :meth:`step` runs to the
    first step at or after each period boundary, as the plugin queries its tables.
    """

    def __init__(
        self,
        tables_dir: str | Path | None = None,
        model: mujoco.MjModel | None = None,
        control_period: float | None = None,
    ) -> None:
        require_plugin()
        if model is None:
            model = load_mbl_model(tables_dir, control_period)
        self.physics = ExcavatorPhysics(model)
        m = self.physics.model
        self._ctrl = np.array([m.actuator(n).id for n in kinematics.JOINTS])
        if m.nplugin != 1 or not all(m.actuator_plugin[i] == 0 for i in self._ctrl):
            raise ValueError("model must drive swing, boom, stick and bucket with one hexgym.mbl plugin instance")
        self._swing_act = int(m.actuator_actadr[self._ctrl[0]])
        # the full machine's servos hold position targets in their activations, the lean's swing its rate
        self._integrated = bool(m.actuator_biasprm[self._ctrl[0], 1] != 0.0)
        self._state = slice(int(m.plugin_stateadr[0]), int(m.plugin_stateadr[0]) + _STATE_SIZE)
        configured = plugin_config_values(m)["control_period"]
        period = float(configured) if configured else self.physics.timestep
        if control_period is not None and abs(period - control_period) > 1e-9:
            raise ValueError(f"control_period {control_period} s differs from the model's {period} s")
        self._period = period
        # as the plugin: steps per period rounded to a multiple of 2**-20, so the step counts are exact
        self._steps_per_period = round(period / self.physics.timestep * 2**20) / 2**20
        self._periods = self._steps = 0  # since reset: the plugin queried the tables at steps ceil(k * period / step)
        self._dofs = contiguous_index(np.array([m.joint(n).dofadr[0] for n in kinematics.JOINTS]))
        self._ctrl_index = contiguous_index(self._ctrl)
        self._load_slots = slice(self._state.start, self._state.start + 4)  # the constraint loads, N m
        self.spools_m = np.zeros(4)

    @property
    def timestep(self) -> float:
        """One control period, s."""
        return self._period

    @property
    def swing_acceleration(self) -> float:
        """The swing table's last acceleration, rad/s^2."""
        return float(self.physics.data.plugin_state[self._state][_ACCELERATION])

    def reset(self, start: str | np.ndarray = "home", payload_kg: float = 0.0) -> None:
        """Start at a keyframe name or joint angles (rad), at rest, spools neutral."""
        d = self.physics.data
        self.physics.start_at(start, payload_kg)
        if not self._integrated:
            d.act[:] = 0.0  # the swing's rate target (start_at writes pose targets for integrating servos)
        d.plugin_state[self._state] = 0.0
        self.spools_m = np.zeros(4)
        d.ctrl[self._ctrl] = 0.0
        self.physics.step()  # as LearnedModel.reset: one step so the constraint forces exist
        # the next step starts a control period; as LearnedModel, no table has been asked yet
        d.plugin_state[self._state.start + _PHASE] = 0.0
        d.plugin_state[self._state.start + _ACCELERATION] = 0.0
        d.time = 0.0
        self._periods = self._steps = 0

    def step(self, spools_m: np.ndarray, n: int = 1) -> None:
        """Advance ``n`` control periods with the spools (m; swing, boom, stick, bucket) held."""
        self.spools_m = validate_spools(spools_m).copy()
        self.physics.data.ctrl[self._ctrl_index] = self.spools_m * 1e3  # the plugin's ctrl is in mm
        self._periods += n
        end = math.ceil(self._periods * self._steps_per_period - 1e-9)
        self.physics.step(end - self._steps)
        self._steps = end

    def joint_loads(self) -> np.ndarray:
        """Torque each main joint's actuator must supply to hold the present motion (N m).

        As LearnedModel.joint_loads: the last step's constraint forces without the joint limits'.
        """
        d = self.physics.data
        dofs = self._dofs
        tau = d.qfrc_bias[dofs] - d.qfrc_passive[dofs] - d.qfrc_applied[dofs]
        return tau - d.plugin_state[self._load_slots]

    def cylinder_loads(self, arms: np.ndarray | None = None) -> np.ndarray:
        """[boom, stick, bucket] cylinder force loads, N (+ = the cylinder must push)."""
        return self.joint_loads()[1:] / (self.physics.moment_arms() if arms is None else arms)

    def observe(self) -> np.ndarray:
        """One trajectory row (``LEARNED_DTYPE``), as LearnedModel.observe."""
        return trajectory_row(self)


_fallback_said = False


def resolve_backend() -> str:
    """ "native" when the plugin is loaded, else "python" (saying why, once per process)."""
    global _fallback_said
    reason = load_plugin()
    if reason and not _fallback_said:
        _fallback_said = True
        warnings.warn(f"hexgym: {reason}; the learned model runs in Python", RuntimeWarning, stacklevel=2)
    return "python" if reason else "native"


def make_learned_model(
    backend: str = "auto",
    tables_dir: str | Path | None = None,
    control_period: float | None = None,
) -> LearnedModel | NativeLearnedModel:
    """The learned model on ``backend``: "native" (the plugin), "python", or "auto" (native when built).

    ``tables_dir``: other tables than the packaged ones (both backends read the same files).
    """
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if backend == "auto":
        backend = resolve_backend()
    if backend == "native":
        return NativeLearnedModel(tables_dir=tables_dir, control_period=control_period)
    from hexgym.mbl.table import load_tables

    tables = load_tables(tables_dir) if tables_dir is not None else None
    return LearnedModel(tables=tables, control_period=control_period)


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
    from hexgym.tools.validate import scenarios

    return scenarios()["test3"]


def _test3_controls(model: LearnedModel | NativeLearnedModel) -> np.ndarray:
    """Test 3's spools (mm), one row per control period of ``model`` (one step of the lean machine)."""
    log, _ = _test3()
    n = int(round(log.duration / model.timestep))
    return np.array([log.spools_at((k + 1e-9) * model.timestep) for k in range(n)])


def native_rollout_realtime_factor(seconds: float = 3.0) -> float:
    """The native model's own speed: ``hexgym validate``'s Test 3 spools as ``mujoco.rollout``'s
    open-loop controls, one thread, in simulated seconds per wall second (needs the plugin)."""
    from mujoco import rollout

    _, pose = _test3()
    native = NativeLearnedModel()
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
        return n * native.timestep

    return _timed(run_rollout, seconds)


def batch_realtime_factor_native(
    nbatch: int = 64, nthread: int | None = None, seconds: float = 3.0, seed: int = 0
) -> float:
    """Simulated seconds of ``nbatch`` native rollouts per wall second, ``nthread`` threads (default:
    every core) of ``mujoco.rollout`` (needs the plugin); see :func:`batch_benchmark`."""
    return batch_benchmark(nbatch, nthread, seconds, seed)["batch_realtime_factor_native"]


def batch_benchmark(nbatch: int = 64, nthread: int | None = None, seconds: float = 3.0, seed: int = 0) -> dict:
    """``batch_realtime_factor_native``: simulated seconds of ``nbatch`` native rollouts per wall
    second on ``nthread`` threads (default: every core) of ``mujoco.rollout`` (needs the plugin);
    ``batch_cores_used``: the cores the process got meanwhile (CPU / wall seconds: below ``nthread``
    when other processes share the cores, and the first figure is then that much short).

    Each rollout is the whole of ``hexgym validate``'s Test 3 spools (48 s), started at a different point of the
    log (a seeded cyclic shift) from Test 3's start pose moved by up to ±0.1 rad per joint, so the
    rollouts differ (as a batch of environments would) but have the same length.
    """
    from mujoco import rollout

    if nbatch < 1:
        raise ValueError(f"nbatch must be >= 1, got {nbatch}")
    nthread = (os.cpu_count() or 1) if nthread is None else nthread
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
    simulated = nbatch * len(control) * native.timestep
    with rollout.Rollout(nthread=nthread) as pool:

        def run_batch() -> float:
            pool.rollout(m, datas, x0, controls, initial_warmstart=None, state=states)
            return simulated

        factor, cores = _timed_with_cores(run_batch, seconds)
    return {"batch_realtime_factor_native": factor, "batch_cores_used": cores, "batch_threads": nthread}


def native_benchmark(seconds: float = 3.0) -> dict[str, float]:
    """Real-time factors of the learned model on one thread: simulated time / wall time.

    All replay the 50 s loading-cycle command log of ``hexgym validate`` (test3) from its start
    pose, repeated for at least ``seconds`` of wall time each:

    - ``learned_realtime_factor_python``: :class:`LearnedModel`, one ``step`` per control period;
    - ``learned_realtime_factor_native``: :func:`native_rollout_realtime_factor`, the native
      model's own speed;
    - ``learned_realtime_factor_native_python_loop``: :class:`NativeLearnedModel`, one ``step``
      per control period from Python (what an environment stepping every period gets).
    """
    _, pose = _test3()

    def per_period(model: LearnedModel | NativeLearnedModel) -> Callable[[], float]:
        spools = _test3_controls(model) * 1e-3

        def run() -> float:
            model.reset(pose)
            for u in spools:
                model.step(u)
            return len(spools) * model.timestep

        return run

    out = {"learned_realtime_factor_python": _timed(per_period(LearnedModel()), seconds)}
    if not native_available():
        return out
    out["learned_realtime_factor_native"] = native_rollout_realtime_factor(seconds)
    out["learned_realtime_factor_native_python_loop"] = _timed(per_period(NativeLearnedModel()), seconds)
    return out
