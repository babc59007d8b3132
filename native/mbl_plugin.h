// hexgym.mbl: the learned actuator model (the circuit model or the MBL tables) as a MuJoCo actuator plugin.
#ifndef HEXGYM_NATIVE_MBL_PLUGIN_H_
#define HEXGYM_NATIVE_MBL_PLUGIN_H_

namespace hexgym {

// Register the hexgym.mbl plugin (once the library has checked the MuJoCo version: register.cc).
void RegisterMblPlugin();

}  // namespace hexgym

#endif  // HEXGYM_NATIVE_MBL_PLUGIN_H_
