#include "collision/collision_world.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <map>
#include <random>
#include <set>

#include "collision/fcl_types.hpp"
#include "common/error.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "patient/patient_model.hpp"

namespace trocar::collision {
namespace {

// The chest wall's rigid frame by structure name: "ribs" (the import's), one rib ("rib_left_5")
// or the costal cartilages a label map may bring.
bool IsChestWall(std::string name) {
  std::transform(name.begin(), name.end(), name.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return name.rfind("rib", 0) == 0 || name.find("_rib") != std::string::npos ||
         name.find("cartilage") != std::string::npos;
}

template <typename BV>
std::shared_ptr<fcl::CollisionGeometryd> MakeBvh(const TriangleMesh& mesh) {
  auto model = std::make_shared<fcl::BVHModel<BV>>();
  std::vector<fcl::Vector3d> vertices(mesh.vertices.begin(), mesh.vertices.end());
  std::vector<fcl::Triangle> triangles;
  triangles.reserve(mesh.triangles.size());
  for (const auto& t : mesh.triangles) triangles.emplace_back(t[0], t[1], t[2]);
  model->beginModel(static_cast<int>(triangles.size()), static_cast<int>(vertices.size()));
  model->addSubModel(vertices, triangles);
  model->endModel();
  model->computeLocalAABB();
  return model;
}

std::shared_ptr<fcl::CollisionGeometryd> MakeMeshGeometry(const TriangleMesh& mesh, BvhKind kind,
                                                          const std::string& name) {
  ValidateMesh(mesh, name);
  return kind == BvhKind::kObb ? MakeBvh<fcl::OBBd>(mesh) : MakeBvh<fcl::OBBRSSd>(mesh);
}

std::shared_ptr<fcl::CollisionGeometryd> MakeShape(
    const robot::Geometry& g, BvhKind kind, const std::string& name,
    std::map<const TriangleMesh*, std::shared_ptr<fcl::CollisionGeometryd>>& meshes) {
  using Shape = robot::Geometry::Shape;
  const Eigen::Vector3d& s = g.size;
  auto positive = [&](double x, const char* what) {
    TROCAR_THROW_UNLESS(std::isfinite(x) && x > 0.0, name << ": " << ToString(g.shape) << " "
                                                          << what << " = " << x
                                                          << ", expected a positive length (m)");
  };
  std::shared_ptr<fcl::CollisionGeometryd> out;
  switch (g.shape) {
    case Shape::kBox:
      positive(s.x(), "x size");
      positive(s.y(), "y size");
      positive(s.z(), "z size");
      out = std::make_shared<fcl::Boxd>(s.x(), s.y(), s.z());
      break;
    case Shape::kSphere:
      positive(s.x(), "radius");
      out = std::make_shared<fcl::Sphered>(s.x());
      break;
    case Shape::kCylinder:
      positive(s.x(), "radius");
      positive(s.y(), "length");
      out = std::make_shared<fcl::Cylinderd>(s.x(), s.y());
      break;
    case Shape::kCapsule:
      positive(s.x(), "radius");
      TROCAR_THROW_UNLESS(std::isfinite(s.y()) && s.y() >= 0.0,
                          name << ": capsule length = " << s.y() << ", expected a length >= 0 (m)");
      out = std::make_shared<fcl::Capsuled>(s.x(), s.y());
      break;
    case Shape::kMesh: {
      TROCAR_THROW_UNLESS(g.mesh, name << ": mesh " << g.mesh_file << " was not loaded");
      auto& cached = meshes[g.mesh.get()];
      if (!cached) cached = MakeMeshGeometry(*g.mesh, kind, name + " (" + g.mesh_file + ")");
      return cached;
    }
  }
  out->computeLocalAABB();
  return out;
}

bool EndsWith(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() &&
         s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

// Links of the subtree rooted at `link`, the root first.
std::vector<int> Subtree(const robot::RobotModel& model, int link) {
  std::vector<int> out{link};
  for (std::size_t i = 0; i < out.size(); ++i) {
    for (int j : model.link(out[i]).child_joints) out.push_back(model.joint(j).child_link);
  }
  return out;
}

std::string ArmName(const robot::RobotModel& model, const std::vector<int>& links) {
  std::string prefix = model.link(links[0]).name;
  for (int l : links) {
    const std::string& n = model.link(l).name;
    std::size_t k = 0;
    while (k < prefix.size() && k < n.size() && prefix[k] == n[k]) ++k;
    prefix.resize(k);
  }
  const auto cut = prefix.rfind('_');
  if (links.size() > 1 && cut != std::string::npos && cut > 0) return prefix.substr(0, cut);
  return model.link(links[0]).name;
}

void AddRobot(CollisionWorld::Impl& w, BvhKind kind) {
  const robot::RobotModel& model = *w.robot;
  // Arms: the subtrees hanging from the base link.
  std::vector<int> arm_of(model.num_links(), -1);
  for (int j : model.link(model.base_link()).child_joints) {
    const std::vector<int> links = Subtree(model, model.joint(j).child_link);
    const int arm = static_cast<int>(w.arms.size());
    w.arms.push_back({ArmName(model, links), links[0]});
    for (int l : links) arm_of[l] = arm;
  }
  // Ports: RCM frames with an insertion (prismatic) joint below them.
  std::vector<std::string> frames = w.options.port_frames;
  const bool automatic = frames.empty();
  if (automatic) {
    for (const auto& f : model.frames()) {
      if (EndsWith(f.name, "rcm")) frames.push_back(f.name);
    }
  }
  std::vector<int> port_of(model.num_links(), -1);
  for (const auto& name : frames) {
    // A named frame or a link (GetFrame names both when neither matches).
    robot::Frame frame;
    try {
      frame = model.GetFrame(name);
    } catch (const Error& e) {
      TROCAR_THROW("collision world: port frame '" << name << "': " << e.what());
    }
    const int link = frame.link;
    int insertion = -1;
    for (int l : Subtree(model, link)) {
      const int pj = model.link(l).parent_joint;
      if (l != link && pj >= 0 && model.joint(pj).type == robot::JointType::kPrismatic &&
          model.joint(pj).drive == robot::JointDrive::kActive) {
        insertion = l;
        break;
      }
    }
    if (insertion < 0) {
      TROCAR_THROW_UNLESS(automatic, "collision world: port frame '"
                                         << name
                                         << "' has no insertion "
                                            "(prismatic active) joint below it");
      continue;
    }
    Port port;
    port.frame = name;
    port.arm = arm_of[link];
    port.links = Subtree(model, insertion);
    for (int l : port.links) port_of[l] = static_cast<int>(w.ports.size());
    w.ports.push_back(port);
    w.port_frame.push_back(frame);
    w.port_link.push_back(link);
  }
  for (const auto& name : w.options.shaft_ports) {
    const int link = model.FindLink(name);
    TROCAR_THROW_UNLESS(link >= 0, "collision world: shaft port link '"
                                       << name << "' is not a link of robot '" << model.name()
                                       << "'");
    TROCAR_THROW_UNLESS(port_of[link] < 0, "collision world: link '"
                                               << name << "' is already an instrument of port '"
                                               << w.ports[port_of[link]].frame << "'");
    Port port;
    port.arm = arm_of[link];
    port.links = Subtree(model, link);
    for (int l : port.links) port_of[l] = static_cast<int>(w.ports.size());
    w.ports.push_back(port);
    w.port_frame.push_back(std::nullopt);
    w.port_link.push_back(link);
  }
  std::map<const TriangleMesh*, std::shared_ptr<fcl::CollisionGeometryd>> meshes;
  for (int l = 0; l < model.num_links(); ++l) {
    const robot::Link& link = model.link(l);
    for (std::size_t s = 0; s < link.collisions.size(); ++s) {
      Body b;
      b.name = link.name + (s == 0 ? "" : "#" + std::to_string(s));
      b.kind = Body::Kind::kRobot;
      b.link = l;
      b.arm = arm_of[l];
      b.port = port_of[l];
      const robot::Geometry& g = link.collisions[s];
      w.geometry.push_back(
          MakeShape(g, kind, "robot '" + model.name() + "' link '" + b.name + "'", meshes));
      using Convex = CollisionWorld::Impl::Convex;
      Convex convex;
      if (g.shape == robot::Geometry::Shape::kCapsule ||
          g.shape == robot::Geometry::Shape::kSphere) {
        convex.kind = Convex::Kind::kSweptSphere;
        convex.radius = g.size.x();
        if (g.shape == robot::Geometry::Shape::kCapsule) {
          convex.a_G = Eigen::Vector3d(0, 0, -0.5 * g.size.y());
          convex.b_G = Eigen::Vector3d(0, 0, 0.5 * g.size.y());
        }
      } else if (g.shape == robot::Geometry::Shape::kBox) {
        convex.kind = Convex::Kind::kBox;
        convex.half = 0.5 * g.size;
      }
      w.convex.push_back(convex);
      w.mesh.push_back(nullptr);
      if (g.shape == robot::Geometry::Shape::kMesh)
        b.triangles = static_cast<long>(g.mesh->triangles.size());
      w.X_pose.push_back(g.X_LG);
      w.robot_bodies.push_back(static_cast<int>(w.bodies.size()));
      w.bodies.push_back(b);
    }
  }
  // Each instrument's distal links (wrist and jaws): within distal_reach of its deepest links,
  // at the robot's rest configuration.
  if (w.ports.empty()) return;
  robot::RobotState rest(model);
  if (!kinematics::ForwardKinematics(model, rest.q, &rest).ok()) kinematics::ForwardKinematics(model, &rest);
  std::vector<char> distal(model.num_links(), 0);
  for (const auto& port : w.ports) {
    std::vector<int> leaves;
    for (int l : port.links)
      if (model.link(l).child_joints.empty()) leaves.push_back(l);
    for (int l : port.links) {
      for (int leaf : leaves) {
        if ((rest.X_WL[l].translation() - rest.X_WL[leaf].translation()).norm() <=
            w.options.distal_reach)
          distal[l] = 1;
      }
    }
  }
  for (Body& b : w.bodies)
    if (b.kind == Body::Kind::kRobot && b.link >= 0 && b.port >= 0) b.distal = distal[b.link] != 0;
}

void AddFixedMesh(CollisionWorld::Impl& w, const std::string& name, const TriangleMesh& mesh,
                  const Eigen::Isometry3d& X_WM, bool patient, bool skin, bool chest_wall,
                  const std::string& context) {
  Body b;
  b.name = name;
  b.kind = patient ? Body::Kind::kPatient : Body::Kind::kFixed;
  b.skin = skin;
  b.chest_wall = patient && (chest_wall || IsChestWall(name));
  b.triangles = static_cast<long>(mesh.triangles.size());
  w.geometry.push_back(MakeMeshGeometry(mesh, w.options.bvh, context));
  w.convex.emplace_back();
  // Patient meshes always get the exact hierarchy: the line-of-sight query needs it
  // (CollisionWorld::FirstAcross); the checker uses it only with exact_mesh_queries.
  w.mesh.push_back(w.options.exact_mesh_queries || patient
                       ? std::make_shared<const TriangleBvh>(mesh)
                       : nullptr);
  w.X_pose.push_back(X_WM);
  w.fixed_bodies.push_back(static_cast<int>(w.bodies.size()));
  w.triangles += b.triangles;
  w.bodies.push_back(b);
}

void AddTable(CollisionWorld::Impl& w, const patient::Table& t) {
  Body b;
  b.name = "table";
  b.kind = Body::Kind::kFixed;
  auto box = std::make_shared<fcl::Boxd>(t.length, t.width, t.thickness);
  box->computeLocalAABB();
  w.geometry.push_back(box);
  w.convex.emplace_back();
  w.mesh.push_back(nullptr);
  Eigen::Isometry3d X_WT = Eigen::Isometry3d::Identity();
  X_WT.translation() = Eigen::Vector3d(0, 0, t.height - 0.5 * t.thickness);
  w.X_pose.push_back(X_WT);
  w.fixed_bodies.push_back(static_cast<int>(w.bodies.size()));
  w.bodies.push_back(b);
}

PairClass ClassOf(const Body& a, const Body& b) {
  const bool ra = a.kind == Body::Kind::kRobot, rb = b.kind == Body::Kind::kRobot;
  if (!ra && !rb) return PairClass::kPatientTable;
  if (ra && rb) return a.arm == b.arm && a.arm >= 0 ? PairClass::kSelf : PairClass::kArmArm;
  const Body& r = ra ? a : b;
  const Body& f = ra ? b : a;
  if (f.kind == Body::Kind::kPatient)
    return r.port >= 0 ? PairClass::kInstrumentPatient : PairClass::kArmPatient;
  return PairClass::kArmTable;
}

}  // namespace

const char* ToString(BvhKind kind) { return kind == BvhKind::kObb ? "OBB" : "OBBRSS"; }

const char* ToString(PairClass cls) {
  switch (cls) {
    case PairClass::kArmArm:
      return "arm-arm";
    case PairClass::kArmPatient:
      return "arm-patient";
    case PairClass::kInstrumentPatient:
      return "instrument-patient";
    case PairClass::kArmTable:
      return "arm-table";
    case PairClass::kSelf:
      return "self";
    case PairClass::kPatientTable:
      return "patient-table";
  }
  return "?";
}

CollisionWorld::CollisionWorld(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

std::shared_ptr<const CollisionWorld> CollisionWorld::WithBodiesMoved(
    const std::vector<std::string>& names, const Eigen::Vector3d& d_W) const {
  TROCAR_THROW_UNLESS(d_W.allFinite(), "collision world: a body moved by a non-finite vector");
  const Impl& w = *impl_;
  // A copy shares the geometry, the hierarchies and the lock guarding them (shared pointers).
  auto impl = std::make_unique<Impl>(w);
  for (const std::string& name : names) {
    bool found = false;
    for (int b : w.fixed_bodies) {
      if (w.bodies[b].name != name) continue;
      impl->X_pose[b].pretranslate(d_W);
      found = true;
    }
    TROCAR_THROW_UNLESS(found, "collision world: no fixed body '" << name << "' to move");
  }
  return std::shared_ptr<const CollisionWorld>(new CollisionWorld(std::move(impl)));
}

CollisionWorld::~CollisionWorld() = default;

const std::vector<Body>& CollisionWorld::bodies() const { return impl_->bodies; }
const std::vector<Arm>& CollisionWorld::arms() const { return impl_->arms; }

std::string CollisionWorld::DescribeBody(int body) const {
  const Body& b = impl_->bodies.at(static_cast<std::size_t>(body));
  if (b.kind != Body::Kind::kRobot) return "the " + b.name;
  const std::string arm = b.arm >= 0 ? impl_->arms[b.arm].name + "'s " : std::string("the robot's ");
  const char* part = b.arm < 0 ? "base" : b.distal ? "wrist" : b.port >= 0 ? "shaft" : "arm";
  return arm + part + " (" + b.name + ")";
}

std::string CollisionWorld::DescribePair(int a, int b) const {
  const bool robot_b_first = impl_->bodies.at(static_cast<std::size_t>(b)).kind == Body::Kind::kRobot &&
                             impl_->bodies.at(static_cast<std::size_t>(a)).kind != Body::Kind::kRobot;
  if (robot_b_first) std::swap(a, b);
  return DescribeBody(a) + " against " + DescribeBody(b);
}
const std::vector<Port>& CollisionWorld::ports() const { return impl_->ports; }
const robot::RobotModel* CollisionWorld::robot() const { return impl_->robot.get(); }
const WorldOptions& CollisionWorld::options() const { return impl_->options; }
bool CollisionWorld::Allowed(int a, int b) const { return impl_->Allowed(a, b); }
int CollisionWorld::auto_allowed_pairs() const { return impl_->auto_allowed; }
PairClass CollisionWorld::Classify(int a, int b) const { return impl_->Class(a, b); }
long CollisionWorld::triangle_count() const { return impl_->triangles; }
SightLine CollisionWorld::FirstAcross(const Eigen::Vector3d& from_W, const Eigen::Vector3d& to_W,
                                      double near_to) const {
  SightLine out;
  const Eigen::Vector3d d = to_W - from_W;
  const double length = d.norm();
  if (!(length > near_to)) return out;  // the whole line lies within the margin
  const Eigen::Vector3d end_W = to_W - near_to * d / length;
  double best = std::numeric_limits<double>::infinity();
  for (int f : impl_->fixed_bodies) {
    if (impl_->bodies[f].kind != Body::Kind::kPatient || !impl_->mesh[f]) continue;
    const Eigen::Isometry3d X_MW = impl_->X_pose[f].inverse();
    const MeshClosest c = impl_->mesh[f]->Closest(X_MW * from_W, X_MW * end_W, 1e-9);
    if (!c.found()) continue;
    const Eigen::Vector3d p_W = impl_->X_pose[f] * c.p_M_query;
    const double along = (p_W - from_W).norm();
    if (along < best) {
      best = along;
      out.body = f;
      out.p_W = p_W;
    }
  }
  return out;
}

int CollisionWorld::FindBody(const std::string& name) const {
  for (std::size_t i = 0; i < impl_->bodies.size(); ++i) {
    if (impl_->bodies[i].name == name) return static_cast<int>(i);
  }
  return -1;
}

std::shared_ptr<const CollisionWorld> CollisionWorld::Build(
    const patient::PatientModel* patient, std::shared_ptr<const robot::RobotModel> robot,
    const WorldOptions& options, const std::vector<AllowedPair>& allowed) {
  std::vector<FixedMesh> meshes;
  if (patient) {
    for (const auto& s : patient->structures) {
      FixedMesh m;
      m.name = s.name;
      m.mesh = s.mesh;
      m.X_WM = patient->X_WP;
      m.skin = s.name == "skin";
      m.patient = true;
      meshes.push_back(std::move(m));
    }
  }
  return BuildWith(meshes, patient && options.add_table ? &patient->table : nullptr,
                   std::move(robot), options, allowed);
}

std::shared_ptr<const CollisionWorld> CollisionWorld::Build(
    const std::vector<FixedMesh>& meshes, std::shared_ptr<const robot::RobotModel> robot,
    const WorldOptions& options, const std::vector<AllowedPair>& allowed) {
  return BuildWith(meshes, nullptr, std::move(robot), options, allowed);
}

namespace {

// Allows a pair of bodies (both orders); counted as allowed automatically when it was not yet.
void AllowPair(CollisionWorld::Impl& w, int a, int b) {
  const std::size_t n = w.n();
  if (!w.allowed[a * n + b]) ++w.auto_allowed;
  w.allowed[a * n + b] = w.allowed[b * n + a] = 1;
}

// Every pair's class; a body with itself and the patient with the table are allowed.
void ClassifyPairs(CollisionWorld::Impl& w) {
  const std::size_t n = w.n();
  w.allowed.assign(n * n, 0);
  w.classes.resize(n * n);
  for (std::size_t a = 0; a < n; ++a) {
    for (std::size_t b = 0; b < n; ++b) {
      w.classes[a * n + b] = ClassOf(w.bodies[a], w.bodies[b]);
      if (a == b || w.classes[a * n + b] == PairClass::kPatientTable) w.allowed[a * n + b] = 1;
    }
  }
}

// Shapes of one link, and links joined by a joint (through links without shapes).
void AllowJoinedLinks(CollisionWorld::Impl& w) {
  const robot::RobotModel& model = *w.robot;
  std::vector<std::vector<int>> bodies_of(model.num_links());
  for (int b : w.robot_bodies) bodies_of[w.bodies[b].link].push_back(b);
  for (int l = 0; l < model.num_links(); ++l) {
    std::set<int> neighbours;
    int up = model.link(l).parent_joint;
    while (up >= 0) {
      const int parent = model.joint(up).parent_link;
      neighbours.insert(parent);
      if (!bodies_of[parent].empty()) break;
      up = model.link(parent).parent_joint;
    }
    for (int a : bodies_of[l]) {
      for (int b : bodies_of[l]) {
        if (a != b) AllowPair(w, a, b);
      }
      for (int p : neighbours) {
        for (int b : bodies_of[p]) AllowPair(w, a, b);
      }
    }
  }
}

// A parallelogram mechanism (four-bar loops sharing links, as the da Vinci's double
// parallelogram) moves as one and its bars never meet in the real arm; our capsules overlap
// near the joints at some angles. The instrument carriage riding on the mechanism's end link is
// part of it too (docs/decisions.md, "Collision"). An instrument's own wrist and jaws against its
// shaft: its joint limits keep them apart.
void AllowMechanisms(CollisionWorld::Impl& w) {
  const robot::RobotModel& model = *w.robot;
  auto allow_links = [&](const std::vector<int>& links) {
    for (int a : w.robot_bodies) {
      for (int b : w.robot_bodies) {
        const bool in_a = std::find(links.begin(), links.end(), w.bodies[a].link) != links.end();
        const bool in_b = std::find(links.begin(), links.end(), w.bodies[b].link) != links.end();
        if (a < b && in_a && in_b) AllowPair(w, a, b);
      }
    }
  };
  std::vector<std::vector<int>> groups;
  for (const auto& c : model.closures()) {
    std::vector<int> loop = {c.ground_link, model.joint(c.driver).child_link,
                             model.joint(c.coupler).child_link, model.joint(c.rocker).child_link};
    for (auto it = groups.begin(); it != groups.end();) {
      const bool shares = std::any_of(loop.begin(), loop.end(), [&](int l) {
        return std::find(it->begin(), it->end(), l) != it->end();
      });
      if (shares) {
        loop.insert(loop.end(), it->begin(), it->end());
        it = groups.erase(it);
      } else {
        ++it;
      }
    }
    groups.push_back(loop);
  }
  for (auto& group : groups) {
    for (const auto& port : w.ports) {
      const int carriage_parent = model.joint(model.link(port.links[0]).parent_joint).parent_link;
      if (std::find(group.begin(), group.end(), carriage_parent) != group.end()) {
        group.insert(group.end(), port.links.begin(), port.links.end());
      }
    }
    allow_links(group);
  }
  for (const auto& port : w.ports) allow_links(port.links);
}

// The caller's pairs, by body or link name (not counted as automatic).
void AllowCallersPairs(CollisionWorld::Impl& w, const std::vector<AllowedPair>& allowed) {
  const std::size_t n = w.n();
  for (const auto& p : allowed) {
    auto matches = [&](const std::string& name) {
      std::vector<int> out;
      for (std::size_t i = 0; i < n; ++i) {
        const Body& body = w.bodies[i];
        if (body.name == name || (body.link >= 0 && w.robot->link(body.link).name == name)) {
          out.push_back(static_cast<int>(i));
        }
      }
      TROCAR_THROW_UNLESS(!out.empty(), "collision world: allowed pair names '"
                                            << name << "', which is no body or link");
      return out;
    };
    for (int a : matches(p.a)) {
      for (int b : matches(p.b)) {
        if (a != b) w.allowed[a * n + b] = w.allowed[b * n + a] = 1;
      }
    }
  }
}

// Pairs of robot shapes touching in (almost) every configuration are part of the design
// (parallelogram links overlapping at their joints): allowed, as MoveIt's setup assistant does.
// Sampled with `world`'s own checker; `w` is that world's state.
void AllowAlwaysTouching(const std::shared_ptr<const CollisionWorld>& world,
                         CollisionWorld::Impl& w, const WorldOptions& options) {
  const robot::RobotModel& model = *w.robot;
  std::map<std::pair<int, int>, int> touching;
  int valid = 0;
  {
    CollisionChecker checker(world);
    robot::RobotState state(model);
    std::mt19937 rng(options.acm_seed);
    auto sample = [&](const robot::JointLimits& lim) {
      const double lo = std::isfinite(lim.lower) ? lim.lower : -M_PI;
      const double hi = std::isfinite(lim.upper) ? lim.upper : M_PI;
      return std::uniform_real_distribution<double>(lo, hi)(rng);
    };
    for (int s = 0; s < options.acm_samples; ++s) {
      robot::RobotState trial = state;
      for (int j : model.dof_joints()) {
        if (model.joint(j).drive == robot::JointDrive::kHeld) {
          trial.joint_values[model.joint(j).dof_index] = sample(model.joint(j).limits);
        }
      }
      Eigen::VectorXd q(model.num_positions());
      for (int i = 0; i < model.num_positions(); ++i)
        q[i] = sample(model.joint(model.active_joints()[i]).limits);
      if (!kinematics::ForwardKinematics(model, q, &trial).ok()) continue;
      ++valid;
      checker.SetRobotState(trial);
      for (const auto& c :
           checker.Check(Bit(PairClass::kSelf) | Bit(PairClass::kArmArm)).contacts) {
        ++touching[{c.a, c.b}];
      }
    }
  }
  if (valid >= std::max(10, options.acm_samples / 4)) {
    for (const auto& [pair, count] : touching) {
      if (count >= options.always_fraction * valid) AllowPair(w, pair.first, pair.second);
    }
  }
}

}  // namespace

std::shared_ptr<const CollisionWorld> CollisionWorld::BuildWith(
    const std::vector<FixedMesh>& meshes, const patient::Table* table,
    std::shared_ptr<const robot::RobotModel> robot, const WorldOptions& options,
    const std::vector<AllowedPair>& allowed) {
  TROCAR_THROW_UNLESS(
      std::isfinite(options.port_radius) && options.port_radius >= 0.0,
      "collision world: port_radius = " << options.port_radius << ", expected >= 0 m");
  auto impl = std::make_unique<Impl>();
  impl->options = options;
  impl->robot = std::move(robot);
  if (impl->robot) AddRobot(*impl, options.bvh);
  for (const auto& m : meshes) {
    TROCAR_THROW_UNLESS(!m.name.empty(), "collision world: a fixed mesh has no name");
    AddFixedMesh(*impl, m.name, m.mesh, m.X_WM, m.patient, m.skin, m.chest_wall,
                 (m.patient ? "patient structure '" : "fixed mesh '") + m.name + "'" +
                     (m.mesh.source.empty() ? "" : " (" + m.mesh.source + ")"));
  }
  if (table) AddTable(*impl, *table);
  ClassifyPairs(*impl);
  if (impl->robot) {
    AllowJoinedLinks(*impl);
    AllowMechanisms(*impl);
  }
  AllowCallersPairs(*impl, allowed);
  Impl& w = *impl;
  std::shared_ptr<CollisionWorld> world(new CollisionWorld(std::move(impl)));
  if (w.robot && options.acm_samples > 0 && !w.robot_bodies.empty())
    AllowAlwaysTouching(world, w, options);
  return world;
}

}  // namespace trocar::collision
