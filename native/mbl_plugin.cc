// hexgym.mbl: the learned actuator model (paper Sec III) as a MuJoCo actuator plugin.
//
// Four plugin actuators on the joints swing, boom, stick, bucket share one plugin instance;
// their ctrl is the spool position in mm (+-11). Every step, inside mj_fwdActuation, the
// instance does what hexgym.model.python_backend.LearnedModel._control_period does in Python:
//   loads   tau = qfrc_bias - qfrc_passive - qfrc_applied - qfrc_constraint (main dofs),
//           cylinder forces f = tau / (dC/dq)                               (Eqns 4-5)
//   spools  stalled functions (stroke end, relief) closed, dead band -> no flow
//   tables  boom, bucket, stick velocities; swing acceleration integrated to a rate target
//   servo   one of two forms, read from the actuators' gain and affine bias (the same for all four):
//           velocity servo (lean machine, assets/cat325_mbl.xml): biasprm 0 0 -kv,
//             force = kv * target - kv * velocity; the swing's activation (actdim 1) is its rate target;
//           integrated-velocity servo (full machine, assets/cat325_mbl_full.xml, as its intvelocity
//             servos): biasprm 0 -kp -kv, actdim 1 each, act_dot = target, so the activation is a
//             position target (kept within a limited joint's range, as intvelocity's actrange,
//             which MuJoCo allows only with a dyntype), force = kp * act - kp * position - kv * velocity.
//           MuJoCo's implicit integrators treat the -kv (biasprm[2]) implicitly.
// State: the previous step's constraint forces at the four dofs (without the joint limits' share:
// at a stroke end the stop carries the load, not the oil; on the full machine the closed chains'
// equality forces are part of it), the last swing acceleration, the place in the control period
// and the targets held within it (the swing's unclipped rate) are the plugin state (mjSTATE_PLUGIN).
// So mj_getState/mj_setState (mjSTATE_FULLPHYSICS) restore a step exactly.
//
// With the circuit model's table set ("circuit": the tables of the valve layout's passages) a query runs
// the circuit model's control period instead of the tables
// (hexgym.model.circuit_model.CircuitModel._control_period; circuit.cc): the joints' loads, moment arms and
// mass matrix at the period's start, the circuit's steps at the spools, the joints' mean rates over the period
// as the servos' targets. The circuit's structure comes from config key "circuit" (numbers packed by
// hexgym.model.circuit_kernel), its valve from the tables; its pressures, pump displacements and the joints'
// rates are plugin state too (kHydraulics, kRates), so a saved state restores the circuit exactly.
#include <dlfcn.h>
#include <limits.h>
#include <sys/stat.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <memory>
#include <utility>
#include <mutex>
#include <sstream>
#include <string>
#include <vector>

#include <mujoco/mujoco.h>

#include "circuit.h"
#include "linkage.h"
#include "mbl_plugin.h"
#include "mbl_table.h"
#include "plugin_interface.h"

namespace hexgym {
namespace {

// The loaded tables of one table set (kTableSets), in its order.
struct LoadedTables {
  const TableSet* set;
  std::vector<MblTable> tables;

