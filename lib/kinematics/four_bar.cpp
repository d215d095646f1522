#include "kinematics/four_bar.hpp"

#include <cmath>
#include <sstream>

#include "common/geometry.hpp"
#include "kinematics/sin_cos.hpp"

namespace trocar::kinematics {
namespace {

using robot::FourBarClosure;

Eigen::Vector2d Rotate2(double angle, const Eigen::Vector2d& v) {
  double s, c;
  SinCos(angle, &s, &c);
  return {c * v.x() - s * v.y(), s * v.x() + c * v.y()};
}

double Angle2(const Eigen::Vector2d& a) { return std::atan2(a.y(), a.x()); }

// Allowed range of |P4 - P2| for the coupler and rocker circles to cross transversally.
struct DistanceRange {
  double min, max;
};

DistanceRange Range(const FourBarClosure& c) {
  const double tol = 1e-6 * (c.L23 + c.L34);
  return {std::abs(c.L23 - c.L34) + tol, c.L23 + c.L34 - tol};
}

// The crank's end P2 for driver value theta.
Eigen::Vector2d CrankEnd(const FourBarClosure& c, double theta) { return c.P1 + Rotate2(theta, c.c0); }

}  // namespace

FourBarSolution SolveFourBar(const robot::RobotModel& model, const FourBarClosure& c,
                             double driver, double previous_driver, double previous_coupler,
                             double previous_rocker) {
  FourBarSolution out;
  const DistanceRange range = Range(c);
  // |P4 - P2| is extremal where the crank is aligned with P1→P4; check those inside the swept
  // interval as well as its ends, so that no change point is jumped over in one step.
  auto feasible_at = [&](const Eigen::Vector2d& P2) {
    const double d = (c.P4 - P2).norm();
    return d >= range.min && d <= range.max;
  };
  auto feasible = [&](double theta) { return feasible_at(CrankEnd(c, theta)); };
  auto refuse = [&](double theta, FourBarSolution::Status status, const char* why) {
    std::ostringstream msg;
    msg << "closure '" << c.name << "': driver '" << model.joint(c.driver).name << "' at "
        << driver << " rad is outside the mechanism's range (" << why << " at " << theta
        << " rad)";
    out.status = status;
    out.message = msg.str();
    return out;
  };
  const Eigen::Vector2d P2 = CrankEnd(c, driver);
  if (!feasible_at(P2)) return refuse(driver, FourBarSolution::Status::kOutsideRange, "the coupler and rocker cannot meet");
  const Eigen::Vector2d D = c.P4 - c.P1;
  if (D.norm() > 1e-12) {
    const double phase = c.change_phase;
    const double lo = std::min(previous_driver, driver), hi = std::max(previous_driver, driver);
    // Extremes at theta = k*pi - phase.
    for (double k = std::ceil((lo + phase) / M_PI); k * M_PI - phase <= hi; k += 1.0) {
      const double theta = k * M_PI - phase;
      if (!feasible(theta)) return refuse(theta, FourBarSolution::Status::kChangePoint, "a change point lies on the way");
    }
  }
  const Eigen::Vector2d to_rocker = c.P4 - P2;
  const double d = to_rocker.norm();
  const Eigen::Vector2d e = to_rocker / d;
  const Eigen::Vector2d e_perp(-e.y(), e.x());
  const double a = (c.L23 * c.L23 - c.L34 * c.L34 + d * d) / (2.0 * d);
  const double h = std::sqrt(std::max(0.0, c.L23 * c.L23 - a * a));
  const Eigen::Vector2d P3 = P2 + a * e + c.branch_sign * h * e_perp;

  const double coupler =
      c.coupler_sign * (Angle2(P3 - P2) - c.coupler_ref_angle - driver);
  const double rocker = c.rocker_sign * (Angle2(P3 - c.P4) - c.rocker_ref_angle);
  out.coupler = previous_coupler + WrapAngle(coupler - previous_coupler);
  out.rocker = previous_rocker + WrapAngle(rocker - previous_rocker);

  // Velocity closure: ω_r r34 − ω_c r23 = ω_d r13 (planar rates about the common axis).
  const Eigen::Vector2d r34 = P3 - c.P4, r23 = P3 - P2, r13 = P3 - c.P1;
  Eigen::Matrix2d M;
  M.col(0) = r34;
  M.col(1) = -r23;
  const Eigen::Vector2d rates = M.inverse() * r13;
  out.drocker_ddriver = c.rocker_sign * rates[0];
  out.dcoupler_ddriver = c.coupler_sign * rates[1];

  for (const auto& [joint_index, value] : {std::pair{c.coupler, out.coupler},
                                           std::pair{c.rocker, out.rocker}}) {
    const robot::Joint& joint = model.joint(joint_index);
    if (value < joint.limits.lower || value > joint.limits.upper) {
      std::ostringstream msg;
      msg << "closure '" << c.name << "': driver '" << model.joint(c.driver).name << "' at "
          << driver << " rad would put joint '" << joint.name << "' at " << value
          << " rad, outside its limits [" << joint.limits.lower << ", " << joint.limits.upper
          << "]";
      out.status = FourBarSolution::Status::kJointLimit;
      out.message = msg.str();
      return out;
    }
  }
  out.status = FourBarSolution::Status::kSolved;
  return out;
}

const char* ToString(FourBarSolution::Status status) {
  switch (status) {
    case FourBarSolution::Status::kSolved: return "solved";
    case FourBarSolution::Status::kOutsideRange: return "outside the mechanism's range";
    case FourBarSolution::Status::kChangePoint: return "a change point on the way";
    case FourBarSolution::Status::kJointLimit: return "a joint limit";
  }
  return "unknown";
}

double FourBarClosureGap(const robot::RobotModel& model, const FourBarClosure& c, double driver,
                         double coupler, double rocker) {
  const robot::Joint& jd = model.joint(c.driver);
  const robot::Joint& jc = model.joint(c.coupler);
  const robot::Joint& jr = model.joint(c.rocker);
  auto motion = [](const robot::Joint& j, double value) {
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.linear() = Eigen::AngleAxisd(value, j.axis_J).toRotationMatrix();
    return X;
  };
  const Eigen::Isometry3d X_GC = jd.X_PJ * motion(jd, driver) * jc.X_PJ * motion(jc, coupler);
  const Eigen::Isometry3d X_GB = jr.X_PJ * motion(jr, rocker);
  return (X_GC * c.p_C3 - X_GB * c.p_B3).norm();
}

}  // namespace trocar::kinematics
