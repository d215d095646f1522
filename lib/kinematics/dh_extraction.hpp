#pragma once
/// @file
/// The equivalent modified-DH table of a serial chain, found from its joint axes at the zero
/// configuration (common normals between successive axes).

#include <optional>
#include <string>

#include "robot/dh_table.hpp"
#include "robot/robot_model.hpp"

namespace trocar::kinematics {

/// The modified-DH table (with base and tool transforms) whose DhToolPose equals the model's
/// tool pose in its base link for every q. Exists when the active joints are exactly the
/// movable joints from the base to the tool, in order (no mimic, closure or held joints on the
/// way). Otherwise returns nullopt and says why in `*why_not`.
std::optional<robot::DhTable> ExtractModifiedDh(const robot::RobotModel& model,
                                                std::string* why_not);

}  // namespace trocar::kinematics