  // The index of table `name` in the set, or -1 when the set has none.
  int Find(const char* name) const {
    for (int i = 0; i < set->num_tables; ++i) {
      if (std::strcmp(set->tables[i].name, name) == 0) return i;
    }
    return -1;
  }
};

// Failure to set up an instance; the message goes to mju_warning (MuJoCo's load error).
class SetupError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

std::string LibraryDirectory() {
  Dl_info info;
  if (dladdr(reinterpret_cast<void*>(&LibraryDirectory), &info) && info.dli_fname) {
    // the real file: a link to it (e.g. in mujoco/plugin/, for MuJoCo's own viewer) has no tables beside it
    char* real = realpath(info.dli_fname, nullptr);
    std::string path = real ? real : info.dli_fname;
    std::free(real);
    size_t slash = path.rfind('/');
    if (slash != std::string::npos) return path.substr(0, slash);
  }
  return ".";
}

const TableSet& FindTableSet(const std::string& name) {
  for (const TableSet& set : kTableSets) {
    if (name == set.name) return set;
  }
  std::string known;
  for (const TableSet& set : kTableSets) known += std::string(known.empty() ? "" : ", ") + set.name;
  throw SetupError("config key 'table_set': unknown table set '" + name + "' (known: " + known + ")");
}

// Tables are immutable once read: one copy per (directory, set, file times) for all models and datas.
std::shared_ptr<const LoadedTables> LoadTables(const std::string& directory, const TableSet& table_set) {
  static std::mutex mutex;
  static std::map<std::string, std::shared_ptr<const LoadedTables>> cache;
  std::string key = directory + "|" + table_set.name;
  for (int i = 0; i < table_set.num_tables; ++i) {
    const TableSchema& spec = table_set.tables[i];
    struct stat st;
    std::string path = directory + "/" + spec.name + ".npz";
    if (stat(path.c_str(), &st) != 0) throw SetupError("MBL table file " + path + " does not exist");
    key += "|" + std::to_string(st.st_mtim.tv_sec) + "." + std::to_string(st.st_mtim.tv_nsec) + ":" +
           std::to_string(st.st_size);
  }
  std::lock_guard<std::mutex> lock(mutex);
  auto it = cache.find(key);
  if (it != cache.end()) return it->second;
  auto set = std::make_shared<LoadedTables>();
  set->set = &table_set;
  for (int i = 0; i < table_set.num_tables; ++i) {
    const TableSchema& spec = table_set.tables[i];
    std::vector<std::string> inputs;
    for (int j = 0; j < spec.num_inputs; ++j) inputs.push_back(kQuantityNames[spec.inputs[j]]);
    try {
      set->tables.emplace_back(directory + "/" + spec.name + ".npz", spec.name, inputs, spec.output);
    } catch (const TableError& e) {
      throw SetupError(e.what());
    }
  }
  cache[key] = set;
  return set;
}

// Every number of config key `key` (count: how many it must hold; 0: any number of them).
std::vector<double> Numbers(const mjModel* m, int instance, const char* key, size_t count) {
  const char* text = mj_getPluginConfig(m, instance, key);
  if (!text || !text[0]) throw SetupError(std::string("config key '") + key + "' is missing");
  std::vector<double> out;
  std::istringstream in(text);
  in.imbue(std::locale::classic());
  std::string word;
  while (in >> word) {
    char* end;
    double v = std::strtod(word.c_str(), &end);
    if (*end || !std::isfinite(v)) throw SetupError(std::string("config key '") + key + "': '" + word + "' is not a number");
    out.push_back(v);
  }
  if (count && out.size() != count) {
    throw SetupError(std::string("config key '") + key + "' needs " + std::to_string(count) + " numbers, got " +
                     std::to_string(out.size()));
  }
  return out;
}

// The circuit of config key "circuit" with the valve of the loaded tables (one copy per numbers and tables).
std::shared_ptr<const Circuit> LoadCircuit(const mjModel* m, int instance, std::shared_ptr<const LoadedTables> tables) {
  static std::mutex mutex;
  static std::map<std::pair<const LoadedTables*, std::vector<double>>, std::shared_ptr<const Circuit>> cache;
  std::vector<double> numbers = Numbers(m, instance, "circuit", 0);
  std::lock_guard<std::mutex> lock(mutex);
  auto key = std::make_pair(tables.get(), numbers);
  auto it = cache.find(key);
  if (it != cache.end()) return it->second;
  std::vector<ValveTable> valve;
  for (const MblTable& t : tables->tables) {
    if (t.dims() != 1) throw SetupError("a circuit table must have one input");
    valve.push_back(MakeValveTable(t.axis_nodes(0).data(), t.values().data(), static_cast<int>(t.values().size())));
  }
  try {
    auto circuit = std::make_shared<const Circuit>(numbers.data(), static_cast<int>(numbers.size()), std::move(valve));
    if (circuit->state_size != kHydraulicsSize) {
      throw SetupError("config key 'circuit': a circuit of " + std::to_string(circuit->state_size) +
                       " states where the plugin state holds " + std::to_string(kHydraulicsSize));
    }
    cache[key] = circuit;  // the tables stay alive in the instance that holds them with this circuit
    return circuit;
  } catch (const CircuitError& e) {
    throw SetupError(std::string("config key 'circuit': ") + e.what());
  }
}

double Number(const mjModel* m, int instance, const char* key) { return Numbers(m, instance, key, 1)[0]; }

Triangle ReadTriangle(const mjModel* m, int instance, const char* key) {
  std::vector<double> v = Numbers(m, instance, key, 6);
  return {{v[0], v[1]}, {v[2], v[3]}, v[4], v[5]};
}

// One instance (per mjData): its config read once from the model (model indices, geometry, limits, tables or
// circuit), and what a step stages between compute and advance.
class MblPlugin {
 public:
  std::shared_ptr<const LoadedTables> tables;
  std::shared_ptr<const Circuit> circuit;  // a circuit model's table set: the circuit model (else null)
  int substeps = 1;                       // the circuit's steps per control period
  int mass_adr[4][4];                     // the main dofs' entries in d->M (CSR, lower triangle), -1: none
  double next_hydraulics[kHydraulicsSize], next_rates[4], next_fault = 0.0;
  int boom_table, bucket_table, stick_table, swing_table;
  Linkage linkage;
  double retracted[3], stroke[3], push_limit[3], pull_limit[3], rate_lo[4], rate_hi[4];
  double end_margin, swing_torque_limit, dead_band, swing_rest_rate;
  int actuator[4], qadr[4], dadr[4];
  int actadr[4], swing_actadr, swing_diag, stateadr;
  bool act_limited[4];                   // integrated servos: the activation stays within the joint's range
  double act_lo[4], act_hi[4];
  bool integrated;                       // integrated-velocity servos (act = position target)
  double slowest_swing, fastest_swing;  // the swing table's rate axis
  double steps_per_period;               // MuJoCo steps per control period (need not be whole)
  double period;                         // the control period, s
  // set by compute, committed by advance (the same mj_step)
  bool queried = false;
  double next_rate = 0.0, swing_acceleration = 0.0, target[4] = {0, 0, 0, 0};
  std::vector<mjtNum> limit_force, limit_qfrc;  // scratch: efc forces of joint-limit rows, J^T of them
  std::vector<bool> machine_body;                // per body: carried by the swinging upper structure
  std::vector<mjtNum> jacp;                       // scratch: a contact point's translation Jacobian

