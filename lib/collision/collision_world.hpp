#pragma once
/// @file
/// Collision checking between the robot's arms, the patient and the table (FCL, kept private).
///
/// Model/state split (docs/architecture.md): a CollisionWorld holds the immutable shared geometry — one BVH
/// per patient structure and per robot mesh, primitives for capsules and boxes, and for each
/// patient structure our own exact hierarchy (triangle_bvh.hpp) that answers the robot's
/// capsules, spheres and boxes against it — and the rules (allowed pairs, ports). A
/// CollisionChecker, one per thread, owns its FCL objects and their poses and answers the queries.
/// Checkers share the world's geometry and never modify it.
///
/// Ports: an instrument's shaft passes through the skin at its own port by design. A robot link
/// below an arm's insertion joint is an *instrument* link of that arm's port (the RCM frame);
/// its contacts with the skin within `port_radius` of the port are not collisions, contacts
/// anywhere else are. Distances between instrument links and the skin are not reported (they
/// are zero by design at the port); instrument links against bones and organs are.

#include <Eigen/Geometry>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "common/mesh.hpp"
#include "robot/robot_model.hpp"
#include "robot/robot_state.hpp"

namespace trocar::patient {
struct PatientModel;
struct Table;
}  // namespace trocar::patient

namespace trocar::collision {

/// Bounding volumes of the meshes' hierarchies. FCL 0.7 transforms (copies) a mesh on every
/// query for AABB, RSS and kIOS trees; OBB and OBBRSS are queried in place. Distance queries
/// need OBBRSS (FCL has no OBB distance traversal).
enum class BvhKind { kObbRss, kObb };
const char* ToString(BvhKind kind);

/// What a collision or clearance is between.
enum class PairClass {
  kArmArm,             ///< robot links of two different arms (or an arm and the cart)
  kArmPatient,         ///< a robot link (not an instrument) and a patient structure
  kInstrumentPatient,  ///< an instrument link and a patient structure (ribs, heart; skin away from
                       ///< the port)
  kArmTable,           ///< a robot link and the table (or another fixed obstacle)
  kSelf,               ///< two links of the same arm that are not allowed to touch
  kPatientTable,       ///< never queried: fixed bodies do not move relative to each other
};
const char* ToString(PairClass cls);
/// Bit for a PairClass in a class mask.
constexpr unsigned Bit(PairClass cls) { return 1u << static_cast<unsigned>(cls); }
constexpr unsigned kAllMovingPairs = Bit(PairClass::kArmArm) | Bit(PairClass::kArmPatient) |
                                     Bit(PairClass::kInstrumentPatient) |
                                     Bit(PairClass::kArmTable) | Bit(PairClass::kSelf);

/// One collision object: a shape of a robot link, a patient structure, the table.
struct Body {
  enum class Kind { kRobot, kPatient, kFixed };
  std::string name;  ///< "psm1_yaw_link", "psm1_insertion_link#1" (second shape), "skin", "table"
  Kind kind = Kind::kFixed;
  int link = -1;       ///< robot link index (robot bodies)
  int arm = -1;        ///< robot: index into CollisionWorld::arms(); -1 for the robot's base link
  int port = -1;       ///< robot: the port its link passes through (an instrument link), else -1
  /// robot: an instrument's wrist or jaws (an instrument link whose origin lies within
  /// WorldOptions::distal_reach of one of the instrument's deepest links at rest): it may touch the
  /// patient at its port's work site (CollisionChecker::SetWorkSite).
  bool distal = false;
  bool skin = false;   ///< the patient's skin (where ports are)
  /// The chest wall's rigid frame that bounds the intercostal spaces (ribs, costal cartilages):
  /// an instrument's cannula may lean on it at its own port, its axis never crossing it
  /// (CollisionChecker::SetPortPosition; docs/decisions.md, "contact rules").
  bool chest_wall = false;
  long triangles = 0;  ///< mesh bodies
};

/// An arm: a subtree hanging from the robot's base link (a da Vinci cart has psm1, psm2, ecm).
struct Arm {
  std::string name;
  int root_link = -1;
};

/// A port: the remote centre of motion of an arm, and the links passing through it.
struct Port {
  std::string frame;  ///< the robot frame at the port, e.g. "psm1_rcm"; "" for a shaft port
  int arm = -1;
  std::vector<int> links;  ///< instrument links (below the arm's insertion joint)
};

struct WorldOptions {
  BvhKind bvh = BvhKind::kObbRss;
  /// Contacts between an instrument and the skin within this distance of its port are allowed.
  double port_radius = 0.015;  ///< m
  /// An instrument's distal links (its wrist and jaws): those within this distance of its deepest
  /// links at rest (m). The EndoWrist's wrist lies about 1 cm behind its jaws' tips.
  double distal_reach = 0.02;
  /// Ports: robot frames at the RCMs; empty: every frame whose name ends in "rcm" whose link has
  /// a prismatic (insertion) joint below it.
  std::vector<std::string> port_frames;
  /// Ports without an RCM frame (an arm holding its instrument through a port in software): the
  /// named link and every link below it are that port's instrument; the port's position is set
  /// with CollisionChecker::SetPortPosition (until then, the link's origin).
  std::vector<std::string> shaft_ports;
  bool add_table = true;
  /// Capsules, spheres and boxes against the patient's meshes by our exact hierarchy
  /// (triangle_bvh.hpp), and capsule–capsule and capsule–box collisions in closed form: mesh
  /// distances about 1000x faster than FCL 0.7's mesh–shape distance. false: FCL for every pair
  /// (the peer in the benchmark, a cross-check in tests).
  bool exact_mesh_queries = true;
  /// Self-collision pairs allowed automatically: links joined by a joint, and pairs in contact in
  /// at least `always_fraction` of `acm_samples` seeded random configurations (every movable
  /// joint within its limits), as MoveIt's setup assistant does.
  int acm_samples = 300;
  double always_fraction = 0.98;
  unsigned acm_seed = 1;
};

/// Where a straight line first meets a patient structure (CollisionWorld::FirstAcross).
struct SightLine {
  int body = -1;  ///< the structure met; -1: the line is clear
  Eigen::Vector3d p_W = Eigen::Vector3d::Zero();  ///< a point of the line on it
  bool clear() const { return body < 0; }
};

/// A pair that may touch, by body name ("psm1_jaw_1_link", "heart", "table") or by a robot
/// link's name, which covers all of its shapes.
struct AllowedPair {
  std::string a, b;
};

class CollisionWorld {
 public:
  /// Builds a world from a patient (its structures in P, placed at X_WP, and its table), a robot
  /// (its links' collision shapes; may be null) and extra allowed pairs.
  /// @throws trocar::Error naming the mesh for degenerate meshes (empty, NaN vertices, zero-area
  ///         triangles, bad indices) and the link for bad shapes; unknown port frames or
  ///         allowed-pair names.
  static std::shared_ptr<const CollisionWorld> Build(const patient::PatientModel* patient,
                                                     std::shared_ptr<const robot::RobotModel> robot,
                                                     const WorldOptions& options = {},
                                                     const std::vector<AllowedPair>& allowed = {});

