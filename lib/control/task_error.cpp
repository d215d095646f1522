#include "control/task_error.hpp"

#include <algorithm>
#include <cmath>

namespace trocar::control {

Eigen::Vector3d OrientationError(const Eigen::Matrix3d& R_WD, const Eigen::Matrix3d& R_WC) {
  const Eigen::Matrix3d R = R_WD * R_WC.transpose();
  return {R(2, 1) - R(1, 2), R(0, 2) - R(2, 0), R(1, 0) - R(0, 1)};
}

Vector6d TaskError(const Eigen::Isometry3d& X_WD, const Eigen::Isometry3d& X_WC) {
  Vector6d e;
  e.head<3>() = OrientationError(X_WD.linear(), X_WC.linear());
  e.tail<3>() = X_WD.translation() - X_WC.translation();
  return e;
}

double AngleBetween(const Eigen::Matrix3d& R_a, const Eigen::Matrix3d& R_b) {
  const double c = 0.5 * ((R_a.transpose() * R_b).trace() - 1.0);
  return std::acos(std::clamp(c, -1.0, 1.0));
}

}  // namespace trocar::control
