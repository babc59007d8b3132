// The circuit model's control period (see circuit.h). Each function names the Python it mirrors.
#include "circuit.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <utility>

namespace hexgym {
namespace {

constexpr double kUniformRtol = 1e-9;  // an axis whose steps agree to this is looked up by its step (MBLTable)

// ---- element laws (hexgym.hydraulics.circuit) -------------------------------------------------
struct Smooth {
  double value, slope;
};

// C1 ramp 0 -> 1 on z in [0, 1] and its derivative (smoothstep).
Smooth Smoothstep(double z) {
  z = std::fmin(std::fmax(z, 0.0), 1.0);
  return {z * z * (3.0 - 2.0 * z), 6.0 * z * (1.0 - z)};
}

// sqrt(2|dp|/rho) sign(dp), regularised to laminar near 0, and its derivative (orifice_law).
Smooth OrificeLaw(double dp, double laminar_sq, double sqrt_2_rho) {
  double w = 1.0 / std::sqrt(std::sqrt(dp * dp + laminar_sq));
  double w2 = w * w;
  return {sqrt_2_rho * dp * w, sqrt_2_rho * (w2 * w2 * w) * (0.5 * dp * dp + laminar_sq)};
}

// The equivalent area of two turbulent orifices in series (series_area).
double SeriesArea(double a1, double a2) { return a1 * a2 / std::sqrt(a1 * a1 + a2 * a2 + 1e-30); }

// 1/beta(p) of oil with entrained air and d(1/beta)/dp, 0 on the vacuum floor (compliance).
Smooth Compliance(const double* law, double pressure) {
  double n = law[kLawPolytropic], pa = law[kLawAtmosphere];
  double p_abs = pressure + pa;
  bool floor = p_abs < law[kLawVacuum] + pa;
  if (floor) p_abs = law[kLawVacuum] + pa;
  double x = law[kLawAirFraction] * std::pow(pa / p_abs, 1.0 / n);
  double dx = -x / (n * p_abs);
  double num = 1.0 / law[kLawBulkModulus] + x / (n * p_abs);
  double dnum = -x * (1.0 + 1.0 / n) / (n * p_abs * p_abs);
  double c = num / (1.0 + x);
  double dc = (dnum * (1.0 + x) - num * dx) / ((1.0 + x) * (1.0 + x));
  return {c, floor ? 0.0 : dc};
}

// The outlet area left by the cushion spear `distance` (m) before a stroke end (HydraulicCircuit._cushion).
double Cushion(const double* law, double count, double distance) {
  double s = Smoothstep(distance / law[kLawCushionLength]).value;
  return count * (law[kLawCushionArea] + (law[kLawCushionPortArea] - law[kLawCushionArea]) * s);
}

// ---- the valve (hexgym.mbl.valve.LearnedValve) -------------------------------------------------
struct ValveAreas {
  double passage[kNumPassages][kMaxSections];
  double pump_bypass[kNumPumps];
  double regeneration[kMaxRegenerations];
};

// How far a spool's metering notch on `side` (1 positive, -1 negative, 0 the more open) is open, 0 -> 1
// (metering_fraction).
double Metering(const double* law, double u, int side) {
  double span = law[kLawSpoolStroke] - law[kLawDeadBand];
  double up = std::pow(std::fmin(std::fmax((u - law[kLawDeadBand]) / span, 0.0), 1.0), law[kLawMeteringExponent]);
  double down = std::pow(std::fmin(std::fmax((-u - law[kLawDeadBand]) / span, 0.0), 1.0), law[kLawMeteringExponent]);
  return side > 0 ? up : side < 0 ? down : std::fmax(up, down);
}

// A passage is closed in the dead band and on the other side of neutral; a priority valve leaves its share of a
// section's meter-in (priority_shares); each pump's bypass combines its sections' tables in series
// (pump_bypass_area); a regeneration passage opens on its side of the dead band, the data sheet's metered with the
// spool.
ValveAreas Valve(const Circuit& k, const double* spools) {
  ValveAreas a;
  std::memset(&a, 0, sizeof(a));
  const double* law = k.law;
  for (int i = 0; i < k.sections; ++i) {
    const Section& s = k.section[i];
    double u = spools[s.function];
    if ((s.raise_only && u < 0.0) || (s.lower_only && u > 0.0)) u = 0.0;  // section_spools
    int open[3] = {kBypass, u > 0 ? kPa : kPb, u > 0 ? kBt : kAt};
    for (int key : open) {
      if (s.table[key] < 0 || (key != kBypass && std::fabs(u) < law[kLawDeadBand])) continue;
      a.passage[key][i] = std::fmax(k.valve[s.table[key]](u), 0.0);
    }
    if (s.priority_function >= 0) {
      double share =
          1.0 - (1.0 - s.priority_share) * Metering(law, spools[s.priority_function], s.priority_side);
      a.passage[kPa][i] *= share;
      a.passage[kPb][i] *= share;
    }
  }
  for (int j = 0; j < kNumPumps; ++j) {
    double resistance = 0.0, smallest = INFINITY;
    for (int i : k.series[j]) {
      double area = std::fmax(a.passage[kBypass][i], law[kLawClosedArea]);
      resistance += 1.0 / (area * area);
      smallest = std::fmin(smallest, area);
    }
    resistance -= k.neutral_term[j];
    a.pump_bypass[j] = 1.0 / std::sqrt(std::fmax(resistance, 1.0 / (smallest * smallest)));
  }
  for (int r = 0; r < k.regenerations; ++r) {
    const Regeneration& g = k.regeneration[r];
    double u = spools[g.function];
    if (g.table < 0) {
      a.regeneration[r] = g.area * Metering(law, u, g.side);
    } else if (g.side * u >= law[kLawDeadBand]) {
      a.regeneration[r] = std::fmax(k.valve[g.table](u), 0.0);
    }
  }
  return a;
}

// ---- the circuit's ODE (HydraulicCircuit) ------------------------------------------------------
struct Workspace {
  double area[kMaxBranches], q[kMaxBranches], g[kMaxBranches];
  double f[kMaxState], cap[kMaxNodes];
  double jac[kMaxState][kMaxState];
  uint64_t pattern[kMaxState];  // each Jacobian row's possibly nonzero columns (bits), the diagonal's too
};

// The geometric area (m^2) of every branch for these valve areas and cylinder extensions (branch_areas).
void BranchAreas(const Circuit& k, const ValveAreas& v, const double* ext, double* area) {
  for (int b = 0; b < k.branches; ++b) area[b] = k.area[b];
  for (int i = 0; i < k.sections; ++i) {
    const int* branch = k.section[i].branch;
    for (int key = kPa; key <= kBt; ++key) {
      if (branch[key - kPa] >= 0) area[branch[key - kPa]] = v.passage[key][i];
    }
  }
  for (int c = 0; c < kNumCylinders; ++c) {  // a->T leaves the head end (retracting), b->T the rod end
    int f = k.function[c];
    const int* branch = k.section[f].branch;
    if (branch[kAt - kPa] >= 0) {
      area[branch[kAt - kPa]] = SeriesArea(v.passage[kAt][f], Cushion(k.law, k.count[c], ext[c]));
    }
    if (branch[kBt - kPa] >= 0) {
      area[branch[kBt - kPa]] = SeriesArea(v.passage[kBt][f], Cushion(k.law, k.count[c], k.stroke[c] - ext[c]));
    }
  }
  for (int j = 0; j < kNumPumps; ++j) area[k.bypass_branch[j]] = v.pump_bypass[j];
  for (int r = 0; r < k.regenerations; ++r) {  // out of the cylinder's port, through its cushion
    const Regeneration& g = k.regeneration[r];
    int c = g.cylinder;
    area[g.branch] = c < 0 ? v.regeneration[r]
                           : SeriesArea(v.regeneration[r],
                                        Cushion(k.law, k.count[c], g.end > 0 ? k.stroke[c] - ext[c] : ext[c]));
  }
}

// Oil volume (m^3) of every node at cylinder extensions `ext` (volumes).
void Volumes(const Circuit& k, const double* ext, double* vol) {
  for (int i = 0; i < k.nodes; ++i) vol[i] = k.node_volume[i];
  for (int c = 0; c < kNumCylinders; ++c) {
    double x = std::fmin(std::fmax(ext[c], 0.0), k.stroke[c]);
    vol[k.head_node[c]] = k.port_volume[c] + k.head_area[c] * x;
    vol[k.rod_node[c]] = k.port_volume[c] + k.rod_area[c] * (k.stroke[c] - x);
  }
}

// d(state)/dt, its Jacobian and the nodes' capacities V/beta into w (_evaluate).
void Evaluate(const Circuit& k, const double* y, const double* ext, const double* vel, double swing_rate,
              Workspace& w) {
  const double* law = k.law;
  int nn = k.nodes, n = k.state_size;
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) w.jac[i][j] = 0.0;
    w.pattern[i] = uint64_t{1} << i;
  }
  double net[kMaxNodes] = {0.0};
  for (int b = 0; b < k.branches; ++b) {  // each branch's flow and its incidence; the tank (node nn) has no row
    int a = k.from[b], c = k.to[b];
    double dp = (a < nn ? y[a] : 0.0) - (c < nn ? y[c] : 0.0);
    int pilot = k.pilot[b];
    double opening = 1.0, dopening = 0.0, dpilot = 0.0;
    if (pilot >= 0) {  // a valve opened by another node's pressure: its opening moves with that node's
      Smooth s = Smoothstep((y[pilot] - k.crack[b]) * k.inv_span[b]);
      opening = s.value, dpilot = s.slope;
    } else if (k.inv_span[b] > 0.0) {  // a pressure-operated valve
      Smooth s = Smoothstep((dp - k.crack[b]) * k.inv_span[b]);
      opening = s.value, dopening = s.slope * k.inv_span[b];
    }
    double cda = law[kLawDischarge] * w.area[b];
    double q = k.laminar[b] * dp, g = k.laminar[b], conductance = 0.0;  // conductance: d(q)/d(pilot pressure)
    if (cda != 0.0 && (opening != 0.0 || dopening != 0.0 || dpilot != 0.0)) {  // closed: their leak only
      Smooth r = OrificeLaw(dp, law[kLawLaminarSq], law[kLawSqrt2Rho]);
      q += cda * opening * r.value;
      g += cda * (dopening * r.value + opening * r.slope);
      conductance = cda * r.value * dpilot * k.inv_span[b];
    }
    if (a < nn) net[a] -= q, w.jac[a][a] -= g;
    if (c < nn) net[c] += q, w.jac[c][c] -= g;
    if (a < nn && c < nn && g != 0.0) {
      w.jac[a][c] += g, w.jac[c][a] += g;
      w.pattern[a] |= uint64_t{1} << c, w.pattern[c] |= uint64_t{1} << a;
    }
    if (conductance != 0.0) {  // pilot_conductance's column
      if (a < nn) w.jac[a][pilot] -= conductance, w.pattern[a] |= uint64_t{1} << pilot;
      if (c < nn) w.jac[c][pilot] += conductance, w.pattern[c] |= uint64_t{1} << pilot;
    }
  }
  // pumps: NFC under the cross-sensing horsepower limit (pump_flows)
  double p1 = y[k.pump_node[0]], p2 = y[k.pump_node[1]], total = p1 + p2;
  double q_hp = total > 0.0 ? law[kLawPowerLimit] / total : INFINITY;
  double dq_dd[kNumPumps];
  for (int i = 0; i < kNumPumps; ++i) {
    double nfc = law[kLawMaxFlow] * std::fmin(std::fmax(y[nn + i], 0.0), 1.0);
    bool limited = nfc > q_hp;
    int node = k.pump_node[i];
    net[node] += limited ? q_hp : nfc;
    dq_dd[i] = limited ? 0.0 : law[kLawMaxFlow];
    if (limited && total > 0.0) {
      double dq_dp = -law[kLawPowerLimit] / (total * total);
      w.jac[node][k.pump_node[0]] += dq_dp;
      w.jac[node][k.pump_node[1]] += dq_dp;
      w.pattern[node] |= (uint64_t{1} << k.pump_node[0]) | (uint64_t{1} << k.pump_node[1]);
    }
  }
  Volumes(k, ext, w.cap);
  for (int i = 0; i < nn; ++i) {
    Smooth c = Compliance(law, y[i]);
    w.cap[i] *= c.value;
    const double* d = &k.displacement[4 * i];
    double rate = d[0] * vel[0] + d[1] * vel[1] + d[2] * vel[2] + d[3] * swing_rate;
    double inv_cap = 1.0 / w.cap[i];
    w.f[i] = (net[i] - rate) * inv_cap;
    for (int j = 0; j < nn; ++j) w.jac[i][j] *= inv_cap;
    w.jac[i][i] -= w.f[i] * c.slope / c.value;
  }
  // the regulators: NFC through its lag, and d(pump pdot)/d(displacement)
  double width = law[kLawNfcMinFlow] - law[kLawNfcFullFlow], drop = 1.0 - law[kLawIdleFraction];
  double tau = law[kLawRegulatorTime];
  for (int i = 0; i < kNumPumps; ++i) {
    Smooth s = Smoothstep((y[k.signal_node[i]] - law[kLawNfcFullFlow]) / width);
    w.f[nn + i] = (1.0 - drop * s.value - y[nn + i]) / tau;
    w.jac[nn + i][k.signal_node[i]] = -drop * s.slope / width / tau;
    w.jac[nn + i][nn + i] = -1.0 / tau;
    w.jac[k.pump_node[i]][nn + i] = dq_dd[i] / w.cap[k.pump_node[i]];
    w.pattern[nn + i] |= uint64_t{1} << k.signal_node[i];
    w.pattern[k.pump_node[i]] |= uint64_t{1} << (nn + i);
  }
}

