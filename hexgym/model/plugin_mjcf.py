"""Generate ``assets/cat325_mbl.xml`` and ``assets/cat325_mbl_full.xml``: the machine driven by the
native ``hexgym.mbl`` plugin.

``cat325_mbl.xml`` is ``assets/cat325_lean.xml`` (:func:`hexgym.machine.mjcf.model_xml` with ``lean=True``) with its
four joint-rate servos replaced by plugin actuators of one ``hexgym.mbl`` instance: ctrl is the
spool position in mm (±11), and the plugin turns spools into joint-rate targets through the MBL
tables every step (see ``native/mbl_plugin.cc``). Each plugin actuator keeps its lean servo's
gain, bias and force range (a default class per joint), so MuJoCo integrates it implicitly as a
stiff velocity servo, exactly as the Python path's servos. The plugin's geometry and limits come
from :mod:`hexgym.machine.parameters` and :mod:`hexgym.machine.kinematics` (config keys, floats written with
``repr`` so they round-trip exactly).

``cat325_mbl_full.xml`` is the same for the full machine ``assets/cat325.xml`` (cylinders and the
bucket four-bar as bodies closed by equality constraints, 2 ms step), for MuJoCo's viewer: its
plugin actuators keep the full model's integrated-velocity servos (kp, kv, activation = position
target, force and activation limits), since a stiff velocity servo on a tree joint of a closed
chain would be damped implicitly while the constraint solver, which works with the plain mass
matrix, drives the cylinder bodies explicitly (they blow up). Its control period is the lean
machine's 25 ms: 12.5 steps, so table queries alternate 13 and 12 steps apart.

Regenerate with ``hexgym build-assets`` (or :func:`write_mbl_model`); a test checks the committed
files are current.
"""

from __future__ import annotations

import re
from pathlib import Path

import mujoco
import numpy as np

from hexgym.files import atomic_path
from hexgym.hydraulics.circuit import HydraulicCircuit, valve_layout
from hexgym.hydraulics.overrides import HydraulicsOverrides, OverriddenCircuit
from hexgym.machine import kinematics, mjcf
from hexgym.machine import parameters as p
from hexgym.machine.assets import assets_dir
from hexgym.mbl.schema import CIRCUIT_TABLE_SETS, DEFAULT_TABLE_SET, VALVE_OF_TABLE_SET
from hexgym.mbl.table import model_hydraulics
from hexgym.model.base import END_MARGIN, PULL_LIMIT, PUSH_LIMIT, STROKES, SWING_REST_RATE
from hexgym.model.circuit_kernel import circuit_numbers
from hexgym.model.circuit_model import MAX_RATE, STOP_CLEARANCE, SUBSTEPS
from hexgym.model.plugin import CONFIG_KEYS, CTRL_PER_SPOOL_M, PLUGIN_NAME

MBL_MODEL_FILE = "cat325_mbl.xml"
MBL_FULL_MODEL_FILE = "cat325_mbl_full.xml"
INSTANCE = "mbl"
SPOOL_RANGE_MM = p.SPOOL_STROKE * CTRL_PER_SPOOL_M  # the plugin actuators' ctrlrange


def _numbers(*values: float) -> str:
    return " ".join(repr(float(v)) for v in values)


def plugin_config(lean: bool = True) -> dict[str, str]:
    """The plugin's config keys (see ``kAttributes`` in native/mbl_plugin.cc) from the machine's numbers
    (``lean``: the rate ranges of the lean machine's servos, else the full machine's)."""
    triangles = {}
    for name in ("boom", "stick"):
        base, rod, offset = kinematics._triangle(name)
        triangles[f"{name}_triangle"] = _numbers(*base, *rod, offset, kinematics._SIGN[name])
    four_bar = (*kinematics._G, *kinematics._P_BUCKET, *kinematics._K_BUCKET, *kinematics._C_BUCKET)
    servos = _servos(lean)
    return {
        **triangles,
        "bucket_four_bar": _numbers(*four_bar, p.GUIDE_LINK_LENGTH, p.POWER_LINK_LENGTH, kinematics._J_SIDE),
        "retracted_length": _numbers(*(p.CYLINDERS[n].retracted_length for n in kinematics.FRONT_CYLINDERS)),
        "stroke": _numbers(*STROKES),
        "end_margin": _numbers(END_MARGIN),
        "push_limit": _numbers(*PUSH_LIMIT),
        "pull_limit": _numbers(*PULL_LIMIT),
        "swing_torque_limit": _numbers(p.SWING_TORQUE_AT_RELIEF),
        "dead_band": _numbers(p.SPOOL_DEAD_BAND),
        "swing_rest_rate": _numbers(SWING_REST_RATE),
        "rate_range": _numbers(*np.concatenate([s["ctrlrange"] for s in servos.values()])),
    }


