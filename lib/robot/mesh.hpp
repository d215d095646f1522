#pragma once
/// @file
/// Triangle meshes for visual and collision geometry, loaded through assimp.

#include <memory>
#include <string>
#include <vector>

#include <Eigen/Geometry>

namespace trocar::robot {

/// An indexed triangle mesh in metres, in the frame of the file (after `scale`).
struct TriangleMesh {
  std::vector<Eigen::Vector3d> vertices;
  std::vector<Eigen::Vector3i> triangles;
  std::string source;                 ///< file it came from
  int degenerate_triangles_removed = 0;  ///< zero-area triangles dropped at load (counted, reported)
};

/// Loads STL, OBJ, DAE, PLY (anything assimp reads), merging all sub-meshes, scaled per axis.
/// Zero-area triangles are removed and counted in `degenerate_triangles_removed`.
/// @throws trocar::Error naming `path` when the file is missing, unreadable, holds no triangles,
///         or has non-finite vertices.
std::shared_ptr<const TriangleMesh> LoadMesh(const std::string& path,
                                             const Eigen::Vector3d& scale = Eigen::Vector3d::Ones());

/// Checks a mesh made in code: finite vertices, indices in range, at least one triangle of
/// non-zero area. @throws trocar::Error whose message starts with `name`.
void ValidateMesh(const TriangleMesh& mesh, const std::string& name);

}  // namespace trocar::robot
