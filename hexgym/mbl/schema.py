"""The MBL tables' schema: the one definition of each table's inputs, output and units, in order.

Collection names its data columns after it, fitting checks data sets against it, both learned
backends build their queries from it, and the native plugin's interface header is generated from it
(:mod:`hexgym.model.plugin`); every table file records its inputs and output, and loading compares
them with this schema. Adding an input is one edit here plus computing the new quantity where the
backends gather their quantities.

Two table sets. ``paper``, the paper's four tables: each function's velocity, or the swing's
acceleration, from its own pump's spools and loads. ``circuit`` learns the control valve instead of
the machine's response: one 1-D table per passage (each section's centre bypass, pump to port a or
b, port a or b to tank) giving its orifice area against the spool, identified from the pressures,
pump flows and velocities of operator-like motion (:mod:`hexgym.mbl.valve`). The circuit model
(:mod:`hexgym.model.circuit_model`) runs the open-centre circuit's structure from the machine's data
sheet with these areas: the reference machine's valve, a Cat two-pump valve (:data:`VALVE_OF_TABLE_SET`). The
native plugin runs both sets (``NATIVE_TABLE_SETS``).

Quantity names carry their SI unit as a suffix: ``_m`` m, ``_n`` N, ``_kgm2`` kg m^2,
``_radps`` rad/s, ``_mps`` m/s, ``_radps2`` rad/s^2, ``_m2`` m^2.
"""

from __future__ import annotations

from dataclasses import dataclass

from hexgym.hydraulics.circuit import DEFAULT_VALVE, REGENERATION, ValveLayout, valve_layout

# Every quantity a table may read, in a fixed order (the plugin's query vector uses this order).
QUANTITIES = (
    "swing_spool_m",
    "boom_spool_m",
    "stick_spool_m",
    "bucket_spool_m",
    "boom_force_n",
    "stick_force_n",
    "bucket_force_n",
    "swing_inertia_kgm2",
    "swing_rate_radps",
)


@dataclass(frozen=True)
class TableSchema:
    """One table: the collection group whose episodes feed it, its inputs (in order), its output, and
    how collection samples it: ``"window"`` (means over a window ending a held-spool segment) or
    ``"trajectory"`` (instants along the motion, for outputs that are never steady, as the swing's)."""

    name: str
    group: str
    inputs: tuple[str, ...]
    output: str
    sampling: str = "window"


def _tables(*specs: TableSchema) -> dict[str, TableSchema]:
    for spec in specs:
        unknown = [q for q in spec.inputs if q not in QUANTITIES]
        if unknown:
            raise ValueError(f"table {spec.name!r} reads unknown quantities {unknown}")
    return {spec.name: spec for spec in specs}


_BOOM_BUCKET = ("boom_spool_m", "bucket_spool_m", "boom_force_n", "bucket_force_n")
_STICK = ("swing_spool_m", "stick_spool_m", "swing_inertia_kgm2", "stick_force_n")
_SWING = ("swing_spool_m", "stick_spool_m", "stick_force_n", "swing_inertia_kgm2", "swing_rate_radps")

TABLE_SETS: dict[str, dict[str, TableSchema]] = {
    # The paper's four tables (Sec III), in the order the plugin and the files list them.
    "paper": _tables(
        TableSchema("boom", "boom_bucket", _BOOM_BUCKET, "boom_velocity_mps"),
        TableSchema("bucket", "boom_bucket", _BOOM_BUCKET, "bucket_velocity_mps"),
        TableSchema("stick", "stick_swing", _STICK, "stick_velocity_mps"),
        TableSchema("swing", "stick_swing", _SWING, "swing_acceleration_radps2", "trajectory"),
    ),
}
# The control valve's passages: each section's centre bypass, then pump -> port a, pump -> port b,
# port a -> tank, port b -> tank (port a: a cylinder's head end, the swing motor's turning-positive port).
VALVE_PASSAGES = ("bypass", "pa", "pb", "at", "bt")
# the regeneration passages (in the spools) the tables learn, and the function whose spool opens each; the stick's
# unloading valve, piloted by its head pressure, is the machine's data like the priority valves
REGENERATION_SPOOLS = {name: r.cylinder for name, r in REGENERATION.items() if r.learned}


def valve_tables(layout: ValveLayout) -> dict[str, TableSchema]:
    """The tables of a valve layout's passages: per passage (bypass first: identifiable in most rows, it is the one
    counted), each section that has it in the layout's order, against its function's spool; then the layout's
    regeneration passages."""
    specs = [
        TableSchema(f"{s.name}_{k}", "operator", (f"{s.function}_spool_m",), f"{s.name}_{k}_area_m2", "trajectory")
        for k in VALVE_PASSAGES
        for s in layout.sections
        if k == "bypass" or k in s.passages
    ]
    for passage, function in REGENERATION_SPOOLS.items():
        if passage in layout.regeneration_passages:
            specs.append(TableSchema(passage, "operator", (f"{function}_spool_m",), f"{passage}_area_m2", "trajectory"))
    return _tables(*specs)


# Both sets are learned from the reference machine with its valve (VALVE_OF_TABLE_SET): ``circuit`` learns that
# valve's passages.
TABLE_SETS["circuit"] = valve_tables(valve_layout(DEFAULT_VALVE))
VALVE_OF_TABLE_SET = {"paper": DEFAULT_VALVE, "circuit": DEFAULT_VALVE}
CIRCUIT_TABLE_SETS = ("circuit",)  # the sets the circuit model runs
NATIVE_TABLE_SETS = ("circuit", "paper")  # the sets the native plugin runs
DEFAULT_TABLE_SET = "circuit"


def check_table_schema(
    source: str, name: str, inputs: tuple[str, ...], output: str, table_set: str = DEFAULT_TABLE_SET
) -> None:
    """Raise ValueError naming ``source`` if table ``name``'s inputs/output differ from ``table_set``'s."""
    tables = TABLE_SETS[table_set]
    if name not in tables:
        raise ValueError(f"{source}: no table named {name!r} in the {table_set!r} tables ({', '.join(tables)})")
    spec = tables[name]
    if (tuple(inputs), output) == (spec.inputs, spec.output):
        return
    missing = [q for q in spec.inputs if q not in inputs]
    extra = [q for q in inputs if q not in spec.inputs]
    what = []
    if missing:
        what.append(f"missing inputs {missing}")
    if extra:
        what.append(f"extra inputs {extra}")
    if not missing and not extra and tuple(inputs) != spec.inputs:
        what.append(f"inputs in the order {list(inputs)} instead of {list(spec.inputs)}")
    if output != spec.output:
        what.append(f"output {output!r} instead of {spec.output!r}")
    raise ValueError(f"{source}: table {name!r} does not match the {table_set!r} schema: {'; '.join(what)}")


def table_set_of(tables: dict) -> str:
    """The name of the table set whose tables ``tables`` (a dict by table name) are."""
    for name, spec in TABLE_SETS.items():
        if set(tables) == set(spec):
            return name
    raise ValueError(f"tables {sorted(tables)} are no table set's ({ {k: list(v) for k, v in TABLE_SETS.items()} })")
