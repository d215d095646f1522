#pragma once
/// @file
/// RobotState: everything a kinematic query writes, one per thread (Pinocchio's Model/Data split).

#include <vector>

#include <Eigen/Geometry>

#include "robot/robot_model.hpp"

namespace trocar::robot {

struct RobotState {
  /// Sized for `model`: q at the model's neutral configuration, held joints at 0 (or the middle
  /// of their range when 0 is outside it), base at the world origin. Call
  /// kinematics::SetConfiguration and ForwardKinematics before reading poses.
  explicit RobotState(const RobotModel& model);

  /// Pose of the robot's base link in the world (the cart pose; planners move it).
  Eigen::Isometry3d X_WB = Eigen::Isometry3d::Identity();
  /// Active joint values (size num_positions()).
  Eigen::VectorXd q;
  /// Every movable joint's value, by Joint::dof_index.
  Eigen::VectorXd joint_values;
  /// d joint_values / d q (num_dofs × num_positions); rows of active joints are unit rows.
  Eigen::MatrixXd dvalues_dq;
  /// Link poses in the world, by link index; valid after ForwardKinematics.
  std::vector<Eigen::Isometry3d> X_WL;
  /// Driver value at which each closure was last solved (0: the assembled zero configuration).
  Eigen::VectorXd closure_drivers;

  /// What setting a configuration changes, kept to undo a step a closure refuses; sized like
  /// the fields above so that keeping it copies without allocating (kinematics only).
  struct Undo {
    Eigen::VectorXd q, joint_values, closure_drivers;
    Eigen::MatrixXd dvalues_dq;
  } undo;
};

}  // namespace trocar::robot
