#pragma once
// Private to lib/collision: the FCL side of CollisionWorld. Not installed, not included by any
// public header.

#include <fcl/fcl.h>

#include <memory>
#include <optional>
#include <mutex>
#include <vector>

#include "collision/collision_world.hpp"
#include "collision/triangle_bvh.hpp"

namespace trocar::collision {

struct CollisionWorld::Impl {
  WorldOptions options;
  std::shared_ptr<const robot::RobotModel> robot;
  std::vector<Body> bodies;
  /// Per body: its shared immutable geometry (bodies built from one mesh share one BVH).
  std::vector<std::shared_ptr<fcl::CollisionGeometryd>> geometry;
  /// Per body: robot bodies, the shape's pose in its link (X_LG); fixed bodies, its pose in W.
  std::vector<Eigen::Isometry3d> X_pose;
  /// A robot body that is a capsule, a sphere or a box, checked against patient meshes with
  /// `mesh` (our exact BVH) rather than FCL: a capsule's axis in the shape frame G (a == b for a
  /// sphere) and radius; a box's half sizes.
  struct Convex {
    enum class Kind { kOther, kSweptSphere, kBox };
    Kind kind = Kind::kOther;
    Eigen::Vector3d a_G = Eigen::Vector3d::Zero(), b_G = Eigen::Vector3d::Zero();
    double radius = 0.0;
    Eigen::Vector3d half = Eigen::Vector3d::Zero();
  };
  std::vector<Convex> convex;                            ///< per body
  std::vector<std::shared_ptr<const TriangleBvh>> mesh;  ///< per body: fixed meshes, else null
  std::vector<Arm> arms;
  std::vector<Port> ports;
  /// Per port: its frame (a named frame or a link's); none for a shaft port (its link in port_link)
  std::vector<std::optional<robot::Frame>> port_frame;
  std::vector<int> port_link;
  std::vector<int> robot_bodies, fixed_bodies;
  std::vector<char> allowed;       ///< bodies × bodies
  std::vector<PairClass> classes;  ///< bodies × bodies
  int auto_allowed = 0;
  long triangles = 0;
  /// FCL's CollisionObject constructor writes the geometry's local AABB (the same values every
  /// time): checkers build their objects under this lock so that the shared geometry is never
  /// written concurrently.
  /// Shared by the worlds that share this geometry (CollisionWorld::WithBodiesMoved).
  std::shared_ptr<std::mutex> object_construction = std::make_shared<std::mutex>();

  std::size_t n() const { return bodies.size(); }
  bool Allowed(int a, int b) const { return allowed[static_cast<std::size_t>(a) * n() + b] != 0; }
  PairClass Class(int a, int b) const { return classes[static_cast<std::size_t>(a) * n() + b]; }
};

}  // namespace trocar::collision