def _machine_text(lean: bool = True) -> str:
    meshes = str(assets_dir() / "meshes")
    return mjcf.model_xml(mjcf.home_keyframe(mjcf.model_xml(lean=lean), meshes), lean=lean)


def _servos(lean: bool = True) -> dict[str, dict[str, np.ndarray | bool]]:
    """Per joint, the (lean or full) model's servo: gain, bias, ctrl (rate) range, force limit.

    (The full model's activation limits, its joints' ranges, the plugin applies itself: MuJoCo
    allows ``actrange`` only with a ``dyntype``.)
    """
    spec = mujoco.MjSpec.from_string(mjcf.model_xml(lean=lean))
    spec.meshdir = str(assets_dir() / "meshes")
    model = spec.compile()
    servos = {}
    for name in kinematics.JOINTS:
        i = model.actuator(name).id
        servos[name] = {
            "gainprm": model.actuator_gainprm[i, :1].copy(),
            "biasprm": model.actuator_biasprm[i, :3].copy(),
            "ctrlrange": model.actuator_ctrlrange[i].copy(),
            "forcelimited": bool(model.actuator_forcelimited[i]),
            "forcerange": model.actuator_forcerange[i].copy(),
        }
    return servos


def _defaults(servos: dict[str, dict[str, np.ndarray | bool]]) -> str:
    lines = []
    for name, s in servos.items():
        force = f' forcerange="{_numbers(*s["forcerange"])}"' if s["forcelimited"] else ""
        lines.append(
            f'    <default class="mbl_{name}">\n'
            f'      <general gaintype="fixed" gainprm="{_numbers(*s["gainprm"])}" biastype="affine"'
            f' biasprm="{_numbers(*s["biasprm"])}"{force}/>\n'
            f"    </default>"
        )
    return "\n".join(lines)


def _actuators(lean: bool = True) -> str:
    lines = [
        "  <actuator>",
        "    <!-- ctrl: spool position, mm (+ extends the cylinder / swings counter-clockwise) -->",
    ]
    for name in kinematics.JOINTS:
        # lean: the swing's rate target is its activation; full: each activation is a position target
        actdim = 1 if name == "swing" or not lean else 0
        lines.append(
            f'    <plugin name="{name}" joint="{name}" instance="{INSTANCE}" class="mbl_{name}" actdim="{actdim}"'
            f' ctrlrange="{_numbers(-SPOOL_RANGE_MM, SPOOL_RANGE_MM)}"/>'
        )
    return "\n".join([*lines, "  </actuator>"])


def circuit_config(
    table_set: str = DEFAULT_TABLE_SET,
    tables_dir: str | Path | None = None,
    hydraulics: HydraulicsOverrides | None = None,
) -> dict[str, str]:
    """The config keys of the circuit model (a table set of :data:`~hexgym.mbl.schema.CIRCUIT_TABLE_SETS`): the
    circuit's numbers with the set's valve layout (:func:`hexgym.model.circuit_kernel.circuit_numbers`), its steps
    per period, and the servos' rate range (wide: the circuit, not the table models' limits, sets the joints'
    rates). ``tables_dir``: a model fitted to a unit's logs brings the unit's pumps
    (:func:`hexgym.mbl.table.model_hydraulics`); ``hydraulics``: the pumps given instead (e.g. a weaker engine's
    power limit, :func:`hexgym.hydraulics.overrides.with_engine_power`)."""
    layout = valve_layout(VALVE_OF_TABLE_SET[table_set])
    if hydraulics is None:
        hydraulics = model_hydraulics(tables_dir)
    circuit = HydraulicCircuit(layout=layout) if hydraulics is None else OverriddenCircuit(hydraulics, layout)
    numbers = circuit_numbers(circuit, STOP_CLEARANCE)
    return {
        "circuit": _numbers(*numbers),
        "substeps": str(SUBSTEPS),
        "rate_range": _numbers(*[-MAX_RATE, MAX_RATE] * len(kinematics.JOINTS)),
    }


