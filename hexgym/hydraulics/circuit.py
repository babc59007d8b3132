"""The analytical open-centre hydraulic circuit: the slow, complete actuator model.

This is the "complete analytical model" of the paper's Sec II (Fig 2-4) that stands in for the
real machine and produces the training data. It is pure numpy: it takes the mechanical state
(cylinder extensions and velocities, the swing rate) and returns pressure derivatives and the
actuator forces; :mod:`hexgym.hydraulics.reference` couples it to the MuJoCo linkage.

The circuit is a nodal network, as a circuit simulator would build it (Fig 4's electrical
analogy taken literally). Twelve oil volumes are pressure nodes; the tank is the ground node at
0 Pa (all pressures are gauge)::

    pump1 ──┬── load check + P->a / P->b metering (boom, bucket: parallel feed)
            └── centre bypass (boom, bucket in series) ── bypass1 ── NFC orifice ∥ NFC relief ── T
    pump2 ──┬── load check + P->a / P->b metering (stick, swing)
            └── centre bypass (stick, swing in series) ── bypass2 ── NFC orifice ∥ NFC relief ── T

Every other element is a two-terminal branch between nodes: a->T / b->T meter-out orifices
(in series with the cylinder's end cushion), main reliefs on the pump lines, port reliefs on
every cylinder port, crossover reliefs between the swing motor ports, anti-cavitation make-up
checks from tank, and laminar leaks. A branch passes ``q = Cd A open(dp) R(dp) + c_lam dp``
with R the orifice law regularised to laminar near dp = 0 and ``open`` a smooth opening of a
pressure-operated valve (check, relief). Each node obeys ``dp/dt = beta(p)/V (sum q - dV/dt)``
with the volume V depending on the piston position and an entrained-air bulk modulus that
softens the oil near vacuum, so pressures cannot fall below absolute zero.

Pumps: flow ``Q_i = Q_max min(d_i, d_hp)``. ``d_i`` (a state) is the displacement fraction set
by negative flow control through a first-order lag (the NFC servo is a slow pilot loop, and the
lag breaks the algebraic loop bypass flow -> NFC pressure -> displacement -> bypass flow).
``d_hp = P_lim / (Q_max (p1 + p2))`` is the cross-sensing horsepower limit, algebraic: the HP
spool acts on the servo with the delivery pressures directly and much faster than NFC, and an
algebraic limit keeps ``p1 Q1 + p2 Q2 <= P_lim`` at every instant.

Integration: the pressure dynamics are stiff (Jacobian eigenvalues up to ~7e4 1/s: small
volumes, large bulk modulus, open orifices at small pressure drop), so
:meth:`HydraulicCircuit.step` uses the linearly implicit (Rosenbrock-)Euler method with the
analytic Jacobian: one 14x14 linear solve per step (~0.25 ms of Python), L-stable, and it keeps
the circuit's steady states exactly (a steady state of the ODE is a fixed point of the step),
which is what the learned tables sample. Where the linearisation cannot be trusted (a pressure
falling towards tank pressure, where the tangent of the square-root law overshoots, or jumping
by more than 5 MPa) the step is split in halves. With the mechanics integrated around it at
1 ms, positions agree with scipy's Radau (rtol 1e-6) to ~0.1 mm over a 2.5 s multi-function
run. :meth:`step_with_sensitivity` also returns d(state)/d(velocities) so a caller can couple
the mechanics implicitly; :meth:`derivatives` and :meth:`jacobian` serve scipy's solvers.

Conventions: spools in m (positive extends the cylinder / turns the swing counter-clockwise),
order ``FUNCTIONS``; cylinder arrays in the order ``CYLINDER_NAMES``; the swing rate is the
upper structure's rate about the swing axis (rad/s), the motor turns ``SWING_REDUCTION`` times
faster; the swing torque returned is on the swing axis.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hexgym.machine import parameters as p

FUNCTIONS = ("swing", "boom", "stick", "bucket")
CYLINDER_NAMES = ("boom", "stick", "bucket")
PUMP_OF = {"boom": 0, "bucket": 0, "stick": 1, "swing": 1}  # pump 1 = index 0
NODES = (
    "pump1",
    "pump2",
    "bypass1",
    "bypass2",
    "boom_head",
    "boom_rod",
    "stick_head",
    "stick_rod",
    "bucket_head",
    "bucket_rod",
    "swing_a",
    "swing_b",
)
N_NODES = len(NODES)
STATE_NAMES = NODES + ("pump1_displacement", "pump2_displacement")
STATE_SIZE = len(STATE_NAMES)
TANK = N_NODES  # index of the ground node in the extended pressure vector
_PORTS = {"boom": (4, 5), "stick": (6, 7), "bucket": (8, 9), "swing": (10, 11)}
_SQRT_2_RHO = np.sqrt(2.0 / p.OIL_DENSITY)
SWING_DISPLACEMENT_RAD = p.SWING_MOTOR_DISPLACEMENT / (2.0 * np.pi)  # m^3/rad
_VACUUM = 1e3 - p.ATMOSPHERIC_PRESSURE  # Pa gauge: the floor of the compliance law
REST_PRESSURE = 1.0e6  # Pa: a chamber that holds no load, at the start
# A step is split where its linearisation cannot be trusted: a pressure above TRUST_FLOOR_PA falling below half,
# or any jumping by more than TRUST_JUMP_PA (tuned on a replay against 0.125 ms steps)
TRUST_FLOOR_PA = 0.3e6
TRUST_JUMP_PA = 5e6


# --------------------------------------------------------------------------------------------
# Element laws (vectorised, with derivatives for the Jacobian).
def smoothstep(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """C1 ramp 0 -> 1 on z in [0, 1] and its derivative."""
    z = np.minimum(np.maximum(z, 0.0), 1.0)  # np.clip is several times slower on small arrays
    return z * z * (3.0 - 2.0 * z), 6.0 * z * (1.0 - z)


def orifice_law(dp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """sqrt(2|dp|/rho) sign(dp), regularised to laminar for |dp| << ORIFICE_LAMINAR_PRESSURE.

    ``R = sqrt(2/rho) dp / (dp^2 + dp_t^2)^(1/4)`` is smooth, odd and tends to the turbulent law;
    returns R and dR/d(dp) (finite at 0, so the Jacobian stays bounded).
    """
    t2 = p.ORIFICE_LAMINAR_PRESSURE**2
    s = dp * dp + t2
    w = s**-0.25
    return _SQRT_2_RHO * dp * w, _SQRT_2_RHO * w**5 * (0.5 * dp * dp + t2)


def series_area(a1: np.ndarray, a2: np.ndarray) -> np.ndarray:
    """Equivalent area of two turbulent orifices in series: 1/A^2 = 1/A1^2 + 1/A2^2."""
    return a1 * a2 / np.sqrt(a1 * a1 + a2 * a2 + 1e-30)


def compliance(pressure: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """1/beta(p) of oil with entrained air (polytropic), and its derivative d(1/beta)/dp.

    ``1/beta = (1/beta0 + x/(n p_abs)) / (1 + x)``, ``x = x0 (p_atm/p_abs)^(1/n)``: stiff
    (``OIL_BULK_MODULUS``) at working pressure, very soft near vacuum, which stands in for
    cavitation.
    """
    n, pa = p.AIR_POLYTROPIC_EXPONENT, p.ATMOSPHERIC_PRESSURE
    p_abs = pressure + pa
    floor = p_abs < _VACUUM + pa
    p_abs = np.where(floor, _VACUUM + pa, p_abs)
    x = p.OIL_AIR_FRACTION * (pa / p_abs) ** (1.0 / n)
    dx = -x / (n * p_abs)
    num = 1.0 / p.OIL_BULK_MODULUS + x / (n * p_abs)
    dnum = -x * (1.0 + 1.0 / n) / (n * p_abs * p_abs)
    c = num / (1.0 + x)
    dc = (dnum * (1.0 + x) - num * dx) / (1.0 + x) ** 2
    return c, np.where(floor, 0.0, dc)


# --------------------------------------------------------------------------------------------
# The valve: its sections, and spool position -> passage areas.
PASSAGES = ("pa", "pb", "at", "bt")


@dataclass(frozen=True)
class RegenerationPassage:
    """A passage beside the sections' metering ones: the cylinder whose oil it passes (its spool opens it), the
    spool's side that opens it (+1 extending, -1 retracting), the end the oil leaves from (through that end's
    cushion), and whether the valve's tables learn its area (else the data sheet's)."""

    cylinder: str
    side: int
    leaves_rod: bool
    learned: bool = True


REGENERATION = {
    "stick_regeneration": RegenerationPassage("stick", 1, leaves_rod=True),  # stick in: rod -> head, a check
    "stick_unloading": RegenerationPassage("stick", 1, leaves_rod=True, learned=False),  # rod -> tank, head-piloted
    "boom_regeneration": RegenerationPassage("boom", -1, leaves_rod=False),  # boom lower: head -> rod, a check
}
REGENERATION_PASSAGES = tuple(REGENERATION)


@dataclass(frozen=True)
class ValveSection:
    """One spool section of the main valve: the function whose spool moves it, the pump (0 or 1) it meters from,
    the full-open areas (m^2) of the passages it has (of ``PASSAGES``) and of its centre bypass."""

    name: str
    function: str
    pump: int
    areas: dict[str, float]

    @property
    def passages(self) -> tuple[str, ...]:
        """The metering passages the section has, in ``PASSAGES`` order."""
        return tuple(k for k in PASSAGES if k in self.areas)


@dataclass(frozen=True)
class ValveLayout:
    """The main valve: its sections (the first four are one per function, in ``FUNCTIONS`` order) and whether
    it has the swing's and the boom raise's priority over the stick and the stick's and boom's regeneration
    (parameters in :mod:`hexgym.machine.parameters`)."""

    name: str
    sections: tuple[ValveSection, ...]
    swing_priority: bool = False
    boom_priority: bool = False
    stick_regeneration: bool = False
    boom_regeneration: bool = False

    def __post_init__(self) -> None:
        check_layout(self)

    @property
    def regeneration_passages(self) -> tuple[str, ...]:
        """The regeneration passages the layout has (of ``REGENERATION_PASSAGES``)."""
        stick = ("stick_regeneration", "stick_unloading") if self.stick_regeneration else ()
        return stick + (("boom_regeneration",) if self.boom_regeneration else ())


def check_layout(layout: ValveLayout) -> None:
    """Raise ValueError, naming the section and parameter, where a layout cannot be a circuit."""
    functions = tuple(s.function for s in layout.sections[: len(FUNCTIONS)])
    if functions != FUNCTIONS:
        raise ValueError(f"valve layout {layout.name!r}: its first sections must be {FUNCTIONS}, got {functions}")
    for s in layout.sections:
        where = f"valve layout {layout.name!r}, section {s.name!r}"
        if s.function not in FUNCTIONS:
            raise ValueError(f"{where}: function {s.function!r} is not one of {FUNCTIONS}")
        if s.pump not in (0, 1):
            raise ValueError(f"{where}: pump {s.pump!r} is not 0 or 1 (the machine has two pumps)")
        unknown = sorted(set(s.areas) - set(PASSAGES) - {"bypass"})
        if unknown or "bypass" not in s.areas:
            raise ValueError(f"{where}: areas must be a bypass and some of {PASSAGES}, got {sorted(s.areas)}")
        bad = [k for k, a in s.areas.items() if not (np.isfinite(a) and a > 0.0)]
        if bad:
            raise ValueError(f"{where}: area {bad[0]!r} = {s.areas[bad[0]]} m^2 is not a positive number")
    for pump in (0, 1):
        if not any(s.pump == pump for s in layout.sections):
            raise ValueError(f"valve layout {layout.name!r}: pump {pump + 1} feeds no section")


def check_circuit_parameters() -> None:
    """Raise ValueError naming the parameter of :mod:`hexgym.machine.parameters` where the circuit's would be
    inconsistent: a relief that opens below the pumps' standby (NFC) pressure, a pump with no flow, an oil volume
    or bulk modulus that is not positive."""
    reliefs = {"MAIN_RELIEF": p.MAIN_RELIEF, "SWING_RELIEF": p.SWING_RELIEF}
    reliefs |= {f"LINE_RELIEF[{k!r}]": v for k, v in p.LINE_RELIEF.items()}
    for name, setting in reliefs.items():
        if not setting > p.NFC_PRESSURE_IDLE:
            raise ValueError(
                f"{name} = {setting / 1e6:g} MPa is not above the pumps' standby pressure NFC_PRESSURE_IDLE "
                f"= {p.NFC_PRESSURE_IDLE / 1e6:g} MPa: the relief would pass the idle flow"
            )
    positive = {"PUMP_MAX_FLOW": p.PUMP_MAX_FLOW, "OIL_BULK_MODULUS": p.OIL_BULK_MODULUS}
    positive |= {"PUMP_LINE_VOLUME": p.PUMP_LINE_VOLUME, "BYPASS_VOLUME": p.BYPASS_VOLUME}
    positive |= {"SWING_PORT_VOLUME": p.SWING_PORT_VOLUME}
    positive |= {f"CYLINDER_PORT_VOLUME[{k!r}]": v for k, v in p.CYLINDER_PORT_VOLUME.items()}
    for name, value in positive.items():
        if not (np.isfinite(value) and value > 0.0):
            raise ValueError(f"{name} = {value} is not a positive number")


def _sections(areas: dict[str, dict[str, float]], pumps: dict[str, int], functions: dict[str, str]) -> tuple:
    return tuple(ValveSection(name, functions.get(name, name), pumps[name], a) for name, a in areas.items())


# The paper's schematic (its Fig 2): pump 1 feeds boom and bucket, pump 2 stick and swing.
PAPER_VALVE = ValveLayout("paper", _sections(p.VALVE_AREAS, PUMP_OF, {}))
# A Cat two-pump valve: the paper's sections, boom 2 and stick 2 on the other pump, swing and boom priority over the
# stick, stick and boom regeneration (the sources by the parameters).
CAT_VALVE = ValveLayout(
    "cat",
    _sections(p.VALVE_AREAS | {"boom": p.VALVE_AREAS["boom"] | {"at": p.CAT_BOOM_LOWER_AREA}}, PUMP_OF, {})
    + _sections(p.COMBINING_VALVE_AREAS, {"boom2": 1, "stick2": 0}, {"boom2": "boom", "stick2": "stick"}),
    swing_priority=True,
    boom_priority=True,
    stick_regeneration=True,
    boom_regeneration=True,
)
VALVE_LAYOUTS = {layout.name: layout for layout in (PAPER_VALVE, CAT_VALVE)}
DEFAULT_LAYOUT = CAT_VALVE  # the reference machine's valve: what every learned model is learned from
DEFAULT_VALVE = DEFAULT_LAYOUT.name


def valve_layout(name: str) -> ValveLayout:
    """The valve layout of that name, or ValueError listing the known ones."""
    if name not in VALVE_LAYOUTS:
        raise ValueError(f"unknown valve layout {name!r}; choose one of {sorted(VALVE_LAYOUTS)}")
    return VALVE_LAYOUTS[name]


@dataclass(frozen=True)
class SpoolAreas:
    """Passage areas (m^2) of the valve's sections, each an array in the layout's section order (the first four
    one per function, ``FUNCTIONS`` order); a passage a section lacks is 0."""

    pa: np.ndarray  # P -> a (through the load check)
    pb: np.ndarray  # P -> b
    at: np.ndarray  # a -> T
    bt: np.ndarray  # b -> T
    bypass: np.ndarray  # centre bypass through this section
    pump_bypass: np.ndarray | None = None  # (2,) each pump's bypass, all its sections; None: their series
    stick_regeneration: float = 0.0  # stick rod -> head through the regeneration check
    stick_unloading: float = 0.0  # stick rod -> tank through the unloading valve (when the head pressure opens it)
    boom_regeneration: float = 0.0  # boom head -> rod through the regeneration check (boom lower)


def _unit(z: np.ndarray) -> np.ndarray:
    return np.minimum(np.maximum(z, 0.0), 1.0)


def _area_max(layout: ValveLayout) -> dict[str, np.ndarray]:
    return {k: np.array([s.areas.get(k, 0.0) for s in layout.sections]) for k in (*PASSAGES, "bypass")}


_AREA_MAX = {name: _area_max(layout) for name, layout in VALVE_LAYOUTS.items()}
_BOOM, _STICK, _SWING = FUNCTIONS.index("boom"), FUNCTIONS.index("stick"), FUNCTIONS.index("swing")


def section_spools(layout: ValveLayout, spools_m: np.ndarray) -> np.ndarray:
    """Each section's spool position (m): its function's, where the section has a passage on that side (a boom 2
    section is piloted for boom raise only, and stays at neutral, its centre bypass open, while the boom lowers)."""
    u = np.asarray(spools_m, dtype=float)[[FUNCTIONS.index(s.function) for s in layout.sections]]
    raise_only = np.array([not ({"pb", "at"} & set(s.areas)) for s in layout.sections])
    lower_only = np.array([not ({"pa", "bt"} & set(s.areas)) for s in layout.sections])
    return np.where((raise_only & (u < 0.0)) | (lower_only & (u > 0.0)), 0.0, u)


def metering_fraction(spools_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How far each spool's positive and negative metering notches are open, 0 -> 1 (``METERING_EXPONENT`` law)."""
    span = p.SPOOL_STROKE - p.SPOOL_DEAD_BAND
    up = _unit((spools_m - p.SPOOL_DEAD_BAND) / span) ** p.METERING_EXPONENT
    return up, _unit((-spools_m - p.SPOOL_DEAD_BAND) / span) ** p.METERING_EXPONENT