  // The instance of a model's config, or null after a warning naming what is wrong (MuJoCo's load error).
  static MblPlugin* Create(const mjModel* m, int instance) {
    try {
      return new MblPlugin(m, instance);
    } catch (const std::exception& e) {
      mju_warning("hexgym.mbl: %s", e.what());
      return nullptr;
    }
  }

  MblPlugin(const mjModel* m, int instance) {
    const char* set_name = mj_getPluginConfig(m, instance, "table_set");
    const TableSet& table_set = FindTableSet(set_name && set_name[0] ? set_name : kDefaultTableSet);
    const char* dir = mj_getPluginConfig(m, instance, "tables");
    tables = LoadTables(dir && dir[0] ? std::string(dir) : LibraryDirectory() + "/mbl_tables/" + table_set.name,
                        table_set);
    ReadMachine(m, instance);
    if (table_set.circuit) {
      circuit = LoadCircuit(m, instance, tables);
      double n = Number(m, instance, "substeps");
      if (!(n >= 1 && n <= 1000 && n == std::floor(n))) throw SetupError("config key 'substeps' must be a whole number >= 1");
      substeps = static_cast<int>(n);
      FindMass(m);
      return;
    }
    boom_table = tables->Find("boom"), bucket_table = tables->Find("bucket"), stick_table = tables->Find("stick");
    swing_table = tables->Find("swing");
    if (boom_table < 0 || bucket_table < 0 || stick_table < 0 || swing_table < 0) {
      throw SetupError(std::string("table set '") + table_set.name + "' lacks a function's table");
    }
    const TableSchema& swing_spec = table_set.tables[swing_table];
    int rate_axis = 0;
    while (rate_axis < swing_spec.num_inputs && swing_spec.inputs[rate_axis] != kQSwingRateRadps) ++rate_axis;
    if (rate_axis == swing_spec.num_inputs) throw SetupError("the swing table does not read the swing rate");
    const MblTable& swing = tables->tables[swing_table];
    slowest_swing = swing.axis_lo(rate_axis);
    fastest_swing = swing.axis_hi(rate_axis);
  }

