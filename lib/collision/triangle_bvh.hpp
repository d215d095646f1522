#pragma once
/// @file
/// Exact distance and contact queries between a triangle mesh and a segment (a capsule's axis; a
/// point for a sphere), over an axis-aligned bounding-box hierarchy. Part of lib/collision's
/// implementation: the checker uses it for the robot's capsules and spheres against the patient's
/// meshes, where FCL 0.7's mesh–shape distance visits far more leaves than it needs (its GJK leaf
/// tests dominate; docs/decisions.md, "Collision").
///
/// Nodes are pruned with the exact segment–box distance, children are visited nearer first, and
/// leaves use closed-form segment–triangle closest points, so a query costs a few hundred box
/// tests on a 10^5-triangle mesh. Immutable after construction: share it between threads.

#include <Eigen/Geometry>
#include <limits>
#include <vector>

#include "common/mesh.hpp"

namespace trocar::collision {

/// Closest points between a query shape (segment, point or box) and a triangle mesh (mesh frame M).
struct MeshClosest {
  double distance = std::numeric_limits<double>::infinity();  ///< m; 0 when they intersect
  Eigen::Vector3d p_M_query = Eigen::Vector3d::Zero();        ///< on the segment or box
  Eigen::Vector3d p_M_mesh = Eigen::Vector3d::Zero();         ///< on the mesh
  int triangle = -1;                                          ///< -1: nothing closer than the bound
  bool found() const { return triangle >= 0; }
};

/// A contact of a swept sphere (capsule) with a mesh, outside an excluded ball (the port).
struct SweptSphereContact {
  bool outside = false;   ///< some triangle is within the radius at a point outside the ball
  bool excluded = false;  ///< some triangle is within the radius only inside the ball
  Eigen::Vector3d p_M = Eigen::Vector3d::Zero();  ///< the first outside contact's point on the mesh
  double depth = 0.0;                             ///< radius minus its distance to the segment
};

class TriangleBvh;

/// One query of a joint search (TriangleBvh::ClosestOfAll): a capsule or sphere (axis [a, b] and
/// radius) or a box (pose and half sizes), against one mesh, all in that mesh's frame M.
struct MeshQuery {
  const TriangleBvh* mesh = nullptr;
  bool box = false;
  Eigen::Vector3d a_M = Eigen::Vector3d::Zero(), b_M = Eigen::Vector3d::Zero();
  double radius = 0.0;
  Eigen::Isometry3d X_MB = Eigen::Isometry3d::Identity();
  Eigen::Vector3d half = Eigen::Vector3d::Zero();
};

/// The nearest of several queries: which one, its surface distance (a capsule's distance less its
/// radius, never below 0) and witness points on the query's surface and on the mesh.
struct NearestQuery {
  int query = -1;  ///< index into the queries; -1: nothing closer than the bound
  double distance = std::numeric_limits<double>::infinity();
  Eigen::Vector3d p_M_query = Eigen::Vector3d::Zero(), p_M_mesh = Eigen::Vector3d::Zero();
};

class TriangleBvh {
 public:
  /// Builds the hierarchy (median split along the longest axis; `leaf_size` triangles a leaf).
  /// The mesh must be valid (ValidateMesh).
  explicit TriangleBvh(const TriangleMesh& mesh, int leaf_size = 4);

  /// Closest points between the segment [a, b] (a == b: a point) and the mesh, when closer than
  /// `bound`; otherwise nothing found.
  MeshClosest Closest(const Eigen::Vector3d& a_M, const Eigen::Vector3d& b_M,
                      double bound = std::numeric_limits<double>::infinity()) const;

  /// Closest points between a box (centred at X_MB, half sizes `half`) and the mesh, when
  /// closer than `bound`.
  MeshClosest ClosestToBox(const Eigen::Isometry3d& X_MB, const Eigen::Vector3d& half,
                           double bound = std::numeric_limits<double>::infinity()) const;

  /// Whether a capsule (segment [a, b], radius) touches the mesh. With `exclude_radius` >= 0 a
  /// triangle whose closest point to the axis lies within `exclude_radius` of `exclude_centre`
  /// does not count (it reports `excluded`); `stop_at_first` stops at the first counting contact.
  SweptSphereContact Touches(const Eigen::Vector3d& a_M, const Eigen::Vector3d& b_M, double radius,
                             const Eigen::Vector3d& exclude_centre = Eigen::Vector3d::Zero(),
                             double exclude_radius = -1.0) const;

