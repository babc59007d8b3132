"""Where the learned model's Test 3 error comes from: the reference's swing dynamics, the tables
at the reference's own states (teacher forcing), and what the tables' inputs cannot see.
``python experiments/swing_analysis.py``.

Prints, on validate's Test 3 (reference model, 20 ms rows):

- how well the swing motor's torque matches the rate of change of the upper structure's angular
  momentum ``d(I w)/dt`` and ``I dw/dt`` (the paper's swing table learns ``dw/dt``: the inertia's
  change while the boom rises is invisible to it);
- the packaged stick and swing tables at the reference's inputs against the reference's stick
  velocity and swing acceleration, in the windows where they differ most;
- hidden state: the same 7 mm swing spool reached by a step and by an operator's 0.4 s ramp gives
  different accelerations at the same swing rate (the line pressure's transient);
- cross-pump power sharing: Test 3 on the reference whose pump regulators each sense only their
  own pressure (the other pump held at its idle pressure, as in the collection, which moves one
  pump's functions at a time) against the real cross-sensing reference. The tables' inputs are
  one pump's spools and loads, so the tip distance between the two is error they cannot learn.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hexgym.hydraulics.circuit import HydraulicCircuit
from hexgym.hydraulics.reference import ReferenceModel
from hexgym.machine import kinematics
from hexgym.machine import parameters as p
from hexgym.mbl.table import load_tables
from hexgym.model.commandlog import CommandLog
from hexgym.model.replay import replay
from hexgym_lab.mbl.fit import fitted_points, load_table_data
from hexgym_lab.mbl.lwr import LocallyWeightedRegression
from hexgym_lab.validate import DT_OUT as VALIDATE_DT_OUT
from hexgym_lab.validate import POSE_CYCLE, scenarios, tip_errors

DT_OUT = 0.02  # s: fine enough for a central difference of the swing rate


def reference_test3(model: ReferenceModel | None = None, dt_out: float = DT_OUT) -> np.ndarray:
    """The reference model's Test 3 trajectory at ``dt_out`` (default: a fresh reference)."""
    log, pose = scenarios()["test3"]
    return replay(model if model is not None else ReferenceModel(), log, start=pose, dt_out=dt_out)


