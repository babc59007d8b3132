"""Where the learned model's Test 3 error comes from: the reference's swing dynamics and the tables
at the reference's own states (teacher forcing). ``python -m hexgym.swing_analysis``.

Prints, on validate's Test 3 (reference model, 20 ms rows):

- how well the swing motor's torque matches the rate of change of the upper structure's angular
  momentum ``d(I w)/dt`` and ``I dw/dt`` (the paper's swing table learns ``dw/dt``: the inertia's
  change while the boom rises is invisible to it);
- the packaged stick and swing tables at the reference's inputs against the reference's stick
  velocity and swing acceleration, in the windows where they differ most.
"""

from __future__ import annotations

import numpy as np

from hexgym.fit import load_tables
from hexgym.reference import ReferenceModel
from hexgym.replay import replay
from hexgym.validate import scenarios

DT_OUT = 0.02  # s: fine enough for a central difference of the swing rate


def reference_test3() -> np.ndarray:
    """The reference model's Test 3 trajectory at ``DT_OUT``."""
    log, pose = scenarios()["test3"]
    return replay(ReferenceModel(), log, start=pose, dt_out=DT_OUT)


def swing_momentum_figures(ref: np.ndarray) -> dict[str, float]:
    """rms of torque - d(I w)/dt and of torque - I dw/dt where the swing spool is open, and rms torque (N m)."""
    t, w, inertia, torque = ref["t"], ref["qd_swing"], ref["swing_inertia_kgm2"], ref["swing_torque_nm"]
    open_ = np.abs(ref["swing_spool_mm"]) > 1.0
    rms = lambda x: float(np.sqrt(np.mean(x[open_] ** 2)))  # noqa: E731
    return {
        "rms_torque_nm": rms(torque),
        "rms_torque_minus_dL_dt_nm": rms(torque - np.gradient(inertia * w, t)),
        "rms_torque_minus_I_dw_dt_nm": rms(torque - inertia * np.gradient(w, t)),
    }


def table_predictions(ref: np.ndarray) -> dict[str, np.ndarray]:
    """The packaged stick and swing tables at the reference's inputs (its own spools and loads)."""
    tables = load_tables()
    u_swing, u_stick = ref["swing_spool_mm"] * 1e-3, ref["stick_spool_mm"] * 1e-3
    inertia, f_stick = ref["swing_inertia_kgm2"], ref["stick_force_n"]
    return {
        "stick_velocity_mps": tables["stick"].lookup(np.column_stack([u_swing, u_stick, inertia, f_stick])),
        "swing_acceleration_radps2": tables["swing"].lookup(
            np.column_stack([u_swing, u_stick, f_stick, inertia, ref["qd_swing"]])
        ),
    }


def main() -> None:
    """Print the figures (about 20 s: the reference model runs Test 3 once)."""
    ref = reference_test3()
    figures = swing_momentum_figures(ref)
    print("Test 3, swing spool open:")
    for key, value in figures.items():
        print(f"  {key:30s} {value / 1e3:7.2f} kN m")
    tables = table_predictions(ref)
    t, w = ref["t"], ref["qd_swing"]
    accel, inertia = np.gradient(w, t), ref["swing_inertia_kgm2"]
    print("\n    t  I t m^2  w rad/s  torque kNm  I*dw/dt kNm  dw/dt ref  dw/dt table   stick m/s ref  table")
    for start, stop in ((3.0, 4.8), (36.8, 40.1)):
        for k in np.flatnonzero((t >= start - 1e-9) & (t <= stop + 1e-9))[::10]:
            print(
                f"{t[k]:5.1f} {inertia[k] / 1e3:8.0f} {w[k]:8.3f} {ref['swing_torque_nm'][k] / 1e3:11.1f}"
                f" {inertia[k] * accel[k] / 1e3:12.1f} {accel[k]:10.3f} {tables['swing_acceleration_radps2'][k]:12.3f}"
                f" {ref['stick_velocity_mps'][k]:15.3f} {tables['stick_velocity_mps'][k]:6.3f}"
            )


if __name__ == "__main__":
    main()