  /// A world from meshes and primitives alone (tests, scenes): fixed bodies in W.
  struct FixedMesh {
    std::string name;
    TriangleMesh mesh;
    Eigen::Isometry3d X_WM = Eigen::Isometry3d::Identity();
    bool skin = false;
    bool patient = true;
    /// Body::chest_wall (a patient structure); also set by name: "ribs", "rib...", "..._rib...",
    /// "...cartilage..."
    bool chest_wall = false;
  };
  static std::shared_ptr<const CollisionWorld> Build(const std::vector<FixedMesh>& meshes,
                                                     std::shared_ptr<const robot::RobotModel> robot,
                                                     const WorldOptions& options = {},
                                                     const std::vector<AllowedPair>& allowed = {});

  /// This world with the named fixed bodies (patient structures) translated by d_W (m, world
  /// frame); every body's geometry and hierarchy, the allowed pairs and the robot shared with
  /// this world (nothing is rebuilt: the robustness check moves the heart with its targets).
  /// @throws trocar::Error naming a body that is not a fixed body of this world.
  std::shared_ptr<const CollisionWorld> WithBodiesMoved(const std::vector<std::string>& names,
                                                        const Eigen::Vector3d& d_W) const;

  ~CollisionWorld();
  CollisionWorld(const CollisionWorld&) = delete;
  CollisionWorld& operator=(const CollisionWorld&) = delete;

