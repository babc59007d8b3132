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
from hexgym.hydraulics.circuit import STATE_SIZE as CIRCUIT_STATE_SIZE
from hexgym.machine import kinematics
from hexgym.mbl.schema import CIRCUIT_TABLE_SETS, DEFAULT_TABLE_SET, NATIVE_TABLE_SETS, QUANTITIES, TABLE_SETS
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
    "table_set": f"the tables directory's table set: {', '.join(NATIVE_TABLE_SETS)} (default {DEFAULT_TABLE_SET})",
    "circuit": "the circuit's numbers (CIRCUIT_COUNTS, then CIRCUIT_FIELDS), for a circuit model's table set",
    "substeps": "the circuit's steps per control period, for a circuit model's table set",
}
# Plugin state slots (mjSTATE_PLUGIN, so mj_getState/mj_setState restore a step exactly): name -> size.
STATE_SLOTS: dict[str, int] = {
    "load": 4,  # the previous step's constraint load at the 4 main dofs, N m (without the joint limits')
    "acceleration": 1,  # the swing table's last acceleration, rad/s^2
    "phase": 1,  # steps since the last table query, less whole control periods
    "targets": 4,  # the joint-rate targets held until the next query (the swing's unclipped)
    "hydraulics": CIRCUIT_STATE_SIZE,  # the circuit model's pressures (Pa) and pump displacements (STATE_NAMES)
    "rates": 4,  # the circuit model's joint rates at the last period's end, rad/s
    "circuit_ready": 1,  # 1 once the circuit's state is set; 0 after a reset (the next query sets it to hold the loads)
    "circuit_fault": 1,  # 1 once the circuit's state went non-finite (the machine then holds still)
}
# The circuit model's constants as the native kernel reads them (native/circuit.cc; config key "circuit", and
# hexgym.model.circuit_kernel's binding): the counts (CIRCUIT_COUNTS: nodes, branches, valve sections, regeneration
# passages), then each field in this order, its numbers in C order of the shape (extent, rows), or (extent,) for one
# row. Extents: "one", the counts, "pumps", "functions" (the spools' order), "cylinders" (boom, stick, bucket).
CIRCUIT_LAWS = (
    "discharge",  # orifice discharge coefficient
    "sqrt_2_rho",  # sqrt(2 / oil density)
    "laminar_sq",  # the orifice law's laminar pressure, squared, Pa^2
    "atmosphere",  # Pa
    "vacuum",  # Pa gauge: the compliance law's floor
    "polytropic",  # entrained air's polytropic exponent
    "air_fraction",  # entrained air at atmospheric pressure
    "bulk_modulus",  # Pa
    "cushion_length",  # m
    "cushion_area",  # m^2
    "cushion_port_area",  # m^2
    "nfc_full_flow",  # Pa: NFC signal for full displacement
    "nfc_min_flow",  # Pa: NFC signal for idle displacement
    "idle_fraction",  # the pumps' idle displacement fraction
    "power_limit",  # W: the pumps' cross-sensing horsepower limit
    "max_flow",  # m^3/s per pump
    "regulator_time",  # s
    "max_splits",  # a step is split in halves at most this deep
    "trust_floor",  # Pa: a pressure above it that more than halves in a step splits it
    "trust_jump",  # Pa: a pressure change larger than this splits a step
    "coulomb",  # N per cylinder
    "friction_velocity",  # m/s
    "viscous",  # N s/m per cylinder
    "swing_reduction",  # motor turns per upper-structure turn
    "swing_displacement",  # m^3/rad of the motor
    "swing_viscous",  # N m s/rad at the motor
    "swing_efficiency",  # the motor and gear's mechanical efficiency
    "swing_friction_speed",  # rad/s at the motor
    "swing_a",  # the swing motor's port nodes
    "swing_b",
    "stop_clearance",  # m inside each stroke end, where the cylinders' stops begin
    "stop_stiffness",  # N/m per cylinder, the stops' springs
    "stop_damping",  # N s/m per cylinder
    "stop_split",  # circuit steps a step is split into where a cylinder runs into its stop
    "stop_split_speed",  # m/s: the slowest such cylinder that splits the step
    "dead_band",  # m of spool: the passages to and from the ports are closed within it
    "spool_stroke",  # m of spool: full stroke
    "metering_exponent",  # a metering notch's area ~ (open fraction of its travel)^this
    "closed_area",  # m^2: a closed bypass section in the series law
    "idle_pressure",  # Pa: the pump and NFC signal lines at rest
    "rest_pressure",  # Pa: a chamber that holds no load
    "fault_pressure",  # Pa: a pressure beyond this (FAULT_FACTOR x the highest relief) is a diverged state
)
CIRCUIT_FIELDS: dict[str, tuple[int, str]] = {
    "laws": (len(CIRCUIT_LAWS), "one"),
    "branch_from": (1, "branches"),  # node indices; the tank is node `nodes`
    "branch_to": (1, "branches"),
    "branch_area": (1, "branches"),  # m^2, fixed orifices (the valve's passages are set each period)
    "branch_crack": (1, "branches"),  # Pa, pressure-operated valves
    "branch_inv_span": (1, "branches"),  # 1/Pa, > 0 for a pressure-operated valve
    "branch_laminar": (1, "branches"),  # m^3/(s Pa), leaks
    "branch_pilot": (1, "branches"),  # the node whose pressure opens a pressure-operated valve; -1: its own drop
    # the function (spool) that moves each valve section, to the sides it has passages on (else it stays at neutral)
    "section_function": (1, "sections"),
    "section_pump": (1, "sections"),  # the pump it meters from; its bypass is in that pump's series, in this order
    "section_table": (5, "sections"),  # the valve table of its bypass, pump->a, pump->b, a->tank, b->tank; -1: none
    "section_branch": (4, "sections"),  # the branch of its pump->a, pump->b, a->tank, b->tank; -1: none
    # a priority valve on its meter-in (pump->a, pump->b): the piloting function (-1: none), the side of that
    # spool that pilots it (1 positive, -1 negative, 0 either), the share of the area left at full pilot spool
    "section_priority": (3, "sections"),
    # a regeneration passage: its branch, the function whose spool opens it, the side (1 positive, -1 negative),
    # its valve table (-1: none, the data sheet's area below metered by the spool), that area (m^2), the cylinder
    # whose oil leaves through it and its cushion (-1: none), the end it leaves (1 the rod's, -1 the head's)
    "regeneration": (7, "regenerations"),
    "bypass_branch": (1, "pumps"),  # each pump's centre bypass branch
    "pump_node": (1, "pumps"),
    "signal_node": (1, "pumps"),  # each pump's NFC signal node
    "head_area": (1, "cylinders"),  # m^2 per cylinder
    "rod_area": (1, "cylinders"),
    "stroke": (1, "cylinders"),  # m
    "cylinder_count": (1, "cylinders"),  # cylinders per function
    "port_volume": (1, "cylinders"),  # m^3 of line per chamber
    "head_node": (1, "cylinders"),
    "rod_node": (1, "cylinders"),
    "function": (1, "cylinders"),  # the section whose a->tank and b->tank pass the cylinder's cushions
    "node_volume": (1, "nodes"),  # m^3; 0 for the chambers, whose volumes follow the pistons
    "displacement": (4, "nodes"),  # d(volume rate)/d(boom, stick, bucket velocity, swing rate)
}
# the counts the numbers start with, in this order
CIRCUIT_COUNTS = ("nodes", "branches", "sections", "regenerations")
CIRCUIT_EXTENTS = ("one", *CIRCUIT_COUNTS, "pumps", "functions", "cylinders")
NUM_PUMPS, NUM_CYLINDERS = 2, 3
# The buffer of one control period through the library's hexgym_circuit_period (the Python circuit model's call):
# slot -> size; spools to load go in, state, rates and ext go in and come out, travel comes out.
PERIOD_SLOTS: dict[str, int] = {
    "spools": 4,  # m, swing boom stick bucket
    "rates": 4,  # rad/s, the joints' rates
    "ext": NUM_CYLINDERS,  # m, the cylinders' extensions
    "arms": NUM_CYLINDERS,  # m/rad, the cylinders' moment arms
    "mass": 16,  # the main joints' mass matrix, row-major
    "load": 4,  # N m, the joints' loads
    "travel": 4,  # rad, each joint's travel over the period
    "state": CIRCUIT_STATE_SIZE,  # the circuit's state
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


def state_offsets(slots: dict[str, int] = STATE_SLOTS) -> dict[str, int]:
    """Each slot's offset: of the instance's plugin state (default), or of other ``slots``."""
    offsets, at = {}, 0
    for name, size in slots.items():
        offsets[name], at = at, at + size
    return offsets


STATE_SIZE = sum(STATE_SLOTS.values())
STATE = state_offsets()
PERIOD = {name: slice(at, at + PERIOD_SLOTS[name]) for name, at in state_offsets(PERIOD_SLOTS).items()}
PERIOD_SIZE = sum(PERIOD_SLOTS.values())


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
        "circuit_table_sets": [name for name in NATIVE_TABLE_SETS if name in CIRCUIT_TABLE_SETS],
        "default_table_set": DEFAULT_TABLE_SET,
        "table_format_version": FORMAT_VERSION,
        "circuit_laws": list(CIRCUIT_LAWS),
        "circuit_numbers_start": list(CIRCUIT_COUNTS),
        "circuit_fields": [[name, rows, per] for name, (rows, per) in CIRCUIT_FIELDS.items()],
        "circuit_period": {name: [at, PERIOD_SLOTS[name]] for name, at in state_offsets(PERIOD_SLOTS).items()},
        "circuit_counts": {"pumps": NUM_PUMPS, "cylinders": NUM_CYLINDERS, "functions": len(kinematics.JOINTS)},
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
        *[
            f"constexpr int k{_camel(name)} = {STATE[name]}, k{_camel(name)}Size = {size};"
            for name, size in STATE_SLOTS.items()
        ],
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
        "  bool circuit;  // the circuit model's valve tables (the numbers of config key circuit say the circuit)",
        "};",
        f"constexpr int kNumTableSets = {len(NATIVE_TABLE_SETS)};",
        "constexpr TableSet kTableSets[kNumTableSets] = {",
        *[
            f"    {{{json.dumps(n)}, {len(t)}, k{_camel(n)}Tables, {str(n in CIRCUIT_TABLE_SETS).lower()}}},"
            for n, t in _native_sets().items()
        ],
        "};",
        f"constexpr char kDefaultTableSet[] = {quote(DEFAULT_TABLE_SET)};",
        "",
        *_circuit_lines(),
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


def _circuit_lines() -> list[str]:
    """The circuit numbers' layout (:data:`CIRCUIT_LAWS`, :data:`CIRCUIT_FIELDS`) as C++ enums and a table."""
    return [
        f'// The circuit model\'s numbers (config key "circuit"): {", ".join(CIRCUIT_COUNTS)}, then these fields',
        "// in order, each rows x extent numbers (C order of (extent, rows))",
        f"constexpr int kNumCircuitCounts = {len(CIRCUIT_COUNTS)};",
        f"constexpr int kNumPumps = {NUM_PUMPS};",
        f"constexpr int kNumCylinders = {NUM_CYLINDERS};",
        f"constexpr int kNumFunctions = {len(kinematics.JOINTS)};",
        "// hexgym_circuit_period's buffer: slot offsets and size",
        *[f"constexpr int kPeriod{_camel(name)} = {at};" for name, at in state_offsets(PERIOD_SLOTS).items()],
        f"constexpr int kPeriodSize = {PERIOD_SIZE};",
        "enum CircuitLaw {",
        *[f"  kLaw{_camel(name)}," for name in CIRCUIT_LAWS],
        "  kNumCircuitLaws",
        "};",
        "enum CircuitExtent {",
        *[f"  kPer{_camel(name)}," for name in CIRCUIT_EXTENTS],
        "};",
        "enum CircuitFieldId {",
        *[f"  kField{_camel(name)}," for name in CIRCUIT_FIELDS],
        "  kNumCircuitFields",
        "};",
        "struct CircuitField {",
        "  const char* name;",
        "  int rows;",
        "  CircuitExtent per;",
        "};",
        "constexpr CircuitField kCircuitFields[kNumCircuitFields] = {",
        *[f"    {{{json.dumps(n)}, {rows}, kPer{_camel(per)}}}," for n, (rows, per) in CIRCUIT_FIELDS.items()],
        "};",
    ]


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
