#pragma once
/// @file
/// What a robot description suggests for using the robot, apart from its kinematics (issue #18):
/// the controller gains and the configuration where sessions start. A RobotModel carries it as a
/// separate part, `model.defaults()`; forward kinematics, Jacobians and closures never read it.
/// The sidecar's `controller:` and `home:` fill it, and so do tuned gains from the overlay beside
/// a robot (control/gain_tuning.hpp).

#include <Eigen/Core>
#include <map>
#include <string>
#include <vector>

namespace trocar::robot {

/// Controller settings carried by a robot description (trocar YAML sidecar `controller:`).
struct ControllerSettings {
  /// Gain per task axis [ωx ωy ωz vx vy vz] (1/s) for every controller; empty when unset.
  Eigen::VectorXd task_gains;
  /// Gains for one controller by name ("jt", "dls", ...), overriding task_gains for it.
  std::map<std::string, Eigen::VectorXd> gains;
};

/// Another description whose visual meshes dress some of this robot's links where drawn (the
/// sidecar's `appearance:`; docs/robot-appearance.md): the two models' kinematics place each worn
/// mesh on the link that wears it (kinematics/appearance.hpp). Drawing only: collision shapes,
/// kinematics and plans never read it.
struct Appearance {
  std::string urdf;   ///< the dressing description's path, resolved; it may be missing
  std::string where;  ///< the file and field that gave it, for messages
  struct Wear {
    std::string link;   ///< this robot's link
    std::string wears;  ///< the dressing description's link whose meshes it wears
  };
  std::vector<Wear> links;
  struct Drive {
    std::string joint;                      ///< this robot's active joint
    std::string drives;                     ///< the dressing description's active joint it sets
    double multiplier = 1.0, offset = 0.0;  ///< theirs = multiplier * ours + offset
  };
  std::vector<Drive> joints;
  /// How far a worn mesh may be drawn from where its own model puts it (m), and for links named
  /// in `tolerances` their own: the two models' links need not be built alike to the millimetre
  /// (docs/robot-appearance.md).
  double tolerance = 0.002;
  std::map<std::string, double> tolerances;
  double ToleranceOf(const std::string& link) const {
    const auto it = tolerances.find(link);
    return it == tolerances.end() ? tolerance : it->second;
  }
};

struct RobotDefaults {
  ControllerSettings controller;
  /// Active joint values (in q order) where sessions start: the description's `home`, within the
  /// joint limits; empty when it gives none (kinematics::ChooseStart then picks a start away from
  /// limits and singularities).
  Eigen::VectorXd home;
  /// Meshes the links wear where drawn (each arm's own, names prefixed as the arm's).
  std::vector<Appearance> appearances;

  bool has_home() const { return home.size() > 0; }
  /// The home, or `fallback` when the description gives none.
  Eigen::VectorXd HomeOr(const Eigen::VectorXd& fallback) const { return has_home() ? home : fallback; }
};

}  // namespace trocar::robot