// x of a x = b for b with m columns, by Gaussian elimination with partial pivoting, as LAPACK's LU does (the
// pivot's reciprocal scales its column); a (n x n, row stride sa) and b (n x m, row stride sb) are overwritten,
// x in b. The circuit's matrix is sparse (a dozen nodes, each on a few branches): each row's possibly nonzero
// columns are tracked as bits (`pattern`, or found), fill-in included, and only they are visited.
void Solve(double* a, int sa, double* b, int sb, int n, int m, const uint64_t* pattern = nullptr) {
  static_assert(kMaxState <= 64, "a row's nonzeros are the bits of one 64-bit word");
  uint64_t mask[kMaxState];
  for (int r = 0; r < n; ++r) {
    mask[r] = 0;
    if (pattern) {
      mask[r] = pattern[r];
      continue;
    }
    for (int j = 0; j < n; ++j) mask[r] |= static_cast<uint64_t>(a[r * sa + j] != 0.0) << j;  // no branches
  }
  for (int col = 0; col < n; ++col) {
    uint64_t bit = uint64_t{1} << col;
    int pivot = col;
    for (int r = col + 1; r < n; ++r) {
      if ((mask[r] & bit) && std::fabs(a[r * sa + col]) > std::fabs(a[pivot * sa + col])) pivot = r;
    }
    if (pivot != col) {
      for (int j = 0; j < n; ++j) std::swap(a[col * sa + j], a[pivot * sa + j]);
      for (int j = 0; j < m; ++j) std::swap(b[col * sb + j], b[pivot * sb + j]);
      std::swap(mask[col], mask[pivot]);
    }
    const double* top = a + col * sa;
    const double* btop = b + col * sb;
    uint64_t right = mask[col] & ~((bit << 1) - 1);  // the pivot row's nonzeros right of the diagonal
    double inv = 1.0 / top[col];
    for (int r = col + 1; r < n; ++r) {
      if (!(mask[r] & bit)) continue;
      double* row = a + r * sa;
      double factor = row[col] * inv;
      for (uint64_t cols = right; cols; cols &= cols - 1) {
        int j = __builtin_ctzll(cols);
        row[j] -= factor * top[j];
      }
      mask[r] |= right;
      double* brow = b + r * sb;
      for (int j = 0; j < m; ++j) brow[j] -= factor * btop[j];
    }
  }
  for (int col = n - 1; col >= 0; --col) {
    const double* row = a + col * sa;
    double* brow = b + col * sb;
    uint64_t bit = uint64_t{1} << col;
    for (uint64_t cols = mask[col] & ~((bit << 1) - 1); cols; cols &= cols - 1) {
      int c = __builtin_ctzll(cols);
      const double* x = b + c * sb;
      for (int j = 0; j < m; ++j) brow[j] -= row[c] * x[j];
    }
    for (int j = 0; j < m; ++j) brow[j] /= row[col];
  }
}

