#pragma once
/// @file
/// Placing a remote centre of motion with the setup joints (SUJ): given where an arm's RCM must
/// be (a port) and, optionally, which way its instrument axis must point, find values of the held
/// setup joints that put it there — or say it is unreachable and how far off the best attempt is.
/// Damped least squares (Levenberg–Marquardt) inside the joint limits, from several seeded starts.

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "robot/robot_model.hpp"
#include "robot/robot_state.hpp"

namespace trocar::kinematics {

struct SetupJointRequest {
  /// The frame to place, e.g. "psm1_rcm" in a cart description.
  std::string frame;
  /// Desired origin of the frame in the world (m).
  Eigen::Vector3d p_WF = Eigen::Vector3d::Zero();
  /// Desired direction in the world of `axis_F` (normalised here); unset: position only.
  std::optional<Eigen::Vector3d> axis_W;
  /// The axis, in the frame, that must point along axis_W. Default −z: the da Vinci arms'
  /// instrument axis at their zero configuration, in their RCM frame.
  Eigen::Vector3d axis_F = -Eigen::Vector3d::UnitZ();
  /// Joints to solve; empty: every held joint on the path from the base to the frame.
  std::vector<std::string> joints;
};

struct SetupJointOptions {
  /// Starts: the state's current values first, then seeded random values within the limits.
  int starts = 32;
  unsigned seed = 1;
  int max_iterations = 300;
  /// Success thresholds.
  double position_tolerance = 1e-4;               ///< m (0.1 mm)
  double angle_tolerance = 0.1 * M_PI / 180.0;    ///< rad (0.1 deg)
  /// Metres that weigh as much as one radian of axis error in the least-squares cost.
  double length_scale = 0.2;
  /// With an axis: the position first and the axis as near as the position allows (each step's
  /// axis part projected into the null space of the position's Jacobian), instead of the
  /// weighted compromise. For an arm whose setup joints cannot both reach the port and aim
  /// there: at the port, aimed as near as they can.
  bool axis_secondary = false;
};

struct SetupJointResult {
  enum class Status { kSolved, kUnreachable };
  Status status = Status::kUnreachable;
  std::vector<std::string> joints;  ///< the solved joints, in path order
  Eigen::VectorXd values;           ///< best values found (within the joint limits)
  double position_error = 0.0;      ///< m, of the best values: how far the target is short
  double angle_error = 0.0;         ///< rad, of the best values (0 when no axis was asked)
  std::string message;              ///< human-readable summary
  bool ok() const { return status == Status::kSolved; }
};
const char* ToString(SetupJointResult::Status status);

/// @param state supplies the base pose X_WB and the values of all other joints; not modified.
/// @throws trocar::Error for bad requests: unknown frame or joint, a joint that is not held or not
///         on the frame's path, non-finite target, zero axis.
SetupJointResult SolveSetupJoints(const robot::RobotModel& model, const robot::RobotState& state,
                                  const SetupJointRequest& request,
                                  const SetupJointOptions& options = {});

}  // namespace trocar::kinematics