def priority_shares(layout: ValveLayout, spools_m: np.ndarray) -> tuple[list[int], float, float]:
    """The layout's priority valves at these spools (``FUNCTIONS`` order): the stick 2 sections' indices, the share
    of stick 1's meter-in the swing priority leaves, and of stick 2's the boom-raise priority leaves (1: none)."""
    up, down = metering_fraction(np.asarray(spools_m, dtype=float))
    swing = 1.0 - (1.0 - p.SWING_PRIORITY_STICK_SHARE) * max(up[_SWING], down[_SWING]) if layout.swing_priority else 1.0
    boom = 1.0 - (1.0 - p.BOOM_PRIORITY_STICK_SHARE) * up[_BOOM] if layout.boom_priority else 1.0
    stick2 = [i for i, s in enumerate(layout.sections) if s.function == "stick" and i >= len(FUNCTIONS)]
    return stick2, float(swing), float(boom)


def spool_areas(spools_m: np.ndarray, layout: ValveLayout = DEFAULT_LAYOUT) -> SpoolAreas:
    """Open-centre section areas: dead band, progressive metering, bypass closed at full stroke."""
    u = np.asarray(spools_m, dtype=float)
    if len(layout.sections) != len(FUNCTIONS):
        u = section_spools(layout, u)
    up, down = metering_fraction(u)
    stroke = np.abs(u) - p.BYPASS_CLOSE_START
    land = 1.0 - _unit(stroke / (p.BYPASS_LAND_CLOSED - p.BYPASS_CLOSE_START))
    notch = 1.0 - _unit(stroke / (p.BYPASS_CLOSED - p.BYPASS_CLOSE_START))
    a = _AREA_MAX[layout.name] if VALVE_LAYOUTS.get(layout.name) is layout else _area_max(layout)
    areas = SpoolAreas(
        pa=a["pa"] * up,
        pb=a["pb"] * down,
        at=a["at"] * down,
        bt=a["bt"] * up,
        bypass=(a["bypass"] - p.BYPASS_NOTCH_AREA) * land + p.BYPASS_NOTCH_AREA * notch,
    )
    stick2, swing_share, boom_share = priority_shares(layout, u[: len(FUNCTIONS)])
    areas.pa[_STICK] *= swing_share
    areas.pb[_STICK] *= swing_share
    areas.pa[stick2] *= boom_share
    areas.pb[stick2] *= boom_share
    extra = {}
    if layout.stick_regeneration:  # stick in: the return restricted, the rod's oil offered to the head
        stick_in = up[_STICK]
        areas.bt[_STICK] *= 1.0 - (1.0 - p.STICK_REGEN_RETURN_SHARE) * stick_in
        extra |= {
            "stick_regeneration": p.STICK_REGEN_AREA * stick_in,
            "stick_unloading": p.STICK_UNLOADING_AREA * stick_in,
        }
    if layout.boom_regeneration:  # boom lower: the head's oil offered to the rod
        extra["boom_regeneration"] = p.BOOM_REGEN_AREA * down[_BOOM]
    return dataclasses.replace(areas, **extra) if extra else areas