// Whether a step's pressure change is small enough for its linearisation (_trusted).
bool Trusted(const double* law, const double* p0, const double* p1, int nn) {
  for (int i = 0; i < nn; ++i) {
    if ((p1[i] < 0.5 * p0[i] && p0[i] > law[kLawTrustFloor]) || p1[i] < law[kLawVacuum] ||
        std::fabs(p1[i] - p0[i]) > law[kLawTrustJump]) {
      return false;
    }
  }
  return true;
}

// One linearly implicit Euler step of dt from y where the ODE gave w: the new state y1 and sensitivity s1,
// (y, 0) + L^-1 (dt f, S - dt dV/dv / cap) with L = I - dt J.
void ImplicitEuler(const Circuit& k, const double* y, const double* sens, double dt, const Workspace& w,
                   double* y1, double* s1) {
  int n = k.state_size, nn = k.nodes;
  double lhs[kMaxState * kMaxState], rhs[kMaxState * 5];
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) lhs[i * n + j] = (i == j ? 1.0 : 0.0) - dt * w.jac[i][j];
    rhs[i * 5] = dt * w.f[i];
    for (int j = 0; j < 4; ++j) {
      rhs[i * 5 + 1 + j] = sens[i * 4 + j] - (i < nn ? dt * k.displacement[4 * i + j] / w.cap[i] : 0.0);
    }
  }
  Solve(lhs, n, rhs, 5, n, 5, w.pattern);
  for (int i = 0; i < n; ++i) {
    y1[i] = y[i] + rhs[i * 5];
    for (int j = 0; j < 4; ++j) s1[i * 4 + j] = rhs[i * 5 + 1 + j];
  }
}

