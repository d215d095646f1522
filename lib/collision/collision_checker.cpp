// CollisionChecker: per-thread FCL objects over a shared CollisionWorld. Robot shapes against each
// other go through FCL's broadphase (a dynamic AABB tree refitted after each SetRobotState); robot
// shapes against the fixed bodies (a handful of patient structures and the table) through a loop
// over the pairs screened by their boxes. Capsules, spheres and boxes against meshes use our exact
// TriangleBvh, capsule–capsule and capsule–box pairs a closed form, everything else FCL. Pairs
// are filtered by the world's allowed pairs, the caller's class mask and the port rule.
#include <algorithm>
#include <cmath>

#include "collision/collision_world.hpp"
#include "collision/fcl_types.hpp"
#include "common/error.hpp"
#include "kinematics/forward_kinematics.hpp"

namespace trocar::collision {
namespace {

constexpr std::size_t kPortContacts = 64;

int BodyOf(const fcl::CollisionObjectd* o) {
  return static_cast<int>(reinterpret_cast<std::intptr_t>(o->getUserData()));
}

using Convex = CollisionWorld::Impl::Convex;

struct QueryData {
  const CollisionWorld::Impl* world = nullptr;
  const std::vector<Eigen::Vector3d>* port_W = nullptr;
  const std::vector<double>* port_radius = nullptr;
  const std::vector<Eigen::Vector3d>* work_W = nullptr;
  const std::vector<double>* work_radius = nullptr;
  unsigned mask = 0;
  int arm = -1;  ///< >= 0: only pairs with a body of this arm
  bool stop_at_first = false;
  bool want_contacts = false;
  bool done = false;
  CollisionReport report;
  bool OfArm(int a, int b) const {
    return arm < 0 || world->bodies[a].arm == arm || world->bodies[b].arm == arm;
  }
};

// If one of the bodies is an instrument link and the other the skin: the port the instrument
// passes through, else -1. `instrument_first` tells which is which.
int PortPair(const CollisionWorld::Impl& w, int a, int b) {
  const Body& A = w.bodies[a];
  const Body& B = w.bodies[b];
  if (A.port >= 0 && B.skin) return A.port;
  if (B.port >= 0 && A.skin) return B.port;
  return -1;
}

// If one of the bodies is an instrument link drawn as a capsule and the other the chest wall's
// frame (Body::chest_wall: the ribs that bound its space): the port the instrument passes
// through, else -1. Its cannula may lean on them near the port, its axis never crossing them.
int SeatPair(const CollisionWorld::Impl& w, int a, int b) {
  const Body& A = w.bodies[a];
  const Body& B = w.bodies[b];
  const int r = A.kind == Body::Kind::kRobot ? a : b;
  const Body& robot = w.bodies[r];
  const Body& other = r == a ? B : A;
  if (robot.port < 0 || !other.chest_wall) return -1;
  return w.convex[r].kind == Convex::Kind::kSweptSphere ? robot.port : -1;
}

// Whether the axis of robot body r (a capsule) crosses fixed body f's mesh: a cannula leaning on a
// rib at its port is allowed (SeatPair), one passing through the bone is not.
SweptSphereContact AxisCrosses(const CollisionWorld::Impl& w, const fcl::CollisionObjectd& o_r,
                               int r, int f) {
  const Eigen::Isometry3d X_MR = w.X_pose[f].inverse() * o_r.getTransform();
  SweptSphereContact hit = w.mesh[f]->Touches(X_MR * w.convex[r].a_G, X_MR * w.convex[r].b_G, 0.0);
  hit.depth = w.convex[r].radius;  // the axis is in the bone: at least the radius deep
  return hit;
}

// If one of the bodies is an instrument's distal link (wrist, jaws) whose port has a work site,
// and the other a patient structure that is not the skin: that port, else -1.
int WorkPair(const CollisionWorld::Impl& w, const std::vector<double>& work_radius, int a, int b) {
  const Body& A = w.bodies[a];
  const Body& B = w.bodies[b];
  const Body* robot = A.kind == Body::Kind::kRobot ? &A : &B;
  const Body* other = robot == &A ? &B : &A;
  if (!robot->distal || robot->port < 0 || other->kind != Body::Kind::kPatient || other->skin)
    return -1;
  return work_radius[robot->port] >= 0.0 ? robot->port : -1;
}

// Whether a pair of bodies (a < b) is to be tested: not an allowed pair, and of a class in `mask`.
bool ScreenPair(const CollisionWorld::Impl& w, unsigned mask, int a, int b, PairClass* cls) {
  if (w.Allowed(a, b)) return false;
  *cls = w.Class(a, b);
  return (mask & Bit(*cls)) != 0;
}

// Orders a broadphase pair by body index and screens it (ScreenPair).
bool Screen(const CollisionWorld::Impl& w, unsigned mask, fcl::CollisionObjectd** o1,
            fcl::CollisionObjectd** o2, int* a, int* b, PairClass* cls) {
  *a = BodyOf(*o1);
  *b = BodyOf(*o2);
  if (*a > *b) {
    std::swap(*a, *b);
    std::swap(*o1, *o2);
  }
  return ScreenPair(w, mask, *a, *b, cls);
}

bool Narrowphase(fcl::CollisionObjectd* o1, fcl::CollisionObjectd* o2, void* raw) {
  auto& d = *static_cast<QueryData*>(raw);
  if (d.done) return true;
  int a = -1, b = -1;
  PairClass cls{};
  if (!Screen(*d.world, d.mask, &o1, &o2, &a, &b, &cls) || !d.OfArm(a, b)) return false;
  const CollisionWorld::Impl& w = *d.world;
  const Convex& A = w.convex[a];
  const Convex& B = w.convex[b];
  const bool swept_a = A.kind == Convex::Kind::kSweptSphere,
             swept_b = B.kind == Convex::Kind::kSweptSphere;
  const bool box_a = A.kind == Convex::Kind::kBox, box_b = B.kind == Convex::Kind::kBox;
  if (w.options.exact_mesh_queries && ((swept_a && (swept_b || box_b)) || (box_a && swept_b))) {
    // Closed form: two capsules (or spheres) whose axes are nearer than their radii, or a capsule
    // whose axis is nearer a box than its radius. c1 on a's axis or box, c2 on b's.
    Eigen::Vector3d c1, c2;
    double d2 = 0.0, reach = 0.0;
    if (swept_a && swept_b) {
      const Eigen::Isometry3d& X_WA = o1->getTransform();
      const Eigen::Isometry3d& X_WB = o2->getTransform();
      d2 = SegmentSegmentClosest(X_WA * A.a_G, X_WA * A.b_G, X_WB * B.a_G, X_WB * B.b_G, &c1, &c2);
      reach = A.radius + B.radius;
    } else {
      const bool box_first = box_a;
      const Convex& box = box_first ? A : B;
      const Convex& cap = box_first ? B : A;
      const Eigen::Isometry3d& X_WX = (box_first ? o1 : o2)->getTransform();
      const Eigen::Isometry3d& X_WC = (box_first ? o2 : o1)->getTransform();
      const Eigen::Isometry3d X_XC = X_WX.inverse() * X_WC;
      const Eigen::Vector3d p = X_XC * cap.a_G, q = X_XC * cap.b_G;
      double t = 0.0;
      d2 = SegmentBoxDistanceSquared(p, q, -box.half, box.half, &t);
      reach = cap.radius;
      const Eigen::Vector3d on_axis = p + t * (q - p);
      const Eigen::Vector3d on_box = on_axis.cwiseMax(-box.half).cwiseMin(box.half);
      c1 = X_WX * (box_first ? on_box : on_axis);
      c2 = X_WX * (box_first ? on_axis : on_box);
    }
    if (d2 > reach * reach) return false;
    const double gap = std::sqrt(d2);
    Contact contact;
    contact.a = a;
    contact.b = b;
    contact.cls = cls;
    // Midway between the two surfaces along the closest points.
    const double r1 = swept_a ? A.radius : 0.0;
    contact.p_W = gap > 0 ? Eigen::Vector3d(c1 + (r1 + 0.5 * (gap - reach)) / gap * (c2 - c1))
                          : Eigen::Vector3d(c1);
    contact.depth = reach - gap;
    d.report.collision = true;
    d.report.contacts.push_back(contact);
    if (d.stop_at_first) d.done = true;
    return d.done;
  }
  // An exempt zone: the skin around the instrument's port, the organ around its work site, or
  // the ribs its cannula leans on at its port (its axis clear of them). A distal link (wrist,
  // jaws) against its port's ribs has two: it may lean there, as the cannula may, while it works
  // elsewhere (the start pose of a motion, just inside the port), and touch them at its work site;
  // either allows the contact.
  const int skin_port = PortPair(w, a, b);
  const int work = skin_port < 0 ? WorkPair(w, *d.work_radius, a, b) : -1;
  const int seat = skin_port < 0 ? SeatPair(w, a, b) : -1;
  const bool zone = skin_port >= 0 || work >= 0 || seat >= 0;
  fcl::CollisionRequestd request(zone ? kPortContacts : 1, zone || d.want_contacts);
  // FCL's own GJK: with libccd (the default) FCL missed shallow capsule–mesh contacts that its
  // distance query saw (tests/collision: ExactMeshQueriesAgreeWithFcl).
  request.gjk_solver_type = fcl::GST_INDEP;
  fcl::CollisionResultd result;
  fcl::collide(o1, o2, request, result);
  if (!result.isCollision()) return false;
  Contact contact;
  contact.a = a;
  contact.b = b;
  contact.cls = cls;
  if (zone) {
    // Touching the skin only within the port's radius is passing through the port; touching the
    // organ only within the work site's radius is working there; leaning on the ribs within the
    // port's radius, the axis clear of the bone, is resting on the port's edge. Each zone in
    // turn; the contact is allowed by the first that holds it (its point and depth otherwise from
    // the last tried).
    auto within = [&](const Eigen::Vector3d& p_W, double r, bool leaning) {
      for (std::size_t i = 0; i < result.numContacts(); ++i) {
        const auto& c = result.getContact(i);
        if ((c.pos - p_W).norm() > r) {
          contact.p_W = c.pos;
          contact.depth = c.penetration_depth;
          return false;
        }
      }
      if (leaning) {
        const int r_body = w.bodies[a].kind == Body::Kind::kRobot ? a : b;
        const int f_body = r_body == a ? b : a;
        const SweptSphereContact axis = AxisCrosses(w, r_body == a ? *o1 : *o2, r_body, f_body);
        if (axis.outside) {
          contact.p_W = w.X_pose[f_body] * axis.p_M;
          contact.depth = axis.depth;
          return false;
        }
      }
      return true;
    };
    if (skin_port >= 0 && within((*d.port_W)[skin_port], (*d.port_radius)[skin_port], false)) {
      ++d.report.port_contacts_allowed;
      return false;
    }
    if (work >= 0 && within((*d.work_W)[work], (*d.work_radius)[work], false)) {
      ++d.report.work_contacts_allowed;
      return false;
    }
    if (seat >= 0 && within((*d.port_W)[seat], (*d.port_radius)[seat], true)) {
      ++d.report.seat_contacts_allowed;
      return false;
    }
  } else if (result.numContacts() > 0) {
    contact.p_W = result.getContact(0).pos;
    contact.depth = result.getContact(0).penetration_depth;
  }
  d.report.collision = true;
  d.report.contacts.push_back(contact);
  if (d.stop_at_first) d.done = true;
  return d.done;
}

struct DistanceData {
  const CollisionWorld::Impl* world = nullptr;
  const std::vector<double>* work_radius = nullptr;
  unsigned mask = 0;
  int arm = -1;  ///< >= 0: only pairs with a body of this arm
  Clearance best;
  bool OfArm(int a, int b) const {
    return arm < 0 || world->bodies[a].arm == arm || world->bodies[b].arm == arm;
  }
};

// FCL's distance between two objects, 0 with a contact point for both witnesses when touching.
double FclDistance(fcl::CollisionObjectd* o1, fcl::CollisionObjectd* o2, Eigen::Vector3d* p1,
                   Eigen::Vector3d* p2) {
  // FCL's own GJK (GST_INDEP) with a tight tolerance: primitives to 1e-6 m and better.
  fcl::DistanceRequestd request(true, false, 0.0, 0.0, 1e-8, fcl::GST_INDEP);
  fcl::DistanceResultd result;
  // FCL 0.7 answers a shape against a mesh by the mesh–shape routine and returns its witness
  // points in that order, not the caller's (fcl#427): ask mesh first and swap back ourselves.
  if (o1->getObjectType() != fcl::OT_BVH && o2->getObjectType() == fcl::OT_BVH) {
    fcl::distance(o2, o1, request, result);
    *p1 = result.nearest_points[1];
    *p2 = result.nearest_points[0];
  } else {
    fcl::distance(o1, o2, request, result);
    *p1 = result.nearest_points[0];
    *p2 = result.nearest_points[1];
  }
  if (result.min_distance > 0.0) return result.min_distance;
  fcl::CollisionRequestd creq(1, true);
  fcl::CollisionResultd cres;
  fcl::collide(o1, o2, creq, cres);
  if (cres.numContacts() > 0) *p1 = *p2 = cres.getContact(0).pos;
  return 0.0;
}

void Keep(DistanceData& d, double distance, int a, int b, PairClass cls, const Eigen::Vector3d& p_a,
          const Eigen::Vector3d& p_b) {
  if (distance >= d.best.distance) return;
  d.best.distance = distance;
  d.best.a = a;
  d.best.b = b;
  d.best.cls = cls;
  d.best.p_W_a = p_a;
  d.best.p_W_b = p_b;
}

double AabbDistance(const fcl::AABBd& x, const fcl::AABBd& y) {
  const Eigen::Vector3d gap = (y.min_ - x.max_).cwiseMax(x.min_ - y.max_).cwiseMax(0.0);
  return gap.norm();
}

bool DistancePair(fcl::CollisionObjectd* o1, fcl::CollisionObjectd* o2, void* raw, double& dist) {
  auto& d = *static_cast<DistanceData*>(raw);
  int a = -1, b = -1;
  PairClass cls{};
  if (!Screen(*d.world, d.mask, &o1, &o2, &a, &b, &cls) || !d.OfArm(a, b)) return false;
  // Zero at the port, and at the work site, by design.
  if (PortPair(*d.world, a, b) >= 0 || WorkPair(*d.world, *d.work_radius, a, b) >= 0) return false;
  // Boxes no nearer than the best so far: the pair cannot be nearer (Keep would drop it).
  if (AabbDistance(o1->getAABB(), o2->getAABB()) >= d.best.distance) {
    dist = d.best.distance;
    return false;
  }
  Eigen::Vector3d p_a, p_b;
  const double distance = FclDistance(o1, o2, &p_a, &p_b);
  Keep(d, distance, a, b, cls, p_a, p_b);
  dist = d.best.distance;
  return dist <= 0.0;
}

// Whether a robot body against a fixed body goes through our TriangleBvh (and as what).
Convex::Kind FastPath(const CollisionWorld::Impl& w, int r, int f) {
  return w.mesh[f] && w.options.exact_mesh_queries ? w.convex[r].kind : Convex::Kind::kOther;
}

// A robot shape G in a fixed mesh's frame M: its pose, and a capsule's (or sphere's) axis.
struct ShapeInMesh {
  Eigen::Isometry3d X_MG = Eigen::Isometry3d::Identity();
  Eigen::Vector3d a_M = Eigen::Vector3d::Zero(), b_M = Eigen::Vector3d::Zero();
};
ShapeInMesh InMesh(const CollisionWorld::Impl& w, const fcl::CollisionObjectd& robot_object, int r,
                   int f) {
  ShapeInMesh out;
  out.X_MG = w.X_pose[f].inverse() * robot_object.getTransform();
  out.a_M = out.X_MG * w.convex[r].a_G;
  out.b_M = out.X_MG * w.convex[r].b_G;
  return out;
}

}  // namespace

struct CollisionChecker::State {
  std::vector<std::unique_ptr<fcl::CollisionObjectd>> objects;  // per body
  /// Robot bodies against each other: FCL's broadphase. Robot against fixed bodies (a few
  /// structures): a loop over the pairs, capsules, spheres and boxes against meshes by TriangleBvh.
  fcl::DynamicAABBTreeCollisionManagerd robot_tree;
  const CollisionWorld::Impl* world = nullptr;
  std::vector<Eigen::Vector3d> port_W;
  std::vector<double> port_radius;
  std::vector<Eigen::Vector3d> work_W;  // per port: its instrument's work site
  std::vector<double> work_radius;      // per port; < 0: none
  struct Candidate {
    double lower_bound;
    int r, f;
  };
  // Reused by MinimumDistance (no allocation once warm).
  std::vector<Candidate> others;
  std::vector<MeshQuery> queries;
  std::vector<std::pair<int, int>> query_pair;  // robot body, fixed body
  TriangleBvh::Scratch scratch;