  const std::vector<Body>& bodies() const;
  const std::vector<Arm>& arms() const;
  const std::vector<Port>& ports() const;
  const robot::RobotModel* robot() const;
  const WorldOptions& options() const;
  /// Whether a pair of bodies is never checked (allowed to touch).
  bool Allowed(int a, int b) const;
  /// Number of robot body pairs allowed automatically (adjacent or always touching) and by the
  /// caller.
  int auto_allowed_pairs() const;
  PairClass Classify(int a, int b) const;
  /// A body in the words a surgeon reads, with the model's name for an engineer: "psm1's shaft
  /// (psm1_insertion_link#1)" (an instrument link through its port), "psm1's wrist
  /// (psm1_wrist_yaw_link)" (Body::distal), "psm2's arm (psm2_pitch_bottom_link)", "the robot's
  /// base (cart)", "the heart", "the table".
  std::string DescribeBody(int body) const;
  /// Two bodies in contact, the robot's first: "psm1's shaft (psm1_insertion_link#1) against the
  /// heart".
  std::string DescribePair(int a, int b) const;
  int FindBody(const std::string& name) const;
  long triangle_count() const;
  /// The patient structure (skin, bone, organ: Body::Kind::kPatient) that the straight line from
  /// `from_W` to `to_W` meets nearest `from_W`, leaving out the last `near_to` metres of the line
  /// (a point on a surface, seen at a grazing angle, is not hidden by that surface next to it);
  /// clear when it meets none (a line wholly inside a closed surface meets none: a camera inside
  /// an organ is a collision, found by the checker). An endoscope sees a target only along a clear line (issue #41,
  /// item 5). With the patient bodies where the world holds them (a world with the targets moved
  /// has its heart moved).
  SightLine FirstAcross(const Eigen::Vector3d& from_W, const Eigen::Vector3d& to_W,
                        double near_to) const;

  struct Impl;
  const Impl& impl() const { return *impl_; }

 private:
  explicit CollisionWorld(std::unique_ptr<Impl> impl);
  static std::shared_ptr<const CollisionWorld> BuildWith(
      const std::vector<FixedMesh>& meshes, const patient::Table* table,
      std::shared_ptr<const robot::RobotModel> robot, const WorldOptions& options,
      const std::vector<AllowedPair>& allowed);
  std::unique_ptr<Impl> impl_;
};

/// A pair of bodies in contact.
struct Contact {
  int a = -1, b = -1;  ///< body indices
  PairClass cls = PairClass::kArmArm;
  Eigen::Vector3d p_W = Eigen::Vector3d::Zero();  ///< a contact point
  /// Penetration depth (m): a capsule or sphere against a mesh, its radius less its axis'
  /// distance (a lower bound once the axis crosses the surface); a box against a mesh, 0 (not
  /// estimated); two capsules, the radii less their axes' distance; otherwise FCL's estimate.
  double depth = 0.0;
};

struct CollisionReport {
  bool collision = false;
  std::vector<Contact> contacts;  ///< one per body pair, in body order
  int port_contacts_allowed = 0;  ///< instrument–skin pairs touching only at their port
  /// instrument–rib pairs where the cannula leans on the ribs of its own port, its axis clear
  int seat_contacts_allowed = 0;
  int work_contacts_allowed = 0;  ///< wrist/jaw–organ pairs touching only at their work site
};

/// Minimum distance between two bodies with witness points.
struct Clearance {
  double distance = std::numeric_limits<double>::infinity();  ///< m; 0 when in contact
  int a = -1, b = -1;
  PairClass cls = PairClass::kArmArm;
  Eigen::Vector3d p_W_a = Eigen::Vector3d::Zero(), p_W_b = Eigen::Vector3d::Zero();
  bool valid() const { return a >= 0; }
};

/// Per-thread queries over a shared world. Not thread safe itself: give each thread its own.
class CollisionChecker {
 public:
  explicit CollisionChecker(std::shared_ptr<const CollisionWorld> world);
  ~CollisionChecker();
  CollisionChecker(const CollisionChecker&) = delete;
  CollisionChecker& operator=(const CollisionChecker&) = delete;

