#pragma once
/// @file
/// Indexed triangle meshes in metres, shared by robots (visual and collision geometry), patients
/// (surfaces from CT) and the collision world; measures and a binary STL writer.

#include <string>
#include <vector>

#include <Eigen/Geometry>

namespace trocar {

/// An indexed triangle mesh in metres, in the frame named by its owner.
struct TriangleMesh {
  std::vector<Eigen::Vector3d> vertices;
  std::vector<Eigen::Vector3i> triangles;
  std::string source;                    ///< file or structure it came from
  int degenerate_triangles_removed = 0;  ///< zero-area triangles dropped at load (counted, reported)
};

double TriangleArea(const TriangleMesh& mesh, const Eigen::Vector3i& triangle);
/// Total area (m²).
double MeshArea(const TriangleMesh& mesh);
/// Signed enclosed volume (m³) by the divergence theorem: positive for a closed mesh whose
/// triangles wind counter-clockwise seen from outside.
double MeshSignedVolume(const TriangleMesh& mesh);
/// Edges used by exactly one triangle (0 for a closed surface) and by more than two.
struct EdgeCounts {
  long boundary = 0, non_manifold = 0, total = 0;
};
EdgeCounts CountEdges(const TriangleMesh& mesh);
/// The point of triangle (a, b, c) nearest to p (Ericson, Real-Time Collision Detection, 5.1.5).
Eigen::Vector3d ClosestPointOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                                       const Eigen::Vector3d& b, const Eigen::Vector3d& c);
/// Distance from p to the mesh's surface by visiting every triangle (for a few queries on a mesh
/// without a hierarchy; collision/triangle_bvh.hpp answers many); infinity for an empty mesh.
double DistanceToMesh(const TriangleMesh& mesh, const Eigen::Vector3d& p);
/// Axis-aligned bounds of the vertices.
void MeshBounds(const TriangleMesh& mesh, Eigen::Vector3d* min, Eigen::Vector3d* max);

/// Checks a mesh: at least one triangle, finite vertices, indices in range, no zero-area
/// triangle. @throws trocar::Error whose message starts with `name`.
void ValidateMesh(const TriangleMesh& mesh, const std::string& name);

/// Writes binary STL (3D Slicer, MeshLab and Blender open it), in millimetres when `mm`,
/// atomically.
void WriteStl(const TriangleMesh& mesh, const std::string& path, bool mm = true);

}  // namespace trocar