  void CollideRobotFixed(QueryData& d);
  void DistanceRobotFixed(DistanceData& d);
  /// Robot pairs, then robot against fixed bodies (stopping early when d.stop_at_first).
  void Collide(QueryData& d) {
    if (robot_tree.size() == 0) return;
    robot_tree.collide(&d, Narrowphase);
    if (!d.done) CollideRobotFixed(d);
  }
};

CollisionChecker::CollisionChecker(std::shared_ptr<const CollisionWorld> world)
    : world_(std::move(world)), state_(std::make_unique<State>()) {
  TROCAR_THROW_UNLESS(world_, "collision checker: no world");
  const CollisionWorld::Impl& w = world_->impl();
  {
    std::lock_guard<std::mutex> lock(*w.object_construction);
    for (std::size_t i = 0; i < w.n(); ++i) {
      auto object = std::make_unique<fcl::CollisionObjectd>(w.geometry[i]);
      object->setUserData(reinterpret_cast<void*>(static_cast<std::intptr_t>(i)));
      state_->objects.push_back(std::move(object));
    }
  }
  state_->world = &w;
  for (int i : w.fixed_bodies) {
    state_->objects[i]->setTransform(w.X_pose[i]);
    state_->objects[i]->computeAABB();
  }
  if (w.robot) {
    const robot::RobotState rest(*w.robot);
    robot::RobotState state = rest;
    if (!kinematics::ForwardKinematics(*w.robot, state.q, &state).ok())
      kinematics::ForwardKinematics(*w.robot, &state);
    std::vector<fcl::CollisionObjectd*> robot;
    for (int i : w.robot_bodies) robot.push_back(state_->objects[i].get());
    SetRobotState(state);
    if (!robot.empty()) state_->robot_tree.registerObjects(robot);
    state_->robot_tree.setup();
  }
  state_->port_W.resize(w.ports.size(), Eigen::Vector3d::Zero());
  state_->port_radius.assign(w.ports.size(), w.options.port_radius);
  state_->work_W.assign(w.ports.size(), Eigen::Vector3d::Zero());
  state_->work_radius.assign(w.ports.size(), -1.0);
}

CollisionChecker::~CollisionChecker() = default;

void CollisionChecker::State::CollideRobotFixed(QueryData& d) {
  const CollisionWorld::Impl& w = *world;
  for (int r : w.robot_bodies) {
    if (d.arm >= 0 && w.bodies[r].arm != d.arm) continue;
    fcl::CollisionObjectd* o_r = objects[r].get();
    for (int f : w.fixed_bodies) {
      if (d.done) return;
      PairClass cls{};
      const int a = std::min(r, f), b = std::max(r, f);
      if (!ScreenPair(w, d.mask, a, b, &cls)) continue;
      fcl::CollisionObjectd* o_f = objects[f].get();
      if (!o_r->getAABB().overlap(o_f->getAABB())) continue;
      // Capsules, spheres and boxes against meshes by our hierarchy; the rest (the table, robot
      // meshes) by FCL.
      const Convex::Kind fast = FastPath(w, r, f);
      if (fast == Convex::Kind::kOther) {
        Narrowphase(o_r, o_f, &d);
        continue;
      }
      const ShapeInMesh shape = InMesh(w, *o_r, r, f);
      // The exempt zones as in Narrowphase: the skin's port; else the work site, then the lean
      // on the port's ribs (a distal link may have both: either allows the contact).
      const int skin_port = PortPair(w, a, b);
      const int work = skin_port < 0 ? WorkPair(w, work_radius, a, b) : -1;
      const int seat = skin_port < 0 ? SeatPair(w, r, f) : -1;
      auto touches = [&](const Eigen::Vector3d& centre_W, double exclude) {
        const Eigen::Vector3d centre_M = w.X_pose[f].inverse() * centre_W;
        return fast == Convex::Kind::kSweptSphere
                   ? w.mesh[f]->Touches(shape.a_M, shape.b_M, w.convex[r].radius, centre_M, exclude)
                   : w.mesh[f]->BoxTouches(shape.X_MG, w.convex[r].half, centre_M, exclude);
      };
      // The first zone: its contact decides when no other zone applies.
      const int first = skin_port >= 0 ? 0 : work >= 0 ? 1 : seat >= 0 ? 2 : -1;
      SweptSphereContact hit = first == 0   ? touches(port_W[skin_port], port_radius[skin_port])
                               : first == 1 ? touches(work_W[work], work_radius[work])
                               : first == 2 ? touches(port_W[seat], port_radius[seat])
                                            : touches(Eigen::Vector3d::Zero(), -1.0);
      SweptSphereContact axis;
      if (!hit.outside && hit.excluded && first == 2) axis = AxisCrosses(w, *o_r, r, f);
      int allowed_by = !hit.outside && !axis.outside && hit.excluded ? first : -1;
      if (!hit.outside && !axis.outside && !hit.excluded) continue;  // no contact at all
      if (allowed_by < 0 && first == 1 && seat >= 0) {
        // Outside the work site: leaning on its port's ribs instead?
        const SweptSphereContact lean = touches(port_W[seat], port_radius[seat]);
        SweptSphereContact lean_axis;
        if (!lean.outside && lean.excluded) lean_axis = AxisCrosses(w, *o_r, r, f);
        if (!lean.outside && !lean_axis.outside) {
          allowed_by = 2;
        } else {
          hit = lean;
          axis = lean_axis;
        }
      }
      if (allowed_by >= 0) {
        ++(allowed_by == 2   ? d.report.seat_contacts_allowed
           : allowed_by == 0 ? d.report.port_contacts_allowed
                             : d.report.work_contacts_allowed);
        continue;
      }
      const SweptSphereContact& at = hit.outside ? hit : axis;
      Contact contact;
      contact.a = a;
      contact.b = b;
      contact.cls = cls;
      contact.p_W = w.X_pose[f] * at.p_M;
      contact.depth = at.depth;
      d.report.collision = true;
      d.report.contacts.push_back(contact);
      if (d.stop_at_first) d.done = true;
    }
  }
}

void CollisionChecker::State::DistanceRobotFixed(DistanceData& d) {
  const CollisionWorld::Impl& w = *world;
  // Capsules, spheres and boxes against meshes: one best-first search over all those pairs at
  // once (TriangleBvh::ClosestOfAll). Other pairs (the table, robot meshes) by FCL afterwards,
  // nearest boxes first, skipped when their boxes are no nearer than the best so far.
  queries.clear();
  query_pair.clear();
  others.clear();
  for (int r : w.robot_bodies) {
    fcl::CollisionObjectd* o_r = objects[r].get();
    for (int f : w.fixed_bodies) {
      PairClass cls{};
      const int a = std::min(r, f), b = std::max(r, f);
      if (!ScreenPair(w, d.mask, a, b, &cls) || PortPair(w, a, b) >= 0 ||
          WorkPair(w, *d.work_radius, a, b) >= 0 || !d.OfArm(a, b))
        continue;
      const Convex::Kind fast = FastPath(w, r, f);
      if (fast == Convex::Kind::kOther) {
        others.push_back({AabbDistance(o_r->getAABB(), objects[f]->getAABB()), r, f});
        continue;
      }
      const ShapeInMesh shape = InMesh(w, *o_r, r, f);
      MeshQuery q;
      q.mesh = w.mesh[f].get();
      q.box = fast == Convex::Kind::kBox;
      q.a_M = shape.a_M;
      q.b_M = shape.b_M;
      q.radius = w.convex[r].radius;
      q.X_MB = shape.X_MG;
      q.half = w.convex[r].half;
      queries.push_back(q);
      query_pair.emplace_back(r, f);
    }
  }
  auto keep = [&](int r, int f, double distance, const Eigen::Vector3d& p_r,
                  const Eigen::Vector3d& p_f) {
    const int a = std::min(r, f), b = std::max(r, f);
    if (r < f) {
      Keep(d, distance, a, b, w.Class(a, b), p_r, p_f);
    } else {
      Keep(d, distance, a, b, w.Class(a, b), p_f, p_r);
    }
  };
  const NearestQuery nearest = TriangleBvh::ClosestOfAll(queries, d.best.distance, &scratch);
  if (nearest.query >= 0) {
    const auto [r, f] = query_pair[nearest.query];
    const Eigen::Isometry3d& X_WM = w.X_pose[f];
    keep(r, f, nearest.distance, X_WM * nearest.p_M_query, X_WM * nearest.p_M_mesh);
  }
  std::sort(others.begin(), others.end(), [](const Candidate& x, const Candidate& y) {
    return std::tie(x.lower_bound, x.r, x.f) < std::tie(y.lower_bound, y.r, y.f);
  });
  for (const Candidate& c : others) {
    if (d.best.distance <= 0.0 || c.lower_bound >= d.best.distance) break;
    Eigen::Vector3d p_r, p_f;
    const double distance = FclDistance(objects[c.r].get(), objects[c.f].get(), &p_r, &p_f);
    keep(c.r, c.f, distance, p_r, p_f);
  }
}

void CollisionChecker::SetRobotState(const robot::RobotState& state) {
  const CollisionWorld::Impl& w = world_->impl();
  TROCAR_THROW_UNLESS(w.robot, "collision checker: the world has no robot");
  TROCAR_THROW_UNLESS(state.X_WL.size() == static_cast<std::size_t>(w.robot->num_links()),
                      "collision checker: robot state has "
                          << state.X_WL.size() << " link poses, robot '" << w.robot->name()
                          << "' has " << w.robot->num_links() << " links");
  // Every pose checked before any is used: a refused state leaves the last one in place.
  for (int i : w.robot_bodies) {
    TROCAR_THROW_UNLESS(state.X_WL[w.bodies[i].link].matrix().allFinite(),
                        "collision checker: link '"
                            << w.robot->link(w.bodies[i].link).name
                            << "' has a non-finite pose (NaN or infinite joint values or "
                               "base pose?)");
  }
  for (int i : w.robot_bodies) {
    fcl::CollisionObjectd& o = *state_->objects[i];
    o.setTransform(state.X_WL[w.bodies[i].link] * w.X_pose[i]);
    o.computeAABB();
  }
  if (state_->robot_tree.size() > 0) state_->robot_tree.update();
  const std::size_t known = state_->port_W.size();
  state_->port_W.resize(w.ports.size());
  for (std::size_t p = 0; p < w.ports.size(); ++p) {
    if (w.port_frame[p]) {
      state_->port_W[p] = kinematics::FramePose(state, *w.port_frame[p]).translation();
    } else if (p >= known) {
      state_->port_W[p] = state.X_WL[w.port_link[p]].translation();
    }
  }
}

void CollisionChecker::SetPortPosition(int port, const Eigen::Vector3d& p_W, double radius) {
  TROCAR_THROW_UNLESS(port >= 0 && port < static_cast<int>(state_->port_W.size()),
                      "collision checker: port " << port << " does not exist ("
                                                 << state_->port_W.size() << " ports)");
  TROCAR_THROW_UNLESS(p_W.allFinite(), "collision checker: port position is not finite");
  TROCAR_THROW_UNLESS(std::isfinite(radius), "collision checker: port radius is not finite");
  state_->port_W[port] = p_W;
  if (radius >= 0.0) state_->port_radius[port] = radius;
}

double CollisionChecker::port_radius(int port) const { return state_->port_radius.at(port); }

void CollisionChecker::SetWorkSite(int port, const Eigen::Vector3d& p_W, double radius) {
  TROCAR_THROW_UNLESS(port >= 0 && port < static_cast<int>(state_->work_W.size()),
                      "collision checker: port " << port << " does not exist ("
                                                 << state_->work_W.size() << " ports)");
  TROCAR_THROW_UNLESS(p_W.allFinite() && std::isfinite(radius),
                      "collision checker: work site is not finite");
  state_->work_W[port] = p_W;
  state_->work_radius[port] = radius;
}

void CollisionChecker::ClearWorkSites() {
  std::fill(state_->work_radius.begin(), state_->work_radius.end(), -1.0);
}

const Eigen::Vector3d& CollisionChecker::port_position(int port) const {
  return state_->port_W.at(port);
}

bool CollisionChecker::InCollision(unsigned mask, int arm) {
  QueryData d;
  d.world = &world_->impl();
  d.port_W = &state_->port_W;
  d.port_radius = &state_->port_radius;
  d.work_W = &state_->work_W;
  d.work_radius = &state_->work_radius;
  d.mask = mask;
  d.arm = arm;
  d.stop_at_first = true;
  state_->Collide(d);
  return d.report.collision;
}

CollisionReport CollisionChecker::Check(unsigned mask, int arm) {
  QueryData d;
  d.world = &world_->impl();
  d.port_W = &state_->port_W;
  d.port_radius = &state_->port_radius;
  d.work_W = &state_->work_W;
  d.work_radius = &state_->work_radius;
  d.mask = mask;
  d.arm = arm;
  d.want_contacts = true;
  state_->Collide(d);
  std::sort(
      d.report.contacts.begin(), d.report.contacts.end(),
      [](const Contact& x, const Contact& y) { return std::tie(x.a, x.b) < std::tie(y.a, y.b); });
  return d.report;
}

Clearance CollisionChecker::MinimumDistance(unsigned mask, int arm, double below) {
  const CollisionWorld::Impl& w = world_->impl();
  TROCAR_THROW_UNLESS(w.options.bvh == BvhKind::kObbRss,
                      "collision checker: distance queries need an OBBRSS world (this one uses "
                          << ToString(w.options.bvh) << ")");
  DistanceData d;
  d.world = &w;
  d.work_radius = &state_->work_radius;
  d.mask = mask;
  d.arm = arm;
  if (!(below > 0.0)) return d.best;  // nothing is nearer than 0 (or NaN): nothing sought
  d.best.distance = below;  // Keep takes only what is nearer
  if (state_->robot_tree.size() == 0) return d.best;
  state_->robot_tree.distance(&d, DistancePair);
  if (d.best.distance > 0.0) state_->DistanceRobotFixed(d);
  return d.best;
}

std::vector<Clearance> CollisionChecker::ClearanceByClass() {
  std::vector<Clearance> out;
  for (PairClass c : {PairClass::kArmArm, PairClass::kArmPatient, PairClass::kInstrumentPatient,
                      PairClass::kArmTable, PairClass::kSelf}) {
    out.push_back(MinimumDistance(Bit(c)));
    out.back().cls = c;
  }
  return out;
}

}  // namespace trocar::collision
