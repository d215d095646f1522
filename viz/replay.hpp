#pragma once
/// @file
/// Replay of a plan's verified motions: the waypoints of a motion interpolated in joint space
/// (linear, as the planner's paths are checked) into frames no more than `max_step` apart, each
/// with its collisions, near misses and clearance by the plan's rules (plan_collisions.hpp).

#include <memory>
#include <string>
#include <vector>

#include "motion/plan_collisions.hpp"
#include "plan/plan_file.hpp"
#include "robot/robot_state.hpp"

namespace trocar::viz {

struct ReplayFrame {
  robot::RobotState state;
  std::size_t segment = 0;  ///< between waypoints segment and segment + 1
  planners::PoseCollisions collisions;
};

/// The frames of `motion` from `start` (the plan's nominal state): every waypoint is a frame, and
/// frames between them are at most `max_step` apart (rad; m for prismatic joints, times 10). A
/// motion not solved that has a failure pose (issue #43 item 9): from the nominal pose straight
/// to the pose that fails, its last frame (the reason is the motion's).
/// @throws trocar::Error when the motion has neither waypoints nor a failure pose, or names a
/// joint the robot has not.
std::vector<ReplayFrame> ReplayMotion(const robot::RobotModel& robot, const robot::RobotState& start,
                                      const planners::StoredMotion& motion,
                                      planners::PlanCollisions* collisions, double max_step = 0.02,
                                      double near_miss = 0.005);

}  // namespace trocar::viz