// The state after dt, d(state)/d(velocities) into sens, and the splits taken (step_with_sensitivity): a step
// the linearisation cannot be trusted with is split in halves, depth first, up to max_splits deep.
int Advance(const Circuit& k, double* y, double dt, const double* ext, const double* vel, double swing_rate,
            double* sens, Workspace& w) {
  int n = k.state_size, nn = k.nodes, max_splits = static_cast<int>(k.law[kLawMaxSplits]);
  for (int i = 0; i < n * 4; ++i) sens[i] = 0.0;
  int pending[64], top = 1, splits = 0;  // depths of the intervals still to go, last is next
  pending[0] = 0;
  double y1[kMaxState], s1[kMaxState * 4];
  Evaluate(k, y, ext, vel, swing_rate, w);
  while (top > 0) {
    int depth = pending[--top];
    ImplicitEuler(k, y, sens, dt * std::ldexp(1.0, -depth), w, y1, s1);
    if (depth < max_splits && !Trusted(k.law, y, y1, nn)) {
      ++splits;
      pending[top++] = depth + 1;
      pending[top++] = depth + 1;
      continue;
    }
    for (int i = 0; i < nn; ++i) {  // a last guard: oil cannot pull a vacuum
      if (y1[i] < k.law[kLawVacuum]) {
        y1[i] = k.law[kLawVacuum];
        for (int j = 0; j < 4; ++j) s1[i * 4 + j] = 0.0;
      }
    }
    std::memcpy(y, y1, sizeof(double) * n);
    std::memcpy(sens, s1, sizeof(double) * n * 4);
    if (top > 0) Evaluate(k, y, ext, vel, swing_rate, w);  // the second half of a split step: from the first's end
  }
  return splits;
}

// ---- the joints (hexgym.model.circuit_model.CircuitModel._substep) ----------------------------------
// Cylinder forces (N) and the swing torque (N m) of state y, no end stops (actuator_forces).
double OilLoads(const Circuit& k, const double* y, const double* vel, double swing_rate, double* force) {
  const double* law = k.law;
  for (int c = 0; c < kNumCylinders; ++c) {
    double friction = law[kLawCoulomb] * std::tanh(vel[c] / law[kLawFrictionVelocity]);
    force[c] = y[k.head_node[c]] * k.head_area[c] - y[k.rod_node[c]] * k.rod_area[c];
    force[c] -= k.count[c] * (friction + law[kLawViscous] * vel[c]);
  }
  double omega = law[kLawSwingReduction] * swing_rate;
  double ideal = law[kLawSwingDisplacement] * (y[static_cast<int>(law[kLawSwingA])] - y[static_cast<int>(law[kLawSwingB])]);
  double loss = (1.0 - law[kLawSwingEfficiency]) * std::fabs(ideal) * std::tanh(omega / law[kLawSwingFrictionSpeed]);
  return law[kLawSwingReduction] * (ideal - loss - law[kLawSwingViscous] * omega);
}