  // The linkage, limits, control period and actuators: what both kinds of query need.
  void ReadMachine(const mjModel* m, int instance) {
    linkage.boom = ReadTriangle(m, instance, "boom_triangle");
    linkage.stick = ReadTriangle(m, instance, "stick_triangle");
    std::vector<double> f = Numbers(m, instance, "bucket_four_bar", 11);
    linkage.bucket = {{f[0], f[1]}, {f[2], f[3]}, {f[4], f[5]}, {f[6], f[7]}, f[8], f[9], f[10]};
    auto copy3 = [&](const char* key, double* out) {
      std::vector<double> v = Numbers(m, instance, key, 3);
      for (int i = 0; i < 3; ++i) out[i] = v[i];
    };
    copy3("retracted_length", retracted);
    copy3("stroke", stroke);
    copy3("push_limit", push_limit);
    copy3("pull_limit", pull_limit);
    std::vector<double> r = Numbers(m, instance, "rate_range", 8);
    for (int i = 0; i < 4; ++i) rate_lo[i] = r[2 * i], rate_hi[i] = r[2 * i + 1];
    end_margin = Number(m, instance, "end_margin");
    swing_torque_limit = Number(m, instance, "swing_torque_limit");
    dead_band = Number(m, instance, "dead_band");
    swing_rest_rate = Number(m, instance, "swing_rest_rate");
    const char* period_text = mj_getPluginConfig(m, instance, "control_period");
    double wanted = period_text && period_text[0] ? Number(m, instance, "control_period") : m->opt.timestep;
    // steps per period, rounded to a multiple of 2^-20 so that the phase arithmetic is exact
    steps_per_period = std::ldexp(std::round(std::ldexp(wanted / m->opt.timestep, 20)), -20);
    if (steps_per_period < 1.0) {
      throw SetupError("control_period " + std::to_string(wanted) + " s is shorter than the step " +
                       std::to_string(m->opt.timestep) + " s");
    }
    period = wanted;
    FindActuators(m, instance);
    stateadr = m->plugin_stateadr[instance];
  }

  // Where each pair of main dofs sits in d->M (its lower triangle in CSR rows).
  void FindMass(const mjModel* m) {
    for (int i = 0; i < 4; ++i) {
      for (int j = 0; j < 4; ++j) {
        int r = std::max(dadr[i], dadr[j]), c = std::min(dadr[i], dadr[j]);
        mass_adr[i][j] = -1;
        for (int a = m->M_rowadr[r]; a < m->M_rowadr[r] + m->M_rownnz[r]; ++a) {
          if (m->M_colind[a] == c) mass_adr[i][j] = a;
        }
      }
    }
  }

