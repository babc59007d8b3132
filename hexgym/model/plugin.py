"""The ``hexgym.mbl`` MuJoCo plugin's interface, defined once, and loading its library.

The plugin (``native/``, built into ``hexgym/_mbl_plugin*.so`` by ``setup.py``) does in C++, inside
``mj_step``, what :class:`hexgym.model.python_backend.LearnedModel` does in Python. What the two sides
must agree on is defined here only: the plugin's name, its config keys (in declared order), its state
slots, the tables it reads (:mod:`hexgym.mbl.schema`), the table file version and the unit of its
ctrl. ``native/plugin_interface.h`` is generated from it (:func:`write_interface_header`, run by
``hexgym build-assets``; a test fails when the committed header is stale), and the built library
reports the interface it was compiled with (``hexgym_mbl_interface``): :func:`load_plugin` refuses a
library whose interface differs from this module's, naming what differs.

The library is loaded when a native model is first built, not on ``import hexgym``.
"""

from __future__ import annotations

import ctypes
import functools
import json
from pathlib import Path

import mujoco
import numpy as np

from hexgym.files import atomic_path
from hexgym.machine import kinematics
from hexgym.mbl.schema import DEFAULT_TABLE_SET, NATIVE_TABLE_SETS, QUANTITIES, TABLE_SETS
from hexgym.mbl.table import FORMAT_VERSION

PLUGIN_NAME = "hexgym.mbl"
CTRL_PER_SPOOL_M = 1000.0  # the plugin actuators' ctrl is the spool position in mm
# Config keys in the plugin's declared order (MuJoCo stores their values in this order), with what each holds.
CONFIG_KEYS: dict[str, str] = {
    "tables": "directory of the tables' .npz files (default: mbl_tables next to the library)",
    "boom_triangle": "base x z, rod x z, frame offset, sign",
    "stick_triangle": "base x z, rod x z, frame offset, sign",
    "bucket_four_bar": "guide pivot x z, bucket pin x z, link pin x z, cylinder base x z, guide, power, side",
    "retracted_length": "boom stick bucket, m",
    "stroke": "boom stick bucket, m",
    "end_margin": "m from a stroke end: at the stop",
    "push_limit": "boom stick bucket, N (line relief x head area)",
    "pull_limit": "boom stick bucket, N (line relief x rod area)",
    "swing_torque_limit": "N m (crossover relief)",
    "dead_band": "m of spool",
    "swing_rest_rate": "rad/s",
    "rate_range": "lo hi per joint, rad/s (the Python path's servo ctrlrange)",
    "control_period": "s between table queries, >= one step (default: one step)",
    "table_set": "which table set the tables directory holds: paper or extended (default: the default set)",
}
# Plugin state slots (mjSTATE_PLUGIN, so mj_getState/mj_setState restore a step exactly): name -> size.
STATE_SLOTS: dict[str, int] = {
    "load": 4,  # the previous step's constraint load at the 4 main dofs, N m (without the joint limits')
    "acceleration": 1,  # the swing table's last acceleration, rad/s^2
    "phase": 1,  # steps since the last table query, less whole control periods
    "targets": 4,  # the joint-rate targets held until the next query (the swing's unclipped)
    "inertia": 1,  # the swing inertia at the last table query, kg m^2 (torque tables keep the momentum)
}
CLEARANCE_PLUGIN_NAME = "hexgym.clearance"
# The clearance sensor plugin's config keys (native/clearance_plugin.cc: one sensor value per instance).
CLEARANCE_CONFIG_KEYS: dict[str, str] = {
    "tool": "the tool's geom name",
    "obstacles": "the obstacles' geom names, space-separated",
    "cutoff": "m, > 0: distances beyond it read as it",
}
_PACKAGE_DIR = Path(__file__).resolve().parents[1]  # the build puts the library into the hexgym package
HEADER = Path("native") / "plugin_interface.h"  # relative to the repository root


def state_offsets() -> dict[str, int]:
    """Each state slot's offset in the instance's plugin state."""
    offsets, at = {}, 0
    for name, size in STATE_SLOTS.items():
        offsets[name], at = at, at + size
    return offsets


STATE_SIZE = sum(STATE_SLOTS.values())
STATE = state_offsets()