  /// Places the robot's shapes from `state.X_WL` (after kinematics::ForwardKinematics); each
  /// port follows its RCM frame (a shaft port keeps the position last set, or starts at its
  /// link's origin).
  void SetRobotState(const robot::RobotState& state);
  /// Puts a port somewhere other than its RCM frame (until the next SetRobotState), and with
  /// `radius` >= 0 sets how far from it an instrument may touch the skin (default
  /// WorldOptions::port_radius; kept until set again: SetRobotState does not reset it). Within
  /// the same distance its instrument may lean on the chest wall's frame (Body::chest_wall: the
  /// ribs bounding its space) as long as the instrument's axis does not cross it: the cannula
  /// rests against the rib's edge, it does not pass through bone.
  void SetPortPosition(int port, const Eigen::Vector3d& p_W, double radius = -1.0);
  const Eigen::Vector3d& port_position(int port) const;
  double port_radius(int port) const;
  /// The work site of a port's instrument: its distal links (Body::distal: wrist and jaws) may
  /// touch the patient's structures other than the skin within `radius` of `p_W` (the target they
  /// work on: the LAD lies on the heart, and reaching it is touching the heart there;
  /// docs/decisions.md, "contact rules"). Every other contact of the instrument stays a collision.
  /// `radius` < 0 clears it (the default: no work site). Kept until set again.
  void SetWorkSite(int port, const Eigen::Vector3d& p_W, double radius);
  /// Clears every port's work site.
  void ClearWorkSites();

  /// Yes/no, stopping at the first collision among the classes in `mask`. With `arm` >= 0 (an
  /// index into CollisionWorld::arms()), only the pairs with a body of that arm: what a caller
  /// who moved that arm alone from a pose it knows to be free needs to check.
  bool InCollision(unsigned mask = kAllMovingPairs, int arm = -1);
  /// Every colliding pair among the classes in `mask` (with `arm` >= 0, of that arm's bodies).
  CollisionReport Check(unsigned mask = kAllMovingPairs, int arm = -1);
  /// Minimum distance over the pairs of the classes in `mask`, with witness points (needs an
  /// OBBRSS world). Pairs in contact give 0. With `arm` >= 0 (an index into
  /// CollisionWorld::arms()), only the pairs with a body of that arm. With `below` finite, only a
  /// distance under it is sought: pairs whose bounds lie at or beyond it are skipped, and a state
  /// with nothing nearer gives an invalid Clearance (the minimum along a path needs no more).
  Clearance MinimumDistance(unsigned mask = kAllMovingPairs, int arm = -1,
                            double below = std::numeric_limits<double>::infinity());
  /// The minimum distance of each class present in the world (index: PairClass).
  std::vector<Clearance> ClearanceByClass();

  const CollisionWorld& world() const { return *world_; }

 private:
  struct State;
  std::shared_ptr<const CollisionWorld> world_;
  std::unique_ptr<State> state_;
};

}  // namespace trocar::collision