// d(force_i)/d(v_i) (N s/m) and d(swing torque)/d(swing rate) (N m s/rad) along a step of sensitivity sens
// (coupling_derivatives).
double Coupling(const Circuit& k, const double* sens, const double* vel, double* dforce) {
  const double* law = k.law;
  for (int c = 0; c < kNumCylinders; ++c) {
    double dpressure = k.head_area[c] * sens[k.head_node[c] * 4 + c] - k.rod_area[c] * sens[k.rod_node[c] * 4 + c];
    double t = std::tanh(vel[c] / law[kLawFrictionVelocity]);
    double friction = law[kLawCoulomb] / law[kLawFrictionVelocity] * (1.0 - t * t) + law[kLawViscous];
    dforce[c] = dpressure - k.count[c] * friction;
  }
  double ratio = law[kLawSwingReduction];
  int a = static_cast<int>(law[kLawSwingA]), b = static_cast<int>(law[kLawSwingB]);
  double dtorque = ratio * law[kLawSwingDisplacement] * (sens[a * 4 + 3] - sens[b * 4 + 3]);
  return dtorque - ratio * ratio * law[kLawSwingViscous];
}

// One circuit step of h s with the joints' rates implicit in the oil's torques and in the stops' springs
// (CircuitModel._joint_step); the caller has set w.area at ext.
int JointStep(const Circuit& k, double h, double* state, double* rates, double* ext, const double* arms,
              const double* mass, const double* load, Workspace& w) {
  double vel[kNumCylinders], sens[kMaxState * 4], force[kNumCylinders], dforce[kNumCylinders];
  for (int c = 0; c < kNumCylinders; ++c) vel[c] = arms[c] * rates[c + 1];
  int splits = Advance(k, state, h, ext, vel, rates[0], sens, w);  // state: the predicted one
  double torque = OilLoads(k, state, vel, rates[0], force);
  double dtorque = Coupling(k, sens, vel, dforce);
  double lhs[16], rhs[4], a[16], b[4], next[4];
  std::memcpy(lhs, mass, sizeof(lhs));
  lhs[0] -= h * dtorque;
  rhs[0] = h * (torque - load[0]);
  for (int c = 0; c < kNumCylinders; ++c) {
    lhs[(c + 1) * 5] -= h * (dforce[c] * (arms[c] * arms[c]));
    rhs[c + 1] = h * (force[c] * arms[c] - load[c + 1]);
  }
  std::memcpy(a, lhs, sizeof(a));
  std::memcpy(b, rhs, sizeof(b));
  Solve(a, 4, b, 1, 4, 1);
  for (int j = 0; j < 4; ++j) next[j] = rates[j] + b[j];
  const double lo = k.law[kLawStopClearance];
  double end[kNumCylinders];
  bool stopped = false;
  for (int c = 0; c < kNumCylinders; ++c) {
    double reach = ext[c] + arms[c] * next[c + 1] * h, hi = k.stroke[c] - lo;
    end[c] = reach > hi ? hi : (reach < lo ? lo : -1.0);
    stopped |= end[c] >= 0.0;
  }
  if (stopped) {  // the stops' springs, implicit: force -K (ext + h v - end) - D v at the step's end
    std::memcpy(b, rhs, sizeof(b));
    for (int c = 0; c < kNumCylinders; ++c) {
      if (end[c] < 0.0) continue;
      double stiff = k.count[c] * k.law[kLawStopStiffness], damp = k.count[c] * k.law[kLawStopDamping];
      double gain = (h * stiff + damp) * (arms[c] * arms[c]);
      lhs[(c + 1) * 5] += h * gain;
      b[c + 1] -= h * (stiff * arms[c] * (ext[c] - end[c]) + gain * rates[c + 1]);
    }
    std::memcpy(a, lhs, sizeof(a));
    Solve(a, 4, b, 1, 4, 1);
    for (int j = 0; j < 4; ++j) next[j] = rates[j] + b[j];
  }
  double dv[4];
  for (int c = 0; c < kNumCylinders; ++c) {
    dv[c] = arms[c] * (next[c + 1] - rates[c + 1]);
    ext[c] += arms[c] * next[c + 1] * h;
  }
  dv[3] = next[0] - rates[0];
  for (int i = 0; i < k.state_size; ++i) {  // the pressures follow the rates the step reached
    const double* s = &sens[i * 4];
    state[i] += s[0] * dv[0] + s[1] * dv[1] + s[2] * dv[2] + s[3] * dv[3];
  }
  std::memcpy(rates, next, sizeof(next));
  return splits;
}

