#pragma once
/// @file
/// Dressing a robot in another description's meshes (docs/robot-appearance.md; issue #43 item 8):
/// the bundled da Vinci is kinematics and primitive collision shapes, and the SurRoL PSM and ECM
/// URDFs (../shared/data/robots, MIT) are the same arms with meshes but other link frames. A
/// robot's `appearance:` (robot_defaults.hpp) names which of its links wear which of the other
/// description's links, and which of its joints drive which of the other's. From the two models'
/// forward kinematics at seeded poses this finds where each worn mesh sits on its link:
///
///   the other description's base frame in this robot's (X_BO): a hand-eye fit, A X = X B over
///   every worn link's motion between poses (rotation by the Kabsch fit of the motions' axes,
///   translation by least squares); then each worn link's offset X_LO = X_BL(q0)^-1 X_BO
///   X_OL'(q0'), and over every pose the distance between where the worn mesh is drawn
///   (X_BL(q) X_LO) and where its own model puts it (X_BO X_OL'(q')), at the corners of its box.
///
/// The dressing is refused, naming the link, when a mesh would sit more than the appearance's
/// `tolerance` from its own model's place at some pose: the two models do not move together there
/// (a joint mapped to the wrong one, a sign or zero offset missing).

#include <string>
#include <vector>

#include "robot/robot_model.hpp"

namespace trocar::kinematics {

struct Dressing {
  /// Per link of the robot: the meshes it wears, posed in the link's frame (X_LG); empty for
  /// links that wear nothing (drawn with their own shapes).
  std::vector<std::vector<robot::Geometry>> worn;
  /// Why some appearance was not used (its description file missing), one line each.
  std::vector<std::string> notes;
  /// Per link: the largest distance between its worn meshes as drawn and as their own model
  /// places them, over the fitting poses (m; 0 for links that wear nothing).
  std::vector<double> drift;
  /// The largest of them, and the link it was on.
  double worst_m = 0.0;
  std::string worst_link;
  bool any() const;
};

struct DressingOptions {
  int poses = 48;  ///< seeded poses the fit and the check use
  unsigned seed = 1;
};

/// Dresses `model` in its appearances (model.defaults().appearances).
/// @throws trocar::Error naming the appearance's file and the link or joint: a name the dressing
///         description lacks, a joint that is not active in its model, or a worn mesh that does
///         not follow its link (more than the appearance's tolerance off at some pose).
Dressing DressRobot(const robot::RobotModel& model, const DressingOptions& options = {});

}  // namespace trocar::kinematics
