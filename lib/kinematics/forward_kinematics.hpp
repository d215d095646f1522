#pragma once
/// @file
/// Configuration and forward kinematics: `(model, q) → state` (Pinocchio style). Every function
/// reads the immutable model and writes only the caller's RobotState, so one state per thread
/// makes them thread safe.

#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "robot/robot_model.hpp"
#include "robot/robot_state.hpp"

namespace trocar::kinematics {

/// Outcome of setting a configuration. A closure that cannot follow is an expected failure (a
/// result, not an exception): the state is then left exactly as it was. Like every result in the
/// robot layer: a `status` (success first), a `message` saying why when not ok(), and ok().
struct ConfigurationResult {
  enum class Status { kSet, kClosureRefused };
  Status status = Status::kSet;
  std::string message;      ///< why, when !ok()
  int failed_closure = -1;  ///< closure index, when !ok()
  bool ok() const { return status == Status::kSet; }
};
const char* ToString(ConfigurationResult::Status status);

/// Sets the active joints to `q`, then resolves mimic joints and closures (in the model's
/// resolve order), also updating d joint_values / d q. Does not compute poses.
/// @throws trocar::Error when q has the wrong size or a non-finite entry (naming the joint).
ConfigurationResult SetConfiguration(const robot::RobotModel& model, const Eigen::VectorXd& q,
                                     robot::RobotState* state);

/// Sets a held (passive, set-before-use) joint and re-resolves the joints that depend on it.
/// @throws trocar::Error when the joint is unknown, not held, the value is not finite or is
///         outside the joint's limits.
ConfigurationResult SetHeldJoint(const robot::RobotModel& model, const std::string& joint,
                                 double value, robot::RobotState* state);

/// Link poses X_WL from state->joint_values and state->X_WB.
void ForwardKinematics(const robot::RobotModel& model, robot::RobotState* state);

/// Link poses X_WL of `link` and the links on its path from the base only, from
/// state->joint_values (resolved) and state->X_WB; other links' poses are left as they were. For
/// solvers that move one chain of a large robot (the setup joints of one arm of a cart).
/// @throws trocar::Error when `link` is not a link of the model.
void ForwardKinematicsToLink(const robot::RobotModel& model, int link, robot::RobotState* state);

/// SetConfiguration followed, when it succeeds, by ForwardKinematics.
ConfigurationResult ForwardKinematics(const robot::RobotModel& model, const Eigen::VectorXd& q,
                                      robot::RobotState* state);

/// Pose of a named frame (after ForwardKinematics).
Eigen::Isometry3d FramePose(const robot::RobotState& state, const robot::Frame& frame);
/// Pose of a link's kinematic frame K (thesis §2.4.2) in the world.
Eigen::Isometry3d KinematicFramePose(const robot::RobotModel& model,
                                     const robot::RobotState& state, int link);
/// Tool pose relative to the robot's base link: X_BT.
Eigen::Isometry3d ToolPoseInBase(const robot::RobotModel& model, const robot::RobotState& state);

/// One entry per active joint whose value in q is outside its position limits, e.g.
/// "joint 'S2' = 2.1 outside [-1.59, 1.59]". Empty when q is within limits.
std::vector<std::string> LimitViolations(const robot::RobotModel& model,
                                         const Eigen::VectorXd& q);

}  // namespace trocar::kinematics
