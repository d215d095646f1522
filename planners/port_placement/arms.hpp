#pragma once
/// @file
/// The arms a port-placement problem places: which frames of a robot description are the
/// ports (remote centres of motion), which are the tools, which arm carries the endoscope, and
/// which of q each arm moves. Everything is read from the robot description (frame and link
/// names), never from string literals, so a cart we have never seen and a plain arm with a
/// software RCM (the PA10 with an instrument) work alike.

#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "robot/robot_model.hpp"

namespace trocar::planners {

enum class ArmRole { kInstrument, kEndoscope };
const char* ToString(ArmRole role);

/// One arm that goes through one port.
struct PlanArm {
  std::string name;  ///< "psm1", "ecm"; the robot's name for a single arm
  ArmRole role = ArmRole::kInstrument;
  /// The robot frame that must sit at the port: a mechanical RCM ("psm1_rcm"). Empty for an arm
  /// without one: its shaft must pass through the port (a software RCM).
  std::string rcm_frame;
  std::string tool_frame;      ///< the instrument tip or the endoscope's camera ("psm1_tool")
  std::vector<int> q_indices;  ///< entries of q that move the tool (the arm's active joints)
  int insertion_q = -1;        ///< q index of the insertion (prismatic below the RCM); -1: none
  /// The instrument shaft as a segment on a link (software RCM arms; also used for reach
  /// checks): from p_L_shaft_a (outside the patient) to p_L_shaft_b (toward the tip).
  int shaft_link = -1;
  Eigen::Vector3d p_L_shaft_a = Eigen::Vector3d::Zero();
  Eigen::Vector3d p_L_shaft_b = Eigen::Vector3d::Zero();
  /// Endoscopes: the frames the camera may look from — the tool frame (a straight scope) and the
  /// arm's other frames named `*camera*` (angled scopes, e.g. 30° up and down), in that order.
  std::vector<std::string> view_frames;
  bool has_rcm() const { return !rcm_frame.empty(); }
};

/// Finds the arms of `robot`.
///
/// Ports are the robot's RCM frames: its `rcm` frame, and every frame named `<prefix>rcm` (a cart
/// composed with `include:` has one per arm); each arm's tool is the frame `<prefix>tool` (or the
/// robot's tool for a single arm). An arm is an endoscope when its description has a camera frame
/// (a frame of the arm named `*camera*`) or its prefix names one (`ecm`, `endoscope`, `camera`);
/// otherwise an instrument. A robot with no RCM frame is one instrument arm with a software RCM:
/// its shaft is the slenderest long shape on the tool's chain (radius at most 10 mm, at least 15
/// times as long as its radius), along the shape's axis.
///
/// @param roles optional overrides "NAME=instrument|endoscope" by arm name or RCM frame; an
///        override naming no arm is an error listing the arms.
/// @throws trocar::Error when the robot has no tool frame for an RCM, no arm at all, or (for a
///         software RCM) no shaft shape.
std::vector<PlanArm> FindArms(const robot::RobotModel& robot,
                              const std::vector<std::string>& roles = {});

/// Restricts `arms` to the named ones (by arm name or RCM frame), in the given order.
/// @throws trocar::Error naming the unknown name and listing the arms.
std::vector<PlanArm> SelectArms(const std::vector<PlanArm>& arms,
                                const std::vector<std::string>& names);

}  // namespace trocar::planners
