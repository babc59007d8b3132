// The library's registration: every plugin it holds (hexgym.mbl, hexgym.clearance), once it has checked
// that it runs in the MuJoCo it was built against; and what the Python side asks the library
// (hexgym.model.plugin: its load error, interface and MuJoCo version).
#include <cstdio>
#include <string>

#include <mujoco/mujoco.h>

#include "clearance_plugin.h"
#include "mbl_plugin.h"
#include "plugin_interface.h"

namespace hexgym {
namespace {

std::string& LoadError() {
  static std::string error;
  return error;
}

// Why a library built against MuJoCo `built` must not register in MuJoCo `running` ("" if it may):
// mjModel/mjData layouts and the plugin API change between versions.
std::string VersionError(int built, int running) {
  if (built == running) return "";
  char message[256];
  std::snprintf(message, sizeof(message),
                "hexgym.mbl was built against MuJoCo %d but is loaded into MuJoCo %d: rebuild hexgym "
                "(pip install -e . or pip install .) for this MuJoCo",
                built, running);
  return message;
}

void Register() {
  std::string refusal = VersionError(mjVERSION_HEADER, mj_version());
  if (!refusal.empty()) {
    LoadError() = refusal;
    std::fprintf(stderr, "%s\n", refusal.c_str());  // also for processes that do not ask (MuJoCo's viewer)
    return;  // not registered: a model that uses them fails to load, naming the plugin
  }
  RegisterMblPlugin();
  RegisterClearance();
}

}  // namespace
}  // namespace hexgym

extern "C" {

// Empty when the plugins registered; else why not (e.g. a MuJoCo version mismatch).
__attribute__((visibility("default"))) const char* hexgym_mbl_load_error(void) {
  return hexgym::LoadError().c_str();
}

// The check Register makes, for any pair of versions (tests): writes its message ("" if they agree)
// into out (size bytes, truncated) and returns the message's full length.
__attribute__((visibility("default"))) int hexgym_mbl_version_error(int built, int running, char* out, int size) {
  std::string message = hexgym::VersionError(built, running);
  if (out && size > 0) std::snprintf(out, static_cast<size_t>(size), "%s", message.c_str());
  return static_cast<int>(message.size());
}

// The interface (plugin name, config keys, state slots, tables, circuit layout, ctrl unit) this library was
// built with, as JSON; hexgym.model.plugin compares it with its own before registering the plugins.
__attribute__((visibility("default"))) const char* hexgym_mbl_interface(void) { return hexgym::kInterfaceJson; }

// The MuJoCo version (mjVERSION_HEADER) this library was built against.
__attribute__((visibility("default"))) int hexgym_mbl_built_mujoco_version(void) { return mjVERSION_HEADER; }

}

mjPLUGIN_LIB_INIT(hexgym_mbl) { hexgym::Register(); }