def _extension(
    tables_dir: str | Path | None,
    control_period: float | None,
    lean: bool,
    table_set: str,
    hydraulics: HydraulicsOverrides | None = None,
) -> str:
    config = plugin_config(lean) | {"table_set": table_set}
    if table_set in CIRCUIT_TABLE_SETS:
        config |= circuit_config(table_set, tables_dir, hydraulics)
    elif hydraulics is not None:
        raise ValueError(f"the {table_set!r} tables hold their pumps in their data: hydraulics cannot be overridden")
    if tables_dir is not None:
        config = {"tables": str(Path(tables_dir).resolve()), **config}
    if control_period is not None:
        config["control_period"] = _numbers(control_period)
    unknown = set(config) - set(CONFIG_KEYS)
    if unknown:
        raise ValueError(f"config keys {sorted(unknown)} are not the plugin's (hexgym.model.plugin.CONFIG_KEYS)")
    keys = "\n".join(f'        <config key="{k}" value="{v}"/>' for k, v in config.items())
    return (
        f'  <extension>\n    <plugin plugin="{PLUGIN_NAME}">\n      <instance name="{INSTANCE}">\n{keys}\n'
        "      </instance>\n    </plugin>\n  </extension>\n\n"
    )


def mbl_model_xml(
    tables_dir: str | Path | None = None,
    control_period: float | None = None,
    full: bool = False,
    table_set: str = DEFAULT_TABLE_SET,
    hydraulics: HydraulicsOverrides | None = None,
) -> str:
    """The text of ``cat325_mbl.xml`` (``full``: ``cat325_mbl_full.xml``).

    ``tables_dir``: other tables than the packaged ones; ``control_period``: seconds between
    table queries, at least one step (default: every step of the lean machine; the lean machine's
    25 ms on the full one); ``hydraulics``: the circuit model's pumps (see :func:`circuit_config`).
    """
    lean = not full
    source, name = ("cat325_lean", "cat325_mbl") if lean else ("cat325", "cat325_mbl_full")
    which = "lean" if lean else "full"
    if full and control_period is None:
        control_period = mjcf.LEAN_TIMESTEP
    text = _machine_text(lean).replace(f'<mujoco model="{source}">', f'<mujoco model="{name}">', 1)
    text = text.replace(
        "edit those, then run `hexgym build-assets`. -->",
        "edit those, then run `hexgym build-assets`.\n"
        f"       The {which} machine driven by the native hexgym.mbl plugin (hexgym/model/plugin_mjcf.py). -->",
        1,
    )
    extension = _extension(tables_dir, control_period, lean, table_set, hydraulics)
    text = text.replace("  <default>\n", extension + "  <default>\n", 1)
    defaults = _defaults(_servos(lean))
    text = re.sub(r"^  </default>$", lambda _: defaults + "\n  </default>", text, count=1, flags=re.M)
    text, count = re.subn(r"  <actuator>.*?</actuator>", lambda _: _actuators(lean), text, count=1, flags=re.S)
    if count != 1:
        raise RuntimeError(f"the {which} model text has no <actuator> block to replace")
    return text


def write_mbl_model(path: str | Path, full: bool = False) -> Path:
    """Generate ``cat325_mbl.xml`` (``full``: ``cat325_mbl_full.xml``) and write it atomically to ``path``."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(mbl_model_xml(full=full))
    return path
