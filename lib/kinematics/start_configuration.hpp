#pragma once
/// @file
/// Where a session starts when a robot gives no `home`: a configuration within the joint limits,
/// away from them and away from singularities, chosen deterministically (issue #18). A plain
/// URDF otherwise starts at q = 0, often stretched straight (singular), and does not track.

#include <string>
#include <vector>

#include <Eigen/Core>

#include "robot/robot_model.hpp"

namespace trocar::kinematics {

/// How good a configuration is to start from.
struct StartQuality {
  enum class Status {
    kAssessed,             ///< closures assembled and the tool Jacobian computed
    kConfigurationRefused, ///< a closure cannot be assembled at q
    kNoJoints,             ///< the robot has no active joints
  };
  Status status = Status::kAssessed;
  std::string message;  ///< why, when !ok()
  bool ok() const { return status == Status::kAssessed; }
  double dexterity = 0.0;     ///< inverse condition number of the tool Jacobian, angular rows
                              ///< scaled by `length` (0 singular, 1 isotropic)
  double limit_margin = 1.0;  ///< smallest distance to a limit over the bounded joints, as a
                              ///< fraction of the joint's range (0.5 at the middle)
  /// What is maximised: dexterity × the room each joint has toward its limits for a typical
  /// hand motion from here (8 cm, 0.25 rad in any direction, through the Jacobian's
  /// pseudo-inverse), full with twice the travel needed, none at a limit.
  double score = 0.0;
};

const char* ToString(StartQuality::Status status);

/// `length` (m) weighs rotation against translation in the Jacobian (a rotation of 1 rad moves a
/// point at that distance by `length`).
StartQuality AssessStart(const robot::RobotModel& model, const Eigen::VectorXd& q, double length);

struct StartConfiguration {
  Eigen::VectorXd q;
  std::string basis;  ///< "home from FILE" or "chosen automatically: ..."
  StartQuality quality;
  double length = 0.1;  ///< characteristic length used (m)
  /// Automatic starts: the fraction of the probe motion (a ±5.5 cm sweep, ±0.3 rad turns) the
  /// tool follows from q; 1 when everything was followed. 1 for a declared home (not probed).
  double probe = 1.0;
  /// Near a singularity (dexterity < 0.02) or a limit (within 2 % of a range): say so.
  std::vector<std::string> warnings;
};

/// The robot's declared home when it has one; otherwise: `samples` seeded configurations within
/// the limits (a 10 % margin kept) ranked by AssessStart, the best dozen refined by a coordinate
/// ascent and then probed by driving the tool (damped least squares, joints clamped) along a
/// ±5.5 cm sweep and through ±0.3 rad turns; the one that follows furthest wins. A warning says
/// when even that start cannot follow the whole probe. Same model and seed, same result.
StartConfiguration ChooseStart(const robot::RobotModel& model, unsigned seed = 1, int samples = 256);

/// Warnings for starting at `q` (any q: a declared home or one given on the command line).
std::vector<std::string> StartWarnings(const robot::RobotModel& model, const Eigen::VectorXd& q,
                                       double length);

}  // namespace trocar::kinematics