def interface() -> dict:
    """Everything the Python side and the plugin must agree on, as JSON-ready data."""
    return {
        "plugin": PLUGIN_NAME,
        "joints": list(kinematics.JOINTS),
        "ctrl_per_spool_m": CTRL_PER_SPOOL_M,
        "config_keys": list(CONFIG_KEYS),
        "clearance_plugin": CLEARANCE_PLUGIN_NAME,
        "clearance_config_keys": list(CLEARANCE_CONFIG_KEYS),
        "state": {name: [STATE[name], size] for name, size in STATE_SLOTS.items()},
        "state_size": STATE_SIZE,
        "quantities": list(QUANTITIES),
        "table_sets": {
            set_name: [{"name": s.name, "inputs": list(s.inputs), "output": s.output} for s in tables.values()]
            for set_name, tables in _native_sets().items()
        },
        "default_table_set": DEFAULT_TABLE_SET,
        "table_format_version": FORMAT_VERSION,
    }


def interface_json() -> str:
    """:func:`interface` as compact canonical JSON (what the library returns)."""
    return json.dumps(interface(), sort_keys=True, separators=(",", ":"))


def interface_differences(library: dict, python: dict) -> list[str]:
    """The keys whose values differ between the library's interface and Python's, described."""
    keys = sorted(set(library) | set(python))
    return [
        f"{k}: library {json.dumps(library.get(k))} vs Python {json.dumps(python.get(k))}"
        for k in keys
        if library.get(k) != python.get(k)
    ]


def header_text() -> str:
    """The text of ``native/plugin_interface.h``."""
    quote = json.dumps  # a JSON string literal is a valid C++ string literal for these ASCII names
    names = ", ".join(quote(n) for n in kinematics.JOINTS)
    lines = [
        "// Generated by hexgym/model/plugin.py (hexgym build-assets) from hexgym/model/plugin.py and",
        "// hexgym/mbl/schema.py; do not edit. The plugin's interface with the Python side.",
        "#ifndef HEXGYM_NATIVE_PLUGIN_INTERFACE_H_",
        "#define HEXGYM_NATIVE_PLUGIN_INTERFACE_H_",
        "",
        "namespace hexgym {",
        "",
        f"constexpr char kPluginName[] = {quote(PLUGIN_NAME)};",
        f"constexpr const char* kJoints[{len(kinematics.JOINTS)}] = {{{names}}};",
        f"constexpr double kCtrlPerSpoolMetre = {CTRL_PER_SPOOL_M!r};  // ctrl unit: mm of spool",
        f"constexpr int kTableFormatVersion = {FORMAT_VERSION};",
        "",
        "// Plugin state slots (offsets) and size",
        *[f"constexpr int k{_camel(name)} = {STATE[name]};  // {size} value(s)" for name, size in STATE_SLOTS.items()],
        f"constexpr int kStateSize = {STATE_SIZE};",
        "",
        "// Config keys, in the declared order",
        "constexpr const char* kAttributes[] = {",
        *[f"    {quote(key)},  // {what}" for key, what in CONFIG_KEYS.items()],
        "};",
        "constexpr int kNumAttributes = sizeof(kAttributes) / sizeof(kAttributes[0]);",
        "",
        "// The clearance sensor plugin: its name and config keys, in the declared order",
        f"constexpr char kClearancePluginName[] = {quote(CLEARANCE_PLUGIN_NAME)};",
        "constexpr const char* kClearanceAttributes[] = {",
        *[f"    {quote(key)},  // {what}" for key, what in CLEARANCE_CONFIG_KEYS.items()],
        "};",
        "constexpr int kNumClearanceAttributes = sizeof(kClearanceAttributes) / sizeof(kClearanceAttributes[0]);",
        "",
        "// The quantities the tables read (the query vector's order)",
        "enum Quantity {",
        *[f"  kQ{_camel(q)}," for q in QUANTITIES],
        "  kNumQuantities",
        "};",
        "constexpr const char* kQuantityNames[kNumQuantities] = {",
        *[f"    {quote(q)}," for q in QUANTITIES],
        "};",
        "",
        f"constexpr int kMaxTableInputs = {max(len(s.inputs) for t in _native_sets().values() for s in t.values())};",
        "struct TableSchema {",
        "  const char* name;",
        "  int num_inputs;",
        "  Quantity inputs[kMaxTableInputs];",
        "  const char* output;",
        "};",
        *[line for name, tables in _native_sets().items() for line in _table_set_lines(name, tables)],
        "struct TableSet {",
        "  const char* name;",
        "  int num_tables;",
        "  const TableSchema* tables;",
        "};",
        f"constexpr int kNumTableSets = {len(NATIVE_TABLE_SETS)};",
        "constexpr TableSet kTableSets[kNumTableSets] = {",
        *[f"    {{{json.dumps(n)}, {len(t)}, k{_camel(n)}Tables}}," for n, t in _native_sets().items()],
        "};",
        f"constexpr char kDefaultTableSet[] = {quote(DEFAULT_TABLE_SET)};",
        "",
        "// All of the above as JSON, returned by hexgym_mbl_interface() for the Python side's check",
        f"constexpr char kInterfaceJson[] = {quote(interface_json())};",
        "",
        "}  // namespace hexgym",
        "",
        "#endif  // HEXGYM_NATIVE_PLUGIN_INTERFACE_H_",
        "",
    ]
    return "\n".join(lines)


