#pragma once
/// @file
/// Scene files (thesis §2.11): what a view shows — the case, the plan and which of its plans (or
/// a robot alone), the robot's base pose and joint values, the external camera, the colours,
/// opacities and visibility of every group, the background — as JSON (`format: trocar-scene`),
/// written atomically. Loading one renders the same picture as the view it was saved from.

#include <string>
#include <utility>
#include <vector>

#include "scene.hpp"
#include "view_inputs.hpp"

namespace trocar::viz {

constexpr int kSceneFormatVersion = 1;

struct SceneFile {
  ViewInputs inputs;  ///< case, plan, plan index, robot (paths absolute when saved)
  bool has_robot_state = false;
  Eigen::Isometry3d X_WB = Eigen::Isometry3d::Identity();
  std::vector<std::pair<std::string, double>> q;  ///< active joints by name
  bool has_camera = false;
  CameraPose camera;  ///< the external view's
  SceneStyle style;
};

/// What `scene` (opened from `inputs`) shows now, with the external camera `camera` (optional).
SceneFile CaptureScene(const ViewInputs& inputs, const Scene& scene, const CameraPose* camera);

/// @throws trocar::Error naming the path when it cannot be written.
void WriteSceneFile(const std::string& path, const SceneFile& file);

/// @throws trocar::Error naming the file and field for a missing, malformed or foreign file.
SceneFile ReadSceneFile(const std::string& path);

/// Opens the view a scene file describes: its inputs loaded and checked as LoadView does, then
/// its style, base pose and joint values. @throws trocar::Error as LoadView, and naming a joint
/// the robot has not.
LoadedView LoadScene(const SceneFile& file);

/// Applies a scene file's robot state and style to an open scene of the same case and robot.
/// @throws trocar::Error naming a joint the robot has not or a robot state with no robot.
void ApplyScene(const SceneFile& file, Scene* scene);

}  // namespace trocar::viz