  void FindActuators(const mjModel* m, int instance) {
    bool kind[4];  // integrated-velocity servo
    for (int k = 0; k < 4; ++k) actuator[k] = -1;
    for (int i = 0; i < m->nu; ++i) {
      if (m->actuator_plugin[i] != instance) continue;
      const char* joint = m->actuator_trntype[i] == mjTRN_JOINT ? mj_id2name(m, mjOBJ_JOINT, m->actuator_trnid[2 * i])
                                                                : nullptr;
      int k = 0;
      while (k < 4 && !(joint && std::strcmp(joint, kJoints[k]) == 0)) ++k;
      if (k == 4) throw SetupError("actuator " + std::to_string(i) + " must act on joint swing, boom, stick or bucket");
      const mjtNum* bias = m->actuator_biasprm + mjNBIAS * i;
      bool servo = m->actuator_gaintype[i] == mjGAIN_FIXED && m->actuator_biastype[i] == mjBIAS_AFFINE &&
                   bias[0] == 0 && bias[2] < 0;
      bool velocity = servo && bias[1] == 0, position = servo && bias[1] == -m->actuator_gainprm[mjNGAIN * i];
      if (!velocity && !position) {
        throw SetupError(std::string("actuator on ") + kJoints[k] +
                         " must be a velocity servo (gaintype fixed kv, biastype affine, biasprm 0 0 -kv) or an"
                         " integrated-velocity servo (gaintype fixed kp, biastype affine, biasprm 0 -kp -kv)");
      }
      if (actuator[k] >= 0) throw SetupError(std::string("two actuators on joint ") + kJoints[k]);
      kind[k] = position;
      actuator[k] = i;
      actadr[k] = m->actuator_actadr[i];
      int joint_id = m->actuator_trnid[2 * i];
      act_limited[k] = m->jnt_limited[joint_id];
      act_lo[k] = m->jnt_range[2 * joint_id];
      act_hi[k] = m->jnt_range[2 * joint_id + 1];
      qadr[k] = m->jnt_qposadr[joint_id];
      dadr[k] = m->jnt_dofadr[joint_id];
    }
    for (int k = 0; k < 4; ++k) {
      if (actuator[k] < 0) throw SetupError(std::string("no plugin actuator on joint ") + kJoints[k]);
    }
    integrated = kind[0];
    for (int k = 0; k < 4; ++k) {
      int i = actuator[k], actdim = (k == 0 || integrated) ? 1 : 0;
      if (kind[k] != integrated) {
        throw SetupError(std::string("actuator on ") + kJoints[k] + " is not the same kind of servo as the swing's");
      }
      if (m->actuator_actnum[i] != actdim || m->actuator_dyntype[i] != mjDYN_NONE) {
        throw SetupError(std::string("actuator on ") + kJoints[k] + " needs actdim=" + std::to_string(actdim) +
                         " and no dyntype (" +
                         (integrated ? "an integrated-velocity servo's activation is its position target"
                                     : "a velocity servo's swing keeps its rate target as activation") +
                         ")");
      }
    }
    swing_actadr = m->actuator_actadr[actuator[0]];
    int upper = mj_name2id(m, mjOBJ_BODY, kUpperBody);
    if (upper < 0) throw SetupError(std::string("the model has no body '") + kUpperBody + "' (the swinging structure)");
    machine_body.assign(m->nbody, false);
    for (int b = 0; b < m->nbody; ++b) {
      for (int a = b; a > 0 && !machine_body[b]; a = m->body_parentid[a]) machine_body[b] = (a == upper);
    }
    swing_diag = m->M_rowadr[dadr[0]] + m->M_rownnz[dadr[0]] - 1;  // a CSR row's diagonal is its last entry
  }

  // LearnedModel._control_period, from the MuJoCo state, ending in the servo forces.
  void Compute(const mjModel* m, mjData* d) {
    const mjtNum* state = d->plugin_state + stateadr;
    queried = state[kPhase] < 1.0;  // the first step at or after a period boundary
    if (queried && circuit) {
      QueryCircuit(m, d, state);
    } else if (queried) {
      Query(m, d, state + kLoad);
    } else {  // between queries the servos hold the last targets (the Python path holds its ctrl)
      next_rate = state[kTargets];
      for (int k = 0; k < 4; ++k) target[k] = std::fmin(std::fmax(state[kTargets + k], rate_lo[k]), rate_hi[k]);
      if (!integrated) {
        next_rate = d->act[swing_actadr];
        d->act_dot[swing_actadr] = 0.0;
      }
    }
    for (int k = 0; k < 4; ++k) {
      int i = actuator[k];
      const mjtNum* bias = m->actuator_biasprm + mjNBIAS * i;
      int out = m->actuator_outadr[i];
      double b = bias[0] + bias[1] * d->actuator_length[out] + bias[2] * d->actuator_velocity[out];
      double input = target[k];
      if (integrated) {  // as MuJoCo's intvelocity: the activation integrates the rate target
        d->act_dot[actadr[k]] = target[k];
        input = d->act[actadr[k]];
      }
      double force = m->actuator_gainprm[mjNGAIN * i] * input + b;
      if (m->actuator_forcelimited[i]) {
        force = std::fmin(std::fmax(force, m->actuator_forcerange[2 * i]), m->actuator_forcerange[2 * i + 1]);
      }
      d->actuator_force[out] = force;
    }
  }

