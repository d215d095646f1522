#include "control/joint_limits.hpp"

#include <algorithm>
#include <cmath>

#include "kinematics/jacobian.hpp"

namespace trocar::control {

double BrakingSpeed(double distance, double acceleration, double dt) {
  if (distance <= 0.0) return 0.0;
  if (!std::isfinite(acceleration)) return distance / dt;
  // Steps at v, v − a·dt, v − 2a·dt, … (m positive terms) travel dt·(m·v − a·dt·m(m−1)/2).
  // For m terms the largest v with that ≤ distance is (distance/dt + a·dt·m(m−1)/2) / m, valid
  // when (m−1)·a·dt < v ≤ m·a·dt. Start from the continuous estimate and check neighbours.
  const double h = acceleration * dt;
  const double estimate = acceleration * (-0.5 * dt + std::sqrt(0.25 * dt * dt + 2.0 * distance / acceleration));
  const double m0 = std::max(1.0, std::ceil(estimate / h));
  double best = 0.0;
  for (double m = std::max(1.0, m0 - 2.0); m <= m0 + 2.0; m += 1.0) {
    const double v = (distance / dt + h * m * (m - 1.0) / 2.0) / m;
    if (v > (m - 1.0) * h && v <= m * h + 1e-15) best = std::max(best, v);
  }
  return std::min(best, distance / dt);
}

bool CanStopWithin(double speed, double distance, double acceleration, double dt) {
  // Braking from `speed` in steps of a·dt takes m ≤ speed/(a·dt) + 1 steps, each moving at most
  // speed·dt: the distance is at most speed²/a + speed·dt. Within `distance`, the speed is at or
  // below BrakingSpeed(distance), which is monotone in the distance.
  if (!(speed >= 0.0) || !(distance > 0.0)) return false;
  if (speed * dt > distance) return false;
  if (!std::isfinite(acceleration)) return true;
  return speed * speed / acceleration + speed * dt <= distance;
}

LimitReport ApplyJointLimits(const robot::RobotModel& model, const Eigen::VectorXd& q,
                             const Eigen::VectorXd& qdot_previous,
                             const Eigen::VectorXd& qdot_command, double dt,
                             Eigen::VectorXd* qdot, Eigen::VectorXd* q_next) {
  LimitReport report;
  const int n = model.num_positions();
  qdot->resize(n);
  q_next->resize(n);
  for (int i = 0; i < n; ++i) {
    const auto& l = model.joint(model.active_joints()[i]).limits;
    double v = qdot_command[i];
    if (std::isfinite(l.acceleration)) {
      const double lo = qdot_previous[i] - l.acceleration * dt;
      const double hi = qdot_previous[i] + l.acceleration * dt;
      if (v < lo || v > hi) ++report.acceleration_limited;
      v = std::clamp(v, lo, hi);
    }
    if (std::isfinite(l.velocity)) {
      if (std::abs(v) > l.velocity) ++report.velocity_limited;
      v = std::clamp(v, -l.velocity, l.velocity);
    }
    // Only the limit the joint moves toward can bind (BrakingSpeed is never negative), and only
    // when the joint is near it: CanStopWithin is a cheap sufficient test.
    const double up = v > 0.0 && std::isfinite(l.upper) &&
                              !CanStopWithin(v, l.upper - q[i], l.acceleration, dt)
                          ? BrakingSpeed(l.upper - q[i], l.acceleration, dt) : HUGE_VAL;
    const double down = v < 0.0 && std::isfinite(l.lower) &&
                                !CanStopWithin(-v, q[i] - l.lower, l.acceleration, dt)
                            ? BrakingSpeed(q[i] - l.lower, l.acceleration, dt) : HUGE_VAL;
    if (v > up || v < -down) ++report.position_limited;
    v = std::clamp(v, -down, up);
    (*qdot)[i] = v;
    (*q_next)[i] = std::clamp(q[i] + v * dt, l.lower, l.upper);
  }
  return report;
}

VelocityDemand JointVelocityDemand(const robot::RobotModel& model, const robot::RobotState& state,
                                   const std::vector<Eigen::Matrix<double, 6, 1>>& V_W,
                                   bool position_only) {
  VelocityDemand out;
  kinematics::Matrix6Xd J;
  kinematics::ComputeFrameJacobian(model, state, model.tool_frame(), &J);
  const Eigen::MatrixXd Jr = position_only ? Eigen::MatrixXd(J.bottomRows<3>()) : Eigen::MatrixXd(J);
  if (Jr.cols() == 0) return out;
  const Eigen::MatrixXd pinv =
      kinematics::PseudoInverse(Eigen::JacobiSVD<Eigen::MatrixXd>(Jr, Eigen::ComputeThinU | Eigen::ComputeThinV), 1e-6);
  const Eigen::VectorXd limits = model.velocity_limits();
  for (const auto& V : V_W) {
    const double speed = V.tail<3>().norm();
    out.peak_tool_speed = std::max(out.peak_tool_speed, speed);
    const Eigen::VectorXd qdot =
        position_only ? Eigen::VectorXd(pinv * V.tail<3>()) : Eigen::VectorXd(pinv * V);
    for (int i = 0; i < qdot.size(); ++i) {
      if (!std::isfinite(limits[i]) || !(limits[i] > 0.0)) continue;
      const double share = std::abs(qdot[i]) / limits[i];
      if (share > out.share) {
        out.share = share;
        out.joint = i;
        out.rate = std::abs(qdot[i]);
        out.tool_speed = speed;
      }
    }
  }
  return out;
}

}  // namespace trocar::control