class OwnPressureCircuit(HydraulicCircuit):
    """The circuit with each pump's horsepower regulator sensing its own pressure plus the other
    pump's idle pressure, instead of both pressures: a counterfactual machine whose two pumps
    do not share the engine's power, i.e. what one-pump-at-a-time data show."""

    @staticmethod
    def pump_flows(p_pumps: np.ndarray, displacement: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """As :meth:`HydraulicCircuit.pump_flows`, pump by pump with the other at idle pressure."""
        q, dq_dd, dq_dp = np.empty(2), np.empty(2), np.zeros((2, 2))
        for i in (0, 1):
            sensed = np.array([p_pumps[i], p.NFC_PRESSURE_IDLE])
            qi, ddi, dpi = HydraulicCircuit.pump_flows(sensed, np.full(2, displacement[i]))
            q[i], dq_dd[i], dq_dp[i, i] = qi[0], ddi[0], dpi[0, 0]
        return q, dq_dd, dq_dp


def cross_pump_figures() -> dict[str, float]:
    """Test 3 tip distance (m) between the own-pressure and the real (cross-sensing) reference:
    mean, max and each joint's mean contribution (validate's rows and Jacobian)."""
    coupled = reference_test3(dt_out=VALIDATE_DT_OUT)
    own = ReferenceModel()
    own.circuit = OwnPressureCircuit()
    errors = tip_errors(coupled, reference_test3(own, dt_out=VALIDATE_DT_OUT))
    contributions = errors["joint_contribution"].mean(axis=0)
    figures = {"mean_tip_m": float(errors["tip_error"].mean()), "max_tip_m": float(errors["tip_error"].max())}
    figures.update({f"{j}_mean_m": float(c) for j, c in zip(kinematics.JOINTS, contributions, strict=True)})
    return figures


def grid_bias_figures(
    data_dir: str | Path = "data", spool_mm: float = 7.0, below_rate: float = 0.2
) -> dict[str, float]:
    """Mean swing-table error (rad/s^2) on the collected swing data at one spool (stick spool
    closed, ``0 < rate < below_rate``): of the packaged grid and of the LWR it was built from."""
    data = load_table_data(Path(data_dir) / "swing.npz", "swing")
    inputs, y = data.X, data.y
    near = (np.abs(inputs[:, 0] - spool_mm * 1e-3) < 6e-4) & (np.abs(inputs[:, 1]) < 6e-4)
    near &= (inputs[:, 4] > 0.0) & (inputs[:, 4] < below_rate)
    table = load_tables(table_set="paper")["swing"]
    kept = fitted_points(data)
    lwr = LocallyWeightedRegression(table.params).fit(kept.X, kept.y)
    return {
        "points": float(near.sum()),
        "grid_mean_error": float(np.mean(table.lookup(inputs[near]) - y[near])),
        "lwr_mean_error": float(np.mean(lwr.predict(inputs[near]) - y[near])),
    }


def swing_start(ramp_s: float, spool_mm: float = 7.0, duration: float = 1.5) -> np.ndarray:
    """The reference swinging from rest at POSE_CYCLE, its spool moved to ``spool_mm`` at 0.2 s
    over ``ramp_s`` (0: a step); rows every 20 ms."""
    t = np.arange(0.0, duration + 1e-9, 0.002)
    u = np.zeros((len(t), 4))
    u[:, 0] = spool_mm * (np.clip((t - 0.2) / ramp_s, 0.0, 1.0) if ramp_s > 0 else (t >= 0.2))
    return replay(ReferenceModel(), CommandLog(t, u), start=POSE_CYCLE, dt_out=DT_OUT)


def _first_at_rate(traj: np.ndarray, rate: float) -> int:
    """The row where the swing first reaches ``rate`` (rad/s)."""
    w = traj["qd_swing_radps"]
    k = int(np.argmax(w >= rate))
    if w[k] < rate:
        raise ValueError(f"the swing never reached {rate} rad/s")
    return k


def value_at_rate(traj: np.ndarray, rate: float, column: str) -> float:
    """``column`` of the row where the swing first reaches ``rate`` (rad/s)."""
    return float(traj[column][_first_at_rate(traj, rate)])


def acceleration_at_rate(traj: np.ndarray, rate: float) -> float:
    """The swing acceleration (rad/s^2) when the swing first reaches ``rate`` (rad/s)."""
    return float(np.gradient(traj["qd_swing_radps"], traj["t"])[_first_at_rate(traj, rate)])


def swing_momentum_figures(ref: np.ndarray) -> dict[str, float]:
    """rms of torque - d(I w)/dt and of torque - I dw/dt where the swing spool is open, and rms torque (N m)."""
    t, w, inertia, torque = ref["t"], ref["qd_swing_radps"], ref["swing_inertia_kgm2"], ref["swing_torque_nm"]
    open_ = np.abs(ref["swing_spool_mm"]) > 1.0
    rms = lambda x: float(np.sqrt(np.mean(x[open_] ** 2)))  # noqa: E731
    return {
        "rms_torque_nm": rms(torque),
        "rms_torque_minus_dL_dt_nm": rms(torque - np.gradient(inertia * w, t)),
        "rms_torque_minus_I_dw_dt_nm": rms(torque - inertia * np.gradient(w, t)),
    }


def table_predictions(ref: np.ndarray) -> dict[str, np.ndarray]:
    """The packaged stick and swing tables at the reference's inputs (its own spools and loads)."""
    tables = load_tables(table_set="paper")
    u_swing, u_stick = ref["swing_spool_mm"] * 1e-3, ref["stick_spool_mm"] * 1e-3
    inertia, f_stick = ref["swing_inertia_kgm2"], ref["stick_force_n"]
    return {
        "stick_velocity_mps": tables["stick"].lookup(np.column_stack([u_swing, u_stick, inertia, f_stick])),
        "swing_acceleration_radps2": tables["swing"].lookup(
            np.column_stack([u_swing, u_stick, f_stick, inertia, ref["qd_swing_radps"]])
        ),
    }


def main() -> None:
    """Print the figures (about 50 s: the reference model runs Test 3 three times)."""
    ref = reference_test3()
    figures = swing_momentum_figures(ref)
    print("Test 3, swing spool open:")
    for key, value in figures.items():
        print(f"  {key:30s} {value / 1e3:7.2f} kN m")
    tables = table_predictions(ref)
    t, w = ref["t"], ref["qd_swing_radps"]
    accel, inertia = np.gradient(w, t), ref["swing_inertia_kgm2"]
    print("\n    t  I t m^2  w rad/s  torque kNm  I*dw/dt kNm  dw/dt ref  dw/dt table   stick m/s ref  table")
    for start, stop in ((3.0, 4.8), (36.8, 40.1)):
        for k in np.flatnonzero((t >= start - 1e-9) & (t <= stop + 1e-9))[::10]:
            print(
                f"{t[k]:5.1f} {inertia[k] / 1e3:8.0f} {w[k]:8.3f} {ref['swing_torque_nm'][k] / 1e3:11.1f}"
                f" {inertia[k] * accel[k] / 1e3:12.1f} {accel[k]:10.3f} {tables['swing_acceleration_radps2'][k]:12.3f}"
                f" {ref['stick_velocity_mps'][k]:15.3f} {tables['stick_velocity_mps'][k]:6.3f}"
            )

    print("\nHidden state: swing acceleration (rad/s^2) at the same swing rate, 7 mm spool from rest")
    starts = {ramp: swing_start(ramp) for ramp in (0.0, 0.4)}
    for rate in (0.03, 0.05, 0.1, 0.15):
        step, ramped = (acceleration_at_rate(starts[r], rate) for r in (0.0, 0.4))
        print(f"  w = {rate:4.2f} rad/s: after a step {step:6.3f}, after a 0.4 s ramp {ramped:6.3f}")
    print("  and the pump 2 pressure (MPa) / flow (L/min) there: the pressure differs, the flow (the regulator) not")
    for rate in (0.03, 0.05, 0.1):
        p, q = (
            [value_at_rate(starts[r], rate, c) for r in (0.0, 0.4)] for c in ("pump2_pressure_pa", "pump2_flow_m3s")
        )
        step, ramp = (f"{p[i] / 1e6:5.1f} / {q[i] * 6e4:5.1f}" for i in (0, 1))
        print(f"  w = {rate:4.2f} rad/s: step {step}, ramp {ramp}")
    if (Path("data") / "swing.npz").is_file():  # the collected data set (`hexgym collect`)
        bias = grid_bias_figures()
        print(f"\nSwing table at the data's 7 mm, 0-0.2 rad/s samples ({bias['points']:.0f}): mean error")
        print(f"  grid {bias['grid_mean_error']:6.3f} rad/s^2, the LWR it was built from {bias['lwr_mean_error']:6.3f}")
    print("\nCross-pump power sharing: Test 3 tip distance, own-pressure vs cross-sensing reference")
    for key, value in cross_pump_figures().items():
        print(f"  {key:14s} {value:6.3f} m")


if __name__ == "__main__":
    main()