  // The tables' joint-rate targets (clipped to the servo ranges) and the swing's next rate.
  void Query(const mjModel* m, mjData* d, const mjtNum* constraint) {
    double tau[4], u[4], arms[3], f[3];
    for (int k = 0; k < 4; ++k) {
      int v = dadr[k];
      tau[k] = d->qfrc_bias[v] - d->qfrc_passive[v] - d->qfrc_applied[v] - constraint[k];
      double mm = d->ctrl[m->actuator_ctrladr[actuator[k]]];
      u[k] = std::isfinite(mm) ? mm / kCtrlPerSpoolMetre : 0.0;
    }
    for (int c = 0; c < 3; ++c) {
      double length;
      linkage.Cylinder(c, d->qpos[qadr[c + 1]], &length, &arms[c]);
      f[c] = tau[c + 1] / arms[c];
      // a stalled function passes no flow: driven into a stroke end or beyond its relief
      double ext = length - retracted[c];
      bool extending = u[c + 1] > 0, retracting = u[c + 1] < 0;
      bool stalled = (ext <= end_margin && retracting) || (ext >= stroke[c] - end_margin && extending) ||
                     (extending && f[c] > push_limit[c]) || (retracting && f[c] < -pull_limit[c]);
      if (stalled) u[c + 1] = 0.0;
    }
    if (std::fabs(tau[0]) > swing_torque_limit && tau[0] * u[0] > 0) u[0] = 0.0;
    double inertia = d->M[swing_diag];
    bool closed[4];
    for (int k = 0; k < 4; ++k) closed[k] = std::fabs(u[k]) < dead_band;
    double rate = integrated ? d->plugin_state[stateadr + kTargets] : d->act[swing_actadr];
    double q[kNumQuantities];
    q[kQSwingSpoolM] = u[0], q[kQBoomSpoolM] = u[1], q[kQStickSpoolM] = u[2], q[kQBucketSpoolM] = u[3];
    q[kQBoomForceN] = f[0], q[kQStickForceN] = f[1], q[kQBucketForceN] = f[2];
    q[kQSwingInertiaKgm2] = inertia, q[kQSwingRateRadps] = rate;
    double v_boom = closed[1] ? 0.0 : Lookup(boom_table, q);
    double v_bucket = closed[3] ? 0.0 : Lookup(bucket_table, q);
    double v_stick = closed[2] ? 0.0 : Lookup(stick_table, q);
    swing_acceleration = Lookup(swing_table, q);
    if (!(slowest_swing < rate && rate < fastest_swing) && swing_acceleration * rate > 0.0) {
      // the table clamps the rate to its grid (the fastest swing in its data): beyond it, it
      // would keep accelerating at that edge's value; it must not go faster
      swing_acceleration = 0.0;
    }
    double dt = period;
    double new_rate = rate + swing_acceleration * dt;
    if (closed[0] && (new_rate * rate <= 0.0 || std::fabs(new_rate) < swing_rest_rate)) {
      new_rate = 0.0;  // braked by the crossover reliefs: it stops, it does not turn back
    }
    double wanted[4] = {new_rate, v_boom / arms[0], v_stick / arms[1], v_bucket / arms[2]};
    bool blocked[4];
    StallAtContacts(m, d, wanted, blocked);
    next_rate = wanted[0];
    if (!integrated) d->act_dot[swing_actadr] = (next_rate - rate) / m->opt.timestep;
    for (int k = 0; k < 4; ++k) target[k] = std::fmin(std::fmax(wanted[k], rate_lo[k]), rate_hi[k]);
  }

