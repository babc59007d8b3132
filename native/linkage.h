// The front linkage's cylinder lengths and moment arms dC/dq (the paper's Eqn 5), the same
// closed forms as hexgym/machine/kinematics.py, with the geometry passed in from hexgym.machine.parameters.
#ifndef HEXGYM_NATIVE_LINKAGE_H_
#define HEXGYM_NATIVE_LINKAGE_H_

namespace hexgym {

struct Vec2 {
  double x, z;
};

// A cylinder between a pin on the parent link and one on the child link (boom, stick).
struct Triangle {
  Vec2 base;      // base pin in the parent frame, relative to the joint
  Vec2 rod;       // rod pin in the child frame
  double offset;  // child frame's rotation at joint angle 0, rad
  double sign;    // rotation per unit joint angle (+1 or -1)
};

// The bucket four-bar in the stick frame (machine.py: _G, _P_BUCKET, _K_BUCKET, _C_BUCKET).
struct FourBar {
  Vec2 guide_pivot, bucket_pin, link_pin, cylinder_base;
  double guide_length, power_length, joint_side;
};

struct Linkage {
  Triangle boom, stick;
  FourBar bucket;

  // Pin-to-pin length (m) and moment arm dC/dq (m/rad) of cylinder k (0 boom, 1 stick,
  // 2 bucket) at its joint's angle; NaN where the four-bar cannot close.
  void Cylinder(int k, double angle, double* length, double* arm) const;
};

}  // namespace hexgym

#endif  // HEXGYM_NATIVE_LINKAGE_H_