// One circuit step of h s (CircuitModel._substep): split into stop_split steps where a cylinder runs into its
// stop within it faster than stop_split_speed.
int Substep(const Circuit& k, const ValveAreas& valve, double h, double* state, double* rates, double* ext,
            const double* arms, const double* mass, const double* load, Workspace& w) {
  const double lo = k.law[kLawStopClearance], fast = k.law[kLawStopSplitSpeed];
  bool split = false;
  for (int c = 0; c < kNumCylinders; ++c) {
    double v = arms[c] * rates[c + 1], reach = ext[c] + v * h;
    split |= (reach > k.stroke[c] - lo && v > fast) || (reach < lo && v < -fast);
  }
  int n = split ? static_cast<int>(k.law[kLawStopSplit]) : 1, splits = 0;
  for (int s = 0; s < n; ++s) {
    BranchAreas(k, valve, ext, w.area);
    splits += JointStep(k, h / n, state, rates, ext, arms, mass, load, w);
  }
  return splits;
}

// ---- reading the packed numbers ----------------------------------------------------------------
int Extent(CircuitExtent per, const int* counts) {
  switch (per) {
    case kPerOne: return 1;
    case kPerNodes: return counts[0];
    case kPerBranches: return counts[1];
    case kPerSections: return counts[2];
    case kPerRegenerations: return counts[3];
    case kPerPumps: return kNumPumps;
    case kPerFunctions: return kNumFunctions;
    case kPerCylinders: return kNumCylinders;
  }
  return 0;
}

// An index in [lowest, limit) (lowest -1: an optional one, -1 for none).
int Index(double v, int limit, const char* field, int lowest = 0) {
  if (!(v >= lowest && v < limit && v == std::floor(v))) {
    throw CircuitError(std::string("circuit field '") + field + "' holds " + std::to_string(v) +
                       ", not an index below " + std::to_string(limit) + (lowest < 0 ? " (or -1)" : ""));
  }
  return static_cast<int>(v);
}

}  // namespace

double ValveTable::operator()(double x) const {
  int n = static_cast<int>(nodes.size());
  double lo = nodes[0], hi = nodes[n - 1];
  double v = x < lo ? lo : x > hi ? hi : x;
  int i;
  double t;
  if (inv_step > 0.0) {  // an even axis: the cell from the spacing
    double pos = (v - lo) * inv_step;
    i = std::min(static_cast<int>(pos), n - 2);
    t = pos - i;
  } else {  // the last node at or below v
    i = static_cast<int>(std::upper_bound(nodes.begin(), nodes.end(), v) - nodes.begin()) - 1;
    i = std::min(std::max(i, 0), n - 2);
    t = (v - nodes[i]) / (nodes[i + 1] - nodes[i]);
  }
  return values[i] + t * (values[i + 1] - values[i]);
}

ValveTable MakeValveTable(const double* nodes, const double* values, int n) {
  if (n < 2) throw CircuitError("a valve table needs at least 2 nodes, got " + std::to_string(n));
  ValveTable t;
  t.nodes.assign(nodes, nodes + n);
  t.values.assign(values, values + n);
  double step = (nodes[n - 1] - nodes[0]) / (n - 1);
  bool even = step > 0.0;
  for (int i = 0; i + 1 < n; ++i) {
    if (!(nodes[i + 1] > nodes[i])) throw CircuitError("a valve table's nodes must ascend");
    even = even && std::fabs((nodes[i + 1] - nodes[i]) - (nodes[1] - nodes[0])) <= kUniformRtol * std::fabs(nodes[1] - nodes[0]);
  }
  t.inv_step = even ? (n - 1) / (nodes[n - 1] - nodes[0]) : 0.0;
  return t;
}