  // The circuit model's control period (CircuitModel._control_period): the joints' rate targets (clipped to the
  // servo ranges) from their travel over the period, the circuit's state and the rates at its end staged.
  void QueryCircuit(const mjModel* m, mjData* d, const mjtNum* state) {
    double load[4], spools[4], arms[3], ext[3], mass[16], rates[4], travel[4] = {0, 0, 0, 0};
    for (int k = 0; k < 4; ++k) {
      int v = dadr[k];
      load[k] = d->qfrc_bias[v] - d->qfrc_passive[v] - d->qfrc_applied[v] - state[kLoad + k];
      double mm = d->ctrl[m->actuator_ctrladr[actuator[k]]];
      spools[k] = std::isfinite(mm) ? mm / kCtrlPerSpoolMetre : 0.0;
      for (int j = 0; j < 4; ++j) mass[4 * k + j] = mass_adr[k][j] < 0 ? 0.0 : d->M[mass_adr[k][j]];
    }
    for (int c = 0; c < 3; ++c) {
      double length;
      linkage.Cylinder(c, d->qpos[qadr[c + 1]], &length, &arms[c]);
      ext[c] = length - retracted[c];
    }
    double ready = state[kCircuitReady];
    next_fault = state[kCircuitFault];
    std::memcpy(next_hydraulics, state + kHydraulics, sizeof(next_hydraulics));
    std::memcpy(rates, state + kRates, sizeof(rates));
    if (ready == 0.0) {  // after a reset: the chambers hold the loads, the joints at rest
      double holding[3] = {load[1] / arms[0], load[2] / arms[1], load[3] / arms[2]};
      InitialState(*circuit, holding, next_hydraulics);
      for (double& r : rates) r = 0.0;
    }
    if (ready >= 0.0 && next_fault == 0.0) {  // ready -1: the reset's settling step, held still
      double y[kHydraulicsSize];
      std::memcpy(y, next_hydraulics, sizeof(y));
      ControlPeriod(*circuit, spools, y, rates, ext, arms, mass, load, period / substeps, substeps, travel);
      if (!Diverged(*circuit, y, rates, travel)) {
        std::memcpy(next_hydraulics, y, sizeof(y));
      } else {  // the machine holds still; the Python side raises, naming the state
        next_fault = 1.0;  // said once on stderr (mju_warning would write MUJOCO_LOG.TXT into the working directory)
        std::fprintf(stderr, "hexgym.mbl: the circuit's state diverged at t = %g s; the machine holds still\n",
                     d->time);
      }
    }
    if (next_fault != 0.0 || ready < 0.0) {
      for (int k = 0; k < 4; ++k) rates[k] = travel[k] = 0.0;
    }
    double wanted[4];
    for (int k = 0; k < 4; ++k) wanted[k] = travel[k] / period;
    bool blocked[4];
    StallAtContacts(m, d, wanted, blocked);
    for (int k = 0; k < 4; ++k) next_rates[k] = blocked[k] ? 0.0 : rates[k];
    double rate = integrated ? state[kTargets] : d->act[swing_actadr];
    swing_acceleration = 0.0;  // the circuit integrates the swing itself
    next_rate = wanted[0];
    if (!integrated) d->act_dot[swing_actadr] = (next_rate - rate) / m->opt.timestep;
    for (int k = 0; k < 4; ++k) target[k] = std::fmin(std::fmax(wanted[k], rate_lo[k]), rate_hi[k]);
  }

  // Table `table` at the quantities q, its inputs gathered in the schema's order.
  double Lookup(int table, const double* q) const {
    const TableSchema& spec = tables->set->tables[table];
    double x[kMaxTableInputs];
    for (int j = 0; j < spec.num_inputs; ++j) x[j] = q[spec.inputs[j]];
    return tables->tables[table](x);
  }

  // LearnedModel.blocked_by_contact: a joint whose rate would move a contact point of the machine
  // along the contact normal into the other body (ground, truck) stalls (its rate becomes 0; blocked says which).
  void StallAtContacts(const mjModel* m, mjData* d, double* rates, bool* blocked) {
    for (int k = 0; k < 4; ++k) blocked[k] = false;
    for (int i = 0; i < d->ncon; ++i) {
      const mjContact& c = d->contact[i];
      if (c.dist >= 0.0) continue;  // not touching
      int b1 = m->geom_bodyid[c.geom1], b2 = m->geom_bodyid[c.geom2];
      bool mine1 = machine_body[b1], mine2 = machine_body[b2];
      if (mine1 == mine2) continue;
      int body = mine1 ? b1 : b2;
      double sign = mine1 ? 1.0 : -1.0;  // the normal points from geom1 to geom2
      jacp.assign(3 * m->nv, 0.0);
      mj_jac(m, d, jacp.data(), nullptr, c.pos, body);
      for (int k = 0; k < 4; ++k) {
        int v = dadr[k];
        double approach = sign * (c.frame[0] * jacp[v] + c.frame[1] * jacp[m->nv + v] + c.frame[2] * jacp[2 * m->nv + v]);
        if (approach * rates[k] > 0.0) blocked[k] = true;
      }
    }
    for (int k = 0; k < 4; ++k) {
      if (blocked[k]) rates[k] = 0.0;
    }
  }

