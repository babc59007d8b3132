"""A machine that is not the packaged one: the reference circuit with what differs between units overridden.

Two machines of one model differ where wear and adjustment differ: how far each valve passage opens, how much the
pumps deliver and where their regulators sit, the relief settings, the leakage. A *hydraulics file* (YAML or JSON,
read with ``yaml.safe_load`` or ``json``, never unpickled) names those differences; everything it leaves out stays
as :mod:`hexgym.machine.parameters` has it::

    valve:
      passage_area_scale:        # a passage's full-open area times this; names as the circuit's branches
        boom_pa: 0.9             # <section>_<pa|pb|at|bt>, <section>_bypass, the regeneration passages
        stick_bt: 1.1
    pump:
      max_flow_scale: 0.95       # or max_flow_m3s: each pump's maximum delivery (not both)
      power_limit_w: 100000      # the cross-sensing horsepower limit p1 Q1 + p2 Q2
      nfc_pressure_full_flow_pa: 0.8e6   # the negative-flow-control curve's corners
      nfc_pressure_min_flow_pa: 2.5e6
    relief:
      main_pa: 34.3e6            # cracking pressures
      swing_pa: 29.4e6
      line_pa: {boom: 37.2e6, stick: 37.2e6, bucket: 36.8e6}
    leakage:
      cylinder_scale: 1.0        # the piston leaks times this
      swing_motor_scale: 1.0     # the swing motor's internal and drain leaks times this

An unknown key, a value that is not a number and a value out of its range (:data:`RANGES`) are refused with a
ValueError naming the file and the key. :func:`overridden_circuit` builds the
:class:`~hexgym.hydraulics.circuit.HydraulicCircuit` with them (``ReferenceModel(hydraulics=...)``); an *identity*
file (every value the packaged one) gives the packaged circuit's trajectories to the bit. The NFC orifice and the
reliefs' rated flows stay the data sheet's (they set the standby pressure and the override, not the unit's wear).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import numbers
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hexgym.checks import parse_float
from hexgym.files import check_input_file
from hexgym.hydraulics.circuit import (
    DEFAULT_LAYOUT,
    PASSAGES,
    VALVE_LAYOUTS,
    HydraulicCircuit,
    SpoolAreas,
    ValveLayout,
    relief_area,
    spool_areas,
)
from hexgym.machine import parameters as p

CYLINDER_RELIEFS = tuple(p.LINE_RELIEF)  # boom, stick, bucket
# Each numeric key's accepted range (inclusive) and unit: wide enough for any unit of the class, narrow enough to
# catch a value in the wrong unit (a pressure in bar, a flow in L/min).
RANGES: dict[str, tuple[float, float, str]] = {
    "valve.passage_area_scale": (0.05, 10.0, "(a factor)"),
    "pump.max_flow_scale": (0.25, 4.0, "(a factor)"),
    "pump.max_flow_m3s": (0.5e-3, 10e-3, "m^3/s per pump (30-600 L/min)"),
    "pump.power_limit_w": (10e3, 500e3, "W"),
    "pump.nfc_pressure_full_flow_pa": (0.0, p.NFC_RELIEF, "Pa"),
    "pump.nfc_pressure_min_flow_pa": (0.0, p.NFC_RELIEF, "Pa"),
    "relief.main_pa": (p.NFC_PRESSURE_IDLE, 60e6, "Pa (above the standby pressure)"),
    "relief.swing_pa": (p.NFC_PRESSURE_IDLE, 60e6, "Pa (above the standby pressure)"),
    "relief.line_pa": (p.NFC_PRESSURE_IDLE, 60e6, "Pa (above the standby pressure)"),
    "leakage.cylinder_scale": (0.0, 100.0, "(a factor)"),
    "leakage.swing_motor_scale": (0.0, 100.0, "(a factor)"),
}
_SECTIONS = {
    "valve": ("passage_area_scale",),
    "pump": ("max_flow_scale", "max_flow_m3s", "power_limit_w", "nfc_pressure_full_flow_pa",
             "nfc_pressure_min_flow_pa"),
    "relief": ("main_pa", "swing_pa", "line_pa"),
    "leakage": ("cylinder_scale", "swing_motor_scale"),
}  # fmt: skip


def passage_names(layout: ValveLayout) -> tuple[str, ...]:
    """The passages of ``layout`` a hydraulics file may scale: ``<section>_<passage>`` for each section's metering
    passages (the circuit's branch names), ``<section>_bypass``, and the layout's regeneration passages."""
    names = [f"{s.name}_{k}" for s in layout.sections for k in (*s.passages, "bypass")]
    return (*names, *layout.regeneration_passages)


_ALL_PASSAGES = frozenset(n for layout in VALVE_LAYOUTS.values() for n in passage_names(layout))


@dataclass(frozen=True)
class HydraulicsOverrides:
    """What differs from the packaged circuit (None: the packaged value); ``source`` names the file in messages."""

    source: str = "hydraulics"
    passage_area_scale: dict[str, float] = field(default_factory=dict)
    max_flow_m3s: float | None = None
    power_limit_w: float | None = None
    nfc_pressure_full_flow_pa: float | None = None
    nfc_pressure_min_flow_pa: float | None = None
    main_relief_pa: float | None = None
    swing_relief_pa: float | None = None
    line_relief_pa: dict[str, float] = field(default_factory=dict)
    cylinder_leakage_scale: float = 1.0
    swing_motor_leakage_scale: float = 1.0


def read_hydraulics_file(path: str | Path) -> HydraulicsOverrides:
    """A hydraulics file (``.yaml``/``.yml`` read with ``yaml.safe_load``, anything else as JSON), checked."""
    path = check_input_file(path, "hydraulics file")
    text = path.read_text(encoding="utf-8", errors="strict")
    if path.suffix.lower() in (".yaml", ".yml"):
        try:
            import yaml
        except ImportError:
            raise ValueError(f"{path}: reading YAML needs PyYAML (pip install 'hexgym[logs]'), or write JSON") from None
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise ValueError(f"{path}: not readable YAML ({' '.join(str(exc).split())})") from None
    else:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: not readable JSON ({exc})") from None
    return parse_hydraulics(data, str(path))


def parse_hydraulics(data: Any, source: str = "hydraulics") -> HydraulicsOverrides:
    """A hydraulics file's content (a mapping, see the module) as overrides; ValueError naming ``source`` and the key
    of the first problem."""
    data = {} if data is None else data
    _mapping(data, source, "the file")
    unknown = sorted(set(data) - set(_SECTIONS))
    if unknown:
        raise ValueError(f"{source}: unknown key {unknown[0]!r}; the keys are {', '.join(_SECTIONS)}")
    values: dict[str, Any] = {}
    for section, keys in _SECTIONS.items():
        body = data.get(section) or {}
        _mapping(body, source, section)
        bad = sorted(set(body) - set(keys))
        if bad:
            raise ValueError(f"{source}: unknown key {section}.{bad[0]!r}; {section} has {', '.join(keys)}")
        values |= {f"{section}.{k}": v for k, v in body.items()}
    return _overrides(values, source)


def _overrides(values: dict[str, Any], source: str) -> HydraulicsOverrides:
    scales = _named_numbers(values.get("valve.passage_area_scale"), source, "valve.passage_area_scale", _ALL_PASSAGES)
    lines = _named_numbers(values.get("relief.line_pa"), source, "relief.line_pa", frozenset(CYLINDER_RELIEFS))
    num = {k: _number(v, source, k) for k, v in values.items() if not isinstance(v, Mapping)}
    if "pump.max_flow_scale" in num and "pump.max_flow_m3s" in num:
        raise ValueError(f"{source}: pump.max_flow_scale and pump.max_flow_m3s: give one of them")
    max_flow = num.get("pump.max_flow_m3s")
    if "pump.max_flow_scale" in num:
        max_flow = p.PUMP_MAX_FLOW * num["pump.max_flow_scale"]
    full = num.get("pump.nfc_pressure_full_flow_pa", p.NFC_PRESSURE_FULL_FLOW)
    if not full < num.get("pump.nfc_pressure_min_flow_pa", p.NFC_PRESSURE_MIN_FLOW):
        raise ValueError(f"{source}: pump.nfc_pressure_full_flow_pa must be below pump.nfc_pressure_min_flow_pa")
    return HydraulicsOverrides(
        source=source,
        passage_area_scale=scales,
        max_flow_m3s=max_flow,
        power_limit_w=num.get("pump.power_limit_w"),
        nfc_pressure_full_flow_pa=num.get("pump.nfc_pressure_full_flow_pa"),
        nfc_pressure_min_flow_pa=num.get("pump.nfc_pressure_min_flow_pa"),
        main_relief_pa=num.get("relief.main_pa"),
        swing_relief_pa=num.get("relief.swing_pa"),
        line_relief_pa=lines,
        cylinder_leakage_scale=num.get("leakage.cylinder_scale", 1.0),
        swing_motor_leakage_scale=num.get("leakage.swing_motor_scale", 1.0),
    )


def _mapping(value: Any, source: str, key: str) -> None:
    if not isinstance(value, Mapping):
        raise ValueError(f"{source}: {key} must be a mapping of names to values, got {type(value).__name__}")


def _named_numbers(value: Any, source: str, key: str, names: frozenset[str]) -> dict[str, float]:
    if value is None:
        return {}
    _mapping(value, source, key)
    unknown = sorted(set(value) - names)
    if unknown:
        raise ValueError(f"{source}: unknown key {key}.{unknown[0]}; the names are {', '.join(sorted(names))}")
    return {name: _number(v, source, key, f"{key}.{name}") for name, v in value.items()}


def _number(value: Any, source: str, key: str, shown: str | None = None) -> float:
    """A finite real number (not a bool, not text) within ``RANGES[key]``."""
    lo, hi, unit = RANGES[key]
    shown = shown or key
    if isinstance(value, str):  # YAML 1.1 reads 0.8e6 (no sign in the exponent) as text
        try:
            value = parse_float(value)
        except ValueError:
            pass
    if not isinstance(value, numbers.Real) or isinstance(value, bool) or not math.isfinite(value):
        raise ValueError(f"{source}: {shown} must be a finite number {unit}, got {value!r}")
    if not lo <= value <= hi:
        raise ValueError(f"{source}: {shown} = {value!r} is out of range: {lo:g} to {hi:g} {unit}")
    return float(value)


def engine_power_limit_w(engine_power_scale: float) -> float:
    """The pumps' power limit (W, p1 Q1 + p2 Q2) of an engine giving ``engine_power_scale`` times ``ENGINE_POWER``:
    ``PUMP_POWER_LIMIT``'s derivation with the weaker engine (the accessories take the same)."""
    return (engine_power_scale * p.ENGINE_POWER - p.ACCESSORY_POWER) * p.PUMP_OVERALL_EFFICIENCY


def with_engine_power(overrides: HydraulicsOverrides | None, engine_power_scale: float) -> HydraulicsOverrides | None:
    """``overrides`` (None: the packaged circuit) with the pumps' power limit of an engine giving
    ``engine_power_scale`` times ``ENGINE_POWER`` (:func:`engine_power_limit_w`); unchanged at a scale of 1."""
    if engine_power_scale == 1.0:
        return overrides
    limit = engine_power_limit_w(engine_power_scale)
    if overrides is None:
        return HydraulicsOverrides(source="engine_power_scale", power_limit_w=limit)
    return dataclasses.replace(overrides, power_limit_w=limit)


def as_overrides(hydraulics: HydraulicsOverrides | Mapping | str | Path) -> HydraulicsOverrides:
    """Overrides from what a caller gives: the object itself, a file's path or a file's content (a mapping)."""
    if isinstance(hydraulics, HydraulicsOverrides):
        return hydraulics
    if isinstance(hydraulics, Mapping):
        return parse_hydraulics(hydraulics)
    return read_hydraulics_file(hydraulics)


# -- the circuit with them -----------------------------------------------------------------------------
class OverriddenCircuit(HydraulicCircuit):
    """:class:`HydraulicCircuit` with a unit's pumps, regulator, valve passages, reliefs and leakage; ``valve``: the
    passages' areas from another law (a learned valve, which already is the unit's: no passage scale then)."""

    def __init__(
        self,
        overrides: HydraulicsOverrides,
        layout: ValveLayout = DEFAULT_LAYOUT,
        valve: Callable[[np.ndarray], SpoolAreas] | None = None,
    ) -> None:
        known = set(passage_names(layout))
        other = sorted(set(overrides.passage_area_scale) - known)
        if other:
            raise ValueError(f"{overrides.source}: valve.passage_area_scale.{other[0]}: the {layout.name!r} valve has "
                             f"no such passage; it has {', '.join(sorted(known))}")  # fmt: skip
        if valve is not None and overrides.passage_area_scale:
            raise ValueError(f"{overrides.source}: valve.passage_area_scale does not apply to a learned valve")
        self.overrides = overrides
        if valve is None:
            valve = functools.partial(_scaled_areas, layout=layout, scales=_scales(overrides, layout))
        super().__init__(valve=valve, layout=layout)
        self._override_reliefs(overrides)
        self._scale_leaks(overrides)

    def pump_flows(self, p_pumps: np.ndarray, displacement: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`HydraulicCircuit.pump_flows` at the unit's maximum flow and power limit."""
        o = self.overrides
        return HydraulicCircuit.pump_flows(p_pumps, displacement, o.max_flow_m3s, o.power_limit_w)

    def nfc_target(self, p_bypass: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`HydraulicCircuit.nfc_target` on the unit's regulator curve."""
        o = self.overrides
        return HydraulicCircuit.nfc_target(p_bypass, o.nfc_pressure_full_flow_pa, o.nfc_pressure_min_flow_pa)

    def _override_reliefs(self, o: HydraulicsOverrides) -> None:
        settings: dict[str, tuple[float, float]] = {}
        if o.main_relief_pa is not None:
            settings |= {f"main_relief{k}": (o.main_relief_pa, p.MAIN_RELIEF_RATED_FLOW) for k in (1, 2)}
        if o.swing_relief_pa is not None:
            settings |= {f"swing_crossover_{s}": (o.swing_relief_pa, p.LINE_RELIEF_RATED_FLOW) for s in ("ab", "ba")}
        for cylinder, value in o.line_relief_pa.items():
            settings |= {f"{cylinder}_line_relief_{s}": (value, p.LINE_RELIEF_RATED_FLOW) for s in ("a", "b")}
        br = self.branches
        for name, (setting, rated) in settings.items():
            i = self.branch_index[name]
            br.area[i] = relief_area(setting, rated)
            br.crack[int(np.flatnonzero(br.valve == i)[0])] = setting

    def _scale_leaks(self, o: HydraulicsOverrides) -> None:
        for i, name in enumerate(self.branches.names):
            if name.endswith("_piston_leak"):
                self.branches.laminar[i] *= o.cylinder_leakage_scale
            elif name.startswith(("swing_internal_leak", "swing_drain_")):
                self.branches.laminar[i] *= o.swing_motor_leakage_scale


def _scales(o: HydraulicsOverrides, layout: ValveLayout) -> dict[str, np.ndarray | float]:
    """Per passage kind (``PASSAGES``, ``bypass``): each section's factor; per regeneration passage: its factor."""
    out: dict[str, np.ndarray | float] = {}
    for kind in (*PASSAGES, "bypass"):
        out[kind] = np.array([o.passage_area_scale.get(f"{s.name}_{kind}", 1.0) for s in layout.sections])
    return out | {k: o.passage_area_scale.get(k, 1.0) for k in layout.regeneration_passages}


def _scaled_areas(spools_m: np.ndarray, layout: ValveLayout, scales: dict[str, np.ndarray | float]) -> SpoolAreas:
    """The data sheet's passage areas (:func:`spool_areas`) times the unit's factors."""
    areas = spool_areas(spools_m, layout)
    return dataclasses.replace(areas, **{k: getattr(areas, k) * s for k, s in scales.items()})


def overridden_circuit(
    hydraulics: HydraulicsOverrides | Mapping | str | Path, layout: ValveLayout = DEFAULT_LAYOUT
) -> OverriddenCircuit:
    """The circuit of a unit described by ``hydraulics`` (overrides, a file's path or its content)."""
    return OverriddenCircuit(as_overrides(hydraulics), layout)
