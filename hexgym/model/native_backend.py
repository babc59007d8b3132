"""The native learned model: the ``hexgym.mbl`` MuJoCo plugin (``native/``) and its Python face.

Models that name the plugin (the lean ``assets/cat325_mbl.xml``, the full ``assets/cat325_mbl_full.xml``,
or one from :func:`hexgym.model.plugin_mjcf.mbl_model_xml`) compile once the plugin library is loaded
(:func:`hexgym.model.plugin.require_plugin`, called here). The plugin does in C++, inside ``mj_step``,
what :class:`hexgym.model.python_backend.LearnedModel` does in Python each control period (loads, stall,
tables, swing integration, servo targets), from the same table files, so the two give the same
trajectories (``tests/test_native.py``). :class:`NativeLearnedModel` has the same interface
(:class:`hexgym.model.base.LearnedModelBase`).
"""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np

from hexgym.hydraulics.circuit import STATE_NAMES as CIRCUIT_STATE_NAMES
from hexgym.hydraulics.circuit import STATE_SIZE as CIRCUIT_STATE_SIZE
from hexgym.hydraulics.circuit import HydraulicCircuit, validate_spools, valve_layout
from hexgym.machine import kinematics
from hexgym.machine.assets import AssetError, asset_path
from hexgym.machine.physics import ExcavatorPhysics, contiguous_index
from hexgym.mbl.schema import CIRCUIT_TABLE_SETS, DEFAULT_TABLE_SET, VALVE_OF_TABLE_SET
from hexgym.mbl.table import require_packaged
from hexgym.model.base import LearnedModelBase
from hexgym.model.circuit_model import circuit_row
from hexgym.model.plugin import CTRL_PER_SPOOL_M, STATE, STATE_SIZE, plugin_config_values, require_plugin


def load_mbl_model(
    tables_dir: str | Path | None = None,
    control_period: float | None = None,
    full: bool = False,
    table_set: str = DEFAULT_TABLE_SET,
) -> mujoco.MjModel:
    """The lean machine driven by the plugin (the packaged ``cat325_mbl.xml``, or one generated for
    other tables, another table set or another control period); ``full``: the full machine
    (``cat325_mbl_full.xml``).

    Table files the plugin cannot use fail the compile with a message naming the file and the
    problem: ValueError (AssetError for the packaged model).
    """
    require_plugin()
    if tables_dir is None and control_period is None and table_set == DEFAULT_TABLE_SET:
        path = asset_path("cat325_mbl_full.xml" if full else "cat325_mbl.xml")
        try:
            return mujoco.MjModel.from_xml_path(str(path))
        except ValueError as exc:
            raise AssetError(f"cannot load model {path}: {exc}") from exc
    from hexgym.model.plugin_mjcf import mbl_model_xml

    if tables_dir is None:
        require_packaged(table_set)  # the plugin would name only the first missing file
    if tables_dir is not None and not Path(tables_dir).is_dir():
        raise FileNotFoundError(f"MBL table directory {tables_dir} does not exist")
    spec = mujoco.MjSpec.from_string(mbl_model_xml(tables_dir, control_period, full=full, table_set=table_set))
    spec.meshdir = str(asset_path("cat325_lean.xml").parent / "meshes")
    try:
        return spec.compile()
    except ValueError as exc:
        raise ValueError(plugin_message(str(exc))) from None


def plugin_message(error: str) -> str:
    """The plugin's own line in MuJoCo's compile error (which wraps it in engine and plugin-id lines), or the
    error as it is."""
    for line in error.splitlines():
        if "hexgym.mbl: " in line:
            return line[line.index("hexgym.mbl: ") + len("hexgym.mbl: ") :].strip()
    return error