  // After integration: the rate target exactly (not act + dt * act_dot), and this step's
  // constraint forces, which the next step's loads need.
  void Advance(const mjModel* m, mjData* d) {
    if (!integrated) d->act[swing_actadr] = next_rate;
    for (int k = 0; integrated && k < 4; ++k) {  // MuJoCo integrated act_dot; the stop bounds the target
      if (act_limited[k]) d->act[actadr[k]] = std::fmin(std::fmax(d->act[actadr[k]], act_lo[k]), act_hi[k]);
    }
    mjtNum* state = d->plugin_state + stateadr;
    for (int k = 0; k < 4; ++k) state[kLoad + k] = d->qfrc_constraint[dadr[k]];
    SubtractJointLimits(m, d, state + kLoad);
    if (queried) {
      state[kAcceleration] = swing_acceleration;
      for (int k = 0; k < 4; ++k) state[kTargets + k] = target[k];
      state[kTargets] = next_rate;  // the swing's rate, unclipped (the servo clips it when used)
      if (circuit) {
        std::memcpy(state + kHydraulics, next_hydraulics, sizeof(next_hydraulics));
        std::memcpy(state + kRates, next_rates, sizeof(next_rates));
        state[kCircuitReady] = state[kCircuitReady] < 0.0 ? 0.0 : 1.0;
        state[kCircuitFault] = next_fault;
      }
    }
    // whole periods are subtracted, not the phase zeroed: a period of 12.5 steps alternates 13 and 12
    double phase = state[kPhase] + 1.0;
    state[kPhase] = phase >= steps_per_period ? phase - steps_per_period : phase;
  }

  // load[k] -= the joint-limit rows' share of qfrc_constraint at dof k (J^T f over those rows).
  void SubtractJointLimits(const mjModel* m, mjData* d, mjtNum* load) {
    bool any = false;
    for (int i = 0; i < d->nefc && !any; ++i) any = d->efc_type[i] == mjCNSTR_LIMIT_JOINT;
    if (!any) return;
    limit_force.assign(d->nefc, 0.0);
    limit_qfrc.assign(m->nv, 0.0);
    for (int i = 0; i < d->nefc; ++i) {
      if (d->efc_type[i] == mjCNSTR_LIMIT_JOINT) limit_force[i] = d->efc_force[i];
    }
    mj_mulJacTVec(m, d, limit_qfrc.data(), limit_force.data());
    for (int k = 0; k < 4; ++k) load[k] -= limit_qfrc[dadr[k]];
  }
};

MblPlugin* Get(const mjData* d, int instance) { return reinterpret_cast<MblPlugin*>(d->plugin_data[instance]); }

}  // namespace

void RegisterMblPlugin() {
  mjpPlugin plugin;
  mjp_defaultPlugin(&plugin);
  plugin.name = kPluginName;
  plugin.capabilityflags |= mjPLUGIN_ACTUATOR;
  plugin.nattribute = kNumAttributes;
  plugin.attributes = kAttributes;
  plugin.nstate = +[](const mjModel*, int) { return kStateSize; };
  plugin.init = +[](const mjModel* m, mjData* d, int instance) {
    MblPlugin* created = MblPlugin::Create(m, instance);
    d->plugin_data[instance] = reinterpret_cast<uintptr_t>(created);
    return created ? 0 : -1;
  };
  plugin.destroy = +[](mjData* d, int instance) {
    delete Get(d, instance);
    d->plugin_data[instance] = 0;
  };
  plugin.copy = +[](mjData* dest, const mjModel*, const mjData* src, int instance) {
    dest->plugin_data[instance] = reinterpret_cast<uintptr_t>(new MblPlugin(*Get(src, instance)));
  };
  plugin.reset = +[](const mjModel*, mjtNum* state, void* data, int) {
    for (int i = 0; i < kStateSize; ++i) state[i] = 0.0;
    if (data) {
      auto* in = static_cast<MblPlugin*>(data);
      in->next_rate = in->swing_acceleration = 0.0;
    }
  };
  plugin.compute = +[](const mjModel* m, mjData* d, int instance, int) { Get(d, instance)->Compute(m, d); };
  plugin.advance = +[](const mjModel* m, mjData* d, int instance) { Get(d, instance)->Advance(m, d); };
  mjp_registerPlugin(&plugin);
}

}  // namespace hexgym
