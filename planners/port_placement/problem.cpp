#include "port_placement/problem.hpp"

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <sstream>
#include <utility>

#include "collision/collision_world.hpp"
#include "collision/triangle_bvh.hpp"
#include "common/error.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "kinematics/jacobian.hpp"
#include "patient/patient_model.hpp"
#include "port_placement/port_rules.hpp"
#include "port_placement/score_terms.hpp"

namespace trocar::planners {

namespace {

constexpr double kCharacteristicLength =
    0.1;  // m: weighs translation against rotation in the Jacobian
constexpr double kNominalDepth =
    0.03;  // m: instrument tips this far past their ports at the nominal pose
constexpr double kDeg = M_PI / 180.0;

Eigen::Vector3d Centroid(const std::vector<Eigen::Vector3d>& points) {
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  for (const auto& p : points) c += p;
  return points.empty() ? c : Eigen::Vector3d(c / static_cast<double>(points.size()));
}

struct IkOutcome {
  bool converged = false;
  double error = 0.0;      // m, tip to aim
  double rcm_error = 0.0;  // m, port to shaft (software RCM)
};

// Position inverse kinematics of an arm's tool toward p_aim_W by damped least squares on the arm's
// joints, clamped to their limits; for an arm without a mechanical RCM, its shaft is also kept
// through `port_W` (two rows across the shaft). Writes q and poses into `state`.
IkOutcome SolveReach(const robot::RobotModel& robot, const PlanArm& arm,
                     const Eigen::Vector3d& p_aim_W, const Eigen::Vector3d& port_W, int iterations,
                     double tolerance, robot::RobotState* state) {
  const robot::Frame& tool = robot.GetFrame(arm.tool_frame);
  const int m = static_cast<int>(arm.q_indices.size());
  const bool software_rcm = !arm.has_rcm();
  const int rows = software_rcm ? 5 : 3;
  kinematics::Matrix6Xd J_tool, J_a, J_b;
  Eigen::MatrixXd J(rows, m);
  Eigen::VectorXd e(rows);
  IkOutcome out;
  const Eigen::VectorXd lower = robot.lower_limits(), upper = robot.upper_limits();
  double damping = 1e-3;
  double previous = std::numeric_limits<double>::infinity();
  // Each step poses only the tool's chain (the Jacobians read the joints on it); the whole robot
  // is posed once at the end, for the collision checks that follow.
  bool configured = false;
  Eigen::VectorXd posed_q;  // the last configuration whose closures were solved
  for (int it = 0; it <= iterations; ++it) {
    configured = kinematics::SetConfiguration(robot, state->q, state).ok();
    if (!configured) break;
    posed_q = state->q;
    kinematics::ForwardKinematicsToLink(robot, tool.link, state);
    const Eigen::Vector3d p = kinematics::FramePose(*state, tool).translation();
    e.head<3>() = p_aim_W - p;
    kinematics::ComputeFrameJacobian(robot, *state, tool, &J_tool);
    for (int c = 0; c < m; ++c) J.block<3, 1>(0, c) = J_tool.block<3, 1>(3, arm.q_indices[c]);
    out.error = e.head<3>().norm();
    out.rcm_error = 0.0;
    if (software_rcm) {
      const Eigen::Vector3d A = state->X_WL[arm.shaft_link] * arm.p_L_shaft_a;
      const Eigen::Vector3d B = state->X_WL[arm.shaft_link] * arm.p_L_shaft_b;
      const Eigen::Vector3d AB = B - A;
      const double lambda = (port_W - A).dot(AB) / AB.squaredNorm();
      const Eigen::Vector3d u = AB.normalized();
      Eigen::Vector3d n1 = u.cross(Eigen::Vector3d::UnitX());
      if (n1.norm() < 0.1) n1 = u.cross(Eigen::Vector3d::UnitY());
      n1.normalize();
      const Eigen::Vector3d n2 = u.cross(n1);
      const Eigen::Vector3d P = A + lambda * AB;
      e[3] = n1.dot(port_W - P);
      e[4] = n2.dot(port_W - P);
      out.rcm_error = e.tail<2>().norm();
      kinematics::ComputeJacobian(robot, *state, arm.shaft_link, arm.p_L_shaft_a, &J_a);
      kinematics::ComputeJacobian(robot, *state, arm.shaft_link, arm.p_L_shaft_b, &J_b);
      for (int c = 0; c < m; ++c) {
        const Eigen::Vector3d v = (1.0 - lambda) * J_a.block<3, 1>(3, arm.q_indices[c]) +
                                  lambda * J_b.block<3, 1>(3, arm.q_indices[c]);
        J(3, c) = n1.dot(v);
        J(4, c) = n2.dot(v);
      }
    }
    if (out.error <= tolerance && out.rcm_error <= tolerance) {
      out.converged = true;
      break;
    }
    if (it == iterations) break;
    const double norm = e.norm();
    damping = norm < previous ? std::max(damping * 0.5, 1e-4) : std::min(damping * 4.0, 1.0);
    previous = norm;
    Eigen::MatrixXd JJt = J * J.transpose();
    JJt.diagonal().array() += damping * damping;
    Eigen::VectorXd dq = J.transpose() * JJt.ldlt().solve(e);
    const double largest = dq.cwiseAbs().maxCoeff();
    if (largest > 0.2) dq *= 0.2 / largest;
    for (int c = 0; c < m; ++c) {
      const int i = arm.q_indices[c];
      state->q[i] = std::clamp(state->q[i] + dq[c], lower[i], upper[i]);
    }
  }
  if (configured) {
    kinematics::ForwardKinematics(robot, state);
  } else if (posed_q.size() > 0) {
    // A step left the closures unsolvable: back to the last posed configuration, whole.
    state->q = posed_q;
    kinematics::ForwardKinematics(robot, state->q, state);
  }
  return out;
}

// The arm's joint that turns the tool about the shaft (a scope's roll), from the tool Jacobian J
// (world frame) and the shaft's direction; -1 when it has none.
int RollJoint(const PlanArm& arm, const kinematics::Matrix6Xd& J, const Eigen::Vector3d& shaft) {
  int roll = -1;
  for (int i : arm.q_indices) {
    const Eigen::Vector3d w = J.col(i).head<3>();
    if (i != arm.insertion_q && w.norm() > 0.5 && std::abs(w.normalized().dot(shaft)) > 0.99)
      roll = i;
  }
  return roll;
}

// A joint's range, a full turn where it has no limit.
std::pair<double, double> JointRange(const robot::RobotModel& robot, int i) {
  return {std::isfinite(robot.lower_limits()[i]) ? robot.lower_limits()[i] : -M_PI,
          std::isfinite(robot.upper_limits()[i]) ? robot.upper_limits()[i] : M_PI};
}

// A direction in the patient's frame (LPS: +x left, +y back, +z head) in anatomical words: its
// largest component, and the next one when it is at least half as large ("toward the feet and the
// front").
std::string AnatomicalDirection(const Eigen::Vector3d& v_P) {
  static const char* const kWords[3][2] = {{"the patient's right", "the patient's left"},
                                           {"the front", "the back"},
                                           {"the feet", "the head"}};
  int order[3] = {0, 1, 2};
  std::sort(order, order + 3, [&](int i, int j) { return std::abs(v_P[i]) > std::abs(v_P[j]); });
  std::string words = std::string("toward ") + kWords[order[0]][v_P[order[0]] > 0.0];
  if (std::abs(v_P[order[1]]) >= 0.5 * std::abs(v_P[order[0]]))
    words += std::string(" and ") + kWords[order[1]][v_P[order[1]] > 0.0];
  return words;
}

}  // namespace

std::string JointLimitWords(const robot::RobotModel& robot, const PlanArm& arm,
                            const robot::RobotState& state, const Eigen::Vector3d& p_aim_W,
                            const Eigen::Isometry3d& X_WP, double error) {
  // Which joint at a limit stops the tip: the one whose motion past its limit would carry the tip
  // most directly toward the point (the tool Jacobian's column, signed by the limit).
  kinematics::Matrix6Xd J_WT;
  kinematics::ComputeFrameJacobian(robot, state, robot.GetFrame(arm.tool_frame), &J_WT);
  const robot::Frame& tool = robot.GetFrame(arm.tool_frame);
  const Eigen::Vector3d p_WT = (state.X_WL[tool.link] * tool.X_LF).translation();
  const Eigen::Vector3d toward = (p_aim_W - p_WT).normalized();
  int best = -1, best_column = -1;
  double best_gain = -std::numeric_limits<double>::infinity();
  Eigen::Vector3d best_v = Eigen::Vector3d::Zero();
  for (std::size_t c = 0; c < arm.q_indices.size(); ++c) {
    const int i = arm.q_indices[c];
    const auto& joint = robot.joint(robot.active_joints()[i]);
    if (!std::isfinite(joint.limits.upper - joint.limits.lower)) continue;
    const bool at_lower = state.q[i] <= joint.limits.lower + 1e-6;
    const bool at_upper = state.q[i] >= joint.limits.upper - 1e-6;
    if (!at_lower && !at_upper) continue;
    const Eigen::Vector3d v = (at_upper ? 1.0 : -1.0) * J_WT.block<3, 1>(3, i);
    const double gain = v.norm() > 1e-9 ? v.normalized().dot(toward) : -1.0;
    if (gain > best_gain) {
      best_gain = gain;
      best = i;
      best_column = static_cast<int>(c);
      best_v = v;
    }
  }
  if (best < 0) return "";
  const auto& joint = robot.joint(robot.active_joints()[best]);
  const bool upper = state.q[best] >= joint.limits.upper - 1e-6;
  // Where the joint sits on the arm: the insertion, the instrument below it (roll, wrist), or the
  // arm above it, which swings the shaft about the port (an RCM arm) or moves the arm (a
  // software-RCM arm).
  int insertion_column = -1;
  for (std::size_t c = 0; c < arm.q_indices.size(); ++c)
    if (arm.q_indices[c] == arm.insertion_q) insertion_column = static_cast<int>(c);
  const std::string where =
      best_v.norm() > 1e-9 ? " " + AnatomicalDirection(X_WP.linear().transpose() * best_v) : "";
  std::ostringstream why;
  if (best == arm.insertion_q) {
    why << arm.name << (arm.role == ArmRole::kEndoscope ? "'s scope is " : "'s instrument is ")
        << (upper ? "inserted as far as it goes" : "withdrawn as far as it goes");
  } else if (insertion_column >= 0 && best_column > insertion_column) {
    why << arm.name << "'s wrist cannot turn the tip further" << where;
  } else if (arm.has_rcm()) {
    why << arm.name << (arm.role == ArmRole::kEndoscope ? "'s scope" : "'s instrument")
        << " cannot swing further" << where << " about its port";
  } else {
    why << arm.name << " cannot move its instrument further" << where;
  }
  why << " (joint limit '" << joint.name << "' (" << (upper ? "upper" : "lower") << ")); the point lies "
      << std::lround(error * 1e3) << " mm beyond";
  return why.str();
}

namespace {

// Why an arm does not reach a point: the insertion limit, a joint at its limit, or no solution.
std::string ReachFailure(const robot::RobotModel& robot, const PlanArm& arm,
                         const robot::RobotState& state, const Eigen::Vector3d& p_aim_W,
                         const Eigen::Vector3d& port_W, double max_reach, const IkOutcome& ik,
                         const Eigen::Isometry3d& X_WP) {
  std::ostringstream why;
  const double distance = (p_aim_W - port_W).norm();
  if (arm.insertion_q >= 0 && distance > max_reach) {
    const auto& joint = robot.joint(robot.active_joints()[arm.insertion_q]);
    why << "insertion limit (" << std::lround(joint.limits.upper * 1e3)
        << " mm) exceeded: the point is " << std::lround(distance * 1e3)
        << " mm from the port, the tool reaches " << std::lround(max_reach * 1e3) << " mm";
    return why.str();
  }
  const std::string limit = JointLimitWords(robot, arm, state, p_aim_W, X_WP, ik.error);
  if (!limit.empty()) return limit;
  if (ik.rcm_error > 0.001) {
    why << "the shaft cannot pass through the port (" << std::lround(ik.rcm_error * 1e3)
        << " mm off)";
  } else {
    why << "no inverse-kinematics solution (" << std::lround(ik.error * 1e3) << " mm short)";
  }
  return why.str();
}

double InverseCondition(const Eigen::MatrixXd& J) {
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(J);
  const auto& s = svd.singularValues();
  if (s.size() == 0 || s[0] <= 0.0) return 0.0;
  return s[s.size() - 1] / s[0];
}

}  // namespace

double ScoreWeights::sum() const {
  double total = 0.0;
  for (const ScoreTermDefinition& term : ScoreTermDefinitions()) total += this->*term.weight;
  return total;
}

Eigen::Isometry3d Placement::X_WB() const {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = Eigen::AngleAxisd(cart_yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  X.translation() = Eigen::Vector3d(cart_x, cart_y, 0.0 - table_raise);  // +0 when not raised
  return X;
}

const ScoreTerm* Evaluation::Find(const std::string& name) const {
  for (const auto& t : terms) {
    if (t.name == name) return &t;
  }
  return nullptr;
}

Workspace::Workspace(const PortPlacementProblem& problem)
    : state(problem.robot()),
      checker(std::make_unique<collision::CollisionChecker>(problem.world())) {}
Workspace::Workspace(const PortPlacementProblem& problem,
                     std::shared_ptr<const collision::CollisionWorld> world)
    : state(problem.robot()), checker(std::make_unique<collision::CollisionChecker>(world)) {}
Workspace::~Workspace() = default;

PortPlacementProblem::~PortPlacementProblem() = default;

PortPlacementProblem::PortPlacementProblem(std::shared_ptr<const patient::PatientModel> patient,
                                           std::shared_ptr<const robot::RobotModel> robot,
                                           const ProblemOptions& options)
    : patient_(std::move(patient)), robot_(std::move(robot)), options_(options) {
  const patient::PatientModel& p = *patient_;
  TROCAR_THROW_UNLESS(!p.targets.empty(),
                      "patient '" << p.name << "' (" << p.case_dir
                                  << "/patient.yaml): no targets to plan for (add `targets:`)");
  for (const auto& t : p.targets) {
    TROCAR_THROW_UNLESS(!t.points.empty(),
                        "patient '" << p.name << "': target '" << t.name << "' has no points");
  }
  std::size_t usable = 0;
  for (const auto& c : p.port_candidates) usable += c.skin.size() >= 2 ? 1 : 0;
  TROCAR_THROW_UNLESS(usable > 0, "patient '"
                                      << p.name << "' (" << p.case_dir
                                      << "/patient.yaml): no port candidate curves (annotate "
                                         "`port_candidates:` or let `intercostal:` find them)");
  TROCAR_THROW_UNLESS(options.samples_per_target >= 1,
                      "samples per target: " << options.samples_per_target << ", expected >= 1");
  TROCAR_THROW_UNLESS(options.weights.sum() > 0.0, "score weights: their sum must be positive");
  for (const ScoreTermDefinition& term : ScoreTermDefinitions()) {
    const double w = options.weights.*term.weight;
    TROCAR_THROW_UNLESS(std::isfinite(w) && w >= 0.0,
                        "score weights: " << w << " is not a finite weight >= 0");
  }
  TROCAR_THROW_UNLESS(
      options.cart_distance_min > 0 && options.cart_distance_max > options.cart_distance_min,
      "cart distance range [" << options.cart_distance_min << ", " << options.cart_distance_max
                              << "] m is empty");
  TROCAR_THROW_UNLESS(
      (std::isnan(options.table_height_min) && std::isnan(options.table_height_max)) ||
          (options.table_height_min >= 0.3 && options.table_height_max <= 1.5 &&
           options.table_height_min <= options.table_height_max),
      "table height range [" << options.table_height_min << ", " << options.table_height_max
                             << "] m: expected 0.3 <= min <= max <= 1.5 m");
  arms_ = FindArms(*robot_, options.roles);
  if (!options.arms.empty()) arms_ = SelectArms(arms_, options.arms);

  // Target samples, evenly by arc length.
  for (int t = 0; t < static_cast<int>(p.targets.size()); ++t) {
    const auto& target = p.targets[t];
    const int n = static_cast<int>(target.points.size());
    std::vector<double> arc(n, 0.0);
    for (int i = 1; i < n; ++i)
      arc[i] = arc[i - 1] + (target.points[i] - target.points[i - 1]).norm();
    const int k = std::min(n, options.samples_per_target);
    std::vector<int> picked;
    for (int s = 0; s < k; ++s) {
      const double want = k == 1 ? 0.5 * arc.back() : arc.back() * s / (k - 1);
      int best = 0;
      for (int i = 1; i < n; ++i) {
        if (std::abs(arc[i] - want) < std::abs(arc[best] - want)) best = i;
      }
      if (std::find(picked.begin(), picked.end(), best) == picked.end()) picked.push_back(best);
    }
    for (int i : picked) {
      TargetSample sample;
      sample.target = t;
      sample.point = i;
      sample.arc_length = arc[i];
      sample.p_W = p.X_WP * target.points[i];
      const Eigen::Vector3d n_P = i < static_cast<int>(target.normals.size())
                                      ? target.normals[i]
                                      : Eigen::Vector3d::UnitY() * -1.0;
      sample.n_W = (p.X_WP.linear() * n_P).normalized();
      samples_.push_back(sample);
    }
  }
  std::vector<Eigen::Vector3d> points;
  for (const auto& s : samples_) points.push_back(s.p_W);
  aim_W_ = Centroid(points);

  // Candidate curves: cumulative arc lengths; their centre anchors the cart's bounds.
  points.clear();
  for (const auto& c : p.port_candidates) {
    std::vector<double> arc(c.skin.size(), 0.0);
    for (std::size_t i = 1; i < c.skin.size(); ++i)
      arc[i] = arc[i - 1] + (c.skin[i] - c.skin[i - 1]).norm();
    candidate_arc_.push_back(arc);
    for (const auto& q : c.skin) points.push_back(p.X_WP * q);
  }
  centre_W_ = Centroid(points);

  for (const auto& arm : arms_) {
    if (!arm.has_rcm()) world_options_.shaft_ports.push_back(robot_->link(arm.shaft_link).name);
  }
  world_ = collision::CollisionWorld::Build(patient_.get(), robot_, world_options_);
  {
    // RCM ports by frame; shaft ports follow them in arm order.
    const auto& ports = world_->ports();
    int shaft = 0;
    for (const auto& port : ports) shaft += port.frame.empty() ? 0 : 1;
    for (const auto& arm : arms_) {
      int index = -1;
      if (arm.has_rcm()) {
        for (std::size_t p = 0; p < ports.size(); ++p) {
          if (ports[p].frame == arm.rcm_frame) index = static_cast<int>(p);
        }
      } else {
        index = shaft++;
      }
      world_port_.push_back(index);
      world_arm_.push_back(index >= 0 ? ports[index].arm : -1);
    }
  }
  std::vector<patient::Structure const*> ribs;
  for (const auto& s : p.structures) {
    if (s.name.rfind("rib", 0) == 0 && !s.mesh.triangles.empty()) ribs.push_back(&s);
  }
  if (!ribs.empty()) {
    TriangleMesh merged;
    for (const auto* s : ribs) {
      const int offset = static_cast<int>(merged.vertices.size());
      merged.vertices.insert(merged.vertices.end(), s->mesh.vertices.begin(),
                             s->mesh.vertices.end());
      for (auto t : s->mesh.triangles)
        merged.triangles.push_back(t + Eigen::Vector3i::Constant(offset));
    }
    ribs_ = std::make_unique<collision::TriangleBvh>(merged);
  }
  if (const patient::Structure* skin = p.Find("skin"); skin && !skin->mesh.triangles.empty())
    skin_ = std::make_unique<collision::TriangleBvh>(skin->mesh);
  FindPivots();

  // Longest reach of each arm's tool from its RCM, insertion at the upper limit.
  for (const auto& arm : arms_) {
    double reach = std::numeric_limits<double>::infinity();
    if (arm.has_rcm() && arm.insertion_q >= 0) {
      robot::RobotState s(*robot_);
      s.q = robot_->defaults().HomeOr(robot_->neutral_configuration());
      s.q[arm.insertion_q] = robot_->joint(robot_->active_joints()[arm.insertion_q]).limits.upper;
      if (kinematics::ForwardKinematics(*robot_, s.q, &s).ok()) {
        reach = (kinematics::FramePose(s, robot_->GetFrame(arm.tool_frame)).translation() -
                 kinematics::FramePose(s, robot_->GetFrame(arm.rcm_frame)).translation())
                    .norm();
      }
    }
    max_reach_.push_back(reach);
  }
}

double PortPlacementProblem::MaxReach(int arm) const { return max_reach_.at(arm); }

std::vector<std::string> PortPlacementProblem::MovingStructures() const {
  // An organ carries a target when the target's points lie on it (patient::TargetLiesOn); the
  // chest wall, skin and bones never move with the targets (patient::IsMobileStructure).
  std::vector<std::string> names;
  for (const auto& s : patient_->structures) {
    if (!patient::IsMobileStructure(s.name) || s.mesh.triangles.empty()) continue;
    for (int t = 0; t < static_cast<int>(patient_->targets.size()); ++t) {
      if (patient::TargetLiesOn(*patient_, t, s.name)) {
        names.push_back(s.name);
        break;
      }
    }
  }
  return names;
}

std::vector<bool> PortPlacementProblem::MovingTargets() const {
  std::vector<bool> moving(patient_->targets.size(), false);
  for (const std::string& name : MovingStructures()) {
    for (int t = 0; t < static_cast<int>(moving.size()); ++t)
      moving[t] = moving[t] || patient::TargetLiesOn(*patient_, t, name);
  }
  return moving;
}

std::shared_ptr<const collision::CollisionWorld> PortPlacementProblem::WorldWithTargetsMoved(
    const Eigen::Vector3d& d_P) const {
  const std::vector<std::string> moving = MovingStructures();
  if (moving.empty()) return world_;
  // The organs' bodies moved in place: their hierarchies are shared, not rebuilt (building the
  // whole world per shift was 8 % of a plan's time on the bundled default, stop 61).
  return world_->WithBodiesMoved(moving, patient_->X_WP.linear() * d_P);
}

std::string PortPlacementProblem::SolveReach(int a, const Placement& placement,
                                             const TargetSample& sample,
                                             robot::RobotState* state) const {
  TROCAR_THROW_UNLESS(a >= 0 && a < static_cast<int>(arms_.size()) &&
                          placement.sites.size() == arms_.size(),
                      "SolveReach: arm " << a << " of " << arms_.size());
  const PlanArm& arm = arms_[a];
  const Eigen::Vector3d port = placement.sites[a].p_rcm_W;
  const Eigen::Vector3d p_aim = sample.p_W + options_.standoff * sample.n_W;
  const IkOutcome ik = planners::SolveReach(*robot_, arm, p_aim, port, options_.ik_iterations,
                                            options_.ik_tolerance, state);
  if (ik.converged) return "";
  return ReachFailure(*robot_, arm, *state, p_aim, port, max_reach_[a], ik, patient_->X_WP);
}

bool PortPlacementProblem::LookAt(int a, const Placement& placement, const Evaluation::View& view,
                                  const Eigen::Vector3d& p_W, robot::RobotState* state,
                                  collision::CollisionChecker* checker, std::string* why) const {
  const robot::RobotModel& robot = *robot_;
  const PlanArm& arm = arms_[a];
  const robot::Frame& camera = robot.GetFrame(view.frame);
  const robot::Frame& tool = robot.GetFrame(arm.tool_frame);
  const Eigen::Vector3d port = placement.sites[a].p_rcm_W;
  // The camera's view axis makes a fixed angle beta with the shaft (0 for a straight scope, 30
  // degrees for an angled one); measured on the given pose.
  const Eigen::Isometry3d X_WT0 = kinematics::FramePose(*state, tool);
  const Eigen::Vector3d w0 = (X_WT0.translation() - port).normalized();
  const Eigen::Vector3d v0 = kinematics::FramePose(*state, camera).linear() * view.axis_F;
  const double beta = std::acos(std::clamp(v0.dot(w0), -1.0, 1.0));
  const Eigen::Vector3d to_point = p_W - port;
  const double D = to_point.norm();
  // The triangle port - tip - point: the tip L along the shaft, the point d along the view axis,
  // the angle at the tip 180 deg - beta; the shaft turned from the line to the point by alpha,
  // toward the docking pose's shaft (the least move).
  auto tip_depth = [&](double d) {
    const double s = d * std::sin(beta);
    return -d * std::cos(beta) + std::sqrt(std::max(0.0, D * D - s * s));
  };
  // From the working distance; a point nearer the port than that is looked at from nearer, down
  // to the scope's shortest viewing distance, the scope's tip at least 1 cm past its pivot (in
  // the chest, not in the wall). tip_depth falls as d grows: the largest d that leaves 1 cm.
  constexpr double kMinTipDepth = 0.01;
  double d = std::clamp(options_.scope_working_distance, options_.scope_min_distance,
                        options_.scope_max_distance);
  if (tip_depth(d) < kMinTipDepth) {
    if (tip_depth(options_.scope_min_distance) < kMinTipDepth) {
      std::ostringstream m;
      m << "it lies " << std::lround(D * 1e3)
        << " mm from the port, nearer than the scope's shortest viewing distance ("
        << std::lround(options_.scope_min_distance * 1e3) << " mm) allows";
      *why = m.str();
      return false;
    }
    double lo = options_.scope_min_distance, hi = d;
    for (int k = 0; k < 40; ++k) {
      const double mid = 0.5 * (lo + hi);
      (tip_depth(mid) >= kMinTipDepth ? lo : hi) = mid;
    }
    d = lo;
  }
  const double L = tip_depth(d);
  const double alpha = std::asin(std::clamp(d * std::sin(beta) / D, -1.0, 1.0));
  const Eigen::Vector3d u = to_point / D;
  Eigen::Vector3d axis = u.cross(w0);
  if (axis.norm() < 1e-9) axis = u.unitOrthogonal();
  const Eigen::Vector3d w = Eigen::AngleAxisd(alpha, axis.normalized()) * u;
  const IkOutcome ik = planners::SolveReach(robot, arm, port + L * w, port, options_.ik_iterations,
                                            options_.ik_tolerance, state);
  if (!ik.converged) {
    *why = ReachFailure(robot, arm, *state, port + L * w, port, max_reach_[a], ik, patient_->X_WP);
    return false;
  }
  // The roll about the shaft that turns the view axis nearest the point (an angled scope).
  auto off_axis = [&](const robot::RobotState& st) {
    const Eigen::Isometry3d X_WC = kinematics::FramePose(st, camera);
    return std::acos(std::clamp(
        (X_WC.linear() * view.axis_F).dot((p_W - X_WC.translation()).normalized()), -1.0, 1.0));
  };
  kinematics::Matrix6Xd J;
  kinematics::ComputeFrameJacobian(robot, *state, tool, &J);
  const Eigen::Vector3d shaft = (kinematics::FramePose(*state, tool).translation() - port).normalized();
  const int roll = RollJoint(arm, J, shaft);
  if (roll >= 0 && beta > 1e-3) {
    const auto [lo, hi] = JointRange(robot, roll);
    robot::RobotState trial = *state;
    double best = off_axis(*state), best_q = state->q[roll];
    for (int k = 0; k <= 24; ++k) {
      trial.q[roll] = lo + (hi - lo) * k / 24.0;
      if (!kinematics::ForwardKinematics(robot, trial.q, &trial).ok()) continue;
      const double off = off_axis(trial);
      if (off < best) {
        best = off;
        best_q = trial.q[roll];
      }
    }
    state->q[roll] = best_q;
    kinematics::ForwardKinematics(robot, state->q, state);
  }
  const Eigen::Isometry3d X_WC = kinematics::FramePose(*state, camera);
  const double dist = (p_W - X_WC.translation()).norm();
  const double angle = off_axis(*state);
  if (angle > options_.scope_half_fov || dist < options_.scope_min_distance ||
      dist > options_.scope_max_distance) {
    std::ostringstream m;
    m << "its view axis comes no nearer than " << std::lround(angle / kDeg) << " deg at "
      << std::lround(dist * 1e3) << " mm";
    *why = m.str();
    return false;
  }
  const int hidden = checker->world().FirstAcross(X_WC.translation(), p_W, kSightMargin).body;
  if (hidden >= 0) {
    *why = "hidden behind the " + checker->world().bodies()[hidden].name;
    return false;
  }
  checker->SetRobotState(*state);
  SetPorts(placement, *state, checker);
  const int only_arm = world_arm_[a];
  if (checker->InCollision(collision::kAllMovingPairs, only_arm)) {
    const auto report = checker->Check(collision::kAllMovingPairs, only_arm);
    *why = "collision: " + checker->world().DescribePair(report.contacts.front().a,
                                                         report.contacts.front().b);
    return false;
  }
  return true;
}

namespace {
// The arm's joints below its insertion joint (an instrument's roll and wrist), in q order.
std::vector<int> DistalJoints(const PlanArm& arm) {
  std::vector<int> distal;
  bool below = false;
  for (int i : arm.q_indices) {
    if (below) distal.push_back(i);
    below = below || i == arm.insertion_q;
  }
  return distal;
}
}  // namespace

int PortPlacementProblem::ReachRestarts(int a) const {
  return DistalJoints(arms_.at(a)).empty() ? 0 : options_.reach_restarts;
}

bool PortPlacementProblem::ReachSeed(int a, int attempt, robot::RobotState* state) const {
  if (attempt == 0) return true;
  if (attempt < 0 || attempt > ReachRestarts(a)) return false;
  const std::vector<int> distal = DistalJoints(arms_.at(a));
  // Halton sequence, bases 2, 3, 5, 7, ... (one per joint): evenly spread, and the same every
  // time.
  static constexpr int kPrimes[] = {2, 3, 5, 7, 11, 13, 17, 19, 23, 29};
  for (std::size_t j = 0; j < distal.size(); ++j) {
    const int base = kPrimes[j % 10];
    double f = 1.0, h = 0.0;
    for (int k = attempt; k > 0; k /= base) {
      f /= base;
      h += f * (k % base);
    }
    const int i = distal[j];
    const double lo = std::isfinite(robot_->lower_limits()[i]) ? robot_->lower_limits()[i] : -M_PI;
    const double hi = std::isfinite(robot_->upper_limits()[i]) ? robot_->upper_limits()[i] : M_PI;
    state->q[i] = lo + h * (hi - lo);
  }
  return true;
}

void PortPlacementProblem::SetPorts(const Placement& placement, const robot::RobotState& state,
                                    collision::CollisionChecker* checker,
                                    const Eigen::Vector3d* work_W) const {
  checker->ClearWorkSites();
  const Eigen::Isometry3d X_PW = patient_->X_WP.inverse();
  for (std::size_t a = 0; a < arms_.size() && a < placement.sites.size(); ++a) {
    if (world_port_[a] < 0) continue;
    const PortSite& site = placement.sites[a];
    double allowance = site.skin_allowance;
    // The cannula's track as the instrument now points (port_rules.hpp, TrackAllowance).
    if (skin_ && arms_[a].role == ArmRole::kInstrument && !state.X_WL.empty()) {
      const Eigen::Vector3d tip_W =
          kinematics::FramePose(state, robot_->GetFrame(arms_[a].tool_frame)).translation();
      const Eigen::Vector3d pivot_P = X_PW * site.p_rcm_W;
      allowance = std::max(allowance,
                           TrackAllowance(*skin_, site.pivot_depth, pivot_P, site.p_P,
                                          X_PW * tip_W, world_->options().port_radius));
    }
    checker->SetPortPosition(world_port_[a], site.p_rcm_W, allowance);
    if (work_W && arms_[a].role == ArmRole::kInstrument)
      checker->SetWorkSite(world_port_[a], *work_W, kWorkSiteRadius);
  }
}

std::vector<double> PortPlacementProblem::lower_bounds() const {
  std::vector<double> lb;
  for (std::size_t i = 0; i < arms_.size(); ++i) lb.insert(lb.end(), {0.0, 0.0});
  lb.insert(lb.end(), {-M_PI, options_.cart_distance_min, -options_.cart_heading_offset_max,
                       options_.TableRaiseMin(patient_->table.height)});
  return lb;
}

std::vector<double> PortPlacementProblem::upper_bounds() const {
  std::vector<double> ub;
  const double n = static_cast<double>(patient_->port_candidates.size());
  for (std::size_t i = 0; i < arms_.size(); ++i) ub.insert(ub.end(), {n, 1.0});
  ub.insert(ub.end(), {M_PI, options_.cart_distance_max, options_.cart_heading_offset_max,
                       options_.TableRaiseMax(patient_->table.height)});
  return ub;
}

namespace {

// The middle of the intercostal gap under a skin point: going in along the skin's inward normal,
// at each depth the point of the plane across the normal farthest from the ribs (a local ascent of
// the distance to the rib meshes, which settles midway between the two neighbouring ribs); the
// pivot is where that clearance is smallest — the gap's waist, at the ribs' depth. False when no
// rib comes within `reach` of the line (no ribs there: the caller falls back).
bool GapUnder(const collision::TriangleBvh& ribs, const Eigen::Vector3d& skin_P,
              const Eigen::Vector3d& inward_P, double depth_max, Eigen::Vector3d* pivot_P) {
  constexpr double kReach = 0.025;  // m: ribs farther than this from the line do not count
  constexpr double kStep = 0.001;   // m: depth step
  constexpr double kLateral = 0.015;  // m: how far across the normal the centre may move
  double best = std::numeric_limits<double>::infinity();
  Eigen::Vector3d lateral = Eigen::Vector3d::Zero();  // carried from depth to depth
  for (double t = 0.0; t <= depth_max + 1e-12; t += kStep) {
    const Eigen::Vector3d q0 = skin_P + t * inward_P;
    Eigen::Vector3d q = q0 + lateral;
    double step = 0.002, clearance = kReach;
    Eigen::Vector3d previous = Eigen::Vector3d::Zero();
    for (int k = 0; k < 24; ++k) {
      const auto c = ribs.Closest(q, q, kReach);
      if (!c.found()) {
        clearance = kReach;
        break;
      }
      clearance = c.distance;
      Eigen::Vector3d away = q - c.p_M_mesh;
      away -= away.dot(inward_P) * inward_P;
      if (away.norm() < 1e-9) break;
      away.normalize();
      if (away.dot(previous) < 0.0) step *= 0.5;
      if (step < 5e-5) break;
      previous = away;
      Eigen::Vector3d next = q + step * away;
      Eigen::Vector3d off = next - q0;
      if (off.norm() > kLateral) next = q0 + off * (kLateral / off.norm());
      q = next;
    }
    lateral = q - q0;
    if (clearance < best) {
      best = clearance;
      *pivot_P = q;
    }
  }
  return best < kReach;
}

// Where the ray from `from_P` along `out_P` first leaves the skin (bisection on the segment's
// contact with the skin mesh), within `length`; false when it does not.
bool SkinCrossing(const collision::TriangleBvh& skin, const Eigen::Vector3d& from_P,
                  const Eigen::Vector3d& out_P, double length, Eigen::Vector3d* crossing_P) {
  auto touches = [&](double t) { return skin.Closest(from_P, from_P + t * out_P, 1e-9).found(); };
  if (!touches(length)) return false;
  double lo = 0.0, hi = length;
  for (int i = 0; i < 30; ++i) {
    const double mid = 0.5 * (lo + hi);
    (touches(mid) ? hi : lo) = mid;
  }
  *crossing_P = from_P + hi * out_P;
  return true;
}

}  // namespace

void PortPlacementProblem::FindPivots() {
  const patient::PatientModel& p = *patient_;
  const Eigen::Isometry3d X_PW = p.X_WP.inverse();
  const Eigen::Vector3d aim_P = X_PW * aim_W_;
  const patient::Structure* skin = p.Find("skin");
  for (const auto& c : p.port_candidates) {
    std::vector<Eigen::Vector3d> pivots;
    std::vector<char> in_gap;
    for (const Eigen::Vector3d& point : c.skin) {
      Eigen::Vector3d pivot = point;
      bool gap = false;
      if (ribs_ && skin && !skin->mesh.vertices.empty()) {
        Eigen::Vector3d inward = -patient::NearestSurfaceNormal(skin->mesh, point);
        // A normal pointing away from the targets is the mesh's winding, not the body.
        if (inward.dot(aim_P - point) < 0.0) inward = -inward;
        gap = GapUnder(*ribs_, point, inward, options_.gap_search_depth, &pivot);
      }
      if (!gap) {
        const Eigen::Vector3d toward = aim_P - point;
        pivot = point + (toward.norm() > 1e-9 ? Eigen::Vector3d(options_.rcm_depth *
                                                                toward.normalized())
                                              : Eigen::Vector3d::Zero());
      }
      pivots.push_back(pivot);
      in_gap.push_back(gap ? 1 : 0);
    }
    candidate_pivot_.push_back(std::move(pivots));
    candidate_in_gap_.push_back(std::move(in_gap));
  }
}

PortSite PortPlacementProblem::Site(int candidate, double s) const {
  const auto& curve = patient_->port_candidates.at(candidate).skin;
  const auto& arc = candidate_arc_.at(candidate);
  const auto& pivot = candidate_pivot_.at(candidate);
  const auto& in_gap = candidate_in_gap_.at(candidate);
  PortSite site;
  site.candidate = candidate;
  site.s = std::clamp(s, 0.0, 1.0);
  std::size_t i = 0;
  double f = 0.0;
  if (curve.size() > 1 && arc.back() > 0.0) {
    const double want = site.s * arc.back();
    i = 1;
    while (i + 1 < arc.size() && arc[i] < want) ++i;
    const double span = arc[i] - arc[i - 1];
    f = span > 0 ? std::clamp((want - arc[i - 1]) / span, 0.0, 1.0) : 0.0;
    --i;
  }
  const std::size_t j = std::min(i + 1, curve.size() - 1);
  site.p_curve_P = (1 - f) * curve[i] + f * curve[j];
  const Eigen::Vector3d pivot_P = (1 - f) * pivot[i] + f * pivot[j];
  site.p_rcm_W = patient_->X_WP * pivot_P;
  site.in_gap = in_gap[i] && in_gap[j];
  // The incision: where the line from the targets' centroid through the pivot leaves the skin,
  // unless that is far from the site (an aim nearly along the chest wall): then the skin point
  // nearest the curve point.
  site.p_P = site.p_curve_P;
  if (skin_) {
    const auto nearest = skin_->Closest(site.p_curve_P, site.p_curve_P);
    if (nearest.found()) site.p_P = nearest.p_M_mesh;
    const Eigen::Vector3d out = pivot_P - patient_->X_WP.inverse() * aim_W_;
    Eigen::Vector3d crossing;
    if (site.in_gap && out.norm() > 1e-9 &&
        SkinCrossing(*skin_, pivot_P, out.normalized(), 0.1, &crossing) &&
        (crossing - site.p_curve_P).norm() <= kMaxIncisionOffset) {
      site.p_P = crossing;
    }
  }
  site.p_W = patient_->X_WP * site.p_P;
  if (skin_) {
    const Eigen::Vector3d pivot_P = patient_->X_WP.inverse() * site.p_rcm_W;
    const auto c = skin_->Closest(pivot_P, pivot_P);
    site.pivot_depth = c.found() ? c.distance : 0.0;
  }
  site.skin_allowance = PortTrackLength(site.pivot_depth, patient_->X_WP.inverse() * site.p_rcm_W,
                                        site.p_P) +
                        world_->options().port_radius;
  return site;
}

Placement PortPlacementProblem::Decode(const std::vector<double>& x) const {
  TROCAR_THROW_UNLESS(static_cast<int>(x.size()) == dimension(),
                      "decision vector: " << x.size() << " values, expected " << dimension());
  Placement placement;
  const int n = static_cast<int>(patient_->port_candidates.size());
  for (std::size_t a = 0; a < arms_.size(); ++a) {
    int c = std::clamp(static_cast<int>(std::floor(x[2 * a])), 0, n - 1);
    // Candidates with fewer than two points are skipped over to the next usable one.
    for (int k = 0; k < n && patient_->port_candidates[c].skin.size() < 2; ++k) c = (c + 1) % n;
    placement.sites.push_back(Site(c, x[2 * a + 1]));
  }
  const int k = 2 * static_cast<int>(arms_.size());
  const double from = x[k], distance = x[k + 1], offset = x[k + 2];
  placement.cart_x = centre_W_.x() + distance * std::cos(from);
  placement.cart_y = centre_W_.y() + distance * std::sin(from);
  // Facing the centre (from + pi), turned by the offset.
  placement.cart_yaw = std::remainder(from + M_PI + offset, 2 * M_PI);
  placement.table_raise = x[k + 3];
  return placement;
}

std::vector<double> PortPlacementProblem::Encode(const Placement& placement) const {
  std::vector<double> x;
  for (const auto& site : placement.sites) x.insert(x.end(), {site.candidate + 0.5, site.s});
  const double dx = placement.cart_x - centre_W_.x(), dy = placement.cart_y - centre_W_.y();
  const double from = std::atan2(dy, dx);
  x.push_back(from);
  x.push_back(
      std::clamp(std::hypot(dx, dy), options_.cart_distance_min, options_.cart_distance_max));
  x.push_back(std::clamp(std::remainder(placement.cart_yaw - from - M_PI, 2 * M_PI),
                         -options_.cart_heading_offset_max, options_.cart_heading_offset_max));
  x.push_back(std::clamp(placement.table_raise, options_.TableRaiseMin(patient_->table.height),
                         options_.TableRaiseMax(patient_->table.height)));
  return x;
}

// What docking left for the rest of an evaluation: the nominal pose is in the workspace's state.
struct PortPlacementProblem::Docking {
  bool placed = false;                 // the setup joints put every RCM at its port
  collision::CollisionReport nominal;  // contacts at the nominal pose
  std::vector<bool> nominal_ok;        // per arm: its nominal pose was reached
};

PortPlacementProblem::Docking PortPlacementProblem::Dock(const Placement& placement,
                                                         const std::vector<TargetSample>& samples,
                                                         bool full_solver, Workspace* ws,
                                                         Evaluation* ev) const {
  const robot::RobotModel& robot = *robot_;
  robot::RobotState& state = ws->state;
  collision::CollisionChecker& checker = *ws->checker;
  Docking out;
  CartPlacementResult placed;
  collision::CollisionReport nominal;
  std::vector<bool> nominal_ok;
  robot::RobotState best_state = state;
  collision::CollisionReport best_nominal;
  std::vector<bool> best_ok;
  std::string best_message;
  bool have_best = false;
  // Collisions at the nominal pose are often the setup arms' choice among their redundant
  // solutions (an arm folded into the cart's column): a few seeded attempts.
  for (int attempt = 0; attempt < options_.placement_attempts; ++attempt) {
    // A pure function of the placement: every evaluation starts from the same state (attempt 0:
    // the setup joints at their neutral values; later attempts: seeded random values, so that the
    // setup-joint solver lands on another of its redundant solutions).
    state = robot::RobotState(robot);
    state.q = robot.defaults().HomeOr(robot.neutral_configuration());
    if (attempt > 0) {
      std::mt19937 rng(options_.seed * 31u + static_cast<unsigned>(attempt));
      for (int d = 0; d < robot.num_dofs(); ++d) {
        const robot::Joint& joint = robot.joint(robot.dof_joints()[d]);
        if (joint.drive != robot::JointDrive::kHeld) continue;
        const double lo = std::isfinite(joint.limits.lower) ? joint.limits.lower : -M_PI;
        const double hi = std::isfinite(joint.limits.upper) ? joint.limits.upper : M_PI;
        kinematics::SetHeldJoint(robot, joint.name,
                                 std::uniform_real_distribution<double>(lo, hi)(rng), &state);
      }
    }
    CartPlacementRequest request;
    request.X_WB = placement.X_WB();
    request.aim_W = aim_W_;
    for (std::size_t a = 0; a < arms_.size(); ++a)
      request.ports.push_back({arms_[a], placement.sites[a].p_rcm_W});
    CartPlacementOptions cart_options;
    cart_options.seed = options_.seed;
    cart_options.starts = full_solver ? 32 : options_.suj_starts;
    cart_options.max_iterations = full_solver ? 300 : options_.suj_iterations;
    cart_options.memo = options_.setup_joint_memo ? &ws->memo : nullptr;
    placed = PlaceCart(robot, request, cart_options, &state);
    ev->message = placed.message;
    if (!placed.ok()) {
      if (attempt == 0) {
        ev->status = PlacementStatus::kUnreachable;
        // Below every placed plan, better the nearer the RCMs come to their ports.
        ev->score = -2.0 - std::min(placed.worst_position_error, 1.0);
        return out;
      }
      continue;
    }
    nominal_ok = AimArms(placement, samples, ws, &nominal);
    ev->q_nominal = state.q;
    ev->joint_values = state.joint_values;
    if (!have_best || nominal.contacts.size() < best_nominal.contacts.size()) {
      have_best = true;
      best_state = state;
      best_nominal = nominal;
      best_ok = nominal_ok;
      best_message = ev->message;
    }
    if (!nominal.collision) break;
  }
  state = best_state;
  out.placed = true;
  out.nominal = best_nominal;
  out.nominal_ok = best_ok;
  ev->message = best_message;
  ev->q_nominal = state.q;
  ev->joint_values = state.joint_values;
  checker.SetRobotState(state);
  SetPorts(placement, state, &checker);
  ev->collisions = static_cast<int>(out.nominal.contacts.size());
  if (out.nominal.collision) {
    ev->status = PlacementStatus::kInCollision;
    std::ostringstream m;
    m << ev->message << "  in collision at the nominal pose: " << out.nominal.contacts.size()
      << " pairs";
    for (std::size_t i = 0; i < std::min<std::size_t>(3, out.nominal.contacts.size()); ++i) {
      m << (i == 0 ? " (" : ", ")
        << checker.world().DescribePair(out.nominal.contacts[i].a, out.nominal.contacts[i].b);
    }
    m << ")\n";
    ev->message = m.str();
  } else {
    ev->status = PlacementStatus::kPlaced;
  }
  return out;
}

std::vector<bool> PortPlacementProblem::AimArms(const Placement& placement,
                                                const std::vector<TargetSample>& samples,
                                                Workspace* ws,
                                                collision::CollisionReport* nominal) const {
  const robot::RobotModel& robot = *robot_;
  robot::RobotState& state = ws->state;
  collision::CollisionChecker& checker = *ws->checker;
  // Nominal pose: each arm aimed at the targets' centroid, the instruments just inside their
  // ports (their start pose), the endoscope at its working distance.
  std::vector<bool> nominal_ok(arms_.size(), true);
  for (std::size_t a = 0; a < arms_.size(); ++a) {
    const PlanArm& arm = arms_[a];
    const Eigen::Vector3d port = placement.sites[a].p_rcm_W;
    const Eigen::Vector3d dir = (aim_W_ - port).normalized();
    const Eigen::Vector3d p = arm.role == ArmRole::kEndoscope
                                  ? Eigen::Vector3d(aim_W_ - options_.scope_working_distance * dir)
                                  : Eigen::Vector3d(port + kNominalDepth * dir);
    const IkOutcome ik =
        planners::SolveReach(robot, arm, p, port, options_.ik_iterations * 2, 0.005, &state);
    nominal_ok[a] = ik.converged;
  }
  kinematics::ForwardKinematics(robot, state.q, &state);
  checker.SetRobotState(state);
  SetPorts(placement, state, &checker);
  *nominal = checker.Check();
  // One aim for every arm (the centroid of all the targets) can run an arm along the chest
  // wall into the ribs of its own space (a port low on the chest, the LIMA high under the
  // wall), and a placement with such a start pose is dropped before its reach is looked at.
  // An arm in contact is then aimed, in turn, at each target's own centroid, then toward the
  // way it enters (the space's inward normal: straight into the chest, as an instrument is
  // inserted under vision); the first aim free of contacts is kept, else the fewest contacts.
  // Re-aiming an arm moves its own bodies alone (world_arm_, as InstrumentReaches relies on):
  // the contacts it has no part in stay as they are. So an arm in none is not re-aimed (no aim
  // could lower the count), and an aim is judged by the arm's own pairs (Check with the arm),
  // the full report taken only for an aim kept: the same aims kept as checking everything.
  const std::vector<collision::Body>& bodies = checker.world().bodies();
  for (std::size_t a = 0; a < arms_.size() && nominal->collision; ++a) {
    const PlanArm& arm = arms_[a];
    const Eigen::Vector3d port = placement.sites[a].p_rcm_W;
    const int own = world_arm_[a];
    std::size_t others = 0;  // contacts without a body of this arm
    if (own >= 0) {
      for (const collision::Contact& c : nominal->contacts)
        others += bodies[c.a].arm != own && bodies[c.b].arm != own ? 1 : 0;
      if (others == nominal->contacts.size()) continue;
    }
    std::vector<Eigen::Vector3d> aims;  // points to aim at, in the order tried
    for (int t = 0; t < static_cast<int>(patient_->targets.size()); ++t) {
      std::vector<Eigen::Vector3d> points;
      for (const auto& sample : samples)
        if (sample.target == t) points.push_back(sample.p_W);
      if (!points.empty()) aims.push_back(Centroid(points));
    }
    if (placement.sites[a].in_gap) {
      const Eigen::Vector3d inward =
          (port - patient_->X_WP * placement.sites[a].p_curve_P).normalized();
      const double reach = (aim_W_ - port).norm();
      if (inward.allFinite()) aims.push_back(port + reach * inward);
    }
    robot::RobotState kept = state;
    bool kept_ok = nominal_ok[a];
    for (const Eigen::Vector3d& aim : aims) {
      const Eigen::Vector3d dir = (aim - port).normalized();
      if (!dir.allFinite()) continue;
      const Eigen::Vector3d p =
          arm.role == ArmRole::kEndoscope
              ? Eigen::Vector3d(
                    port +
                    std::max(kNominalDepth, (aim - port).norm() - options_.scope_working_distance) *
                        dir)
              : Eigen::Vector3d(port + kNominalDepth * dir);
      robot::RobotState trial = state;
      const IkOutcome ik =
          planners::SolveReach(robot, arm, p, port, options_.ik_iterations * 2, 0.005, &trial);
      if (!ik.converged) continue;
      kinematics::ForwardKinematics(robot, trial.q, &trial);
      checker.SetRobotState(trial);
      const std::size_t turned =
          own >= 0 ? others + checker.Check(collision::kAllMovingPairs, own).contacts.size()
                   : checker.Check().contacts.size();
      if (turned < nominal->contacts.size()) {
        *nominal = checker.Check();
        kept = trial;
        kept_ok = true;
      }
      if (turned == 0) break;
    }
    state = kept;
    nominal_ok[a] = kept_ok;
    checker.SetRobotState(state);
  }
  return nominal_ok;
}

void PortPlacementProblem::ChooseViews(const Placement& placement,
                                       const std::vector<TargetSample>& samples,
                                       const Docking& docked, bool skip_reach, Workspace* ws,
                                       Evaluation* ev) const {
  // Endoscopes: which camera (straight or angled scope) and which roll of the scope sees the most
  // samples from the nominal pose. The straight scope looks along the shaft: its view axis is the
  // tool frame's axis nearest the shaft; an angled camera frame looks along the same axis of its
  // own frame. The roll is the arm's joint turning about the shaft.
  const robot::RobotModel& robot = *robot_;
  robot::RobotState& state = ws->state;
  collision::CollisionChecker& checker = *ws->checker;
  const int ns = static_cast<int>(samples.size());
  // The lines of sight from the scope's nominal tip, shared by every roll and camera frame tried
  // (a roll turns the scope about its shaft: its tip stays where it is); found when first asked
  // (-1: not yet).
  std::vector<signed char> in_sight;
  Eigen::Vector3d sight_from_W = Eigen::Vector3d::Zero();
  auto count_seen = [&](const robot::RobotState& st, const std::string& frame,
                        const Eigen::Vector3d& axis_F) {
    const Eigen::Isometry3d X_WC = kinematics::FramePose(st, robot.GetFrame(frame));
    const Eigen::Vector3d view = X_WC.linear() * axis_F;
    int seen = 0;
    for (int s = 0; s < ns; ++s) {
      const Eigen::Vector3d d = samples[s].p_W - X_WC.translation();
      const double dist = d.norm();
      const double angle = std::acos(std::clamp(view.dot(d / std::max(dist, 1e-9)), -1.0, 1.0));
      if (angle > options_.scope_half_fov || dist < options_.scope_min_distance ||
          dist > options_.scope_max_distance)
        continue;
      if (in_sight[s] < 0)
        in_sight[s] =
            checker.world().FirstAcross(sight_from_W, samples[s].p_W, kSightMargin).body < 0 ? 1
                                                                                             : 0;
      seen += in_sight[s];
    }
    return seen;
  };
  for (std::size_t a = 0; a < arms_.size(); ++a) {
    const PlanArm& arm = arms_[a];
    if (arm.role != ArmRole::kEndoscope) continue;
    Evaluation::View view;
    view.arm = static_cast<int>(a);
    view.frame = arm.tool_frame;
    const Eigen::Isometry3d X_WT = kinematics::FramePose(state, robot.GetFrame(arm.tool_frame));
    const Eigen::Vector3d shaft = (X_WT.translation() - placement.sites[a].p_rcm_W).normalized();
    int k = 0;
    for (int c = 1; c < 3; ++c) {
      if (std::abs(X_WT.linear().col(c).dot(shaft)) > std::abs(X_WT.linear().col(k).dot(shaft)))
        k = c;
    }
    view.axis_F = Eigen::Vector3d::Unit(k) * (X_WT.linear().col(k).dot(shaft) < 0 ? -1.0 : 1.0);
    if (!skip_reach && docked.nominal_ok[a]) {
      in_sight.assign(ns, -1);
      sight_from_W = X_WT.translation();
      kinematics::Matrix6Xd J;
      kinematics::ComputeFrameJacobian(robot, state, robot.GetFrame(arm.tool_frame), &J);
      const int roll = RollJoint(arm, J, shaft);
      std::vector<double> rolls = {0.0};  // no roll joint: one pass per frame
      if (roll >= 0) {
        rolls.clear();
        const auto [lo, hi] = JointRange(robot, roll);
        for (int r = 0; r <= 12; ++r) rolls.push_back(lo + (hi - lo) * r / 12.0);
      }
      const Eigen::VectorXd q0 = state.q;
      int best = count_seen(state, view.frame, view.axis_F);
      double best_roll = roll >= 0 ? q0[roll] : 0.0;
      robot::RobotState trial = state;
      for (const std::string& frame : arm.view_frames) {
        for (double r : rolls) {
          if (roll >= 0) trial.q[roll] = r;
          if (!kinematics::ForwardKinematics(robot, trial.q, &trial).ok()) continue;
          const int seen = count_seen(trial, frame, view.axis_F);
          if (seen > best) {
            best = seen;
            best_roll = roll >= 0 ? r : 0.0;
            view.frame = frame;
          }
        }
      }
      if (roll >= 0 && best_roll != q0[roll]) {
        trial.q = q0;
        trial.q[roll] = best_roll;
        kinematics::ForwardKinematics(robot, trial.q, &trial);
        checker.SetRobotState(trial);
        SetPorts(placement, trial, &checker);
        if (!checker.InCollision()) {
          state = trial;
        } else {
          view.frame = arm.tool_frame;  // the rolled scope collides: keep the straight view
        }
      }
    }
    ev->views.push_back(view);
  }
}

void PortPlacementProblem::ScopeReaches(int a, const Placement& placement,
                                        const std::vector<TargetSample>& samples,
                                        const Docking& docked,
                                        const robot::RobotState& nominal_state,
                                        const Evaluation& ev, Workspace* ws,
                                        std::vector<SampleReach>* reach) const {
  const robot::RobotModel& robot = *robot_;
  robot::RobotState& state = ws->state;
  collision::CollisionChecker& checker = *ws->checker;
  const PlanArm& arm = arms_[a];
  const bool ok = docked.nominal_ok[a], collision = docked.nominal.collision;
  const int ns = static_cast<int>(samples.size());
  state = nominal_state;
  const Evaluation::View* chosen = nullptr;
  for (const auto& v : ev.views) {
    if (v.arm == a) chosen = &v;
  }
  const Eigen::Isometry3d X_WC = kinematics::FramePose(state, robot.GetFrame(chosen->frame));
  const Eigen::Vector3d tip = X_WC.translation();
  const Eigen::Vector3d view = X_WC.linear() * chosen->axis_F;
  for (int s = 0; s < ns; ++s) {
    SampleReach& r = (*reach)[s];
    r.sample = s;
    r.arm = a;
    const Eigen::Vector3d d = samples[s].p_W - tip;
    const double dist = d.norm();
    const double angle = std::acos(std::clamp(view.dot(d / std::max(dist, 1e-9)), -1.0, 1.0));
    const bool in_view = ok && !collision && angle <= options_.scope_half_fov &&
                         dist >= options_.scope_min_distance && dist <= options_.scope_max_distance;
    const int hidden =
        in_view ? checker.world().FirstAcross(tip, samples[s].p_W, kSightMargin).body : -1;
    r.seen = in_view && hidden < 0;
    r.reached = r.seen;
    r.approach = angle;
    if (!r.seen) {
      std::ostringstream why;
      if (!ok)
        why << "the endoscope cannot reach its viewpoint";
      else if (collision)
        why << "the nominal pose is in collision";
      else if (angle > options_.scope_half_fov)
        why << "outside the field of view (" << std::lround(angle / kDeg) << " deg off the axis)";
      else if (hidden >= 0)
        why << "hidden behind the " << checker.world().bodies()[hidden].name;
      else
        why << "outside the working distance (" << std::lround(dist * 1e3) << " mm)";
      r.reason = why.str();
    }
    r.q_arm.resize(arm.q_indices.size());
    for (std::size_t c = 0; c < arm.q_indices.size(); ++c) r.q_arm[c] = state.q[arm.q_indices[c]];
    // Not seen from the docking pose: the camera is moved to look at it, as the surgeon
    // moves it to each work site (Cannon et al. 2003 score the endoscope per surgical site;
    // docs/decisions.md, "The endoscope looks at each work site").
    if (!r.seen && options_.scope_moves && ok && !collision) {
      robot::RobotState moved = nominal_state;
      std::string why_not;
      if (LookAt(a, placement, *chosen, samples[s].p_W, &moved, &checker, &why_not)) {
        r.seen = r.reached = true;
        r.reason.clear();
        const Eigen::Isometry3d X_WM = kinematics::FramePose(moved, robot.GetFrame(chosen->frame));
        const Eigen::Vector3d dm = samples[s].p_W - X_WM.translation();
        r.approach =
            std::acos(std::clamp((X_WM.linear() * chosen->axis_F).dot(dm.normalized()), -1.0, 1.0));
        for (std::size_t c = 0; c < arm.q_indices.size(); ++c)
          r.q_arm[c] = moved.q[arm.q_indices[c]];
      } else if (!why_not.empty()) {
        r.reason += "; moved to look at it: " + why_not;
      }
    }
  }
  checker.SetRobotState(nominal_state);
  SetPorts(placement, nominal_state, &checker);
}

void PortPlacementProblem::InstrumentReaches(int a, const Placement& placement,
                                             const std::vector<TargetSample>& samples,
                                             const Docking& docked, bool skip_reach,
                                             const robot::RobotState& nominal_state,
                                             const EvaluateOptions& how, Workspace* ws,
                                             std::vector<SampleReach>* reach) const {
  const robot::RobotModel& robot = *robot_;
  robot::RobotState& state = ws->state;
  collision::CollisionChecker& checker = *ws->checker;
  const PlanArm& arm = arms_[a];
  const Eigen::Vector3d port = placement.sites[a].p_rcm_W;
  const int ns = static_cast<int>(samples.size());
  for (int s = 0; s < ns; ++s) {
    SampleReach& r = (*reach)[s];
    r.sample = s;
    r.arm = a;
    if (skip_reach) {
      r.reason = "the nominal pose is in collision";
      continue;
    }
    const Eigen::Vector3d p_aim = samples[s].p_W + options_.standoff * samples[s].n_W;
    const Eigen::Vector3d dir = (p_aim - port).normalized();
    r.approach = std::acos(std::clamp(dir.dot(-samples[s].n_W), -1.0, 1.0));
    // From the nominal pose, then, when that solution is in contact, from other wrist poses
    // (ReachSeed); the first valid solution is kept, else the first attempt's answer and reason.
    for (int attempt = 0;; ++attempt) {
      state = nominal_state;
      if (!ReachSeed(a, attempt, &state)) break;
      const IkOutcome ik = planners::SolveReach(robot, arm, p_aim, port, options_.ik_iterations,
                                                options_.ik_tolerance, &state);
      std::string why;
      if (!ik.converged) {
        if (attempt == 0)
          why = ReachFailure(robot, arm, state, p_aim, port, max_reach_[a], ik, patient_->X_WP);
      } else {
        checker.SetRobotState(state);
        SetPorts(placement, state, &checker,
                 &samples[s].p_W);  // the jaws may touch the organ there
        // Only this arm moved from the nominal pose: when that pose is free, only its pairs can
        // collide (the others' allowances and work sites are as they were or wider).
        const int only_arm = docked.nominal.collision ? -1 : world_arm_[a];
        if (!checker.InCollision(how.sample_mask & collision::kAllMovingPairs, only_arm)) {
          r.reached = true;
        } else if (attempt == 0 && how.detailed) {
          const auto report = checker.Check(how.sample_mask & collision::kAllMovingPairs, only_arm);
          const auto& c = report.contacts.front();
          why = "collision: " + checker.world().DescribePair(c.a, c.b);
        } else if (attempt == 0) {
          why = "collision";
        }
      }
      if (attempt == 0 || r.reached) {
        r.tip_error = ik.error;
        r.q_arm.resize(arm.q_indices.size());
        for (std::size_t c = 0; c < arm.q_indices.size(); ++c)
          r.q_arm[c] = state.q[arm.q_indices[c]];
      }
      if (attempt == 0) r.reason = why;
      if (r.reached) {
        r.reason.clear();
        break;
      }
      // Out of the arm's reach from its nominal pose: the outer joints decide that, and another
      // wrist pose moves the tip by a centimetre at most; the restarts are for contacts.
      if (attempt == 0 && !ik.converged) break;
    }
    if (!r.reached) continue;
    kinematics::Matrix6Xd J_WT;
    kinematics::ComputeFrameJacobian(robot, state, robot.GetFrame(arm.tool_frame), &J_WT);
    std::vector<int> cols;
    for (int i : arm.q_indices) {
      if (J_WT.col(i).norm() > 1e-9) cols.push_back(i);
    }
    Eigen::MatrixXd J(6, cols.size());
    for (std::size_t c = 0; c < cols.size(); ++c) {
      J.col(c).head<3>() = J_WT.col(cols[c]).head<3>();
      J.col(c).tail<3>() = J_WT.col(cols[c]).tail<3>() / kCharacteristicLength;
    }
    r.dexterity = InverseCondition(J);
  }
}

double PortPlacementProblem::ShaftRibClearance(const Placement& placement) const {
  double rib = std::numeric_limits<double>::infinity();
  if (!ribs_) return rib;
  const Eigen::Isometry3d X_PW = patient_->X_WP.inverse();
  for (std::size_t a = 0; a < arms_.size(); ++a) {
    const Eigen::Vector3d port = placement.sites[a].p_rcm_W;
    const Eigen::Vector3d dir = (aim_W_ - port).normalized();
    // The shaft through the chest wall: 4 cm either side of its pivot.
    const auto closest = ribs_->Closest(X_PW * (port - 0.04 * dir), X_PW * (port + 0.04 * dir));
    rib = std::min(rib, closest.distance);
  }
  return rib;
}

// The stages: the cart docked and the arms at their nominal pose (Dock, AimArms), the endoscopes'
// views (ChooseViews), each arm's reach or view of every sample (InstrumentReaches,
// ScopeReaches), then the score terms (score_terms.hpp) and their weighted mean.
Evaluation PortPlacementProblem::Evaluate(const Placement& placement, Workspace* ws,
                                          const EvaluateOptions& how) const {
  const std::vector<TargetSample>& samples = how.samples ? *how.samples : samples_;
  TROCAR_THROW_UNLESS(
      placement.sites.size() == arms_.size(),
      "placement: " << placement.sites.size() << " ports for " << arms_.size() << " arms");
  Evaluation ev;
  const Docking docked = Dock(placement, samples, how.full_solver, ws, &ev);
  if (!docked.placed) return ev;
  robot::RobotState& state = ws->state;
  collision::CollisionChecker& checker = *ws->checker;
  // Per arm and sample: reach (instruments) or view (endoscopes). While optimising, a placement
  // already in collision at its nominal pose is not taken further (its score is banded below
  // every collision-free one, ranked by its geometric terms and its number of contacts).
  const bool skip_reach = docked.nominal.collision && !how.detailed;
  const int ns = static_cast<int>(samples.size());
  ChooseViews(placement, samples, docked, skip_reach, ws, &ev);
  ev.q_nominal = state.q;
  ev.joint_values = state.joint_values;
  checker.SetRobotState(state);
  SetPorts(placement, state, &checker);
  const robot::RobotState nominal_state = state;

  std::vector<std::vector<SampleReach>> reach(arms_.size(), std::vector<SampleReach>(ns));
  std::vector<int> instruments, scopes;
  for (std::size_t a = 0; a < arms_.size(); ++a) {
    const int arm = static_cast<int>(a);
    if (arms_[a].role == ArmRole::kEndoscope) {
      scopes.push_back(arm);
      ScopeReaches(arm, placement, samples, docked, nominal_state, ev, ws, &reach[a]);
    } else {
      instruments.push_back(arm);
      InstrumentReaches(arm, placement, samples, docked, skip_reach, nominal_state, how, ws,
                        &reach[a]);
    }
  }
  ev.served.assign(ns, true);
  for (int s = 0; s < ns; ++s) {
    for (int a : instruments) ev.served[s] = ev.served[s] && reach[a][s].reached;
    if (!scopes.empty()) {
      bool seen = false;
      for (int a : scopes) seen = seen || reach[a][s].seen;
      ev.served[s] = ev.served[s] && seen;
    }
  }
  // Clearances at the nominal pose.
  checker.SetRobotState(nominal_state);
  SetPorts(placement, nominal_state, &checker);
  const auto by_class = checker.ClearanceByClass();
  auto clearance = [&](collision::PairClass cls) {
    const auto i = static_cast<std::size_t>(cls);
    return i < by_class.size() && by_class[i].valid() ? by_class[i].distance
                                                      : std::numeric_limits<double>::infinity();
  };
  const TermInputs in{placement,
                      samples,
                      reach,
                      ev.served,
                      instruments,
                      scopes,
                      options_,
                      clearance(collision::PairClass::kArmArm),
                      clearance(collision::PairClass::kArmPatient),
                      ShaftRibClearance(placement)};
  ev.terms = EvaluateTerms(in, options_.weights);
  double total = 0, weights = 0;
  for (const auto& t : ev.terms) {
    total += t.weight * t.score;
    weights += t.weight;
  }
  ev.score = weights > 0 ? total / weights : 0.0;
  if (ev.status == PlacementStatus::kInCollision) {
    // Below every collision-free plan, better with fewer colliding pairs.
    ev.score = -1.0 + 0.5 * ev.score - 0.01 * std::min(ev.collisions, 50);
  }
  if (how.detailed) {
    for (auto& arm_reach : reach) {
      for (auto& r : arm_reach) ev.reaches.push_back(std::move(r));
    }
  }
  return ev;
}

}  // namespace trocar::planners
