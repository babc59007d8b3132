// hexgym.clearance: a tool's least distance to a set of obstacles, as a MuJoCo sensor plugin.
#ifndef HEXGYM_NATIVE_CLEARANCE_PLUGIN_H_
#define HEXGYM_NATIVE_CLEARANCE_PLUGIN_H_

namespace hexgym {

// Register the hexgym.clearance plugin (once the library has checked the MuJoCo version).
void RegisterClearance();

}  // namespace hexgym

#endif  // HEXGYM_NATIVE_CLEARANCE_PLUGIN_H_