Circuit::Circuit(const double* numbers, int count, std::vector<ValveTable> tables) {
  if (count < kNumCircuitCounts) {
    throw CircuitError("circuit numbers: fewer than the " + std::to_string(kNumCircuitCounts) +
                       " counts (nodes, branches, sections, regenerations)");
  }
  int counts[kNumCircuitCounts];
  const int limits[kNumCircuitCounts] = {kMaxNodes, kMaxBranches, kMaxSections, kMaxRegenerations};
  const int lowest[kNumCircuitCounts] = {2, 1, kNumFunctions, 0};
  const char* names[kNumCircuitCounts] = {"nodes", "branches", "sections", "regenerations"};
  for (int i = 0; i < kNumCircuitCounts; ++i) {
    counts[i] = static_cast<int>(numbers[i]);
    if (!(numbers[i] == counts[i] && counts[i] >= lowest[i] && counts[i] <= limits[i])) {
      throw CircuitError("circuit numbers: " + std::to_string(numbers[i]) + " " + names[i] + " (" +
                         std::to_string(lowest[i]) + " to " + std::to_string(limits[i]) + ")");
    }
  }
  nodes = counts[0], branches = counts[1], sections = counts[2], regenerations = counts[3];
  state_size = nodes + kNumPumps;
  const double* field[kNumCircuitFields];
  int at = kNumCircuitCounts;
  for (int i = 0; i < kNumCircuitFields; ++i) {
    field[i] = numbers + at;
    at += kCircuitFields[i].rows * Extent(kCircuitFields[i].per, counts);
  }
  if (at != count) {
    throw CircuitError("circuit numbers: " + std::to_string(count) + " numbers where the layout of " +
                       std::to_string(nodes) + " nodes, " + std::to_string(branches) + " branches, " +
                       std::to_string(sections) + " sections and " + std::to_string(regenerations) +
                       " regeneration passages needs " + std::to_string(at));
  }
  for (int i = 0; i < count; ++i) {
    if (!std::isfinite(numbers[i])) throw CircuitError("circuit numbers: number " + std::to_string(i) + " is not finite");
  }
  std::memcpy(law, field[kFieldLaws], sizeof(law));
  auto ints = [&](int id, int n, int limit, int* out, int lowest = 0) {
    for (int i = 0; i < n; ++i) out[i] = Index(field[id][i], limit, kCircuitFields[id].name, lowest);
  };
  int num_tables = static_cast<int>(tables.size());
  from.resize(branches), to.resize(branches), pilot.resize(branches);
  ints(kFieldBranchFrom, branches, nodes + 1, from.data());
  ints(kFieldBranchTo, branches, nodes + 1, to.data());
  ints(kFieldBranchPilot, branches, nodes, pilot.data(), -1);
  area.assign(field[kFieldBranchArea], field[kFieldBranchArea] + branches);
  crack.assign(field[kFieldBranchCrack], field[kFieldBranchCrack] + branches);
  inv_span.assign(field[kFieldBranchInvSpan], field[kFieldBranchInvSpan] + branches);
  laminar.assign(field[kFieldBranchLaminar], field[kFieldBranchLaminar] + branches);
  for (int b = 0; b < branches; ++b) {
    if (pilot[b] >= 0 && !(inv_span[b] > 0.0)) {
      throw CircuitError("circuit field 'branch_pilot': branch " + std::to_string(b) +
                         " has a pilot but is no pressure-operated valve (branch_inv_span 0)");
    }
  }
  std::vector<int> used(num_tables, 0);
  auto table = [&](double v, const char* what) {
    int t = Index(v, num_tables, what, -1);
    if (t >= 0) ++used[t];
    return t;
  };
  section.resize(sections);
  for (int i = 0; i < sections; ++i) {
    Section& s = section[i];
    s.function = Index(field[kFieldSectionFunction][i], kNumFunctions, "section_function");
    s.pump = Index(field[kFieldSectionPump][i], kNumPumps, "section_pump");
    for (int j = 0; j < kNumPassages; ++j) {
      s.table[j] = table(field[kFieldSectionTable][kNumPassages * i + j], "section_table");
    }
    for (int j = 0; j < 4; ++j) {
      s.branch[j] = Index(field[kFieldSectionBranch][4 * i + j], branches, "section_branch", -1);
    }
    if (s.table[kBypass] < 0) {
      throw CircuitError("circuit field 'section_table': section " + std::to_string(i) + " has no bypass table");
    }
    for (int j = 0; j < 4; ++j) {
      if ((s.table[j + 1] < 0) != (s.branch[j] < 0)) {
        throw CircuitError("circuit fields 'section_table', 'section_branch': section " + std::to_string(i) +
                           " has a passage's table without its branch, or its branch without its table");
      }
    }
    s.raise_only = s.table[kPb] < 0 && s.table[kAt] < 0;
    s.lower_only = s.table[kPa] < 0 && s.table[kBt] < 0;
    const double* priority = field[kFieldSectionPriority] + 3 * i;
    s.priority_function = Index(priority[0], kNumFunctions, "section_priority", -1);
    s.priority_side = Index(priority[1] + 1, 3, "section_priority (side + 1)") - 1;
    s.priority_share = priority[2];
    series[s.pump].push_back(i);
  }
  regeneration.resize(regenerations);
  for (int r = 0; r < regenerations; ++r) {
    const double* row = field[kFieldRegeneration] + 7 * r;
    Regeneration& g = regeneration[r];
    g.branch = Index(row[0], branches, "regeneration (branch)");
    g.function = Index(row[1], kNumFunctions, "regeneration (function)");
    g.side = Index(row[2] + 1, 3, "regeneration (side + 1)") - 1;
    g.table = table(row[3], "regeneration (table)");
    g.area = row[4];
    g.cylinder = Index(row[5], kNumCylinders, "regeneration (cylinder)", -1);
    g.end = Index(row[6] + 1, 3, "regeneration (end + 1)") - 1;
    if (g.side == 0) {
      throw CircuitError("circuit field 'regeneration': passage " + std::to_string(r) + " opens on no side");
    }
  }
  for (int t = 0; t < num_tables; ++t) {
    if (used[t] != 1) {
      throw CircuitError("the valve's table " + std::to_string(t) + " of " + std::to_string(num_tables) +
                         " is used by " + std::to_string(used[t]) +
                         " passages of the circuit, not one (tables of another layout?)");
    }
  }
  ints(kFieldBypassBranch, kNumPumps, branches, bypass_branch);
  ints(kFieldPumpNode, kNumPumps, nodes, pump_node);
  ints(kFieldSignalNode, kNumPumps, nodes, signal_node);
  std::memcpy(head_area, field[kFieldHeadArea], sizeof(head_area));
  std::memcpy(rod_area, field[kFieldRodArea], sizeof(rod_area));
  std::memcpy(stroke, field[kFieldStroke], sizeof(stroke));
  std::memcpy(this->count, field[kFieldCylinderCount], sizeof(this->count));
  std::memcpy(port_volume, field[kFieldPortVolume], sizeof(port_volume));
  ints(kFieldHeadNode, kNumCylinders, nodes, head_node);
  ints(kFieldRodNode, kNumCylinders, nodes, rod_node);
  ints(kFieldFunction, kNumCylinders, sections, function);
  node_volume.assign(field[kFieldNodeVolume], field[kFieldNodeVolume] + nodes);
  displacement.assign(field[kFieldDisplacement], field[kFieldDisplacement] + 4 * nodes);
  Index(law[kLawSwingA], nodes, "laws: swing_a");
  Index(law[kLawSwingB], nodes, "laws: swing_b");
  if (!(law[kLawMaxSplits] >= 0 && law[kLawMaxSplits] <= 30)) throw CircuitError("laws: max_splits must be 0 to 30");
  valve = std::move(tables);
  for (int j = 0; j < kNumPumps; ++j) {  // LearnedValve: the mean of its sections' bypass tables at neutral
    if (series[j].empty()) {
      throw CircuitError("circuit field 'section_pump': pump " + std::to_string(j + 1) + " feeds no section");
    }
    double neutral = 0.0;
    for (int i : series[j]) neutral += valve[section[i].table[kBypass]](0.0);
    neutral /= static_cast<double>(series[j].size());
    if (!(neutral > 0.0)) {
      throw CircuitError("the bypass tables give a closed centre at neutral on pump " + std::to_string(j + 1));
    }
    neutral_term[j] = static_cast<double>(series[j].size() - 1) * (1.0 / (neutral * neutral));
  }
}