def relief_area(setting: float, rated_flow: float) -> float:
    """Full-open area of a relief that passes ``rated_flow`` at setting + RELIEF_OVERRIDE."""
    return rated_flow / (p.DISCHARGE_COEFFICIENT * _SQRT_2_RHO * np.sqrt(setting + p.RELIEF_OVERRIDE))


def validate_spools(spools_m: np.ndarray) -> np.ndarray:
    """Return the spools as a float array, or raise ValueError naming the bad one."""
    u = np.asarray(spools_m, dtype=float)
    if u.shape != (len(FUNCTIONS),):
        raise ValueError(f"spools must have shape (4,) in the order {FUNCTIONS}, got shape {u.shape}")
    values, limit = u.tolist(), p.SPOOL_STROKE * (1.0 + 1e-9)
    # the fast path, in plain floats (called every control period): a NaN or inf makes the sum one
    if math.isfinite(sum(values)) and -limit <= min(values) and max(values) <= limit:
        return u
    for name, value in zip(FUNCTIONS, u, strict=True):
        if not np.isfinite(value):
            raise ValueError(f"spool {name!r} is {value} (not a finite number)")
        if abs(value) > p.SPOOL_STROKE * (1.0 + 1e-9):
            raise ValueError(
                f"spool {name!r} = {value * 1e3:.3f} mm is beyond the stroke ±{p.SPOOL_STROKE * 1e3:.0f} mm"
            )
    return u


