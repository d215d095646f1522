// CollisionChecker: per-thread FCL objects over a shared CollisionWorld. Two broadphase trees
// (dynamic AABB trees): the fixed bodies (patient, table), built once per checker, and the
// robot's shapes, refitted after each SetRobotState. Narrowphase pairs are filtered by the
// world's allowed pairs, the caller's class mask and the port rule.
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

}  // namespace

struct CollisionChecker::State {
  std::vector<std::unique_ptr<fcl::CollisionObjectd>> objects;  // per body
  fcl::DynamicAABBTreeCollisionManagerd robot_tree, fixed_tree;
  std::vector<Eigen::Vector3d> port_W;
};

namespace {

struct QueryData {
  const CollisionWorld::Impl* world = nullptr;
  const std::vector<Eigen::Vector3d>* port_W = nullptr;
  unsigned mask = 0;
  bool stop_at_first = false;
  bool want_contacts = false;
  bool done = false;
  CollisionReport report;
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

// Orders a broadphase pair by body index and says whether it is to be tested: not an allowed
// pair, and of a class in `mask`.
bool Screen(const CollisionWorld::Impl& w, unsigned mask, fcl::CollisionObjectd** o1, fcl::CollisionObjectd** o2,
            int* a, int* b, PairClass* cls) {
  *a = BodyOf(*o1);
  *b = BodyOf(*o2);
  if (*a > *b) {
    std::swap(*a, *b);
    std::swap(*o1, *o2);
  }
  if (w.Allowed(*a, *b)) return false;
  *cls = w.Class(*a, *b);
  return (mask & Bit(*cls)) != 0;
}

bool Narrowphase(fcl::CollisionObjectd* o1, fcl::CollisionObjectd* o2, void* raw) {
  auto& d = *static_cast<QueryData*>(raw);
  if (d.done) return true;
  int a = -1, b = -1;
  PairClass cls{};
  if (!Screen(*d.world, d.mask, &o1, &o2, &a, &b, &cls)) return false;
  const CollisionWorld::Impl& w = *d.world;
  const int port = PortPair(w, a, b);
  fcl::CollisionRequestd request(port >= 0 ? kPortContacts : 1, port >= 0 || d.want_contacts);
  fcl::CollisionResultd result;
  fcl::collide(o1, o2, request, result);
  if (!result.isCollision()) return false;
  Contact contact;
  contact.a = a;
  contact.b = b;
  contact.cls = cls;
  if (port >= 0) {
    // Touching the skin only within the port's radius is passing through the port.
    const Eigen::Vector3d& p_W = (*d.port_W)[port];
    const double r = w.options.port_radius;
    bool outside = false;
    for (std::size_t i = 0; i < result.numContacts() && !outside; ++i) {
      const auto& c = result.getContact(i);
      if ((c.pos - p_W).norm() > r) {
        outside = true;
        contact.p_W = c.pos;
        contact.depth = c.penetration_depth;
      }
    }
    if (!outside) {
      ++d.report.port_contacts_allowed;
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
  unsigned mask = 0;
  Clearance best;
};

bool DistancePair(fcl::CollisionObjectd* o1, fcl::CollisionObjectd* o2, void* raw, double& dist) {
  auto& d = *static_cast<DistanceData*>(raw);
  int a = -1, b = -1;
  PairClass cls{};
  if (!Screen(*d.world, d.mask, &o1, &o2, &a, &b, &cls)) return false;
  const CollisionWorld::Impl& w = *d.world;
  if (PortPair(w, a, b) >= 0) return false;  // zero at the port by design
  // FCL's own GJK (GST_INDEP) with a tight tolerance: primitives to 1e-6 m and better.
  fcl::DistanceRequestd request(true, false, 0.0, 0.0, 1e-8, fcl::GST_INDEP);
  fcl::DistanceResultd result;
  fcl::distance(o1, o2, request, result);
  double distance = result.min_distance;
  Eigen::Vector3d p_a = result.nearest_points[0], p_b = result.nearest_points[1];
  if (distance <= 0.0) {
    // In contact: distance 0, both witnesses at a contact point.
    fcl::CollisionRequestd creq(1, true);
    fcl::CollisionResultd cres;
    fcl::collide(o1, o2, creq, cres);
    distance = 0.0;
    if (cres.numContacts() > 0) p_a = p_b = cres.getContact(0).pos;
  }
  if (distance < d.best.distance) {
    d.best.distance = distance;
    d.best.a = a;
    d.best.b = b;
    d.best.cls = cls;
    d.best.p_W_a = p_a;
    d.best.p_W_b = p_b;
  }
  dist = d.best.distance;
  return dist <= 0.0;
}

}  // namespace

CollisionChecker::CollisionChecker(std::shared_ptr<const CollisionWorld> world)
    : world_(std::move(world)), state_(std::make_unique<State>()) {
  TROCAR_THROW_UNLESS(world_, "collision checker: no world");
  const CollisionWorld::Impl& w = world_->impl();
  {
    std::lock_guard<std::mutex> lock(w.object_construction);
    for (std::size_t i = 0; i < w.n(); ++i) {
      auto object = std::make_unique<fcl::CollisionObjectd>(w.geometry[i]);
      object->setUserData(reinterpret_cast<void*>(static_cast<std::intptr_t>(i)));
      state_->objects.push_back(std::move(object));
    }
  }
  std::vector<fcl::CollisionObjectd*> fixed, robot;
  for (int i : w.fixed_bodies) {
    state_->objects[i]->setTransform(w.X_pose[i]);
    state_->objects[i]->computeAABB();
    fixed.push_back(state_->objects[i].get());
  }
  if (!fixed.empty()) state_->fixed_tree.registerObjects(fixed);
  state_->fixed_tree.setup();
  if (w.robot) {
    const robot::RobotState rest(*w.robot);
    robot::RobotState state = rest;
    if (!kinematics::ForwardKinematics(*w.robot, state.q, &state).ok) kinematics::ForwardKinematics(*w.robot, &state);
    for (int i : w.robot_bodies) robot.push_back(state_->objects[i].get());
    SetRobotState(state);
    if (!robot.empty()) state_->robot_tree.registerObjects(robot);
    state_->robot_tree.setup();
  }
  state_->port_W.resize(w.ports.size(), Eigen::Vector3d::Zero());
}

CollisionChecker::~CollisionChecker() = default;

void CollisionChecker::SetRobotState(const robot::RobotState& state) {
  const CollisionWorld::Impl& w = world_->impl();
  TROCAR_THROW_UNLESS(w.robot, "collision checker: the world has no robot");
  TROCAR_THROW_UNLESS(state.X_WL.size() == static_cast<std::size_t>(w.robot->num_links()),
                      "collision checker: robot state has " << state.X_WL.size() << " link poses, robot '"
                                                            << w.robot->name() << "' has "
                                                            << w.robot->num_links() << " links");
  for (int i : w.robot_bodies) {
    fcl::CollisionObjectd& o = *state_->objects[i];
    o.setTransform(state.X_WL[w.bodies[i].link] * w.X_pose[i]);
    o.computeAABB();
  }
  if (state_->robot_tree.size() > 0) state_->robot_tree.update();
  state_->port_W.resize(w.ports.size());
  for (std::size_t p = 0; p < w.ports.size(); ++p) {
    state_->port_W[p] = kinematics::FramePose(state, w.robot->frames()[w.port_frame[p]]).translation();
  }
}

void CollisionChecker::SetPortPosition(int port, const Eigen::Vector3d& p_W) {
  TROCAR_THROW_UNLESS(port >= 0 && port < static_cast<int>(state_->port_W.size()),
                      "collision checker: port " << port << " does not exist (" << state_->port_W.size()
                                                 << " ports)");
  TROCAR_THROW_UNLESS(p_W.allFinite(), "collision checker: port position is not finite");
  state_->port_W[port] = p_W;
}

const Eigen::Vector3d& CollisionChecker::port_position(int port) const { return state_->port_W.at(port); }

bool CollisionChecker::InCollision(unsigned mask) {
  QueryData d;
  d.world = &world_->impl();
  d.port_W = &state_->port_W;
  d.mask = mask;
  d.stop_at_first = true;
  if (state_->robot_tree.size() > 0) {
    state_->robot_tree.collide(&d, Narrowphase);
    if (!d.done && state_->fixed_tree.size() > 0) state_->robot_tree.collide(&state_->fixed_tree, &d, Narrowphase);
  }
  return d.report.collision;
}

CollisionReport CollisionChecker::Check(unsigned mask) {
  QueryData d;
  d.world = &world_->impl();
  d.port_W = &state_->port_W;
  d.mask = mask;
  d.want_contacts = true;
  if (state_->robot_tree.size() > 0) {
    state_->robot_tree.collide(&d, Narrowphase);
    if (!d.done && state_->fixed_tree.size() > 0) state_->robot_tree.collide(&state_->fixed_tree, &d, Narrowphase);
  }
  std::sort(d.report.contacts.begin(), d.report.contacts.end(),
            [](const Contact& x, const Contact& y) { return std::tie(x.a, x.b) < std::tie(y.a, y.b); });
  return d.report;
}

Clearance CollisionChecker::MinimumDistance(unsigned mask) {
  const CollisionWorld::Impl& w = world_->impl();
  TROCAR_THROW_UNLESS(w.options.bvh == BvhKind::kObbRss,
                      "collision checker: distance queries need an OBBRSS world (this one uses "
                          << ToString(w.options.bvh) << ")");
  DistanceData d;
  d.world = &w;
  d.mask = mask;
  if (state_->robot_tree.size() == 0) return d.best;
  state_->robot_tree.distance(&d, DistancePair);
  if (d.best.distance > 0.0 && state_->fixed_tree.size() > 0) {
    state_->robot_tree.distance(&state_->fixed_tree, &d, DistancePair);
  }
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
