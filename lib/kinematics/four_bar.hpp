#pragma once
/// @file
/// The four-bar closure solver (thesis appendix A), generalised to any four parallel revolute
/// axes: rotate into the plane normal to the axes, intersect the coupler and rocker circles on
/// the branch the mechanism was assembled in, keep link lengths, and refuse any driver motion
/// that would pass a change point (where the loop could invert) or leave its range.

#include <string>

#include "robot/robot_model.hpp"

namespace trocar::kinematics {

struct FourBarSolution {
  enum class Status {
    kSolved,
    kOutsideRange,  ///< the coupler and rocker cannot meet at this driver value
    kChangePoint,   ///< a change point (where the loop could invert) lies on the way
    kJointLimit,    ///< the coupler or the rocker would leave its joint limits
  };
  Status status = Status::kSolved;
  std::string message;  ///< why the step was refused, when !ok()
  bool ok() const { return status == Status::kSolved; }
  double coupler = 0.0;  ///< coupler joint value (rad)
  double rocker = 0.0;   ///< rocker joint value (rad)
  double dcoupler_ddriver = 0.0;
  double drocker_ddriver = 0.0;
};

const char* ToString(FourBarSolution::Status status);

/// Solves `closure` for the driver value `driver`, moving continuously from `previous_driver`
/// (where the loop was closed with coupler and rocker values `previous_coupler` and
/// `previous_rocker`, used to unwrap the angles). Fails, with a message, when the driver's range
/// is left or a change point lies between the two driver values, or when the coupler or rocker
/// would leave its joint limits.
FourBarSolution SolveFourBar(const robot::RobotModel& model,
                             const robot::FourBarClosure& closure, double driver,
                             double previous_driver, double previous_coupler,
                             double previous_rocker);

/// Distance between the cut joint's points on the coupler and on the rocker for the given joint
/// values (0 when the loop is closed): a check for tests and tools.
double FourBarClosureGap(const robot::RobotModel& model, const robot::FourBarClosure& closure,
                         double driver, double coupler, double rocker);

}  // namespace trocar::kinematics
