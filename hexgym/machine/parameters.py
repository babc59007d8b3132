"""Every physical number of the Cat 325-class machine, in one place, with its source.

Tags as in ``shared/reference/cat325-parameters.md``: [pub] published for the 325 family,
[cmp] a comparable 20-30 t machine, [est] an engineering estimate, [derived] computed here
from the others. SI units throughout (m, kg, s, N, Pa, m^3/s, rad).

Geometry is given in planar link frames ``(x, z)``: each link's frame has its origin at the
link's own hinge pin, ``x`` along the link (boom: foot pin -> stick pin chord; stick: stick pin
-> bucket pin; bucket: along the stick at bucket angle 0) and ``z`` perpendicular in the arm
plane. At all joint angles zero the boom chord is horizontal, the stick hangs at right angles
below the boom chord and the bucket is aligned with the stick.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# --------------------------------------------------------------------------------------------
# Physical constants
GRAVITY = 9.81  # m/s^2

# --------------------------------------------------------------------------------------------
# Upper structure and undercarriage (upper frame: origin on the swing axis at the top of the
# swing bearing, x forward, z up; y to the left, where the cab is).
SWING_BEARING_HEIGHT = 1.10  # m above ground [est] (carbody + bearing of a 25 t machine)
BOOM_FOOT = (0.25, 0.85)  # (x, z) in the upper frame: 0.25 m ahead, 1.95 m above ground [est]
BOOM_CYLINDER_BASE = (0.410, 0.015)  # (x, z) upper frame; 0.85 m from the foot pin [est]
TAIL_SWING_RADIUS = 3.10  # m [est]
TRACK_GAUGE = 2.60  # m, centre to centre [est]
TRACK_LENGTH = 4.90  # m overall [est]
TRACK_SHOE_WIDTH = 0.80  # m [est]
TRACK_HEIGHT = 0.95  # m [est]
CAB_SIZE = (1.80, 1.00)  # length, width, m [est]
CAB_ROOF_HEIGHT = 3.00  # m above ground [est]

# --------------------------------------------------------------------------------------------
# Front linkage, planar link frames (see module docstring).
BOOM_LENGTH = 6.15  # foot pin -> stick pin [est, 325B/C reach boom]
BOOM_KNEE = (2.85, 1.05)  # bend of the banana boom, boom frame; ~140 deg included angle [est]
BOOM_CYLINDER_ROD_PIN = (2.570, 0.400)  # boom frame; 2.60 m from the foot, under the boom [est]
STICK_CYLINDER_BASE = (3.264, 1.600)  # boom frame; 3.30 m behind the stick pin, on top [est]

STICK_LENGTH = 3.20  # stick pin -> bucket pin [est]
STICK_CYLINDER_ROD_PIN = (-0.795, 0.421)  # stick frame: the stick's tail, 0.90 m from the pin
BUCKET_CYLINDER_BASE = (0.35, 0.55)  # stick frame, on the stick's outer side [est]
GUIDE_LINK_PIVOT = (2.60, 0.175)  # stick frame, 0.62 m above the bucket pin [est]
GUIDE_LINK_LENGTH = 0.775  # pivot -> cylinder/link joint [est]
POWER_LINK_LENGTH = 0.75  # cylinder/link joint -> bucket link pin [est]
BUCKET_LINK_PIN = (0.125, 0.55)  # bucket frame: power link pin, 0.56 m from the pin [est]

BUCKET_TIP = (1.35, -0.80)  # bucket frame: teeth, 1.57 m from the pin [cmp: 20 t machine 1.56 m]
BUCKET_WIDTH = 1.50  # m [pub, paper]
BUCKET_HEAPED_CAPACITY = 1.30  # m^3 [est, 1.2-1.4]
# the bucket's profile: hexgym.machine.bucket builds it from these and the pins above [est]
BUCKET_PLATE = 0.03  # wrapper and side plates
BUCKET_PIN_STANDOFF = 0.20  # pin line (bucket pin -> link pin) to the inside of the top plate
BUCKET_LIP_AHEAD = 0.25  # top lip this far ahead of the bucket pin, along link pin -> pin
BUCKET_FLOOR_ANGLE = np.radians(55.0)  # between the floor at the cutting edge and the strike line
BUCKET_FLOOR_HANDLE = 0.7  # floor tangent length relative to the top plate's: shapes the heel
TOOTH_LENGTH = 0.28  # teeth beyond the cutting edge

# --------------------------------------------------------------------------------------------
# Masses (operating weight about 27 t) [est]
UNDERCARRIAGE_MASS = 9500.0
UPPER_MASS = 11500.0  # including the counterweight below
COUNTERWEIGHT_MASS = 5000.0
BOOM_MASS = 2100.0
STICK_MASS = 1200.0
BUCKET_MASS = 850.0  # shell, teeth; the linkage and bucket cylinder make up "bucket + linkage 1.1 t"
GUIDE_LINK_MASS = 90.0
POWER_LINK_MASS = 110.0
UPPER_YAW_INERTIA = 35000.0  # kg m^2 about the swing axis, front excluded [est, 30-40 t m^2]


@dataclass(frozen=True)
class Cylinder:
    """A double-acting hydraulic cylinder (or a parallel pair acting as one)."""

    name: str
    bore: float  # m
    rod: float  # m
    stroke: float  # m
    retracted_length: float  # pin to pin, fully retracted, m
    count: int = 1  # cylinders acting in parallel
    barrel_mass: float = 0.0  # kg, per cylinder
    rod_mass: float = 0.0  # kg, per cylinder (rod + piston)

    @property
    def head_area(self) -> float:
        """Piston (cap-end) area of all cylinders together, m^2."""
        return self.count * np.pi * self.bore**2 / 4.0

    @property
    def rod_area(self) -> float:
        """Annulus (rod-end) area of all cylinders together, m^2."""
        return self.count * np.pi * (self.bore**2 - self.rod**2) / 4.0

    @property
    def extended_length(self) -> float:
        """Pin to pin, fully extended, m."""
        return self.retracted_length + self.stroke


# Bore / rod / stroke [est] per the parameter file; retracted lengths [est] = stroke + dead
# length (gland, piston, end caps and clevises) of about 0.7-0.95 m.
BOOM_CYLINDER = Cylinder("boom", 0.130, 0.090, 1.30, 2.00, count=2, barrel_mass=260.0, rod_mass=120.0)
STICK_CYLINDER = Cylinder("stick", 0.150, 0.105, 1.60, 2.55, barrel_mass=360.0, rod_mass=170.0)
BUCKET_CYLINDER = Cylinder("bucket", 0.130, 0.090, 1.15, 1.85, barrel_mass=230.0, rod_mass=100.0)
CYLINDERS = {c.name: c for c in (BOOM_CYLINDER, STICK_CYLINDER, BUCKET_CYLINDER)}

# --------------------------------------------------------------------------------------------
# Engine, pumps, valves, oil
ENGINE_POWER = 125e3  # W net at 2000 rpm [pub, Cat 3116TA]
ENGINE_SPEED = 2000.0 / 60.0 * 2.0 * np.pi  # rad/s [pub]
PUMP_MAX_FLOW = 230.0 / 60000.0  # m^3/s per pump [cmp: 210-240 L/min]
PUMP_IDLE_FLOW_FRACTION = 0.15  # open-centre standby flow [pub, paper: 10-20 %]
MAIN_RELIEF = 34.3e6  # Pa [pub 325C]
LINE_RELIEF = {"boom": 37.2e6, "stick": 37.2e6, "bucket": 36.8e6}  # Pa [pub 325C]
SWING_RELIEF = 29.4e6  # Pa [pub 325C/D]
SPOOL_STROKE = 0.011  # m, +-11 mm [pub, paper]
DISCHARGE_COEFFICIENT = 0.67  # [textbook]
OIL_DENSITY = 870.0  # kg/m^3 [textbook]
OIL_BULK_MODULUS = 1.1e9  # Pa, effective with hoses [textbook 1.0-1.2 GPa]
SWING_MOTOR_DISPLACEMENT = 140e-6  # m^3/rev [est 130-150 cm^3]
SWING_REDUCTION = 150.0  # [est 150-170]; 150 so that one pump's flow gives the 11 rpm below
SWING_SPEED = 11.0 / 60.0 * 2.0 * np.pi  # rad/s at full spool [cmp 11.2-11.3 rpm]
SWING_TORQUE = 75e3  # N m [cmp 73-74 kN m]
BSFC = 215.0  # g/kWh near rated [est]
DIESEL_DENSITY = 0.85  # kg/L [est]

# --------------------------------------------------------------------------------------------
# Published acceptance figures the reference model is held to (hexgym reference-report): full-stroke cylinder
# times, empty bucket, engine at full speed, new machine [pub: Cat 323F testing and adjusting, cylinder speed; the
# service limits of a worn machine in PUBLISHED_SERVICE_LIMITS_S]; the swing's 180 deg from rest on level ground
# [pub: Cat 330D-340D] and its top speed [pub: Cat 325F L]; relief settings [pub: 325C / 325D L testing and
# adjusting]. The cylinders' "extend" moves: boom raise, stick in, bucket curl.
PUBLISHED_CYLINDER_TIMES_S = {
    "boom_raise": 3.1,
    "boom_lower": 1.8,
    "stick_extend": 3.2,
    "stick_retract": 2.5,
    "bucket_extend": 3.8,
    "bucket_retract": 2.0,
}
PUBLISHED_SERVICE_LIMITS_S = {
    "boom_raise": 4.7,
    "boom_lower": 2.7,
    "stick_extend": 4.8,
    "stick_retract": 3.8,
    "bucket_extend": 5.7,
    "bucket_retract": 3.0,
}
PUBLISHED_SWING_180_S = 4.9  # at most
PUBLISHED_SWING_RPM = 11.2
PUBLISHED_RELIEF_RANGES_PA = {
    "main": (34.3e6, 35.0e6),
    "boom": (37.0e6, 38.0e6),
    "stick": (37.0e6, 38.0e6),
    "bucket": (36.8e6, 37.0e6),
    "swing": (29.4e6, 29.4e6),
}
PUBLISHED_FIGURE_TOLERANCE = 0.2  # a model's time within +-20 % of the published one

# --------------------------------------------------------------------------------------------
# Material
MATERIAL_DENSITY = 1650.0  # kg/m^3, sand and gravel, dry, loose
# the lightest and heaviest material a site task takes (its material_density_scale), times MATERIAL_DENSITY:
# 825-2475 kg/m^3, from dry loose soil to wet gravel and blasted rock [textbook 1.2-2.5 t/m^3, loose]
MATERIAL_DENSITY_SCALE_RANGE = (0.5, 1.5)
PAYLOAD_EMPTY_HALF_FULL = (0.0, 1000.0, 2000.0)  # kg, the paper's load cases

# --------------------------------------------------------------------------------------------
# Hydraulic circuit (hexgym.hydraulics.circuit): the open-centre circuit of the analytical reference
# model. Pressures are gauge (tank = 0 Pa). Areas are flow areas of the valve passages, m^2.
# Valve functions in spool order (swing, boom, stick, bucket); port "a" is the cylinder head
# (cap) end or the swing motor's counter-clockwise port, port "b" the rod end / clockwise port.
ATMOSPHERIC_PRESSURE = 101325.0  # Pa [textbook]
OIL_AIR_FRACTION = 0.005  # entrained air by volume at atmospheric pressure [textbook 0.1-1 %]
AIR_POLYTROPIC_EXPONENT = 1.4  # [textbook]
ORIFICE_LAMINAR_PRESSURE = 0.05e6  # Pa: orifice law regularised to laminar below ~this drop [est]

# Pumps and their regulators. Pump 1: boom + bucket; pump 2: stick + swing [pub, paper].
PUMP_MAX_DISPLACEMENT = PUMP_MAX_FLOW / (ENGINE_SPEED / (2.0 * np.pi))  # m^3/rev, 1:1 drive [derived]
PUMP_OVERALL_EFFICIENCY = 0.88  # hydraulic power / shaft power [est, 0.85-0.9]
ACCESSORY_POWER = 8e3  # W: fan, alternator, pilot pump [est]
PUMP_POWER_LIMIT = (ENGINE_POWER - ACCESSORY_POWER) * PUMP_OVERALL_EFFICIENCY  # W, p1Q1+p2Q2 [derived]
PUMP_REGULATOR_TIME_CONSTANT = 0.08  # s, negative-flow-control servo [est, 50-150 ms]
NFC_PRESSURE_FULL_FLOW = 0.8e6  # Pa: NFC signal at or below this -> maximum displacement [est]
NFC_PRESSURE_MIN_FLOW = 2.5e6  # Pa: NFC signal at or above this -> idle displacement [est]
NFC_PRESSURE_IDLE = 3.0e6  # Pa: NFC signal with all spools neutral at idle flow [est]
NFC_ORIFICE_AREA = (  # m^2: idle flow through it builds NFC_PRESSURE_IDLE [derived]
    PUMP_IDLE_FLOW_FRACTION * PUMP_MAX_FLOW / (DISCHARGE_COEFFICIENT * np.sqrt(2.0 * NFC_PRESSURE_IDLE / OIL_DENSITY))
)
NFC_RELIEF = 4.0e6  # Pa: relief beside the NFC orifice (caps the signal when bypass flow is high) [est]

# Relief and check valves. A relief cracks at its setting and passes its rated flow at the
# setting plus its override ("relief gradient").
RELIEF_OVERRIDE = 1.5e6  # Pa, cracking -> rated flow [est, 1-2 MPa]
MAIN_RELIEF_RATED_FLOW = PUMP_MAX_FLOW  # m^3/s [derived]
LINE_RELIEF_RATED_FLOW = PUMP_MAX_FLOW  # m^3/s, port and swing crossover reliefs: a braking swing
# motor pumps full flow through its crossover relief [derived]
LOAD_CHECK_CRACKING = 0.1e6  # Pa [est, spring of a valve-body load check]
LOAD_CHECK_SPAN = 0.3e6  # Pa, cracking -> fully open [est]
MAKEUP_CRACKING = 0.01e6  # Pa, anti-cavitation check from tank [est]
MAKEUP_SPAN = 0.03e6  # Pa [est]
MAKEUP_AREA = 6e-4  # m^2 per port [est, generous so ports do not cavitate deeply]

# Oil volumes (pressure nodes). Cylinder ports: hose + valve port + cylinder dead volume.
PUMP_LINE_VOLUME = 2.5e-3  # m^3, pump outlet hose + valve gallery [est]
BYPASS_VOLUME = 0.3e-3  # m^3, centre-bypass passage downstream of the spools + NFC line [est]
CYLINDER_PORT_VOLUME = {"boom": 2.0e-3, "stick": 2.5e-3, "bucket": 2.5e-3}  # m^3 per port [est]
SWING_PORT_VOLUME = 1.5e-3  # m^3 per motor port incl. hoses [est]

# Open-centre valve: spool stroke SPOOL_STROKE; metering opens after the dead band
# (overlap) along progressive notches, area ~ z^METERING_EXPONENT with z the fraction of the
# metering stroke. The centre bypass starts closing at BYPASS_CLOSE_START: its main land is
# shut by BYPASS_LAND_CLOSED, leaving a bypass notch (BYPASS_NOTCH_AREA at neutral) that closes
# linearly by BYPASS_CLOSED, so with standby flow the pump pressure builds over mid-stroke
# (~2 MPa at 4 mm, ~10 MPa at 7 mm, ~30 MPa at 8 mm above the NFC pressure): open-centre metering.
SPOOL_DEAD_BAND = 1.5e-3  # m [est, 1-2 mm overlap]
STROKE_END_MARGIN = 0.005  # m from a stroke end: the cylinder is at its stop [est]
BYPASS_CLOSE_START = 0.8e-3  # m [est]
BYPASS_LAND_CLOSED = 3.0e-3  # m [est]
BYPASS_CLOSED = 9.5e-3  # m [est: fully closed before full stroke]
BYPASS_NOTCH_AREA = 20e-6  # m^2 [est]
METERING_EXPONENT = 1.8  # [est, notched spools: progressive]
# Max passage areas per function, m^2: pa = P->a, pb = P->b, at = a->T, bt = b->T, bypass [est;
# meter-in sized for ~1 MPa at full pump flow, meter-out for the larger head-side return flow,
# boom-down (a->T) and stick-in (b->T) throttled against the weight they lower, swing meter-out
# restrictive for braking].
VALVE_AREAS = {
    "swing": {"pa": 100e-6, "pb": 100e-6, "at": 80e-6, "bt": 80e-6, "bypass": 250e-6},
    "boom": {"pa": 120e-6, "pb": 90e-6, "at": 110e-6, "bt": 100e-6, "bypass": 250e-6},
    "stick": {"pa": 120e-6, "pb": 120e-6, "at": 150e-6, "bt": 80e-6, "bypass": 250e-6},
    "bucket": {"pa": 110e-6, "pb": 100e-6, "at": 140e-6, "bt": 100e-6, "bypass": 250e-6},
}
# The main valve of a Cat two-pump excavator (hexgym.hydraulics.circuit's "cat" layout) has more than the paper's
# four sections [cmp: Cat SERV1852, 300D-series boom, stick and bucket circuits (320D-330D); Cat 311D-314D systems
# operation]: a boom 2 section on pump 2 adds its flow to boom raise, a stick 2 section on pump 1 to stick in and
# out; each cuts its own pump's centre bypass as it strokes, so the other pump's flow has to follow. Their
# meter-in passages are sized as the first sections' [est].
COMBINING_VALVE_AREAS = {
    "boom2": {"pa": 120e-6, "bypass": 250e-6},  # boom raise only
    "stick2": {"pa": 120e-6, "pb": 120e-6, "bypass": 250e-6},
}
# Swing priority [cmp: 20 t-class two-pump circuits]: with the swing spool open, a priority valve throttles the
# stick 1 section's supply from pump 2, so the swing keeps that pump's flow and the stick takes pump 1's.
SWING_PRIORITY_STICK_SHARE = 0.2  # of the stick 1 meter-in area left at full swing spool [est]
# Boom priority [cmp: two-pump excavator circuits, boom raise + stick in]: raising the boom throttles the stick 2
# section's supply from pump 1, so the heavy boom keeps pump 1's flow instead of the light stick taking both pumps'.
BOOM_PRIORITY_STICK_SHARE = 0.05  # of the stick 2 meter-in area left at full boom-raise spool [est]
# Stick regeneration [cmp: Cat 311D-314D systems operation, "Fast STICK IN - Regeneration"]: on stick in, the
# regeneration valve restricts the rod end's return through stick 1 and a check passes the rod's oil to the head
# whenever the rod's pressure is the higher one (the stick's weight pulling it in, from full out to vertical); as
# the head pressure rises (past vertical, digging), the unloading valve opens the rod's return to tank again.
# m^2, rod -> head through the check, full stick-in spool [est: half a meter-in passage; of 150, 60 and 30 mm^2,
# 60 puts the stick-in time inside the published figure's +-20 % (150: 32 % fast), so that figure is no independent
# check of it]
STICK_REGEN_AREA = 60e-6
STICK_REGEN_RETURN_SHARE = 0.25  # of the stick 1 rod -> tank area left while regenerating [est]
STICK_UNLOADING_AREA = 100e-6  # m^2, rod -> tank through the opened unloading valve [est]
STICK_UNLOADING_PRESSURE = 6.0e6  # Pa, head pressure that starts opening it [est]
STICK_UNLOADING_SPAN = 4.0e6  # Pa, starting -> fully open [est]
# Boom regeneration [cmp: Cat SERV1852]: on boom lower, a check in the boom 1 section passes the head end's oil
# to the rod end, which the boom's weight drives; what the rod does not take returns to tank.
BOOM_REGEN_AREA = 100e-6  # m^2, head -> rod through the check, full boom-lower spool [est]
# The Cat valve's boom 1 head -> tank passage on boom lower, throttled against the boom's weight: with the regeneration
# the rod end is fed from the head, so this passage alone sets how fast the boom falls. m^2 [est: of 110 (the paper
# valve's), 60, 50 and 40 mm^2, 40 puts the published boom-lower time inside +-20 % (110: 1.25 s, 31 % fast; 60:
# 1.47 s), so that figure is no independent check of it]
CAT_BOOM_LOWER_AREA = 40e-6

# Cylinders (values per cylinder; a pair scales by Cylinder.count).
CYLINDER_COULOMB_FRICTION = 2.0e3  # N, seals [est, 1-3 kN for 130-150 mm bores]
CYLINDER_VISCOUS_FRICTION = 5.0e3  # N s/m [est]
CYLINDER_FRICTION_VELOCITY = 5e-3  # m/s, tanh smoothing of the Coulomb term [est]
CYLINDER_LEAKAGE = 2e-14  # m^3/(s Pa) across the piston [est: 25 mL/min at 20 MPa]
CUSHION_LENGTH = 0.04  # m: the cushion spear closes the outlet over the last 40 mm [est, 30-50]
CUSHION_AREA = 8e-6  # m^2 per cylinder: cushion orifice left when the spear is in [est]
CUSHION_PORT_AREA = 600e-6  # m^2 per cylinder: unrestricted port [est]
END_STOP_STIFFNESS = 1e8  # N/m beyond the stroke (standalone use; MuJoCo has its own limits) [est]
END_STOP_DAMPING = 1e5  # N s/m [est]
# The stroke-end stop of the learned circuit model's cylinders (hexgym/model/circuit_model.py), per cylinder: as the
# reference's MuJoCo joint limit stops the stick cylinder at its crowded-in end (effective mass ~2.3e5 kg there),
# measured: from 0.17 m/s within ~1.2 mm and ~16 ms (~100 rad/s); critically damped there, as the limit's solref
# (0.02 1) is (the reference's rebound is its oil's); it holds a cylinder at relief pressure within 0.5 mm [est]
CYLINDER_STOP_STIFFNESS = 2e9  # N/m
CYLINDER_STOP_DAMPING = 4e7  # N s/m

# Swing motor and reduction (SWING_MOTOR_DISPLACEMENT, SWING_REDUCTION above).
SWING_MOTOR_VOLUMETRIC_EFFICIENCY = 0.95  # at SWING_RELIEF and full pump flow [est]
SWING_MECHANICAL_EFFICIENCY = 0.90  # motor x reduction gear [est]
# the torque the motor turns the upper structure with at its crossover relief, N m [derived]
SWING_TORQUE_AT_RELIEF = (
    SWING_MOTOR_DISPLACEMENT * SWING_REDUCTION / (2 * np.pi) * SWING_RELIEF * SWING_MECHANICAL_EFFICIENCY
)
SWING_MOTOR_LEAKAGE = (  # m^3/(s Pa), total leakage coefficient [derived from the efficiency]
    (1.0 - SWING_MOTOR_VOLUMETRIC_EFFICIENCY) * PUMP_MAX_FLOW / SWING_RELIEF
)
SWING_MOTOR_EXTERNAL_LEAK_SHARE = 0.3  # of the leakage to the case drain, the rest port to port [est]
SWING_MOTOR_VISCOUS_FRICTION = 0.05  # N m s/rad at the motor shaft [est]
SWING_FRICTION_SPEED = 0.5  # rad/s at the motor shaft, tanh smoothing [est]

# Fuel: brake-specific fuel consumption at constant (rated) speed vs load fraction
# P_brake / ENGINE_POWER, shaped like a heavy-duty diesel's map with its minimum (BSFC) near
# 80 % load [est]; below the first point the fuel rate falls linearly to the no-load rate.
BSFC_LOAD_FRACTION = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
BSFC_MAP = (420.0, 300.0, 262.0, 243.0, 232.0, 224.0, 218.0, BSFC, 216.0, 220.0)  # g/kWh [est]
ENGINE_NO_LOAD_FUEL = 3.0  # kg/h at rated speed, no load [derived: Willans-line extrapolation]

# --------------------------------------------------------------------------------------------
# Earthwork / truck (HexLoading-v0, hexgym.envs). The material is MATERIAL_DENSITY's sand and
# gravel; the bucket's mouth and capacity are hexgym.machine.bucket's, computed from its profile.
MATERIAL_FRICTION_ANGLE = np.radians(35.0)  # internal friction of loose sand and gravel [textbook 30-40 deg]
MATERIAL_REPOSE_ANGLE = np.radians(34.0)  # angle of repose, dry sand and gravel [textbook 30-38 deg]
MATERIAL_TOOL_FRICTION_ANGLE = np.radians(23.0)  # soil on steel, about 2/3 of the internal angle [textbook]
BUCKET_SPILL_TIME_CONSTANT = 0.3  # s: excess material leaves the bucket with this time constant [est]
DIG_REFERENCE_SPEED = 0.05  # m/s: digging resistance reaches its full value above this edge speed [est]
DIG_VELOCITY_FILTER = 0.1  # s: the resistance follows the edge's velocity low-passed by this [est: without
# it the force -> cylinder load -> table speed -> force loop oscillates at the control period]
PILE_HEIGHT_RANGE = (1.3, 1.6)  # m, flat-topped heap of stockpiled material [est]
PILE_TOP_RADIUS_RANGE = (1.0, 1.4)  # m, its flat top; flanks at the angle of repose [est]
PILE_DISTANCE_RANGE = (7.0, 7.8)  # m from the swing axis to the pile's centre [est: within reach]
PILE_SWING_RANGE = np.radians((-10.0, 10.0))  # direction of the pile from the machine's x axis [est]
# A tandem-axle dump truck (e.g. a 10-wheeler): bed inside dimensions, floor height, rim [est]
TRUCK_BED_LENGTH = 5.0  # m inside [est, 4.9-5.5]
TRUCK_BED_WIDTH = 2.3  # m inside [est, 2.2-2.4]
TRUCK_BED_FLOOR_HEIGHT = 1.55  # m above ground [est]
TRUCK_BED_WALL_HEIGHT = 1.05  # m above the floor: rim at 2.6 m [est]
TRUCK_CAPACITY = 13000.0  # kg payload [est: tandem dump truck, 12-15 t]
TRUCK_DISTANCE_RANGE = (6.6, 7.4)  # m from the swing axis to the bed's centre [est: within dump reach]
TRUCK_SWING_RANGE = np.radians((70.0, 110.0))  # |angle| of the truck from the machine's x axis, either side [est]
# Layouts outside those ranges (HexLoading-v0's site_ranges="shifted": a robustness test, never trained on): each
# quantity drawn from a band just below or just above its range (a fair coin each; the truck only farther: nearer,
# the arm's start pose, swung towards it, stands in its bed's wall), the pile turned away from the truck's side.
# Within reach (a cut's entry at 9.0 m at most; the bed's near wall 6.2-6.6 m out) and the truck no nearer the
# pile's toe than the closest training layout's (its cab reaches 1.1 m over the toe) [est]
SHIFTED_PILE_DISTANCE_BANDS = ((6.6, 7.0), (7.8, 8.2))  # m: 0.4 m either side of PILE_DISTANCE_RANGE
SHIFTED_PILE_SWING_BAND = np.radians((10.0, 15.0))  # |direction|, on the side away from the truck
SHIFTED_TRUCK_DISTANCE_BANDS = ((7.4, 7.8),)  # m: 0.4 m beyond TRUCK_DISTANCE_RANGE
SHIFTED_TRUCK_SWING_BANDS = (np.radians((60.0, 70.0)), np.radians((110.0, 120.0)))  # |angle|: 10 deg either side
# Fuel of the learned model: mechanical power at the actuators through the open-centre valves
# and the pumps, plus the standby (bypass) flow's power, then BSFC (hexgym.hydraulics.circuit.fuel_rate)
HYDRAULIC_VALVE_EFFICIENCY = 0.7  # actuator power / pump power: metering and line losses [est 0.6-0.8]
STANDBY_HYDRAULIC_POWER = 2.0 * PUMP_IDLE_FLOW_FRACTION * PUMP_MAX_FLOW * NFC_PRESSURE_IDLE  # W [derived]
HARD_CONTACT_FORCE = 50e3  # N: bucket/stick contact force above this counts as a hard contact [est]
# The lean machine's contacts are inactive (the learned model stalls at them); their force is
# estimated from the depth the bucket or stick reached: compacted ground / a steel bed under a
# loaded bucket edge, ~50 kN per cm [est]
CONTACT_STIFFNESS = 5e6  # N/m
HARD_CONTACT_FORCE_CAP = 265e3  # N: counted at most this: the operating weight, beyond which the real
# machine would lift itself off its tracks rather than press harder [derived: ~27 t x g]
