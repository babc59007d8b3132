// hexgym.clearance: the least signed distance (m) from one tool geom to a set of obstacle geoms, at
// most a cutoff -- what MuJoCo's geomdist sensors of the pairs read, min-ed -- as one sensor value.
//
// Why a plugin: a geomdist sensor runs the narrow phase (GJK for a mesh against a box) on every pair
// at every step, however far apart the geoms are. Here a pair is measured only when a cheap lower
// bound of its distance is within the cutoff; else its distance is beyond the cutoff and reads as it
// either way, so the reading is the same. The bound: the distance from the tool's bounding sphere
// (around its local bounding box) to the obstacle's bounding box in the obstacle's frame, or to the
// obstacle's plane.
//
// Config (hexgym/model/plugin.py CLEARANCE_CONFIG_KEYS): tool (a geom name), obstacles (geom names,
// space-separated), cutoff (m, > 0). Stage: positions. No state.
#include "clearance_plugin.h"

#include <cmath>
#include <cstdlib>
#include <exception>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include <mujoco/mujoco.h>

#include "plugin_interface.h"

namespace hexgym {
namespace {

struct Clearance {
  int tool = -1;
  std::vector<int> obstacles;
  mjtNum cutoff = 0.0;
  int sensor_adr = -1;  // where the instance's one value goes in sensordata
};

Clearance* Get(const mjData* d, int instance) { return reinterpret_cast<Clearance*>(d->plugin_data[instance]); }

int GeomId(const mjModel* m, const std::string& name) {
  int id = mj_name2id(m, mjOBJ_GEOM, name.c_str());
  if (id < 0) throw std::runtime_error("no geom named '" + name + "'");
  return id;
}

Clearance Configure(const mjModel* m, int instance) {
  Clearance c;
  const char* tool = mj_getPluginConfig(m, instance, "tool");
  c.tool = GeomId(m, tool ? tool : "");
  const char* obstacles = mj_getPluginConfig(m, instance, "obstacles");
  std::istringstream names(obstacles ? obstacles : "");
  for (std::string name; names >> name;) c.obstacles.push_back(GeomId(m, name));
  if (c.obstacles.empty()) throw std::runtime_error("obstacles names no geom");
  const char* cutoff = mj_getPluginConfig(m, instance, "cutoff");
  char* end = nullptr;
  c.cutoff = std::strtod(cutoff ? cutoff : "", &end);
  if (!cutoff || end == cutoff || *end != '\0' || !(c.cutoff > 0.0) || !std::isfinite(c.cutoff))
    throw std::runtime_error(std::string("cutoff must be a number > 0, got '") + (cutoff ? cutoff : "") + "'");
  for (int i = 0; i < m->nsensor; ++i) {
    if (m->sensor_type[i] != mjSENS_PLUGIN || m->sensor_plugin[i] != instance) continue;
    if (c.sensor_adr >= 0) throw std::runtime_error("one sensor per instance");
    c.sensor_adr = m->sensor_adr[i];
  }
  if (c.sensor_adr < 0) throw std::runtime_error("the instance has no sensor");
  return c;
}

// A lower bound of the distance between a sphere (world centre, radius) around the tool and geom `other`
// (negative: they may overlap): to the obstacle's local bounding box, or its plane.
mjtNum LowerBound(const mjModel* m, const mjData* d, const mjtNum centre[3], mjtNum radius, int other) {
  mjtNum offset[3], local[3];
  mju_sub3(offset, centre, d->geom_xpos + 3 * other);
  mju_mulMatTVec3(local, d->geom_xmat + 9 * other, offset);
  if (m->geom_type[other] == mjGEOM_PLANE) return local[2] - radius;  // the plane's normal is its z axis
  const mjtNum* box = m->geom_aabb + 6 * other;
  mjtNum outside = 0.0;
  for (int k = 0; k < 3; ++k) {
    mjtNum excess = std::fabs(local[k] - box[k]) - box[3 + k];
    if (excess > 0.0) outside += excess * excess;
  }
  return std::sqrt(outside) - radius;
}

void Compute(const mjModel* m, mjData* d, int instance) {
  const Clearance& c = *Get(d, instance);
  const mjtNum* aabb = m->geom_aabb + 6 * c.tool;  // the tool's box: centre and half-sizes in its frame
  mjtNum centre[3], radius = mju_norm3(aabb + 3);  // the sphere around it
  mju_mulMatVec3(centre, d->geom_xmat + 9 * c.tool, aabb);
  mju_addTo3(centre, d->geom_xpos + 3 * c.tool);
  mjtNum least = c.cutoff;
  for (int other : c.obstacles) {
    if (LowerBound(m, d, centre, radius, other) > least) continue;  // farther than the cutoff or a nearer pair
    least = mju_min(least, mj_geomDistance(m, d, c.tool, other, least, nullptr));
  }
  d->sensordata[c.sensor_adr] = least;
}

}  // namespace

void RegisterClearance() {
  mjpPlugin plugin;
  mjp_defaultPlugin(&plugin);
  plugin.name = kClearancePluginName;
  plugin.capabilityflags |= mjPLUGIN_SENSOR;
  plugin.needstage = mjSTAGE_POS;
  plugin.nattribute = kNumClearanceAttributes;
  plugin.attributes = kClearanceAttributes;
  plugin.nstate = +[](const mjModel*, int) { return 0; };
  plugin.nsensordata = +[](const mjModel*, int, int) { return 1; };
  plugin.init = +[](const mjModel* m, mjData* d, int instance) {
    try {
      d->plugin_data[instance] = reinterpret_cast<uintptr_t>(new Clearance(Configure(m, instance)));
      return 0;
    } catch (const std::exception& e) {
      mju_warning("hexgym.clearance: %s", e.what());
      return -1;
    }
  };
  plugin.destroy = +[](mjData* d, int instance) {
    delete Get(d, instance);
    d->plugin_data[instance] = 0;
  };
  plugin.copy = +[](mjData* dest, const mjModel*, const mjData* src, int instance) {
    dest->plugin_data[instance] = reinterpret_cast<uintptr_t>(new Clearance(*Get(src, instance)));
  };
  plugin.reset = +[](const mjModel*, mjtNum*, void*, int) {};
  plugin.compute = +[](const mjModel* m, mjData* d, int instance, int) { Compute(m, d, instance); };
  mjp_registerPlugin(&plugin);
}

}  // namespace hexgym
