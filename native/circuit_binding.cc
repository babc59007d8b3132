// The circuit kernel's C interface, for the Python circuit model (hexgym.model.circuit_kernel, through ctypes):
// the same ControlPeriod the plugin runs.
#include <chrono>
#include <cstdio>
#include <cstring>
#include <exception>
#include <vector>

#include "circuit.h"

extern "C" {

// A kernel for `count` circuit numbers and the valve's `num_tables` tables (sizes[i] nodes each, their nodes and
// values concatenated), or null with the reason in error (size bytes).
__attribute__((visibility("default"))) void* hexgym_circuit_new(const double* numbers, int count, const int* sizes,
                                                                int num_tables, const double* nodes,
                                                                const double* values, char* error, int size) {
  try {
    std::vector<hexgym::ValveTable> tables;
    long at = 0;
    for (int i = 0; i < num_tables; ++i) {
      tables.push_back(hexgym::MakeValveTable(nodes + at, values + at, sizes[i]));
      at += sizes[i];
    }
    return new hexgym::Circuit(numbers, count, std::move(tables));
  } catch (const std::exception& e) {
    if (error && size > 0) std::snprintf(error, static_cast<size_t>(size), "%s", e.what());
    return nullptr;
  }
}

__attribute__((visibility("default"))) void hexgym_circuit_free(void* circuit) {
  delete static_cast<hexgym::Circuit*>(circuit);
}

// One control period on the buffer whose slots plugin_interface.h names (kPeriod*); returns the steps split.
__attribute__((visibility("default"))) int hexgym_circuit_period(const void* circuit, double* b, double h,
                                                                int substeps) {
  using namespace hexgym;
  return ControlPeriod(*static_cast<const Circuit*>(circuit), b + kPeriodSpools, b + kPeriodState, b + kPeriodRates,
                       b + kPeriodExt, b + kPeriodArms, b + kPeriodMass, b + kPeriodLoad, h, substeps,
                       b + kPeriodTravel);
}

// The period's pieces (circuit.h), for the tests.
__attribute__((visibility("default"))) void hexgym_circuit_areas(const void* circuit, const double* spools,
                                                                const double* ext, double* area) {
  hexgym::BranchAreasAt(*static_cast<const hexgym::Circuit*>(circuit), spools, ext, area);
}

__attribute__((visibility("default"))) void hexgym_circuit_derivatives(const void* circuit, const double* y,
                                                                      const double* spools, const double* ext,
                                                                      const double* vel, double swing_rate,
                                                                      double* f, double* jac) {
  hexgym::Derivatives(*static_cast<const hexgym::Circuit*>(circuit), y, spools, ext, vel, swing_rate, f, jac);
}

__attribute__((visibility("default"))) int hexgym_circuit_step(const void* circuit, double* y, const double* spools,
                                                              const double* ext, const double* vel,
                                                              double swing_rate, double dt, double* sens) {
  return hexgym::Step(*static_cast<const hexgym::Circuit*>(circuit), y, spools, ext, vel, swing_rate, dt, sens);
}

__attribute__((visibility("default"))) double hexgym_circuit_forces(const void* circuit, const double* y,
                                                                   const double* vel, double swing_rate,
                                                                   double* force) {
  return hexgym::OilForces(*static_cast<const hexgym::Circuit*>(circuit), y, vel, swing_rate, force);
}

__attribute__((visibility("default"))) double hexgym_circuit_coupling(const void* circuit, const double* sens,
                                                                     const double* vel, double* dforce) {
  return hexgym::CouplingDerivatives(*static_cast<const hexgym::Circuit*>(circuit), sens, vel, dforce);
}

// Nanoseconds per control period on the buffer's inputs (plugin_interface.h's kPeriod* slots; the buffer is not
// changed), `repeat` times, timed inside the library so no call overhead counts (hexgym bench's cost split);
// steps_only: the period's `substeps` circuit steps alone, without the joints' coupling.
__attribute__((visibility("default"))) double hexgym_circuit_time(const void* circuit, const double* b, double h,
                                                                 int substeps, int repeat, int steps_only) {
  using namespace hexgym;
  const Circuit& k = *static_cast<const Circuit*>(circuit);
  double state[kMaxState], rates[4], ext[kNumCylinders], travel[4], vel[kNumCylinders], sens[kMaxState * 4];
  auto start = std::chrono::steady_clock::now();
  for (int r = 0; r < repeat; ++r) {
    std::memcpy(state, b + kPeriodState, sizeof(double) * k.state_size);
    std::memcpy(rates, b + kPeriodRates, sizeof(rates));
    std::memcpy(ext, b + kPeriodExt, sizeof(ext));
    if (steps_only) {
      for (int c = 0; c < kNumCylinders; ++c) vel[c] = b[kPeriodArms + c] * rates[c + 1];
      for (int s = 0; s < substeps; ++s) Step(k, state, b + kPeriodSpools, ext, vel, rates[0], h, sens);
    } else {
      ControlPeriod(k, b + kPeriodSpools, state, rates, ext, b + kPeriodArms, b + kPeriodMass, b + kPeriodLoad, h,
                    substeps, travel);
    }
  }
  std::chrono::duration<double, std::nano> elapsed = std::chrono::steady_clock::now() - start;
  return elapsed.count() / (repeat > 0 ? repeat : 1);
}
}
