#pragma once
/// @file
/// Robot meshes for visual and collision geometry, loaded through assimp (the mesh type itself is
/// common/mesh.hpp).

#include <memory>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "common/mesh.hpp"

namespace trocar::robot {

using trocar::TriangleMesh;
using trocar::ValidateMesh;

/// Loads STL, OBJ, DAE, PLY (anything assimp reads), merging all sub-meshes, scaled per axis.
/// Zero-area triangles are removed and counted in `degenerate_triangles_removed`.
/// @throws trocar::Error naming `path` when the file is missing, unreadable, holds no triangles,
///         or has non-finite vertices.
std::shared_ptr<const TriangleMesh> LoadMesh(const std::string& path,
                                             const Eigen::Vector3d& scale = Eigen::Vector3d::Ones());

}  // namespace trocar::robot
