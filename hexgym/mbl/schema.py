"""The MBL tables' schema: the one definition of each table's inputs, output and units, in order.

Collection names its data columns after it, fitting checks data sets against it, both learned
backends build their queries from it, and the native plugin's interface header is generated from it
(:mod:`hexgym.model.plugin`); every table file records its inputs and output, and loading compares
them with this schema. Adding an input is one edit here plus computing the new quantity where the
backends gather their quantities.

Quantity names carry their SI unit as a suffix (``_m``, ``_n``, ``_kgm2``, ``_radps``, ``_mps``,
``_radps2``); :data:`UNITS` spells them out.
"""

from __future__ import annotations

from dataclasses import dataclass

UNITS = {"_m": "m", "_n": "N", "_kgm2": "kg m^2", "_radps": "rad/s", "_mps": "m/s", "_radps2": "rad/s^2"}

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
    """One table: the collection group whose episodes feed it, its inputs (in order) and its output."""

    name: str
    group: str
    inputs: tuple[str, ...]
    output: str


def _tables(*specs: TableSchema) -> dict[str, TableSchema]:
    for spec in specs:
        unknown = [q for q in spec.inputs if q not in QUANTITIES]
        if unknown:
            raise ValueError(f"table {spec.name!r} reads unknown quantities {unknown}")
    return {spec.name: spec for spec in specs}


# The paper's four tables (Sec III), in the order the plugin and the files list them.
TABLES: dict[str, TableSchema] = _tables(
    TableSchema(
        "boom", "boom_bucket", ("boom_spool_m", "bucket_spool_m", "boom_force_n", "bucket_force_n"), "boom_velocity_mps"
    ),
    TableSchema(
        "bucket",
        "boom_bucket",
        ("boom_spool_m", "bucket_spool_m", "boom_force_n", "bucket_force_n"),
        "bucket_velocity_mps",
    ),
    TableSchema(
        "stick",
        "stick_swing",
        ("swing_spool_m", "stick_spool_m", "swing_inertia_kgm2", "stick_force_n"),
        "stick_velocity_mps",
    ),
    TableSchema(
        "swing",
        "stick_swing",
        ("swing_spool_m", "stick_spool_m", "stick_force_n", "swing_inertia_kgm2", "swing_rate_radps"),
        "swing_acceleration_radps2",
    ),
)
TABLE_NAMES = tuple(TABLES)


def unit(quantity: str) -> str:
    """The SI unit of a schema quantity, from its name's suffix."""
    for suffix in sorted(UNITS, key=len, reverse=True):
        if quantity.endswith(suffix):
            return UNITS[suffix]
    raise ValueError(f"quantity {quantity!r} has no unit suffix")


def check_table_schema(source: str, name: str, inputs: tuple[str, ...], output: str) -> None:
    """Raise ValueError naming ``source`` if table ``name``'s inputs/output differ from the schema's."""
    if name not in TABLES:
        raise ValueError(f"{source}: no table named {name!r} in the schema (tables: {', '.join(TABLE_NAMES)})")
    spec = TABLES[name]
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
    raise ValueError(f"{source}: table {name!r} does not match the schema: {'; '.join(what)}")
