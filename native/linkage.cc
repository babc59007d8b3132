// Closed-form linkage kinematics, mirroring hexgym/machine/kinematics.py operation for operation.
#include "linkage.h"

#include <cmath>

namespace hexgym {
namespace {

Vec2 Rotate(double angle, Vec2 v) {
  double c = std::cos(angle), s = std::sin(angle);
  return {c * v.x + -s * v.z, s * v.x + c * v.z};
}
Vec2 Perp(Vec2 v) { return {-v.z, v.x}; }
Vec2 Sub(Vec2 a, Vec2 b) { return {a.x - b.x, a.z - b.z}; }
double Dot(Vec2 a, Vec2 b) { return a.x * b.x + a.z * b.z; }
double Norm(Vec2 v) { return std::hypot(v.x, v.z); }

// The intersection of two circles on the `side` of c1 -> c2 (machine._circle_intersection);
// NaN where they do not meet.
Vec2 CircleIntersection(Vec2 c1, double r1, Vec2 c2, double r2, double side) {
  Vec2 dv = Sub(c2, c1);
  double d = Norm(dv);
  double a = (r1 * r1 - r2 * r2 + d * d) / (2.0 * d);
  double h2 = r1 * r1 - a * a;
  if (h2 < 0.0) return {NAN, NAN};
  Vec2 u = {dv.x / d, dv.z / d};
  double h = side * std::sqrt(h2);
  Vec2 p = Perp(u);
  return {c1.x + a * u.x + h * p.x, c1.z + a * u.z + h * p.z};
}

// Bucket link joint J and link pin K in the stick frame (machine.bucket_link_points).
void BucketPoints(const FourBar& f, double q, Vec2* j, Vec2* k) {
  Vec2 r = Rotate(-q, f.link_pin);
  *k = {f.bucket_pin.x + r.x, f.bucket_pin.z + r.z};
  *j = CircleIntersection(f.guide_pivot, f.guide_length, *k, f.power_length, f.joint_side);
}

Vec2 RodInParent(const Triangle& t, double angle) { return Rotate(t.offset + t.sign * angle, t.rod); }

}  // namespace

void Linkage::Cylinder(int k, double angle, double* length, double* arm) const {
  if (k == 2) {
    // |J - G| and |J - K| are constant: (J-G).dJ = 0 and (J-K).(dJ - dK) = 0, solved for dJ
    Vec2 j, kp;
    BucketPoints(bucket, angle, &j, &kp);
    Vec2 dk = Perp(Sub(kp, bucket.bucket_pin));
    dk = {-dk.x, -dk.z};
    Vec2 r0 = Sub(j, bucket.guide_pivot), r1 = Sub(j, kp);
    double b1 = Dot(r1, dk);
    double det = r0.x * r1.z - r0.z * r1.x;
    Vec2 dj = {(0.0 * r1.z - r0.z * b1) / det, (r0.x * b1 - 0.0 * r1.x) / det};
    Vec2 d = Sub(j, bucket.cylinder_base);
    *length = Norm(d);
    *arm = Dot(d, dj) / *length;
    return;
  }
  const Triangle& t = k == 0 ? boom : stick;
  Vec2 rod = RodInParent(t, angle);
  Vec2 d = Sub(rod, t.base);
  *length = Norm(d);
  *arm = t.sign * Dot(d, Perp(rod)) / *length;
}

}  // namespace hexgym
