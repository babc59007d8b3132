// The circuit model's control period: the open-centre circuit with the learned valve, coupled
// implicitly to the main joints. The same law as hexgym/hydraulics/circuit.py (HydraulicCircuit,
// the definition, which makes the training data) and hexgym/model/circuit_model.py's coupling, term
// by term; the one fast implementation, run by the hexgym.mbl plugin and, through ctypes
// (circuit_binding.cc), by the Python circuit model.
//
// The circuit is data: its nodes, branches, valve sections, pumps, cylinders, swing motor and scalar
// laws come as numbers packed by hexgym.model.circuit_kernel.circuit_numbers in the layout that
// hexgym/model/plugin.py defines (kCircuitFields, kCircuitLaws in the generated plugin_interface.h). The
// valve is any layout of sections (hexgym.hydraulics.circuit.ValveLayout): each moved by a function's
// spool, metering from a pump, its passages' 1-D tables and branches; each pump's bypass the series of its
// sections'; priority valves on a section's meter-in and regeneration passages, the data sheet's.
#ifndef HEXGYM_NATIVE_CIRCUIT_H_
#define HEXGYM_NATIVE_CIRCUIT_H_

#include <stdexcept>
#include <string>
#include <vector>

#include "plugin_interface.h"

namespace hexgym {

// Circuit numbers or valve tables that cannot be used; what() says which and why.
class CircuitError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

constexpr int kMaxNodes = 30;  // the workspace's capacity; a larger circuit is refused when packed
constexpr int kMaxState = kMaxNodes + kNumPumps;
constexpr int kMaxBranches = 160;
constexpr int kMaxSections = 16;
constexpr int kMaxRegenerations = 8;
constexpr int kNumPassages = 5;  // bypass, pump->a, pump->b, a->tank, b->tank (hexgym.mbl.schema.VALVE_PASSAGES)
enum Passage { kBypass, kPa, kPb, kAt, kBt };

// A valve table: linear between its nodes, clamped to its ends (MBLTable's lookup in one input).
struct ValveTable {
  std::vector<double> nodes, values;
  double inv_step = 0.0;  // 1 / node spacing of an even axis; 0: searched
  double operator()(double x) const;
};
// A table of n nodes at `nodes` (ascending) with `values`.
ValveTable MakeValveTable(const double* nodes, const double* values, int n);

// A valve section: the function whose spool moves it (to the sides it has passages on: `raise_only`, no pump->b
// nor a->tank, stays at neutral for a negative spool, `lower_only` for a positive one), the pump it meters from,
// its passages' tables (Passage order; -1: it has none) and branches (pa, pb, at, bt; -1: none), and a priority
// valve on its meter-in (the piloting function, -1: none; the side of its spool, 1, -1 or 0 for either; the area's
// share left at full spool).
struct Section {
  int function, pump, table[kNumPassages], branch[4];
  bool raise_only, lower_only;
  int priority_function, priority_side;
  double priority_share;
};

// A regeneration passage: its branch, the function whose spool opens it on `side` (1 or -1), its table (-1: the
// data sheet's `area` metered by the spool), the cylinder whose oil leaves through it and its cushion (-1: none)
// and that cylinder's end (1 the rod's, -1 the head's).
struct Regeneration {
  int branch, function, side, table;
  double area;
  int cylinder, end;
};

struct Circuit {
  int nodes = 0, branches = 0, sections = 0, regenerations = 0, state_size = 0;
  double law[kNumCircuitLaws];
  std::vector<int> from, to, pilot;  // the tank is node `nodes`; pilot: the node that opens a valve, -1: its drop
  std::vector<double> area, crack, inv_span, laminar;
  std::vector<Section> section;
  std::vector<Regeneration> regeneration;
  int bypass_branch[kNumPumps], pump_node[kNumPumps], signal_node[kNumPumps];
  std::vector<int> series[kNumPumps];  // each pump's sections, in series on its bypass
  double head_area[kNumCylinders], rod_area[kNumCylinders], stroke[kNumCylinders], count[kNumCylinders];
  double port_volume[kNumCylinders];
  int head_node[kNumCylinders], rod_node[kNumCylinders], function[kNumCylinders];
  std::vector<double> node_volume;   // (nodes): 0 for the cylinder chambers, whose volumes follow the pistons
  std::vector<double> displacement;  // (nodes, 4): d(volume rate)/d(boom, stick, bucket velocity, swing rate)
  std::vector<ValveTable> valve;     // the valve's tables, as the sections and regeneration passages index them
  double neutral_term[kNumPumps];    // (sections - 1) / (each pump's bypass area at neutral)^2

  // From `count` packed numbers and the valve's tables (each used by a section's passage or a regeneration).
  Circuit(const double* numbers, int count, std::vector<ValveTable> tables);
};

// The circuit's state at rest with idle pumps and chamber pressures holding `holding` (N per cylinder).
void InitialState(const Circuit& k, const double* holding, double* state);

// Whether a period's end is no state of the machine: a node's pressure beyond the fault pressure, or anything not
// finite.
bool Diverged(const Circuit& k, const double* state, const double* rates, const double* travel);

constexpr int kRefine = 8, kMaxRefine = 64;  // a diverged period's retries: steps 8 and 64 times shorter

// One control period: `substeps` circuit steps of `h` s at `spools` (m), the joints' rates implicit in the
// oil's torques, with moment arms `arms` (3), the main joints' mass matrix `mass` (4x4, row-major) and loads
// `load` (4). `state` (state_size), `rates` (4: swing, boom, stick, bucket) and `ext` (3) advance in place;
// `travel` (4) gets each joint's travel (rad); a period that diverges is run again in shorter steps
// (kRefine, kMaxRefine). Returns the steps split.
int ControlPeriod(const Circuit& k, const double* spools, double* state, double* rates, double* ext,
                  const double* arms, const double* mass, const double* load, double h, int substeps,
                  double* travel);

// The period's pieces, for the tests that hold them to the definition (hexgym_circuit_* in circuit_binding.cc):
// the branches' areas (branches) at spools and extensions; d(state)/dt (state_size) and its Jacobian (row-major);
// one circuit step of dt in place with d(state)/d(velocities) (state_size x 4), returning the splits; the oil's
// cylinder forces (3) returning the swing torque; d(force)/d(velocity) (3) returning d(torque)/d(swing rate).
void BranchAreasAt(const Circuit& k, const double* spools, const double* ext, double* area);
void Derivatives(const Circuit& k, const double* y, const double* spools, const double* ext, const double* vel,
                 double swing_rate, double* f, double* jac);
int Step(const Circuit& k, double* y, const double* spools, const double* ext, const double* vel, double swing_rate,
         double dt, double* sens);
double OilForces(const Circuit& k, const double* y, const double* vel, double swing_rate, double* force);
double CouplingDerivatives(const Circuit& k, const double* sens, const double* vel, double* dforce);

}  // namespace hexgym

#endif  // HEXGYM_NATIVE_CIRCUIT_H_
