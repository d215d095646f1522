#pragma once
/// @file
/// Force feedback for a teleoperated arm (docs/network-devices.md, "Force feedback"): a force on
/// the operator's hand that grows as the arm nears something it may not touch (the patient's
/// structures, another arm, the table), and a cue as a joint nears its limit (the insertion
/// limit among them). The force is computed in the world and expressed in the device's frame,
/// so that it pushes the hand the way that moves the tool out of trouble.

#include <limits>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "robot/robot_model.hpp"
#include "robot/robot_state.hpp"

namespace trocar::control {

struct ForceFeedbackOptions {
  double influence = 0.010;    ///< m: nearer than this to an obstacle, a force
  double max_force = 3.0;      ///< N: the force at contact
  double limit_margin = 0.05;  ///< share of a joint's range in which the limit cue rises
  double limit_force = 1.5;    ///< N: the cue at the limit itself
};

/// The arm's nearest approach to anything else, with witness points (from the collision world).
struct ArmNearness {
  double distance = std::numeric_limits<double>::infinity();  ///< m; 0 in contact
  Eigen::Vector3d p_W_arm = Eigen::Vector3d::Zero();
  Eigen::Vector3d p_W_other = Eigen::Vector3d::Zero();
  std::string what;  ///< "psm1_tool_shaft - heart"
};

struct ForceCue {
  Eigen::Vector3d f_W = Eigen::Vector3d::Zero();  ///< N, in the world
  enum Reason : unsigned { kNone = 0, kNear = 1, kJointLimit = 2, kInsertionLimit = 4 };
  unsigned reasons = kNone;
  std::string joint;  ///< the joint nearest its limit, when a cue acts
};

/// Keeps the direction of the last force while the witness points coincide (in contact).
class ForceFeedback {
 public:
  /// @param positions indices into q of the arm's joints (its tool's path).
  /// @throws trocar::Error for non-positive or non-finite options.
  ForceFeedback(const robot::RobotModel& model, std::vector<int> positions,
                const ForceFeedbackOptions& options = {});

  /// The cue for the arm at `state` (forward kinematics done), for the tool `tool`.
  ForceCue Compute(const robot::RobotState& state, const robot::Frame& tool, const ArmNearness& near);

  /// `f_W` in a device whose frame is `R_WD` in the world (the mapping's camera frame times the
  /// device-to-camera rotation).
  static Eigen::Vector3d InDevice(const Eigen::Vector3d& f_W, const Eigen::Matrix3d& R_WD) {
    return R_WD.transpose() * f_W;
  }

 private:
  const robot::RobotModel& model_;
  std::vector<int> positions_;
  ForceFeedbackOptions options_;
  Eigen::Vector3d last_away_W_ = Eigen::Vector3d::Zero();
  Eigen::Matrix<double, 6, Eigen::Dynamic> J_;
};

}  // namespace trocar::control