def _native_sets() -> dict:
    """The table sets the plugin runs, by name."""
    return {name: TABLE_SETS[name] for name in NATIVE_TABLE_SETS}


def _table_set_lines(name: str, tables: dict) -> list[str]:
    return [
        f"constexpr TableSchema k{_camel(name)}Tables[] = {{",
        *[_table_row(s.name, s.inputs, s.output) for s in tables.values()],
        "};",
    ]


def _table_row(name: str, inputs: tuple[str, ...], output: str) -> str:
    quantities = ", ".join("kQ" + _camel(q) for q in inputs)
    return f"    {{{json.dumps(name)}, {len(inputs)}, {{{quantities}}}, {json.dumps(output)}}},"


def _camel(name: str) -> str:
    return "".join(part.capitalize() for part in name.split("_"))


def write_interface_header(path: str | Path) -> Path:
    """Write :func:`header_text` atomically to ``path`` (the repository's ``native/plugin_interface.h``)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(header_text())
    return path


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
        mismatch = _interface_error(library)  # before registering: a mismatched library must not run
        if mismatch:
            return mismatch
        mujoco.mj_loadPluginLibrary(str(library))
        return _library_error(library)
    except (OSError, AttributeError, mujoco.FatalError) as exc:
        return f"the native plugin {library} cannot be loaded: {exc}"


def _interface_error(library: Path) -> str:
    """Why ``library``'s compiled-in interface does not match this module's ("" if it does)."""
    lib = ctypes.CDLL(str(library))
    if not hasattr(lib, "hexgym_mbl_interface"):
        return f"the native plugin {library} reports no interface (an old build): rebuild hexgym (pip install -e .)"
    lib.hexgym_mbl_interface.restype = ctypes.c_char_p
    built = json.loads(lib.hexgym_mbl_interface().decode())
    differences = interface_differences(built, interface())
    if not differences:
        return ""
    return (
        f"the native plugin {library} was built for another interface than hexgym/model/plugin.py defines ("
        + "; ".join(differences)
        + "): rebuild hexgym (pip install -e .)"
    )


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


def plugin_config_values(model: mujoco.MjModel, instance: int = 0) -> dict[str, str]:
    """The config of a ``hexgym.mbl`` instance as compiled (unset keys are "").

    MuJoCo stores one NUL-terminated value per declared attribute, in the declared order, which
    :func:`load_plugin` has checked to be :data:`CONFIG_KEYS`.
    """
    start = int(model.plugin_attradr[instance])
    end = int(model.plugin_attradr[instance + 1]) if instance + 1 < model.nplugin else len(model.plugin_attr)
    values = np.asarray(model.plugin_attr[start:end]).tobytes().split(b"\0")[: len(CONFIG_KEYS)]
    if len(values) != len(CONFIG_KEYS):
        raise ValueError(f"plugin instance {instance} holds {len(values)} config values, expected {len(CONFIG_KEYS)}")
    return {k: v.decode() for k, v in zip(CONFIG_KEYS, values, strict=True)}