def _validate_mechanics(ext: np.ndarray, vel: np.ndarray, swing_rate: float) -> tuple[np.ndarray, np.ndarray]:
    x, v = np.asarray(ext, dtype=float), np.asarray(vel, dtype=float)
    if x.shape == v.shape == (3,) and np.isfinite(x.sum() + v.sum() + swing_rate):
        return x, v
    for label, arr in (("cylinder extensions", x), ("cylinder velocities", v)):
        if arr.shape != (3,):
            raise ValueError(f"{label} must have shape (3,) in the order {CYLINDER_NAMES}, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            bad = CYLINDER_NAMES[int(np.argmin(np.isfinite(arr)))]
            raise ValueError(f"{label}: {bad!r} is not a finite number")
    if not np.isfinite(swing_rate):
        raise ValueError(f"swing rate is {swing_rate} (not a finite number)")
    return x, v


# --------------------------------------------------------------------------------------------
# Fuel.
def fuel_rate(brake_power_w: float) -> float:
    """Fuel rate (L/h) at rated speed from the BSFC map (g/kWh vs load fraction)."""
    return float(fuel_rates(np.asarray([brake_power_w], float))[0])


def fuel_rates(brake_power_w: np.ndarray) -> np.ndarray:
    """:func:`fuel_rate` of an array of brake powers (W), elementwise."""
    power = np.maximum(np.asarray(brake_power_w, float), 0.0)
    load = power / p.ENGINE_POWER
    first = p.BSFC_LOAD_FRACTION[0]
    mapped = np.interp(load, p.BSFC_LOAD_FRACTION, p.BSFC_MAP) * power / 3.6e9 * 3600.0
    at_first = p.BSFC_MAP[0] * first * p.ENGINE_POWER / 1e6  # below the map: linear from the no-load fuel rate
    willans = p.ENGINE_NO_LOAD_FUEL + (at_first - p.ENGINE_NO_LOAD_FUEL) * load / first  # (Willans line)
    return np.where(load >= first, mapped, willans) / p.DIESEL_DENSITY


def regulated_flows(
    p_pumps: np.ndarray, displacement: np.ndarray, max_flow: float | None = None, power_limit: float | None = None
) -> np.ndarray:
    """The pumps' flows (m^3/s; (..., 2)) by the cross-sensing horsepower regulator at pump pressures (..., 2) and
    displacements (..., 2): ``Q_i = Q_max min(d_i, P_lim / (Q_max (p1 + p2)))``; ``Q_max`` and ``P_lim`` default to
    ``PUMP_MAX_FLOW`` and ``PUMP_POWER_LIMIT``."""
    q_max = p.PUMP_MAX_FLOW if max_flow is None else max_flow
    p_lim = p.PUMP_POWER_LIMIT if power_limit is None else power_limit
    total = np.add.reduce(p_pumps, axis=-1, keepdims=True)
    horsepower = np.divide(p_lim, total, out=np.full(total.shape, np.inf), where=total > 0.0)
    return np.minimum(q_max * np.minimum(np.maximum(displacement, 0.0), 1.0), horsepower)


def engine_fuel_rates(states: np.ndarray) -> np.ndarray:
    """The engine's fuel rate (L/h) at circuit states (..., STATE_SIZE), as :meth:`HydraulicCircuit.pump_power` and
    :func:`fuel_rate` give it one state at a time: the pumps' pressures times their flows by the regulator's law."""
    states = np.asarray(states, float)
    pressures = states[..., 0:2]
    flows = regulated_flows(pressures, states[..., N_NODES:])
    return fuel_rates(engine_brake_power((pressures * flows).sum(axis=-1)))


def engine_brake_power(hydraulic_w: np.ndarray | float) -> np.ndarray:
    """The engine's brake power (W) for the pumps' hydraulic power (W): through their overall efficiency, and the
    accessories."""
    return p.ACCESSORY_POWER + np.maximum(hydraulic_w, 0.0) / p.PUMP_OVERALL_EFFICIENCY


# --------------------------------------------------------------------------------------------
@dataclass
class _Branches:
    """The branch table: from/to node, constant area, valve opening law, laminar coefficient."""

    names: list[str]
    frm: np.ndarray
    to: np.ndarray
    area: np.ndarray
    valve: np.ndarray  # indices of pressure-operated branches
    crack: np.ndarray  # per valve branch
    inv_span: np.ndarray
    laminar: np.ndarray
    pilot: np.ndarray  # per valve branch: the node whose pressure opens it, or -1 for its own pressure drop


def _build_branches(layout: ValveLayout) -> tuple[_Branches, dict[str, np.ndarray]]:
    """The branches and, per passage (``PASSAGES``, ``bypass`` and the layout's ``REGENERATION_PASSAGES``), the
    branches the valve's areas go to; ``"<passage>_section"`` names the section each comes from."""
    rows: list[tuple[str, int, int, float, float | None, float, float, int]] = []

    def add(name: str, frm: int, to: int, area: float = 0.0, crack=None, span=1.0, lam=0.0, pilot=-1) -> None:
        rows.append((name, frm, to, area, crack, span, lam, pilot))

    groups: dict[str, list[int]] = {k: [] for k in (*PASSAGES, "bypass")}
    sections: dict[str, list[int]] = {k: [] for k in PASSAGES}
    for pump in range(2):
        groups["bypass"].append(len(rows))
        add(f"bypass{pump + 1}", pump, 2 + pump)
        add(f"nfc_orifice{pump + 1}", 2 + pump, TANK, p.NFC_ORIFICE_AREA)
        add(f"nfc_relief{pump + 1}", 2 + pump, TANK, relief_area(p.NFC_RELIEF, p.PUMP_MAX_FLOW), p.NFC_RELIEF)
        main = relief_area(p.MAIN_RELIEF, p.MAIN_RELIEF_RATED_FLOW)
        add(f"main_relief{pump + 1}", pump, TANK, main, p.MAIN_RELIEF, p.RELIEF_OVERRIDE)
    for i, section in enumerate(layout.sections):
        a, b = _PORTS[section.function]
        ends = {"pa": (section.pump, a), "pb": (section.pump, b), "at": (a, TANK), "bt": (b, TANK)}
        for key in section.passages:
            groups[key].append(len(rows))
            sections[key].append(i)
            crack = p.LOAD_CHECK_CRACKING if key in ("pa", "pb") else None
            add(f"{section.name}_{key}", *ends[key], 0.0, crack, p.LOAD_CHECK_SPAN)
        if i < len(FUNCTIONS):  # a function's ports, once
            for port, node in (("a", a), ("b", b)):
                add(f"{section.function}_makeup_{port}", TANK, node, p.MAKEUP_AREA, p.MAKEUP_CRACKING, p.MAKEUP_SPAN)
            _add_port_reliefs(add, section.function, a, b)
    if layout.stick_regeneration:
        head, rod = _PORTS["stick"]
        groups["stick_regeneration"] = [len(rows)]
        add("stick_regeneration", rod, head, 0.0, p.LOAD_CHECK_CRACKING, p.LOAD_CHECK_SPAN)
        groups["stick_unloading"] = [len(rows)]
        add("stick_unloading", rod, TANK, 0.0, p.STICK_UNLOADING_PRESSURE, p.STICK_UNLOADING_SPAN, pilot=head)
    if layout.boom_regeneration:
        head, rod = _PORTS["boom"]
        groups["boom_regeneration"] = [len(rows)]
        add("boom_regeneration", head, rod, 0.0, p.LOAD_CHECK_CRACKING, p.LOAD_CHECK_SPAN)
    out = {k: np.array(v, dtype=int) for k, v in groups.items()}
    return _table(rows), out | {f"{k}_section": np.array(v, dtype=int) for k, v in sections.items()}


def _add_port_reliefs(add, f: str, a: int, b: int) -> None:
    """Port reliefs + piston leak on a cylinder; crossover reliefs + leaks on the swing motor."""
    if f == "swing":
        area = relief_area(p.SWING_RELIEF, p.LINE_RELIEF_RATED_FLOW)
        add("swing_crossover_ab", a, b, area, p.SWING_RELIEF, p.RELIEF_OVERRIDE)
        add("swing_crossover_ba", b, a, area, p.SWING_RELIEF, p.RELIEF_OVERRIDE)
        share = p.SWING_MOTOR_EXTERNAL_LEAK_SHARE
        add("swing_internal_leak", a, b, lam=(1.0 - share) * p.SWING_MOTOR_LEAKAGE)
        add("swing_drain_a", a, TANK, lam=0.5 * share * p.SWING_MOTOR_LEAKAGE)
        add("swing_drain_b", b, TANK, lam=0.5 * share * p.SWING_MOTOR_LEAKAGE)
        return
    setting = p.LINE_RELIEF[f]
    area = relief_area(setting, p.LINE_RELIEF_RATED_FLOW)
    add(f"{f}_line_relief_a", a, TANK, area, setting, p.RELIEF_OVERRIDE)
    add(f"{f}_line_relief_b", b, TANK, area, setting, p.RELIEF_OVERRIDE)
    add(f"{f}_piston_leak", a, b, lam=p.CYLINDERS[f].count * p.CYLINDER_LEAKAGE)


def _table(rows: list) -> _Branches:
    valve = [i for i, r in enumerate(rows) if r[4] is not None]
    return _Branches(
        names=[r[0] for r in rows],
        frm=np.array([r[1] for r in rows]),
        to=np.array([r[2] for r in rows]),
        area=np.array([r[3] for r in rows], dtype=float),
        valve=np.array(valve),
        crack=np.array([rows[i][4] for i in valve], dtype=float),
        inv_span=np.array([1.0 / rows[i][5] for i in valve]),
        laminar=np.array([r[6] for r in rows], dtype=float),
        pilot=np.array([rows[i][7] for i in valve], dtype=int),
    )


# --------------------------------------------------------------------------------------------
class HydraulicCircuit:
    """The open-centre circuit of the machine: state, derivatives, Jacobian, forces, outputs.

    State vector (``STATE_SIZE`` = 14, names ``STATE_NAMES``): the 12 node pressures (Pa gauge,
    ``NODES``) then the two pumps' NFC displacement fractions (of the maximum). The object holds
    only constants (and a cache, and ``split_count``, the number of steps split so far, for
    diagnosis), so one instance can serve any number of simulations.
    """

    MAX_SPLITS = 6  # a step is cut to 1/64 at most

    def __init__(
        self, valve: Callable[[np.ndarray], SpoolAreas] | None = None, layout: ValveLayout = DEFAULT_LAYOUT
    ) -> None:
        check_circuit_parameters()
        self.layout = layout
        # spools (m) -> passage areas: the data sheet's law, or a learned one
        self.valve = functools.partial(spool_areas, layout=layout) if valve is None else valve
        self.split_count = 0
        self.branches, self._groups = _build_branches(layout)
        br = self.branches
        self.branch_index = {n: i for i, n in enumerate(br.names)}
        inc = np.zeros((N_NODES + 1, len(br.names)))
        inc[br.to, np.arange(len(br.names))] += 1.0
        inc[br.frm, np.arange(len(br.names))] -= 1.0
        self._inc = inc[:N_NODES]  # the tank row is dropped: its pressure is fixed
        self._into_tank = inc[TANK]
        self._external_leak = np.array([n.startswith("swing_drain") for n in br.names], dtype=float)
        cyl = [p.CYLINDERS[n] for n in CYLINDER_NAMES]
        self.head_area = np.array([c.head_area for c in cyl])
        self.rod_area = np.array([c.rod_area for c in cyl])
        self.stroke = np.array([c.stroke for c in cyl])
        self._count = np.array([c.count for c in cyl], dtype=float)
        self._port_volume = np.array([p.CYLINDER_PORT_VOLUME[n] for n in CYLINDER_NAMES])
        self._head_nodes = np.array([_PORTS[n][0] for n in CYLINDER_NAMES])
        self._rod_nodes = np.array([_PORTS[n][1] for n in CYLINDER_NAMES])
        self._pump_sections = [np.array([i for i, s in enumerate(layout.sections) if s.pump == k]) for k in (0, 1)]
        self._cushioned = np.array([FUNCTIONS.index(n) for n in CYLINDER_NAMES])
        br = self.branches
        self._piloted = br.valve[br.pilot >= 0]  # branches opened by another node's pressure
        self._pilot_node = br.pilot[br.pilot >= 0]
        self._spool_key: bytes | None = None
        self._spool_areas = self.valve(np.zeros(len(FUNCTIONS)))
        self._eye = np.eye(STATE_SIZE)
        # d(volume rate)/d(v_boom, v_stick, v_bucket, swing rate) of every node
        self._displacement = np.zeros((N_NODES, 4))
        self._displacement[self._head_nodes, np.arange(3)] = self.head_area
        self._displacement[self._rod_nodes, np.arange(3)] = -self.rod_area
        swept = SWING_DISPLACEMENT_RAD * p.SWING_REDUCTION
        self._displacement[10, 3], self._displacement[11, 3] = swept, -swept

    # ---- initial state ---------------------------------------------------------------------
    def initial_state(
        self, holding_forces_n: np.ndarray | None = None, rest_pressure: float = REST_PRESSURE
    ) -> np.ndarray:
        """Idle pumps, neutral valve, and chamber pressures that hold ``holding_forces_n``.

        ``holding_forces_n`` (N, per cylinder) is the force the cylinder must push (positive) or
        pull (negative) to hold its load; the other chamber sits at ``rest_pressure``.
        """
        y = np.zeros(STATE_SIZE)
        y[0:4] = p.NFC_PRESSURE_IDLE
        y[N_NODES:] = p.PUMP_IDLE_FLOW_FRACTION
        f = np.zeros(3) if holding_forces_n is None else np.asarray(holding_forces_n, dtype=float)
        push = f >= 0.0
        y[self._head_nodes] = np.where(push, (f + rest_pressure * self.rod_area) / self.head_area, rest_pressure)
        y[self._rod_nodes] = np.where(push, rest_pressure, (-f + rest_pressure * self.head_area) / self.rod_area)
        y[10:12] = rest_pressure
        return y

    # ---- the layout, read-only (for the native kernel's numbers, hexgym.model.circuit_kernel) ----
    @property
    def branch_groups(self) -> dict[str, np.ndarray]:
        """Branch indices of the valve's passages: ``pa``, ``pb``, ``at``, ``bt`` in section order (the sections
        that have the passage, ``"<passage>_section"``), ``bypass`` one per pump, and the layout's regeneration
        passages (``REGENERATION_PASSAGES``) (copies)."""
        return {k: v.copy() for k, v in self._groups.items()}

    @property
    def head_nodes(self) -> np.ndarray:
        """Node index of each cylinder's head chamber, ``CYLINDER_NAMES`` order (a copy)."""
        return self._head_nodes.copy()

    @property
    def rod_nodes(self) -> np.ndarray:
        """Node index of each cylinder's rod chamber, ``CYLINDER_NAMES`` order (a copy)."""
        return self._rod_nodes.copy()

    @property
    def cylinder_count(self) -> np.ndarray:
        """Cylinders per function (the boom has two), ``CYLINDER_NAMES`` order (a copy)."""
        return self._count.copy()

    @property
    def port_volumes(self) -> np.ndarray:
        """Each cylinder's oil volume (m^3) in its lines and ports, per chamber (a copy)."""
        return self._port_volume.copy()

    @property
    def displacement(self) -> np.ndarray:
        """d(node volume rate)/d(boom, stick, bucket velocity, swing rate), (N_NODES, 4) (a copy)."""
        return self._displacement.copy()

    # ---- pieces ---------------------------------------------------------------------------
    def volumes(self, ext: np.ndarray) -> np.ndarray:
        """Oil volume (m^3) of every node at cylinder extensions ``ext``."""
        x = np.minimum(np.maximum(ext, 0.0), self.stroke)
        vol = np.empty(N_NODES)
        vol[0:2] = p.PUMP_LINE_VOLUME
        vol[2:4] = p.BYPASS_VOLUME
        vol[self._head_nodes] = self._port_volume + self.head_area * x
        vol[self._rod_nodes] = self._port_volume + self.rod_area * (self.stroke - x)
        vol[10:12] = p.SWING_PORT_VOLUME
        return vol

    def _volume_rates(self, vel: np.ndarray, swing_rate: float) -> np.ndarray:
        # the swing motor swallows port a's oil turning positive
        return self._displacement[:, :3] @ vel + self._displacement[:, 3] * swing_rate

    def _cushion(self, distance: np.ndarray) -> np.ndarray:
        """Outlet area left by the cushion spear ``distance`` (m) before the end of stroke."""
        s, _ = smoothstep(distance / p.CUSHION_LENGTH)
        return self._count * (p.CUSHION_AREA + (p.CUSHION_PORT_AREA - p.CUSHION_AREA) * s)

    def branch_areas(self, spools: np.ndarray, ext: np.ndarray) -> np.ndarray:
        """Geometric area (m^2) of every branch for these spools and cylinder extensions."""
        key = spools.tobytes()
        if key != self._spool_key:  # spools are held for many steps: reuse their areas
            self._spool_key, self._spool_areas = key, self.valve(spools)
        sa = self._spool_areas
        area = self.branches.area.copy()
        g = self._groups
        area[g["pa"]], area[g["pb"]] = sa.pa[g["pa_section"]], sa.pb[g["pb_section"]]
        at, bt = sa.at.copy(), sa.bt.copy()
        c = self._cushioned  # a->T leaves the head end (retracting), b->T the rod end (extending)
        head_cushion, rod_cushion = self._cushion(np.asarray(ext)), self._cushion(self.stroke - np.asarray(ext))
        at[c] = series_area(at[c], head_cushion)
        bt[c] = series_area(bt[c], rod_cushion)
        area[g["at"]], area[g["bt"]] = at[g["at_section"]], bt[g["bt_section"]]
        for k, sections in enumerate(self._pump_sections):  # the pump's spools in series
            series = functools.reduce(series_area, sa.bypass[sections])
            area[g["bypass"][k]] = series if sa.pump_bypass is None else sa.pump_bypass[k]
        for passage, r in REGENERATION.items():  # out of the cylinder's port, through its cushion like the valve's
            if passage in g:
                cushion = (rod_cushion if r.leaves_rod else head_cushion)[CYLINDER_NAMES.index(r.cylinder)]
                area[g[passage]] = series_area(getattr(sa, passage), cushion)
        return area

    def branch_flows(self, pressures: np.ndarray, area: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flow (m^3/s, from -> to) of every branch and its conductance dq/d(dp)."""
        br = self.branches
        pe = np.zeros(N_NODES + 1)  # the tank, last, stays at 0 Pa
        pe[:N_NODES] = pressures
        dp = pe[br.frm] - pe[br.to]
        r, dr = orifice_law(dp)
        opening, dopening = np.ones_like(dp), np.zeros_like(dp)
        drop = dp[br.valve] if len(self._piloted) == 0 else np.where(br.pilot >= 0, pe[br.pilot], dp[br.valve])
        opening[br.valve], ds = smoothstep((drop - br.crack) * br.inv_span)
        dopening[br.valve] = ds * br.inv_span
        dopening[self._piloted] = 0.0  # a piloted valve's opening moves with its pilot (pilot_conductance)
        cda = p.DISCHARGE_COEFFICIENT * area
        q = cda * opening * r + br.laminar * dp
        g = cda * (dopening * r + opening * dr) + br.laminar
        return q, g

    def pilot_conductance(self, pressures: np.ndarray, area: np.ndarray) -> np.ndarray:
        """d(flow)/d(pilot pressure) of each piloted branch (``branches.pilot``), m^3/(s Pa)."""
        br, b = self.branches, self._piloted
        dp = pressures[br.frm[b]] - np.where(br.to[b] == TANK, 0.0, pressures[np.minimum(br.to[b], N_NODES - 1)])
        inv_span = br.inv_span[br.pilot >= 0]
        _, ds = smoothstep((pressures[self._pilot_node] - br.crack[br.pilot >= 0]) * inv_span)
        return p.DISCHARGE_COEFFICIENT * area[b] * orifice_law(dp)[0] * ds * inv_span

    @staticmethod
    def nfc_target(
        p_bypass: np.ndarray, full_flow_pa: float | None = None, min_flow_pa: float | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """NFC displacement fraction for the bypass (NFC signal) pressure, and its derivative; the regulator's
        corner pressures default to ``NFC_PRESSURE_FULL_FLOW`` and ``NFC_PRESSURE_MIN_FLOW``."""
        full = p.NFC_PRESSURE_FULL_FLOW if full_flow_pa is None else full_flow_pa
        width = (p.NFC_PRESSURE_MIN_FLOW if min_flow_pa is None else min_flow_pa) - full
        s, ds = smoothstep((p_bypass - full) / width)
        drop = 1.0 - p.PUMP_IDLE_FLOW_FRACTION
        return 1.0 - drop * s, -drop * ds / width

    @staticmethod
    def pump_flows(
        p_pumps: np.ndarray, displacement: np.ndarray, max_flow: float | None = None, power_limit: float | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pump flows (m^3/s), dQ/d(displacement) (2,) and dQ/d(p1, p2) (2, 2).

        Cross-sensing horsepower control: ``Q_i = Q_max min(d_i, P_lim / (Q_max (p1 + p2)))``; ``Q_max`` and
        ``P_lim`` default to ``PUMP_MAX_FLOW`` and ``PUMP_POWER_LIMIT``.
        """
        q_max = p.PUMP_MAX_FLOW if max_flow is None else max_flow
        p_lim = p.PUMP_POWER_LIMIT if power_limit is None else power_limit
        # the regulator's law as regulated_flows states it, written out for two pumps: this runs in every circuit
        # step of the Python models (2-3x faster than the general form; tests hold the two equal)
        d = np.minimum(np.maximum(displacement, 0.0), 1.0)
        total = p_pumps[0] + p_pumps[1]
        q_hp = p_lim / total if total > 0.0 else np.inf
        nfc = q_max * d
        limited = nfc > q_hp
        q = np.where(limited, q_hp, nfc)
        dq_dd = np.where(limited, 0.0, q_max)
        dq_dp = np.zeros((2, 2))
        dq_dp[limited, :] = -p_lim / total**2 if total > 0.0 else 0.0
        return q, dq_dd, dq_dp

    # ---- the ODE ----------------------------------------------------------------------------
    def _evaluate(self, y, spools, ext, vel, swing_rate, want_jacobian: bool):
        if y.shape != (STATE_SIZE,) or not np.isfinite(y.sum()):
            raise ValueError(f"hydraulic state must be {STATE_SIZE} finite numbers ({STATE_NAMES})")
        pr, d = y[:N_NODES], y[N_NODES:]
        area = self.branch_areas(spools, ext)
        q, g = self.branch_flows(pr, area)
        net = self._inc @ q
        q_pump, dq_dd, dq_dp = self.pump_flows(pr[0:2], d)
        net[0:2] += q_pump
        c, dc = compliance(pr)
        cap = self.volumes(ext) * c  # V / beta
        pdot = (net - self._volume_rates(vel, swing_rate)) / cap
        target, dtarget = self.nfc_target(pr[2:4])
        tau = p.PUMP_REGULATOR_TIME_CONSTANT
        f = np.concatenate([pdot, (target - d) / tau])
        if not want_jacobian:
            return f, None, cap
        jac = np.zeros((STATE_SIZE, STATE_SIZE))
        dnet = -(self._inc * g) @ self._inc.T
        if len(self._piloted):
            dnet[:, self._pilot_node] += self._inc[:, self._piloted] * self.pilot_conductance(pr, area)
        dnet[0:2, 0:2] += dq_dp
        jac[:N_NODES, :N_NODES] = dnet / cap[:, None]
        jac[np.arange(N_NODES), np.arange(N_NODES)] -= pdot * dc / c
        jac[[0, 1], [N_NODES, N_NODES + 1]] = dq_dd / cap[0:2]
        jac[[N_NODES, N_NODES + 1], [2, 3]] = dtarget / tau
        jac[[N_NODES, N_NODES + 1], [N_NODES, N_NODES + 1]] = -1.0 / tau
        return f, jac, cap

    def derivatives(
        self,
        state: np.ndarray,
        spools_m: np.ndarray,
        ext_m: np.ndarray,
        vel_mps: np.ndarray,
        swing_rate: float,
    ) -> np.ndarray:
        """d(state)/dt for spools (m), cylinder extensions (m) and velocities (m/s), swing rate (rad/s)."""
        x, v = _validate_mechanics(ext_m, vel_mps, swing_rate)
        y = np.asarray(state, float)
        return self._evaluate(y, validate_spools(spools_m), x, v, swing_rate, False)[0]

    def jacobian(
        self,
        state: np.ndarray,
        spools_m: np.ndarray,
        ext_m: np.ndarray,
        vel_mps: np.ndarray,
        swing_rate: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(d(state)/dt, its Jacobian with respect to the state), analytic."""
        x, v = _validate_mechanics(ext_m, vel_mps, swing_rate)
        return self._evaluate(np.asarray(state, float), validate_spools(spools_m), x, v, swing_rate, True)[:2]

    def step(
        self,
        state: np.ndarray,
        dt: float,
        spools_m: np.ndarray,
        ext_m: np.ndarray,
        vel_mps: np.ndarray,
        swing_rate: float,
    ) -> np.ndarray:
        """Advance the state by ``dt`` (s), mechanics frozen: linearly implicit Euler steps.

        A step whose pressure change the linearisation cannot be trusted with (see
        :meth:`_trusted`) is split in halves, recursively, up to ``MAX_SPLITS`` times.
        """
        return self.step_with_sensitivity(state, dt, spools_m, ext_m, vel_mps, swing_rate)[0]

    def step_with_sensitivity(
        self,
        state: np.ndarray,
        dt: float,
        spools_m: np.ndarray,
        ext_m: np.ndarray,
        vel_mps: np.ndarray,
        swing_rate: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`step`, and d(new state)/d(boom, stick, bucket velocity, swing rate), (14, 4).

        The sensitivity lets a caller treat the coupling implicitly: the pressures at the end
        of the step move with the velocities the mechanics reach over it (see
        :meth:`coupling_derivatives`), and ``new_state + S @ dv`` corrects them afterwards.
        """
        x, v = _validate_mechanics(ext_m, vel_mps, swing_rate)
        u = validate_spools(spools_m)
        return self._advance(np.asarray(state, float), dt, u, x, v, swing_rate, np.zeros((STATE_SIZE, 4)), 0)

    def _advance(self, y, dt, u, x, v, w, sens, depth: int) -> tuple[np.ndarray, np.ndarray]:
        # Linearly implicit Euler, y1 = y + L^-1 dt f with L = I - dt J; the velocity
        # sensitivity follows the same solve: S1 = L^-1 (S + dt df/dv).
        f, jac, cap = self._evaluate(y, u, x, v, w, True)
        rhs = np.empty((STATE_SIZE, 5))
        rhs[:, 0] = dt * f
        rhs[:, 1:] = sens
        rhs[:N_NODES, 1:] -= dt * self._displacement / cap[:, None]
        sol = np.linalg.solve(self._eye - dt * jac, rhs)
        y1 = y + sol[:, 0]
        if depth < self.MAX_SPLITS and not self._trusted(y[:N_NODES], y1[:N_NODES]):
            self.split_count += 1
            half, sens_half = self._advance(y, 0.5 * dt, u, x, v, w, sens, depth + 1)
            return self._advance(half, 0.5 * dt, u, x, v, w, sens_half, depth + 1)
        sens1 = sol[:, 1:]
        vacuum = y1[:N_NODES] < _VACUUM  # a last guard: oil cannot pull a vacuum
        y1[:N_NODES][vacuum] = _VACUUM
        sens1[:N_NODES][vacuum] = 0.0
        return y1, sens1

    def coupling_derivatives(
        self, sensitivity: np.ndarray, vel_mps: np.ndarray, swing_rate: float
    ) -> tuple[np.ndarray, float]:
        """d(force_i)/d(v_i) (N s/m, per cylinder) and d(swing torque)/d(swing rate) (N m s/rad).

        Along a step from :meth:`step_with_sensitivity`: the change of the pressures at its
        end plus the friction's slope. Negative: the circuit damps (the hydraulic spring, seen
        over one step, acts as damping ``k dt``). Only each actuator's own velocity is kept:
        what an actuator with an affine velocity bias in MuJoCo's implicit integrator can use.
        """
        i = np.arange(3)
        dpressure = self.head_area * sensitivity[self._head_nodes, i]
        dpressure -= self.rod_area * sensitivity[self._rod_nodes, i]
        v = np.asarray(vel_mps, dtype=float)
        sech2 = 1.0 - np.tanh(v / p.CYLINDER_FRICTION_VELOCITY) ** 2  # d tanh / dx; no overflow at speed
        friction = p.CYLINDER_COULOMB_FRICTION / p.CYLINDER_FRICTION_VELOCITY * sech2 + p.CYLINDER_VISCOUS_FRICTION
        ratio = p.SWING_REDUCTION
        dtorque = ratio * SWING_DISPLACEMENT_RAD * (sensitivity[10, 3] - sensitivity[11, 3])
        dtorque -= ratio * ratio * p.SWING_MOTOR_VISCOUS_FRICTION
        return dpressure - self._count * friction, float(dtorque)

    @staticmethod
    def _trusted(p0: np.ndarray, p1: np.ndarray) -> bool:
        """Whether a step's pressure change is small enough for its linearisation.

        The tangent of an orifice's square-root law overshoots a pressure that falls towards
        the tank pressure (a node that loses its inflow lands at about -p0), and a large jump
        crosses relief and check thresholds: both call for smaller steps. The thresholds (a
        fall below half, a jump over 5 MPa) were tuned on a replay against 0.125 ms steps.
        """
        falls = (p1 < 0.5 * p0) & (p0 > TRUST_FLOOR_PA)
        return not (np.any(falls) or np.any(p1 < _VACUUM) or np.any(np.abs(p1 - p0) > TRUST_JUMP_PA))

    # ---- forces and outputs -----------------------------------------------------------------
    def actuator_forces(
        self,
        state: np.ndarray,
        ext_m: np.ndarray,
        vel_mps: np.ndarray,
        swing_rate: float,
        end_stops: bool = True,
    ) -> tuple[np.ndarray, float]:
        """Cylinder forces (N, positive extends; ``CYLINDER_NAMES`` order) and swing torque (N m).

        Force = p_head A_head - p_rod A_rod - seal friction (Coulomb, tanh-smoothed, + viscous)
        - end-stop contact force (if ``end_stops``; leave it to MuJoCo's joint limits otherwise).
        The swing torque on the swing axis is the motor's through the reduction, less the
        mechanical losses of motor and gear.
        """
        x, v = _validate_mechanics(ext_m, vel_mps, swing_rate)
        y = np.asarray(state, float)
        force = y[self._head_nodes] * self.head_area - y[self._rod_nodes] * self.rod_area
        friction = p.CYLINDER_COULOMB_FRICTION * np.tanh(v / p.CYLINDER_FRICTION_VELOCITY)
        force -= self._count * (friction + p.CYLINDER_VISCOUS_FRICTION * v)
        if end_stops:
            over, under = np.maximum(x - self.stroke, 0.0), np.maximum(-x, 0.0)
            contact = (over > 0.0) | (under > 0.0)
            force -= p.END_STOP_STIFFNESS * (over - under) + p.END_STOP_DAMPING * v * contact
        return force, self.swing_torque(y, swing_rate)

    @staticmethod
    def swing_torque(state: np.ndarray, swing_rate: float) -> float:
        """Torque (N m) on the swing axis from the motor port pressures."""
        omega = p.SWING_REDUCTION * swing_rate
        dp = state[10] - state[11]
        ideal = SWING_DISPLACEMENT_RAD * dp
        loss = (1.0 - p.SWING_MECHANICAL_EFFICIENCY) * abs(ideal) * np.tanh(omega / p.SWING_FRICTION_SPEED)
        return float(p.SWING_REDUCTION * (ideal - loss - p.SWING_MOTOR_VISCOUS_FRICTION * omega))

    def pump_power(self, state: np.ndarray) -> tuple[np.ndarray, float, float]:
        """The pumps' flows (m^3/s, 2), their hydraulic power and the engine's brake power (W) at a circuit state
        (pump pressures times flows; the engine drives the pumps through their overall efficiency and the
        accessories)."""
        q_pump, _, _ = self.pump_flows(state[0:2], state[N_NODES:])
        hyd = float(state[0] * q_pump[0] + state[1] * q_pump[1])
        return q_pump, hyd, float(engine_brake_power(hyd))

    def outputs(
        self,
        state: np.ndarray,
        spools_m: np.ndarray,
        ext_m: np.ndarray,
        vel_mps: np.ndarray,
        swing_rate: float,
    ) -> dict[str, float]:
        """Pressures (Pa) by node, pump flows, power (W), fuel (L/h) and the flows to tank (m^3/s)."""
        x, _ = _validate_mechanics(ext_m, vel_mps, swing_rate)
        y = np.asarray(state, float)
        q, _ = self.branch_flows(y[:N_NODES], self.branch_areas(validate_spools(spools_m), x))
        q_pump, hyd, brake = self.pump_power(y)
        out = {f"{n}_pressure_pa": float(y[i]) for i, n in enumerate(NODES)}
        leak = float(self._external_leak @ q)
        out |= {
            "pump1_flow_m3s": float(q_pump[0]),
            "pump2_flow_m3s": float(q_pump[1]),
            "pump1_displacement": float(y[N_NODES]),
            "pump2_displacement": float(y[N_NODES + 1]),
            "bypass1_flow_m3s": float(q[self.branch_index["bypass1"]]),
            "bypass2_flow_m3s": float(q[self.branch_index["bypass2"]]),
            "pump_power_w": hyd,
            "brake_power_w": float(brake),
            "fuel_rate_l_per_h": fuel_rate(brake),
            "tank_return_m3s": float(self._into_tank @ q) - leak,
            "external_leak_m3s": leak,
        }
        return out
