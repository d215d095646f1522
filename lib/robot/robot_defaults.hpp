#pragma once
/// @file
/// What a robot description suggests for using the robot, apart from its kinematics (issue #18):
/// the controller gains and the configuration where sessions start. A RobotModel carries it as a
/// separate part, `model.defaults()`; forward kinematics, Jacobians and closures never read it.
/// The sidecar's `controller:` and `home:` fill it, and so do tuned gains from the overlay beside
/// a robot (control/gain_tuning.hpp).

#include <map>
#include <string>

#include <Eigen/Core>

namespace trocar::robot {

/// Controller settings carried by a robot description (trocar YAML sidecar `controller:`).
struct ControllerSettings {
  /// Gain per task axis [ωx ωy ωz vx vy vz] (1/s) for every controller; empty when unset.
  Eigen::VectorXd task_gains;
  /// Gains for one controller by name ("jt", "dls", ...), overriding task_gains for it.
  std::map<std::string, Eigen::VectorXd> gains;
};

struct RobotDefaults {
  ControllerSettings controller;
  /// Active joint values (in q order) where sessions start: the description's `home`, within the
  /// joint limits; empty when it gives none (kinematics::ChooseStart then picks a start away from
  /// limits and singularities).
  Eigen::VectorXd home;

  bool has_home() const { return home.size() > 0; }
  /// The home, or `fallback` when the description gives none.
  Eigen::VectorXd HomeOr(const Eigen::VectorXd& fallback) const { return has_home() ? home : fallback; }
};

}  // namespace trocar::robot