  /// Whether a box (centred at X_MB, half sizes) intersects the mesh, with the same exclusion.
  /// Its `depth` is not estimated (0).
  SweptSphereContact BoxTouches(const Eigen::Isometry3d& X_MB, const Eigen::Vector3d& half,
                                const Eigen::Vector3d& exclude_centre = Eigen::Vector3d::Zero(),
                                double exclude_radius = -1.0) const;

  /// The distance along the ray from `origin_M` in direction `dir_M` (any length) to the first
  /// triangle it crosses, either face, within `max_t` (m); infinity when none.
  double FirstHit(const Eigen::Vector3d& origin_M, const Eigen::Vector3d& dir_M,
                  double max_t = std::numeric_limits<double>::infinity()) const;

  /// Brute force over every triangle (tests): Closest and ClosestToBox must agree with these.
  MeshClosest ClosestBruteForce(const Eigen::Vector3d& a_M, const Eigen::Vector3d& b_M) const;
  MeshClosest ClosestToBoxBruteForce(const Eigen::Isometry3d& X_MB,
                                     const Eigen::Vector3d& half) const;

  int triangle_count() const { return static_cast<int>(triangles_.size()); }

  /// The nearest of all `queries` (each against its own mesh), searched best first over all of
  /// them at once: one priority queue of (query, node) by lower bound, so that only nodes nearer
  /// than the final answer are opened, whichever query they belong to. Nothing is reported unless
  /// nearer than `bound`. `scratch` is reused between calls (no allocation once warm).
  struct Scratch;
  static NearestQuery ClosestOfAll(const std::vector<MeshQuery>& queries, double bound,
                                   Scratch* scratch);

 private:
  struct Node {
    Eigen::Vector3d lo, hi;
    int first = 0;  ///< leaf: first triangle; inner: left child (right child = first + 1)
    int count = 0;  ///< leaf: triangles; inner: 0
  };
  struct Triangle {
    Eigen::Vector3d v0, v1, v2;
    int index = -1;  ///< in the input mesh
  };
  void Build(int begin, int end, int leaf_size);
  template <typename Query>
  MeshClosest Search(const Query& query, double bound) const;
  template <typename Query>
  SweptSphereContact TouchesWith(const Query& query, double radius,
                                 const Eigen::Vector3d& exclude_centre,
                                 double exclude_radius) const;

  std::vector<Node> nodes_;
  std::vector<Triangle> triangles_;
};

struct TriangleBvh::Scratch {
  struct Entry {
    double bound;  ///< lower bound on the surface distance
    int query, node;
  };
  std::vector<Entry> heap;
};

/// Exact squared distance between the segment [a, b] and the box [lo, hi]; `t` (optional): the
/// parameter along the segment where it is attained.
double SegmentBoxDistanceSquared(const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                                 const Eigen::Vector3d& lo, const Eigen::Vector3d& hi,
                                 double* t = nullptr);

/// Closest points between a box (centred at the origin of its frame B, half sizes `half`) and the
/// triangle (v0, v1, v2) given in B; returns the distance.
double BoxTriangleClosest(const Eigen::Vector3d& half, const Eigen::Vector3d& v0,
                          const Eigen::Vector3d& v1, const Eigen::Vector3d& v2,
                          Eigen::Vector3d* p_box, Eigen::Vector3d* p_triangle);

/// Closest points of the segments [p1, q1] and [p2, q2] (either may be a point); returns the
/// squared distance.
double SegmentSegmentClosest(const Eigen::Vector3d& p1, const Eigen::Vector3d& q1,
                             const Eigen::Vector3d& p2, const Eigen::Vector3d& q2,
                             Eigen::Vector3d* c1, Eigen::Vector3d* c2);

/// Closest points between the segment [a, b] and the triangle (v0, v1, v2); returns the distance.
double SegmentTriangleClosest(const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                              const Eigen::Vector3d& v0, const Eigen::Vector3d& v1,
                              const Eigen::Vector3d& v2, Eigen::Vector3d* p_segment,
                              Eigen::Vector3d* p_triangle);

}  // namespace trocar::collision
