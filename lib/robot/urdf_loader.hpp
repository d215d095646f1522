#pragma once
/// @file
/// URDF reading (urdfdom) into a RobotModelBuilder.

#include <string>
#include <vector>

#include "robot/robot_model.hpp"

namespace trocar::robot {

struct LoadOptions {
  /// Read mesh files into memory (visual and collision). Mesh files must exist either way.
  bool load_meshes = true;
  /// Extra roots searched for package://<package>/... mesh paths, before the environment's
  /// TROCAR_PACKAGE_PATH and ROS_PACKAGE_PATH (colon-separated).
  std::vector<std::string> package_paths;
};

/// Resolves a mesh reference of a description file: relative (to the file's folder), file://,
/// or package://<package>/<path> (looked up beside the file, then in the package paths).
/// @throws trocar::Error naming the description file and the reference when not found.
std::string ResolveMeshPath(const std::string& uri, const std::string& description_file,
                            const std::vector<std::string>& package_paths);

/// Parses a URDF file: links with visual/collision geometry (meshes loaded through assimp),
/// revolute/continuous/prismatic/fixed joints, limits and mimic joints.
/// @throws trocar::Error naming the file and element for malformed XML, unsupported joint
///         types, missing meshes.
RobotModelBuilder ParseUrdf(const std::string& path, const LoadOptions& options = {});

}  // namespace trocar::robot
