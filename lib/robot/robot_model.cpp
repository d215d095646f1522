#include "robot/robot_model.hpp"

#include <cmath>
#include <functional>
#include <map>
#include <set>

#include "common/error.hpp"
#include "common/geometry.hpp"
#include "robot/robot_state.hpp"

namespace trocar::robot {

const char* ToString(JointType type) {
  switch (type) {
    case JointType::kFixed: return "fixed";
    case JointType::kRevolute: return "revolute";
    case JointType::kPrismatic: return "prismatic";
  }
  return "?";
}

const char* ToString(JointDrive drive) {
  switch (drive) {
    case JointDrive::kActive: return "active";
    case JointDrive::kHeld: return "held";
    case JointDrive::kMimic: return "mimic";
    case JointDrive::kClosure: return "closure";
  }
  return "?";
}

const char* ToString(Geometry::Shape shape) {
  switch (shape) {
    case Geometry::Shape::kMesh: return "mesh";
    case Geometry::Shape::kBox: return "box";
    case Geometry::Shape::kCylinder: return "cylinder";
    case Geometry::Shape::kSphere: return "sphere";
    case Geometry::Shape::kCapsule: return "capsule";
  }
  return "?";
}

// ---------------------------------------------------------------------------------------------
// RobotModel

namespace {

template <typename T>
int FindByName(const std::vector<T>& items, const std::string& name) {
  for (std::size_t i = 0; i < items.size(); ++i) {
    if (items[i].name == name) return static_cast<int>(i);
  }
  return -1;
}

template <typename T>
std::string NameList(const std::vector<T>& items) {
  std::string out;
  for (const auto& item : items) out += (out.empty() ? "" : ", ") + item.name;
  return out;
}

}  // namespace

int RobotModel::FindLink(const std::string& name) const { return FindByName(links_, name); }
int RobotModel::FindJoint(const std::string& name) const { return FindByName(joints_, name); }

int RobotModel::GetLink(const std::string& name) const {
  const int index = FindLink(name);
  TROCAR_THROW_UNLESS(index >= 0, source_ << ": robot '" << name_ << "' has no link '" << name
                                          << "' (links: " << NameList(links_) << ")");
  return index;
}

int RobotModel::GetJoint(const std::string& name) const {
  const int index = FindJoint(name);
  TROCAR_THROW_UNLESS(index >= 0, source_ << ": robot '" << name_ << "' has no joint '" << name
                                          << "' (joints: " << NameList(joints_) << ")");
  return index;
}

const Frame& RobotModel::GetFrame(const std::string& name) const {
  const int index = FindByName(frames_, name);
  if (index >= 0) return frames_[index];
  const int link = FindByName(link_frames_, name);
  TROCAR_THROW_UNLESS(link >= 0, source_ << ": robot '" << name_ << "' has no frame or link '"
                                         << name << "' (frames: " << NameList(frames_)
                                         << "; links: " << NameList(links_) << ")");
  return link_frames_[link];
}

Eigen::VectorXd RobotModel::ActiveLimits(double JointLimits::*member) const {
  Eigen::VectorXd v(num_positions());
  for (int i = 0; i < num_positions(); ++i) v[i] = joints_[active_joints_[i]].limits.*member;
  return v;
}

Eigen::VectorXd RobotModel::lower_limits() const { return ActiveLimits(&JointLimits::lower); }
Eigen::VectorXd RobotModel::upper_limits() const { return ActiveLimits(&JointLimits::upper); }
Eigen::VectorXd RobotModel::velocity_limits() const { return ActiveLimits(&JointLimits::velocity); }
Eigen::VectorXd RobotModel::acceleration_limits() const {
  return ActiveLimits(&JointLimits::acceleration);
}

namespace {
double NeutralValue(const JointLimits& limits) {
  if (limits.lower <= 0.0 && 0.0 <= limits.upper) return 0.0;
  return 0.5 * (limits.lower + limits.upper);
}
}  // namespace

Eigen::VectorXd RobotModel::neutral_configuration() const {
  Eigen::VectorXd q(num_positions());
  for (int i = 0; i < num_positions(); ++i) q[i] = NeutralValue(joints_[active_joints_[i]].limits);
  return q;
}

RobotState::RobotState(const RobotModel& model)
    : q(model.neutral_configuration()),
      joint_values(Eigen::VectorXd::Zero(model.num_dofs())),
      dvalues_dq(Eigen::MatrixXd::Zero(model.num_dofs(), model.num_positions())),
      X_WL(model.num_links(), Eigen::Isometry3d::Identity()),
      closure_drivers(Eigen::VectorXd::Zero(static_cast<int>(model.closures().size()))),
      undo{q, joint_values, closure_drivers, dvalues_dq} {
  for (const Joint& joint : model.joints()) {
    if (!joint.movable()) continue;
    if (joint.drive == JointDrive::kActive) {
      joint_values[joint.dof_index] = q[joint.q_index];
      dvalues_dq(joint.dof_index, joint.q_index) = 1.0;
    } else if (joint.drive == JointDrive::kHeld) {
      joint_values[joint.dof_index] = NeutralValue(joint.limits);
    }
  }
}

// ---------------------------------------------------------------------------------------------
// RobotModelBuilder

RobotModelBuilder::RobotModelBuilder(std::string name, std::string source)
    : name_(std::move(name)), source_(std::move(source)) {}

RobotModelBuilder::LinkSpec& RobotModelBuilder::AddLink(const std::string& name) {
  TROCAR_THROW_UNLESS(!name.empty(), source_ << ": a link has an empty name");
  TROCAR_THROW_UNLESS(FindLink(name) == nullptr,
                      source_ << ": link '" << name << "' is defined twice");
  links_.push_back(LinkSpec{name, {}, {}});
  return links_.back();
}

RobotModelBuilder::JointSpec& RobotModelBuilder::AddJoint(const std::string& name) {
  TROCAR_THROW_UNLESS(!name.empty(), source_ << ": a joint has an empty name");
  TROCAR_THROW_UNLESS(FindJoint(name) == nullptr,
                      source_ << ": joint '" << name << "' is defined twice");
  joints_.emplace_back();
  joints_.back().name = name;
  return joints_.back();
}

RobotModelBuilder::LinkSpec* RobotModelBuilder::FindLink(const std::string& name) {
  for (auto& link : links_) {
    if (link.name == name) return &link;
  }
  return nullptr;
}

RobotModelBuilder::JointSpec* RobotModelBuilder::FindJoint(const std::string& name) {
  for (auto& joint : joints_) {
    if (joint.name == name) return &joint;
  }
  return nullptr;
}

RobotModelBuilder::LinkSpec& RobotModelBuilder::GetLink(const std::string& name) {
  LinkSpec* link = FindLink(name);
  TROCAR_THROW_UNLESS(link != nullptr, source_ << ": no link named '" << name << "' (links: "
                                               << NameList(links_) << ")");
  return *link;
}

RobotModelBuilder::JointSpec& RobotModelBuilder::GetJoint(const std::string& name) {
  JointSpec* joint = FindJoint(name);
  TROCAR_THROW_UNLESS(joint != nullptr, source_ << ": no joint named '" << name << "' (joints: "
                                                << NameList(joints_) << ")");
  return *joint;
}

void RobotModelBuilder::Attach(const RobotModelBuilder& other, const std::string& prefix,
                               const std::string& parent_link, const Eigen::Isometry3d& X_PC) {
  std::string root;
  for (const LinkSpec& link : other.links_) {
    bool has_parent = false;
    for (const JointSpec& joint : other.joints_) has_parent = has_parent || joint.child == link.name;
    if (!has_parent && root.empty()) root = link.name;
  }
  TROCAR_THROW_UNLESS(!root.empty(), source_ << ": included description '" << other.source_
                                             << "' has no root link");
  if (!parent_link.empty()) {
    TROCAR_THROW_UNLESS(FindLink(parent_link) != nullptr,
                        source_ << ": include of '" << other.source_ << "': no parent link '"
                                << parent_link << "'");
  }
  for (const LinkSpec& link : other.links_) {
    LinkSpec& copy = AddLink(prefix + link.name);
    copy.visuals = link.visuals;
    copy.collisions = link.collisions;
  }
  for (const JointSpec& joint : other.joints_) {
    JointSpec& copy = AddJoint(prefix + joint.name);
    copy = joint;
    copy.name = prefix + joint.name;
    copy.parent = prefix + joint.parent;
    copy.child = prefix + joint.child;
    if (joint.mimic_master) copy.mimic_master = prefix + *joint.mimic_master;
  }
  for (FourBarSpec bar : other.four_bars_) {
    bar.name = prefix + bar.name;
    bar.driver = prefix + bar.driver;
    bar.coupler = prefix + bar.coupler;
    bar.rocker = prefix + bar.rocker;
    four_bars_.push_back(bar);
  }
  auto prefixed = [&](FrameSpec frame, const std::string& name) {
    frame.name = prefix + name;
    frame.link = prefix + frame.link;
    return frame;
  };
  for (const FrameSpec& frame : other.frames_) frames_.push_back(prefixed(frame, frame.name));
  const bool as_base = parent_link.empty();
  if (other.tool_) {
    if (as_base && !tool_ && prefix.empty()) {
      tool_ = other.tool_;
    } else {
      frames_.push_back(prefixed(*other.tool_, "tool"));
    }
  }
  if (other.rcm_) {
    if (as_base && !rcm_ && prefix.empty()) {
      rcm_ = other.rcm_;
    } else {
      frames_.push_back(prefixed(*other.rcm_, "rcm"));
    }
  }
  if (as_base && !home_) home_ = other.home_;
  if (other.active_order_) {
    if (!active_order_) active_order_.emplace();
    for (const std::string& name : *other.active_order_) active_order_->push_back(prefix + name);
  }
  if (as_base && controller_.task_gains.size() == 0 && controller_.gains.empty()) {
    controller_ = other.controller_;
  }
  for (Appearance appearance : other.appearances_) {  // worn by the same links, renamed
    for (auto& wear : appearance.links) wear.link = prefix + wear.link;
    for (auto& drive : appearance.joints) drive.joint = prefix + drive.joint;
    std::map<std::string, double> tolerances;
    for (const auto& [link, m] : appearance.tolerances) tolerances[prefix + link] = m;
    appearance.tolerances = std::move(tolerances);
    appearances_.push_back(std::move(appearance));
  }
  if (!as_base) {
    JointSpec& mount = AddJoint(prefix + "mount");
    mount.type = JointType::kFixed;
    mount.parent = parent_link;
    mount.child = prefix + root;
    mount.X_PJ = X_PC;
  }
}

void RobotModelBuilder::AddAppearance(Appearance appearance) {
  for (const auto& wear : appearance.links) {
    TROCAR_THROW_UNLESS(FindLink(wear.link) != nullptr,
                        appearance.where << ".links: no link named '" << wear.link << "'");
  }
  for (const auto& drive : appearance.joints) {
    TROCAR_THROW_UNLESS(FindJoint(drive.joint) != nullptr,
                        appearance.where << ".joints: no joint named '" << drive.joint << "'");
  }
  appearances_.push_back(std::move(appearance));
}

namespace {

constexpr double kParallelTolerance = 1e-6;  // sine of the largest accepted angle between axes
constexpr double kAssemblyTolerance = 1e-6;  // metres

// Beyond this a robot part is not physical (a damaged or hostile file: a radius of 1e308 makes
// every bounding volume infinite).
constexpr double kMaxPartSize = 100.0;  // metres

void ValidateGeometry(const std::string& where, const Geometry& g) {
  TROCAR_THROW_UNLESS(g.X_LG.matrix().allFinite(), where << ": pose is not finite");
  TROCAR_THROW_UNLESS(g.X_LG.translation().norm() <= kMaxPartSize,
                      where << ": origin " << FormatVector(g.X_LG.translation()) << " is more than "
                            << kMaxPartSize << " m from its link");
  if (g.shape != Geometry::Shape::kMesh) {
    TROCAR_THROW_UNLESS(!(g.size.cwiseAbs().maxCoeff() > kMaxPartSize),
                        where << ": " << ToString(g.shape) << " size " << FormatVector(g.size)
                              << " is larger than " << kMaxPartSize << " m (not a robot part)");
  } else {
    TROCAR_THROW_UNLESS(g.mesh_scale.allFinite() && (g.mesh_scale.array().abs() > 0).all() &&
                            g.mesh_scale.cwiseAbs().maxCoeff() <= 1000.0,
                        where << ": mesh scale " << FormatVector(g.mesh_scale)
                              << " (expected finite, non-zero, at most 1000)");
  }
  TROCAR_THROW_UNLESS(g.rgba.allFinite(), where << ": colour is not finite");
  switch (g.shape) {
    case Geometry::Shape::kMesh:
      TROCAR_THROW_UNLESS(!g.mesh_file.empty() || g.mesh != nullptr, where << ": mesh has no file");
      return;
    case Geometry::Shape::kBox:
      TROCAR_THROW_UNLESS(g.size.allFinite() && (g.size.array() > 0).all(),
                          where << ": box size " << FormatVector(g.size)
                                << " must be three positive lengths");
      return;
    case Geometry::Shape::kSphere:
      TROCAR_THROW_UNLESS(std::isfinite(g.size[0]) && g.size[0] > 0,
                          where << ": sphere radius " << g.size[0] << " must be positive");
      return;
    case Geometry::Shape::kCylinder:
    case Geometry::Shape::kCapsule:
      TROCAR_THROW_UNLESS(std::isfinite(g.size[0]) && g.size[0] > 0 && std::isfinite(g.size[1]) &&
                              g.size[1] >= 0,
                          where << ": " << ToString(g.shape) << " radius " << g.size[0]
                                << " and length " << g.size[1]
                                << " must be positive (length may be 0 for a capsule)");
      return;
  }
}

void ValidateLimits(const std::string& where, const JointLimits& l) {
  TROCAR_THROW_UNLESS(!std::isnan(l.lower) && !std::isnan(l.upper),
                      where << ": position limit is NaN");
  TROCAR_THROW_UNLESS(l.lower <= l.upper,
                      where << ": lower limit " << l.lower << " > upper limit " << l.upper);
  TROCAR_THROW_UNLESS(!std::isnan(l.velocity) && l.velocity > 0,
                      where << ": velocity limit " << l.velocity << " must be positive");
  TROCAR_THROW_UNLESS(!std::isnan(l.acceleration) && l.acceleration > 0,
                      where << ": acceleration limit " << l.acceleration << " must be positive");
  TROCAR_THROW_UNLESS(!std::isnan(l.effort) && l.effort >= 0,
                      where << ": effort limit " << l.effort << " must not be negative");
}

// In-plane basis for unit normal n.
void PlaneBasis(const Eigen::Vector3d& n, Eigen::Vector3d* u, Eigen::Vector3d* v) {
  const Eigen::Vector3d helper =
      std::abs(n.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  *u = (helper - helper.dot(n) * n).normalized();
  *v = n.cross(*u);
}

double Cross2(const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  return a.x() * b.y() - a.y() * b.x();
}

double Angle2(const Eigen::Vector2d& a) { return std::atan2(a.y(), a.x()); }

// Kinematic frame from a point and axis pair (thesis §2.4.2), both in the link frame.
Eigen::Isometry3d FrameFromAxis(const Eigen::Vector3d& origin, const Eigen::Vector3d& z_axis,
                                const Eigen::Vector3d& x_hint) {
  const Eigen::Vector3d z = z_axis.normalized();
  Eigen::Vector3d x = x_hint - x_hint.dot(z) * z;
  if (x.norm() < 1e-9) {
    const Eigen::Vector3d fallback =
        std::abs(z.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
    x = fallback - fallback.dot(z) * z;
  }
  x.normalize();
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear().col(0) = x;
  X.linear().col(1) = z.cross(x);
  X.linear().col(2) = z;
  X.translation() = origin;
  return X;
}

}  // namespace


// ---------------------------------------------------------------------------------------------
// RobotModelBuilder::Build, stage by stage

// 1. The tree: every joint's links exist, each link has at most one parent joint, exactly one
// root, every link reached from it; joints' origins, axes and limits valid. Returns the
// depth-first order of the link and joint specs.
RobotModelBuilder::TreeOrder RobotModelBuilder::ValidateTree() const {
  const std::string& src = source_;
  TROCAR_THROW_UNLESS(!links_.empty(), src << ": robot '" << name_ << "' has no links");
  // --- Tree structure: each link has at most one parent joint; exactly one root.
  std::map<std::string, int> link_spec_index;
  for (std::size_t i = 0; i < links_.size(); ++i) link_spec_index[links_[i].name] = int(i);
  std::map<std::string, int> parent_joint_of;  // child link name → joint spec index
  std::vector<std::vector<int>> child_specs(links_.size());
  for (std::size_t j = 0; j < joints_.size(); ++j) {
    const JointSpec& js = joints_[j];
    const std::string where = src + ": joint '" + js.name + "'";
    TROCAR_THROW_UNLESS(link_spec_index.count(js.parent),
                        where << ": parent link '" << js.parent << "' does not exist");
    TROCAR_THROW_UNLESS(link_spec_index.count(js.child),
                        where << ": child link '" << js.child << "' does not exist");
    TROCAR_THROW_UNLESS(js.parent != js.child, where << ": connects link '" << js.parent
                                                     << "' to itself");
    TROCAR_THROW_UNLESS(!parent_joint_of.count(js.child),
                        where << ": link '" << js.child << "' already has parent joint '"
                              << joints_[parent_joint_of[js.child]].name
                              << "' (a kinematic tree; close loops with a four-bar closure)");
    parent_joint_of[js.child] = int(j);
    child_specs[link_spec_index[js.parent]].push_back(int(j));
    TROCAR_THROW_UNLESS(js.X_PJ.matrix().allFinite(), where << ": origin is not finite");
    if (js.type != JointType::kFixed) {
      TROCAR_THROW_UNLESS(js.axis.allFinite() && js.axis.norm() > 1e-12,
                          where << ": axis " << FormatVector(js.axis)
                                << " must be a finite non-zero vector");
      ValidateLimits(where, js.limits);
    }
  }
  std::vector<int> roots;
  for (std::size_t i = 0; i < links_.size(); ++i) {
    if (!parent_joint_of.count(links_[i].name)) roots.push_back(int(i));
  }
  if (roots.size() != 1) {
    std::string names;
    for (int r : roots) names += (names.empty() ? "" : ", ") + links_[r].name;
    TROCAR_THROW(src << ": robot '" << name_ << "' must have exactly one root link, found "
                     << roots.size() << (roots.empty() ? " (the joints form a loop)" : ": ")
                     << names);
  }

  // --- Depth-first order of links and joints.
  TreeOrder order;
  std::vector<int>& link_order = order.links;
  std::vector<int>& joint_order = order.joints;
  std::function<void(int)> visit = [&](int link_spec) {
    link_order.push_back(link_spec);
    for (int j : child_specs[link_spec]) {
      joint_order.push_back(j);
      visit(link_spec_index[joints_[j].child]);
    }
  };
  visit(roots[0]);
  TROCAR_THROW_UNLESS(link_order.size() == links_.size(),
                      src << ": some links are not connected to the root link '"
                          << links_[roots[0]].name << "'");
  return order;
}

// 2. Links (their geometry checked) and joints in depth-first order, with the model's indices.
RobotModelBuilder::NameIndex RobotModelBuilder::AddLinksAndJoints(const TreeOrder& order,
                                                                  RobotModel* out) const {
  const std::string& src = source_;
  RobotModel& model = *out;
  NameIndex names;
  std::map<std::string, int>& link_index = names.links;
  std::map<std::string, int>& joint_index = names.joints;
  const std::vector<int>& link_order = order.links;
  const std::vector<int>& joint_order = order.joints;
  for (int spec : link_order) {
    Link link;
    link.name = links_[spec].name;
    link.visuals = links_[spec].visuals;
    link.collisions = links_[spec].collisions;
    for (std::size_t g = 0; g < link.visuals.size(); ++g) {
      ValidateGeometry(src + ": link '" + link.name + "': visual " + std::to_string(g),
                       link.visuals[g]);
    }
    for (std::size_t g = 0; g < link.collisions.size(); ++g) {
      ValidateGeometry(src + ": link '" + link.name + "': collision " + std::to_string(g),
                       link.collisions[g]);
    }
    link_index[link.name] = model.num_links();
    model.links_.push_back(std::move(link));
  }
  for (int spec : joint_order) {
    const JointSpec& js = joints_[spec];
    Joint joint;
    joint.name = js.name;
    joint.type = js.type;
    joint.parent_link = link_index[js.parent];
    joint.child_link = link_index[js.child];
    joint.X_PJ = js.X_PJ;
    joint.X_PJ.linear() = Eigen::Quaterniond(js.X_PJ.linear()).normalized().toRotationMatrix();
    joint.axis_J = js.type == JointType::kFixed ? Eigen::Vector3d::UnitZ() : js.axis.normalized();
    {
      const Eigen::Vector3d& a = joint.axis_J;
      Eigen::Matrix3d K;
      K << 0, -a.z(), a.y(), a.z(), 0, -a.x(), -a.y(), a.x(), 0;
      joint.rodrigues_M = joint.X_PJ.linear() * (a * a.transpose());
      joint.rodrigues_N = joint.X_PJ.linear() * K;
    }
    joint.limits = js.limits;
    const int index = model.num_joints();
    joint_index[joint.name] = index;
    model.links_[joint.parent_link].child_joints.push_back(index);
    model.links_[joint.child_link].parent_joint = index;
    if (joint.movable()) {
      joint.dof_index = int(model.dof_joints_.size());
      model.dof_joints_.push_back(index);
    }
    model.joints_.push_back(std::move(joint));
  }
  return names;
}

// A movable joint by name, for a role ("closure 'x' driver"), or an error naming both.
int RobotModelBuilder::MovableJoint(const NameIndex& names, const RobotModel& model,
                                    const std::string& name, const std::string& role) const {
  const std::string& src = source_;
  const auto found = names.joints.find(name);
  TROCAR_THROW_UNLESS(found != names.joints.end(),
                      src << ": " << role << ": no joint named '" << name << "'");
  const int j = found->second;
  TROCAR_THROW_UNLESS(model.joints_[j].movable(),
                      src << ": " << role << ": joint '" << name << "' is fixed");
  return j;
}

// 3. Drives declared per joint: mimic (master, multiplier, offset) and held.
void RobotModelBuilder::AssignDrives(const TreeOrder& order, const NameIndex& names,
                                     RobotModel* out) const {
  const std::string& src = source_;
  RobotModel& model = *out;
  const std::vector<int>& joint_order = order.joints;
  const std::map<std::string, int>& joint_index = names.joints;
  // --- Drives: mimic, closure, held, active.
  for (int spec : joint_order) {
    const JointSpec& js = joints_[spec];
    Joint& joint = model.joints_[joint_index.at(js.name)];
    if (!joint.movable()) continue;
    if (js.mimic_master) {
      const std::string role = "joint '" + js.name + "' mimic";
      joint.drive = JointDrive::kMimic;
      joint.mimic.master = MovableJoint(names, model, *js.mimic_master, role);
      TROCAR_THROW_UNLESS(joint.mimic.master != joint_index.at(js.name),
                          src << ": " << role << ": a joint cannot mimic itself");
      TROCAR_THROW_UNLESS(std::isfinite(js.mimic_multiplier) && std::isfinite(js.mimic_offset),
                          src << ": " << role << ": multiplier " << js.mimic_multiplier
                              << " and offset " << js.mimic_offset << " must be finite");
      joint.mimic.multiplier = js.mimic_multiplier;
      joint.mimic.offset = js.mimic_offset;
    } else if (js.held) {
      joint.drive = JointDrive::kHeld;
    }
  }
}

// 4. Four-bar closures: their joints (revolute, parallel axes, the right links), their drive,
// and their planar geometry in the ground link at the zero configuration.
void RobotModelBuilder::BuildClosures(const NameIndex& names, RobotModel* out) const {
  const std::string& src = source_;
  RobotModel& model = *out;
  for (const FourBarSpec& spec : four_bars_) {
    const std::string where = src + ": closure '" + spec.name + "'";
    FourBarClosure c;
    c.name = spec.name;
    c.driver = MovableJoint(names, model, spec.driver, "closure '" + spec.name + "' driver");
    c.coupler = MovableJoint(names, model, spec.coupler, "closure '" + spec.name + "' coupler");
    c.rocker = MovableJoint(names, model, spec.rocker, "closure '" + spec.name + "' rocker");
    const Joint& jd = model.joints_[c.driver];
    Joint& jc = model.joints_[c.coupler];
    Joint& jr = model.joints_[c.rocker];
    for (const Joint* j : {&jd, static_cast<const Joint*>(&jc), static_cast<const Joint*>(&jr)}) {
      TROCAR_THROW_UNLESS(j->type == JointType::kRevolute,
                          where << ": joint '" << j->name << "' must be revolute, is "
                                << ToString(j->type));
    }
    TROCAR_THROW_UNLESS(c.driver != c.coupler && c.driver != c.rocker && c.coupler != c.rocker,
                        where << ": driver, coupler and rocker must be three different joints");
    TROCAR_THROW_UNLESS(jd.parent_link == jr.parent_link,
                        where << ": driver '" << jd.name << "' and rocker '" << jr.name
                              << "' must hang from the same (ground) link, but hang from '"
                              << model.links_[jd.parent_link].name << "' and '"
                              << model.links_[jr.parent_link].name << "'");
    TROCAR_THROW_UNLESS(jc.parent_link == jd.child_link,
                        where << ": coupler '" << jc.name << "' must hang from the driver's link '"
                              << model.links_[jd.child_link].name << "', hangs from '"
                              << model.links_[jc.parent_link].name << "'");
    for (Joint* j : {&jc, &jr}) {
      TROCAR_THROW_UNLESS(j->drive != JointDrive::kMimic && j->drive != JointDrive::kClosure,
                          where << ": joint '" << j->name << "' is already driven ("
                                << ToString(j->drive) << ")");
      j->drive = JointDrive::kClosure;
      j->closure = int(model.closures_.size());
    }
    c.ground_link = jd.parent_link;
    // Geometry in the ground frame G at the zero configuration.
    const Eigen::Isometry3d& X_GJd = jd.X_PJ;
    const Eigen::Isometry3d X_GC = X_GJd * jc.X_PJ;
    const Eigen::Isometry3d& X_GJr = jr.X_PJ;
    c.n_G = (X_GJd.linear() * jd.axis_J).normalized();
    const Eigen::Vector3d a_c = X_GC.linear() * jc.axis_J;
    const Eigen::Vector3d a_r = X_GJr.linear() * jr.axis_J;
    for (const auto& [joint, axis] : {std::pair{&jc, a_c}, std::pair{&jr, a_r}}) {
      const double sine = c.n_G.cross(axis).norm();
      TROCAR_THROW_UNLESS(sine < kParallelTolerance,
                          where << ": axis of joint '" << joint->name << "' is "
                                << std::asin(std::min(1.0, sine)) * 180.0 / M_PI
                                << " deg from the driver '" << jd.name
                                << "' axis; a four-bar needs four parallel axes");
    }
    c.coupler_sign = a_c.dot(c.n_G) > 0 ? 1.0 : -1.0;
    c.rocker_sign = a_r.dot(c.n_G) > 0 ? 1.0 : -1.0;
    PlaneBasis(c.n_G, &c.u_G, &c.v_G);
    auto proj = [&](const Eigen::Vector3d& p) { return Eigen::Vector2d(p.dot(c.u_G), p.dot(c.v_G)); };
    const Eigen::Vector3d P3_G = X_GC * spec.p_C3;
    c.p_C3 = spec.p_C3;
    if (spec.p_B3) {
      const double gap = (X_GJr * *spec.p_B3 - P3_G).norm();
      TROCAR_THROW_UNLESS(gap < kAssemblyTolerance,
                          where << ": not assembled at the zero configuration: the cut points on '"
                                << model.links_[jc.child_link].name << "' and '"
                                << model.links_[jr.child_link].name << "' are " << gap
                                << " m apart");
      c.p_B3 = *spec.p_B3;
    } else {
      c.p_B3 = X_GJr.inverse() * P3_G;
    }
    TROCAR_THROW_UNLESS(c.p_C3.allFinite() && c.p_B3.allFinite(),
                        where << ": cut point is not finite");
    c.P1 = proj(X_GJd.translation());
    const Eigen::Vector2d P2 = proj(X_GC.translation());
    c.c0 = P2 - c.P1;
    c.P4 = proj(X_GJr.translation());
    const Eigen::Vector2d P3 = proj(P3_G);
    c.L23 = (P3 - P2).norm();
    c.L34 = (P3 - c.P4).norm();
    const double scale = std::max({c.L23, c.L34, c.c0.norm(), (c.P4 - c.P1).norm()});
    TROCAR_THROW_UNLESS(c.L23 > 1e-9 && c.L34 > 1e-9 && c.c0.norm() > 1e-9,
                        where << ": degenerate loop: crank " << c.c0.norm() << " m, coupler "
                              << c.L23 << " m, rocker " << c.L34 << " m");
    c.coupler_ref_angle = Angle2(P3 - P2);
    c.rocker_ref_angle = Angle2(P3 - c.P4);
    const double side = Cross2(c.P4 - P2, P3 - P2);
    TROCAR_THROW_UNLESS(std::abs(side) > 1e-9 * scale * scale,
                        where << ": the loop is at a change point (coupler and rocker aligned) in "
                                 "the zero configuration; its branch is undefined");
    c.branch_sign = side > 0 ? 1.0 : -1.0;
    const Eigen::Vector2d D = c.P4 - c.P1;
    c.change_phase = D.norm() > 1e-12 ? Angle2(c.c0) - Angle2(D) : 0.0;
    model.closures_.push_back(c);
  }
}

// 5. Active joints: the plain movable ones in depth-first order, or the description's list
// (the others held).
void RobotModelBuilder::AssignActiveJoints(const NameIndex& names, RobotModel* out) const {
  const std::string& src = source_;
  RobotModel& model = *out;
  const std::map<std::string, int>& joint_index = names.joints;
  // Active joints: the plain movable ones in depth-first order, or the sidecar's list.
  if (active_order_) {
    std::set<int> listed;
    for (const std::string& name : *active_order_) {
      const int j = MovableJoint(names, model, name, "active_joints");
      Joint& joint = model.joints_[j];
      TROCAR_THROW_UNLESS(joint.drive != JointDrive::kMimic && joint.drive != JointDrive::kClosure,
                          src << ": active_joints: joint '" << name << "' is driven by "
                              << ToString(joint.drive) << " and cannot be active");
      TROCAR_THROW_UNLESS(listed.insert(j).second,
                          src << ": active_joints: joint '" << name << "' is listed twice");
      joint.drive = JointDrive::kActive;
    }
    for (int j : model.dof_joints_) {
      Joint& joint = model.joints_[j];
      if (joint.drive == JointDrive::kActive && !listed.count(j)) joint.drive = JointDrive::kHeld;
    }
    for (const std::string& name : *active_order_) {
      const int j = joint_index.at(name);
      model.joints_[j].q_index = int(model.active_joints_.size());
      model.active_joints_.push_back(j);
    }
  } else {
    for (int j : model.dof_joints_) {
      Joint& joint = model.joints_[j];
      if (joint.drive != JointDrive::kActive) continue;
      joint.q_index = int(model.active_joints_.size());
      model.active_joints_.push_back(j);
    }
  }
}

// 6. The order in which mimic and closure joints are resolved (dependencies first, cycles
// refused).
void RobotModelBuilder::OrderResolution(RobotModel* out) const {
  const std::string& src = source_;
  RobotModel& model = *out;
  // --- Resolution order for mimic and closure joints (dependencies first, cycles refused).
  {
    std::vector<int> state(model.joints_.size(), 0);  // 0 new, 1 visiting, 2 done
    std::vector<char> closure_done(model.closures_.size(), 0);
    std::function<void(int, const std::string&)> resolve = [&](int j, const std::string& chain) {
      Joint& joint = model.joints_[j];
      if (joint.drive == JointDrive::kActive || joint.drive == JointDrive::kHeld) return;
      if (state[j] == 2) return;
      TROCAR_THROW_UNLESS(state[j] != 1, src << ": joints depend on each other in a cycle: "
                                             << chain << " -> " << joint.name);
      state[j] = 1;
      const std::string next = chain.empty() ? joint.name : chain + " -> " + joint.name;
      if (joint.drive == JointDrive::kMimic) {
        resolve(joint.mimic.master, next);
        model.resolve_order_.push_back(j);
      } else {
        const FourBarClosure& c = model.closures_[joint.closure];
        resolve(c.driver, next);
        if (!closure_done[joint.closure]) {
          closure_done[joint.closure] = 1;
          model.resolve_order_.push_back(-1 - joint.closure);
        }
      }
      state[j] = 2;
    };
    for (int j : model.dof_joints_) resolve(j, "");
  }
}

// 7. Kinematic frames per body (thesis §2.4.2).
void RobotModelBuilder::AddKinematicFrames(RobotModel* out) const {
  RobotModel& model = *out;
  const Eigen::Isometry3d I = Eigen::Isometry3d::Identity();
  // --- Kinematic frames per body (thesis §2.4.2).
  for (int l = 0; l < model.num_links(); ++l) {
    Link& link = model.links_[l];
    const Joint* parent = link.parent_joint >= 0 ? &model.joints_[link.parent_joint] : nullptr;
    if (parent && parent->movable() && parent->drive == JointDrive::kActive) {
      link.X_LK = FrameFromAxis(Eigen::Vector3d::Zero(), parent->axis_J, Eigen::Vector3d::UnitX());
      continue;
    }
    std::vector<std::pair<Eigen::Vector3d, Eigen::Vector3d>> passive;  // point, axis in L
    if (parent && parent->movable()) passive.emplace_back(Eigen::Vector3d::Zero(), parent->axis_J);
    for (int cj : link.child_joints) {
      const Joint& child = model.joints_[cj];
      if (child.movable() && child.drive != JointDrive::kActive) {
        passive.emplace_back(child.X_PJ.translation(), child.X_PJ.linear() * child.axis_J);
      }
    }
    for (const FourBarClosure& c : model.closures_) {
      if (model.joints_[c.coupler].child_link == l) {
        passive.emplace_back(c.p_C3, model.joints_[c.coupler].axis_J);
      }
      if (model.joints_[c.rocker].child_link == l) {
        passive.emplace_back(c.p_B3, model.joints_[c.rocker].axis_J);
      }
    }
    if (passive.size() >= 2) {
      const auto& [p1, a1] = passive[0];
      const auto& [p2, a2] = passive[1];
      link.X_LK = FrameFromAxis(0.5 * (p1 + p2), a2, p2 - p1);
    } else {
      link.X_LK = I;
    }
  }
}

// 8. Paths of movable joints from the base to each link, used by Jacobians.
void RobotModelBuilder::AddMovablePaths(RobotModel* out) const {
  RobotModel& model = *out;
  // --- Paths from the base, used by Jacobians.
  model.movable_paths_.resize(model.links_.size());
  for (int l = 1; l < model.num_links(); ++l) {
    const Joint& joint = model.joints_[model.links_[l].parent_joint];
    model.movable_paths_[l] = model.movable_paths_[joint.parent_link];
    if (joint.movable()) model.movable_paths_[l].push_back(model.links_[l].parent_joint);
  }
}

// 9. Named frames: the tool (declared, a link named 'tool', or the tip of the chain below the
// last active joint), the RCM, declared frames, and one frame per link.
void RobotModelBuilder::AddNamedFrames(const NameIndex& names, RobotModel* out) const {
  const std::string& src = source_;
  RobotModel& model = *out;
  const Eigen::Isometry3d I = Eigen::Isometry3d::Identity();
  const std::map<std::string, int>& link_index = names.links;
  // --- Named frames.
  auto make_frame = [&](const FrameSpec& spec, const std::string& role) {
    TROCAR_THROW_UNLESS(link_index.count(spec.link), src << ": " << role << " '" << spec.name
                                                         << "': no link named '" << spec.link
                                                         << "'");
    TROCAR_THROW_UNLESS(spec.X_LF.matrix().allFinite(),
                        src << ": " << role << " '" << spec.name << "': pose is not finite");
    return Frame{spec.name, link_index.at(spec.link), spec.X_LF};
  };
  // A declared frame named like a link must be that link's own frame: otherwise one name would
  // mean two poses (`--frame tool` giving the wrong link).
  auto check_clash = [&](const Frame& frame, const std::string& role) {
    const int link = FindByName(model.links_, frame.name);
    TROCAR_THROW_UNLESS(link < 0 || (link == frame.link && frame.X_LF.isApprox(I, 1e-12)),
                        src << ": " << role << " '" << frame.name << "' (on link '"
                            << model.links_[frame.link].name
                            << "') has the name of link '" << model.links_[std::max(link, 0)].name
                            << "' but not its pose: rename one of them");
  };
  if (tool_) {
    model.tool_ = make_frame(*tool_, "tool");
    model.tool_basis_ = "declared in the description";
    check_clash(model.tool_, "tool frame");
  } else if (const int named = FindByName(model.links_, "tool"); named >= 0) {
    model.tool_ = Frame{"tool", named, I};
    model.tool_basis_ = "the link named 'tool'";
  } else {
    // The tip of the chain below the last active joint, followed through fixed and mimic joints
    // while the chain does not branch.
    int link = model.active_joints_.empty()
                   ? model.num_links() - 1
                   : model.joints_[model.active_joints_.back()].child_link;
    std::string through;
    for (;;) {
      const auto& children = model.links_[link].child_joints;
      if (children.size() != 1) break;
      const Joint& next = model.joints_[children[0]];
      if (next.movable() && next.drive != JointDrive::kMimic) break;
      through += (through.empty() ? "" : ", ") + std::string(next.movable() ? "mimic " : "fixed ") +
                 "'" + next.name + "'";
      link = next.child_link;
    }
    model.tool_ = Frame{"tool", link, I};
    model.tool_basis_ =
        model.active_joints_.empty()
            ? std::string("the last link (no active joints)")
            : "the tip of the chain below the last active joint '" +
                  model.joints_[model.active_joints_.back()].name + "'" +
                  (through.empty() ? std::string() : " through " + through) +
                  (model.links_[link].child_joints.size() > 1 ? " (the chain branches there)" : "");
  }
  model.frames_.push_back(model.tool_);
  if (rcm_) {
    model.rcm_ = make_frame(*rcm_, "rcm");
    check_clash(*model.rcm_, "rcm frame");
    model.frames_.push_back(*model.rcm_);
  }
  std::set<std::string> frame_names{model.tool_.name};
  if (model.rcm_) frame_names.insert(model.rcm_->name);
  for (const FrameSpec& spec : frames_) {
    TROCAR_THROW_UNLESS(frame_names.insert(spec.name).second,
                        src << ": frame '" << spec.name << "' is defined twice");
    model.frames_.push_back(make_frame(spec, "frame"));
    check_clash(model.frames_.back(), "frame");
  }
  for (int l = 0; l < model.num_links(); ++l) {
    model.link_frames_.push_back(Frame{model.links_[l].name, l, I});
  }
}

// 10. Defaults for sessions: the home configuration (within the limits) and controller gains.
void RobotModelBuilder::SetDefaults(RobotModel* out) const {
  const std::string& src = source_;
  RobotModel& model = *out;
  if (home_) {
    TROCAR_THROW_UNLESS(static_cast<int>(home_->size()) == model.num_positions(),
                        src << ": home: " << home_->size() << " values, expected "
                            << model.num_positions() << " (one per active joint)");
    model.defaults_.home = Eigen::Map<const Eigen::VectorXd>(home_->data(), model.num_positions());
    for (int i = 0; i < model.num_positions(); ++i) {
      const Joint& joint = model.joints_[model.active_joints_[i]];
      TROCAR_THROW_UNLESS(model.defaults_.home[i] >= joint.limits.lower && model.defaults_.home[i] <= joint.limits.upper,
                          src << ": home: joint '" << joint.name << "' value " << model.defaults_.home[i]
                              << " is outside its limits [" << joint.limits.lower << ", "
                              << joint.limits.upper << "]");
    }
  }
  model.defaults_.controller = controller_;
  model.defaults_.appearances = appearances_;
  auto check_gains = [&](const Eigen::VectorXd& gains, const std::string& field) {
    TROCAR_THROW_UNLESS(gains.size() == 6, src << ": " << field
                                               << ": expected 6 values [wx wy wz vx vy vz], got "
                                               << gains.size());
    TROCAR_THROW_UNLESS(gains.allFinite() && (gains.array() >= 0).all(),
                        src << ": " << field << ": " << FormatVector(gains)
                            << " must be finite and non-negative");
  };
  if (model.defaults_.controller.task_gains.size() != 0) {
    check_gains(model.defaults_.controller.task_gains, "controller.task_gains");
  }
  for (const auto& [name, gains] : model.defaults_.controller.gains) {
    check_gains(gains, "controller.gains." + name);
  }
}

RobotModel RobotModelBuilder::Build() const {
  RobotModel model;
  model.name_ = name_;
  model.source_ = source_;
  const TreeOrder order = ValidateTree();
  const NameIndex names = AddLinksAndJoints(order, &model);
  AssignDrives(order, names, &model);
  BuildClosures(names, &model);
  AssignActiveJoints(names, &model);
  OrderResolution(&model);
  AddKinematicFrames(&model);
  AddMovablePaths(&model);
  AddNamedFrames(names, &model);
  SetDefaults(&model);
  return model;
}

}  // namespace trocar::robot