void InitialState(const Circuit& k, const double* holding, double* y) {
  const double* law = k.law;
  double rest = law[kLawRestPressure];
  for (int i = 0; i < k.nodes; ++i) y[i] = rest;
  for (int j = 0; j < kNumPumps; ++j) {
    y[k.pump_node[j]] = y[k.signal_node[j]] = law[kLawIdlePressure];
    y[k.nodes + j] = law[kLawIdleFraction];
  }
  for (int c = 0; c < kNumCylinders; ++c) {
    double f = holding[c];
    bool push = f >= 0.0;
    y[k.head_node[c]] = push ? (f + rest * k.rod_area[c]) / k.head_area[c] : rest;
    y[k.rod_node[c]] = push ? rest : (-f + rest * k.head_area[c]) / k.rod_area[c];
  }
}

bool Diverged(const Circuit& k, const double* state, const double* rates, const double* travel) {
  for (int i = 0; i < k.nodes; ++i) {
    if (!(std::fabs(state[i]) <= k.law[kLawFaultPressure])) return true;  // NaN too
  }
  for (int i = k.nodes; i < k.state_size; ++i) {
    if (!std::isfinite(state[i])) return true;
  }
  for (int j = 0; j < 4; ++j) {
    if (!std::isfinite(rates[j]) || !std::isfinite(travel[j])) return true;
  }
  return false;
}

int ControlPeriod(const Circuit& k, const double* spools, double* state, double* rates, double* ext,
                  const double* arms, const double* mass, const double* load, double h, int substeps,
                  double* travel) {
  ValveAreas valve = Valve(k, spools);
  Workspace w;
  double state0[kMaxState], rates0[4], ext0[kNumCylinders];
  std::memcpy(state0, state, sizeof(double) * k.state_size);
  std::memcpy(rates0, rates, sizeof(rates0));
  std::memcpy(ext0, ext, sizeof(ext0));
  int splits = 0;
  // A period that diverges (its linearised steps overshoot where the oil's stiffness jumps) is run again from
  // its start in steps kRefine times shorter, up to kMaxRefine: the caller meets a diverged state only if
  // that fails too.
  for (int refine = 1;; refine *= kRefine) {
    double dt = h / refine;
    for (int j = 0; j < 4; ++j) travel[j] = 0.0;
    for (int s = 0; s < substeps * refine; ++s) {
      splits += Substep(k, valve, dt, state, rates, ext, arms, mass, load, w);
      for (int j = 0; j < 4; ++j) travel[j] += rates[j] * dt;
    }
    if (refine >= kMaxRefine || !Diverged(k, state, rates, travel)) return splits;
    std::memcpy(state, state0, sizeof(double) * k.state_size);
    std::memcpy(rates, rates0, sizeof(rates0));
    std::memcpy(ext, ext0, sizeof(ext0));
  }
}

void BranchAreasAt(const Circuit& k, const double* spools, const double* ext, double* area) {
  BranchAreas(k, Valve(k, spools), ext, area);
}

void Derivatives(const Circuit& k, const double* y, const double* spools, const double* ext, const double* vel,
                 double swing_rate, double* f, double* jac) {
  Workspace w;
  BranchAreas(k, Valve(k, spools), ext, w.area);
  Evaluate(k, y, ext, vel, swing_rate, w);
  int n = k.state_size;
  for (int i = 0; i < n; ++i) {
    f[i] = w.f[i];
    for (int j = 0; j < n; ++j) jac[i * n + j] = w.jac[i][j];
  }
}

int Step(const Circuit& k, double* y, const double* spools, const double* ext, const double* vel, double swing_rate,
         double dt, double* sens) {
  Workspace w;
  BranchAreas(k, Valve(k, spools), ext, w.area);
  return Advance(k, y, dt, ext, vel, swing_rate, sens, w);
}

double OilForces(const Circuit& k, const double* y, const double* vel, double swing_rate, double* force) {
  return OilLoads(k, y, vel, swing_rate, force);
}

double CouplingDerivatives(const Circuit& k, const double* sens, const double* vel, double* dforce) {
  return Coupling(k, sens, vel, dforce);
}

}  // namespace hexgym