class NativeLearnedModel(LearnedModelBase):
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
        table_set: str = DEFAULT_TABLE_SET,
    ) -> None:
        require_plugin()
        if model is None:
            model = load_mbl_model(tables_dir, control_period, table_set=table_set)
        self.physics = ExcavatorPhysics(model)
        m = self.physics.model
        self._ctrl = np.array([m.actuator(n).id for n in kinematics.JOINTS])
        instance = int(m.actuator_plugin[self._ctrl[0]])
        if instance < 0 or not all(m.actuator_plugin[i] == instance for i in self._ctrl):
            raise ValueError("model must drive swing, boom, stick and bucket with one hexgym.mbl plugin instance")
        self._swing_act = int(m.actuator_actadr[self._ctrl[0]])
        # the full machine's servos hold position targets in their activations, the lean's swing its rate
        self._integrated = bool(m.actuator_biasprm[self._ctrl[0], 1] != 0.0)
        self._state = slice(int(m.plugin_stateadr[instance]), int(m.plugin_stateadr[instance]) + STATE_SIZE)
        configured = plugin_config_values(m, instance)["control_period"]
        period = float(configured) if configured else self.physics.timestep
        if control_period is not None and abs(period - control_period) > 1e-9:
            raise ValueError(f"control_period {control_period} s differs from the model's {period} s")
        self._period = period
        # as the plugin: steps per period rounded to a multiple of 2**-20, so the step counts are exact
        self._steps_per_period = round(period / self.physics.timestep * 2**20) / 2**20
        self._periods = self._steps = 0  # since reset: the plugin queried the tables at steps ceil(k * period / step)
        self._dofs = contiguous_index(np.array([m.joint(n).dofadr[0] for n in kinematics.JOINTS]))
        self._ctrl_index = contiguous_index(self._ctrl)
        load = self._state.start + STATE["load"]
        self._load_slots = slice(load, load + 4)  # the constraint loads, N m
        self.spools_m = np.zeros(4)
        self.table_set = plugin_config_values(m, instance)["table_set"] or DEFAULT_TABLE_SET
        # the circuit model's state in the plugin state: the circuit's pressures and pump displacements
        self._hydraulics = self._state.start + STATE["hydraulics"] + np.arange(CIRCUIT_STATE_SIZE)
        layout = valve_layout(VALVE_OF_TABLE_SET[self.table_set]) if self.table_set in CIRCUIT_TABLE_SETS else None
        self._circuit = None if layout is None else HydraulicCircuit(layout=layout)

    @property
    def control_period(self) -> float:
        """Seconds between table queries (one :meth:`step`)."""
        return self._period

    @property
    def swing_acceleration(self) -> float:
        """The swing table's last acceleration, rad/s^2."""
        return float(self.physics.data.plugin_state[self._state][STATE["acceleration"]])

    def reset(self, start: str | np.ndarray = "home", payload_kg: float = 0.0) -> None:
        """Start at a keyframe name or joint angles (rad), at rest, spools neutral."""
        d = self.physics.data
        self.physics.start_at(start, payload_kg)
        if not self._integrated:
            d.act[:] = 0.0  # the swing's rate target (start_at writes pose targets for integrating servos)
        d.plugin_state[self._state] = 0.0
        self.spools_m = np.zeros(4)
        d.ctrl[self._ctrl] = 0.0
        d.plugin_state[self._state.start + STATE["circuit_ready"]] = -1.0  # the circuit holds this settling step
        self.physics.step()  # as LearnedModel.reset: one step so the constraint forces exist
        # the next step starts a control period; as LearnedModel, no table has been asked yet (and the circuit's
        # state is set there to hold the loads)
        d.plugin_state[self._state.start + STATE["phase"]] = 0.0
        d.plugin_state[self._state.start + STATE["acceleration"]] = 0.0
        d.plugin_state[self._state.start + STATE["circuit_ready"]] = 0.0
        d.time = 0.0
        self._periods = self._steps = 0

    @property
    def hydraulic_slots(self) -> np.ndarray | None:
        """The circuit's state's indices in ``plugin_state`` (None: a table model, no circuit)."""
        return None if self._circuit is None else self._hydraulics

    def set_hydraulic_state(self, hydraulic_state: np.ndarray, rates: np.ndarray) -> None:
        """Start the circuit model from a given circuit state (pressures and pump displacements, ``STATE_NAMES``: e.g.
        the reference's, whose circuit has the same nodes) and joint rates (rad/s) instead of the one that holds the
        loads at rest (after :meth:`reset`)."""
        if self.hydraulic_slots is None:
            raise ValueError(f"table set {self.table_set!r} has no circuit: no hydraulic state to set")
        hydraulic_state, rates = np.asarray(hydraulic_state, float), np.asarray(rates, float)
        if hydraulic_state.shape != (CIRCUIT_STATE_SIZE,) or not np.isfinite(hydraulic_state).all():
            raise ValueError(f"hydraulic state must be {CIRCUIT_STATE_SIZE} finite numbers ({CIRCUIT_STATE_NAMES})")
        d, start = self.physics.data, self._state.start
        d.plugin_state[self.hydraulic_slots] = hydraulic_state
        d.plugin_state[start + STATE["rates"] : start + STATE["rates"] + 4] = rates
        d.plugin_state[start + STATE["circuit_ready"]] = 1.0

    def step(self, spools_m: np.ndarray, n: int = 1) -> None:
        """Advance ``n`` control periods with the spools (m; swing, boom, stick, bucket) held."""
        self.spools_m = validate_spools(spools_m).copy()
        self.physics.data.ctrl[self._ctrl_index] = self.spools_m * CTRL_PER_SPOOL_M
        self._periods += n
        end = math.ceil(self._periods * self._steps_per_period - 1e-9)
        self.physics.step(end - self._steps)
        self._steps = end
        if self._circuit is not None and self.physics.data.plugin_state[self._state.start + STATE["circuit_fault"]]:
            raise ValueError(
                f"hydraulic state must be {CIRCUIT_STATE_SIZE} finite numbers ({CIRCUIT_STATE_NAMES}) within ten"
                f" times the highest relief: the circuit's state diverged by t = {self.physics.time:.3f} s"
            )

    @property
    def hydraulic_state(self) -> np.ndarray:
        """The circuit model's state (a copy): pressures (Pa) and pump displacements (``STATE_NAMES``)."""
        return self.physics.data.plugin_state[self._hydraulics].copy()

    def observe(self) -> np.ndarray:
        """One trajectory row; the circuit model's also its pumps' pressures, flows, power and fuel rate
        (``CIRCUIT_DTYPE``, as :class:`~hexgym.model.circuit_model.CircuitModel`)."""
        row = super().observe()
        return row if self._circuit is None else circuit_row(row, self._circuit, self.hydraulic_state)

    def joint_loads(self) -> np.ndarray:
        """Torque each main joint's actuator must supply to hold the present motion (N m).

        As LearnedModel.joint_loads: the last step's constraint forces without the joint limits'.
        """
        d = self.physics.data
        dofs = self._dofs
        tau = d.qfrc_bias[dofs] - d.qfrc_passive[dofs] - d.qfrc_applied[dofs]
        return tau - d.plugin_state[self._load_slots]
