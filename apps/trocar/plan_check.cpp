// trocar check --plan: re-checks every claim a plan file makes through the robot model, the joint
// limits and the collision checker only — none of the optimiser's code (planners/port_placement's
// problem and optimizer) is used, so a bug there cannot vouch for itself.
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <memory>
#include <sstream>

#include "apps/trocar/commands.hpp"
#include "collision/collision_world.hpp"
#include "collision/triangle_bvh.hpp"
#include "common/error.hpp"
#include "common/file_util.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "patient/patient_model.hpp"
#include "plan/plan_file.hpp"
#include "port_placement/plan_io.hpp"
#include "port_placement/port_rules.hpp"
#include "robot/load_robot.hpp"

namespace trocar::apps {
namespace {

constexpr double kPortTolerance = 0.001;  // m: an RCM at its port, a port on its curve
constexpr double kSlack = 1e-4;           // m: beyond the tolerance the plan claims

double DistanceToPolyline(const Eigen::Vector3d& p, const std::vector<Eigen::Vector3d>& line) {
  double best = std::numeric_limits<double>::infinity();
  for (std::size_t i = 0; i + 1 < line.size(); ++i) {
    const Eigen::Vector3d a = line[i], ab = line[i + 1] - line[i];
    const double t =
        ab.squaredNorm() > 0 ? std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0) : 0.0;
    best = std::min(best, (a + t * ab - p).norm());
  }
  if (line.size() == 1) best = (line[0] - p).norm();
  return best;
}

std::string Mm(double m) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(2) << m * 1e3 << " mm";
  return s.str();
}

// What every claim of a plan file is checked against, built once per file: the robot, the
// patient, a collision world with a port per arm (RCM ports by frame, shaft ports after them in
// arm order), the skin for the ports' depths, and the target samples. Each stage checks one kind
// of claim of one plan and adds what fails to `failures`.
class ClaimCheck {
 public:
  ClaimCheck(const planners::PlanFile& file, std::vector<std::string>* failures)
      : file_(file), arms_(file.arms), failures_(failures) {
    const std::string& path = file.path;
    if (const std::string m = planners::RobotFileMismatch(file); !m.empty()) Fail(m);
    TROCAR_THROW_UNLESS(IsRegularFile(file.robot_file),
                        path << ": its robot " << file.robot_file << " does not exist");
    robot_ = std::make_shared<const robot::RobotModel>(robot::LoadRobot(file.robot_file));
    patient_ = patient::ImportPatient(file.case_dir);
    if (const std::string m = planners::PatientModelMismatch(file, patient_, file.case_dir);
        !m.empty())
      Fail(m);
    // Every arm's tool frame is a frame of the robot (a tampered or foreign plan file is named,
    // before any pose is checked with it).
    for (std::size_t i = 0; i < arms_.size(); ++i) {
      const std::string& tool = arms_[i].tool_frame;
      if (tool.empty()) continue;
      try {
        (void)robot_->GetFrame(tool);
      } catch (const Error& e) {
        TROCAR_THROW(path << ": robot.arms[" << i << "].tool_frame: " << e.what());
      }
    }
    const planners::StoredScoring& scoring = file.scoring;
    ik_tolerance_ = scoring.ik_tolerance_m;
    half_fov_ = scoring.scope_half_fov_deg * M_PI / 180;
    scope_min_ = scoring.scope_min_distance_m;
    scope_max_ = scoring.scope_max_distance_m;
    collision::WorldOptions world_options;
    for (const auto& arm : arms_) {
      if (arm.rcm_frame.empty()) world_options.shaft_ports.push_back(arm.shaft_link);
    }
    world_ = collision::CollisionWorld::Build(&patient_, robot_, world_options);
    if (const patient::Structure* skin = patient_.Find("skin");
        skin && !skin->mesh.triangles.empty())
      skin_bvh_ = std::make_unique<collision::TriangleBvh>(skin->mesh);
    checker_ = std::make_unique<collision::CollisionChecker>(world_);
    // Each arm's port in the world: RCM ports by frame, shaft ports after them in arm order. A
    // shaft may touch the skin within its pivot's depth under the skin plus the port radius of
    // the pivot (docs/plan-format.md, "Ports"), recomputed here from the skin mesh.
    int shaft = 0;
    for (const auto& port : world_->ports()) shaft += port.frame.empty() ? 0 : 1;
    for (const auto& arm : arms_) {
      const std::string& rcm = arm.rcm_frame;
      int index = rcm.empty() ? shaft++ : -1;
      for (std::size_t p = 0; p < world_->ports().size() && !rcm.empty(); ++p) {
        if (world_->ports()[p].frame == rcm) index = static_cast<int>(p);
      }
      world_port_.push_back(index);
    }
    X_PW_ = patient_.X_WP.inverse();
    for (const planners::StoredSample& s : file.samples) {
      aims_.push_back(s.aim_W);
      sample_points_.push_back(s.p_W);
    }
  }

  int claims() const { return claims_; }

  // Every claim of one plan (a ranked plan or a baseline's), its messages prefixed by `tag`.
  void Check(const planners::StoredPlan& plan, const std::string& tag) {
    const robot::RobotState nominal = NominalPose(plan, tag);
    const std::vector<Eigen::Vector3d> pivots = Ports(plan, nominal, tag);
    // Nominal pose collision-free when the plan says "placed".
    if (plan.status == "placed") {
      ++claims_;
      const auto [n, which] = Collisions(nominal, pivots);
      if (n > 0)
        Fail(tag + "claims a collision-free placement, but " + std::to_string(n) +
             " pairs collide at the nominal pose: " + which);
    }
    Reaches(plan, nominal, pivots, tag);
    if (plan.verified) Motions(plan, nominal, pivots, tag);
  }

 private:
  void Fail(const std::string& what) { failures_->push_back(what); }

  int ArmIndex(const std::string& name, const char* what) const {
    for (std::size_t i = 0; i < arms_.size(); ++i) {
      if (arms_[i].name == name) return static_cast<int>(i);
    }
    TROCAR_THROW(file_.path << ": " << what << " names unknown arm '" << name << "'");
  }

  // The pivot's depth under the skin (port_rules.hpp).
  double Depth(const Eigen::Vector3d& pivot_W) const {
    if (!skin_bvh_) return 0.0;
    const auto c = skin_bvh_->Closest(X_PW_ * pivot_W, X_PW_ * pivot_W);
    return c.found() ? c.distance : 0.0;
  }

  // The port rule's allowance: an instrument's follows its cannula's track in the pose checked
  // (planners::TrackAllowance).
  double Allowance(std::size_t a, const Eigen::Vector3d& pivot_W,
                   const robot::RobotState& state) const {
    const double d = Depth(pivot_W);
    const double r = world_->options().port_radius;
    if (a >= incisions_W_.size()) return d + r;
    const double cut = planners::PortTrackLength(d, pivot_W, incisions_W_[a]) + r;
    const std::string& tool = arms_[a].tool_frame;
    if (!skin_bvh_ || arms_[a].role != "instrument" || tool.empty()) return cut;
    const Eigen::Vector3d tip_W =
        kinematics::FramePose(state, robot_->GetFrame(tool)).translation();
    return planners::TrackAllowance(*skin_bvh_, d, X_PW_ * pivot_W, X_PW_ * incisions_W_[a],
                                    X_PW_ * tip_W, r);
  }

  // Colliding pairs in `state` (their count, the first three named). The contact rule at the
  // target (port_rules.hpp, kWorkSiteRadius): with `work_W` (the sample being worked on), each
  // instrument's wrist and jaws may touch the organ there.
  std::pair<int, std::string> Collisions(const robot::RobotState& state,
                                         const std::vector<Eigen::Vector3d>& pivots_W,
                                         const Eigen::Vector3d* work_W = nullptr) {
    checker_->SetRobotState(state);
    checker_->ClearWorkSites();
    for (std::size_t a = 0; a < world_port_.size() && a < pivots_W.size(); ++a) {
      if (world_port_[a] < 0) continue;
      checker_->SetPortPosition(world_port_[a], pivots_W[a], Allowance(a, pivots_W[a], state));
      if (work_W && arms_[a].role == "instrument")
        checker_->SetWorkSite(world_port_[a], *work_W, planners::kWorkSiteRadius);
    }
    const collision::CollisionReport report = checker_->Check();
    const auto& bodies = world_->bodies();
    std::string text;
    for (std::size_t i = 0; i < std::min<std::size_t>(3, report.contacts.size()); ++i) {
      text += (i ? ", " : "") + bodies[report.contacts[i].a].name + " - " +
              bodies[report.contacts[i].b].name;
    }
    return {static_cast<int>(report.contacts.size()), text};
  }

  // The cart on the floor at x, y, yaw; the setup joints held within their limits; the nominal
  // configuration within its limits and closed.
  robot::RobotState NominalPose(const planners::StoredPlan& plan, const std::string& tag) {
    robot::RobotState state(*robot_);
    const double yaw = plan.cart_yaw_deg * M_PI / 180;
    state.X_WB = Eigen::Isometry3d::Identity();
    state.X_WB.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    state.X_WB.translation() = Eigen::Vector3d(plan.cart_x, plan.cart_y, plan.cart_z);
    ++claims_;
    for (const auto& [name, value] : plan.setup_joints) {
      ++claims_;
      try {
        const auto r = kinematics::SetHeldJoint(*robot_, name, value, &state);
        if (!r.ok()) Fail(tag + "setup joint '" + name + "': " + r.message);
      } catch (const Error& e) {
        Fail(tag + "setup joint '" + name + "': " + e.what());
      }
    }
    for (const auto& [name, value] : plan.q_nominal) {
      const int j = robot_->GetJoint(name);
      TROCAR_THROW_UNLESS(robot_->joint(j).q_index >= 0,
                          file_.path << ": q_nominal names '" << name << "', not an active joint");
      state.q[robot_->joint(j).q_index] = value;
    }
    ++claims_;
    for (const auto& v : kinematics::LimitViolations(*robot_, state.q))
      Fail(tag + "nominal pose: " + v);
    const auto fk = kinematics::ForwardKinematics(*robot_, state.q, &state);
    if (!fk.ok()) Fail(tag + "nominal pose: " + fk.message);
    return state;
  }

  // Ports: incisions on the skin and X_WP p_P, sites on their candidate curve and within the
  // incision offset, pivots near their port and no deeper than allowed, RCMs at their pivots.
  // @return the pivots, per arm; the incisions are kept for the port rule.
  std::vector<Eigen::Vector3d> Ports(const planners::StoredPlan& plan,
                                     const robot::RobotState& nominal, const std::string& tag) {
    std::vector<Eigen::Vector3d> pivots;
    incisions_W_.clear();
    const std::vector<planners::StoredPort>& ports = plan.ports;
    TROCAR_THROW_UNLESS(ports.size() == arms_.size(), file_.path << ": " << tag << ports.size()
                                                                 << " ports for " << arms_.size()
                                                                 << " arms");
    for (std::size_t a = 0; a < arms_.size(); ++a) {
      const planners::StoredPort& port = ports[a];
      const Eigen::Vector3d p_W = port.p_W;
      const Eigen::Vector3d p_P = port.p_P;
      const std::string& arm_name = arms_[a].name;
      incisions_W_.push_back(p_W);
      claims_ += 2;
      if ((patient_.X_WP * p_P - p_W).norm() > kSlack)
        Fail(tag + arm_name + ": port p_W is not X_WP p_P");
      const std::string& candidate = port.candidate;
      const patient::PortCandidate* curve = nullptr;
      for (const auto& c : patient_.port_candidates) {
        if (c.name == candidate) curve = &c;
      }
      if (!curve) {
        Fail(tag + arm_name + ": port candidate '" + candidate + "' is not one of the patient's");
      } else {
        const Eigen::Vector3d curve_P = port.curve_P;
        ++claims_;
        if (DistanceToPolyline(curve_P, curve->skin) > kPortTolerance)
          Fail(tag + arm_name + ": port site is " + Mm(DistanceToPolyline(curve_P, curve->skin)) +
               " off its curve " + candidate);
        if ((curve_P - p_P).norm() > planners::kMaxIncisionOffset + kSlack)
          Fail(tag + arm_name + ": the incision is " + Mm((curve_P - p_P).norm()) +
               " from its site on " + candidate);
      }
      if (skin_bvh_) {
        ++claims_;
        const double off = skin_bvh_->Closest(p_P, p_P).distance;
        if (off > kPortTolerance)
          Fail(tag + arm_name + ": the incision is " + Mm(off) + " off the skin");
      }
      const std::string& rcm = arms_[a].rcm_frame;
      const Eigen::Vector3d rcm_W = port.rcm_W;
      pivots.push_back(rcm_W);
      ++claims_;
      if ((rcm_W - p_W).norm() > 0.1)
        Fail(tag + arm_name + ": the pivot is " + Mm((rcm_W - p_W).norm()) + " from the skin port");
      ++claims_;
      if (Depth(rcm_W) > planners::kMaxPivotDepth + kSlack)
        Fail(tag + arm_name + ": the pivot is " + Mm(Depth(rcm_W)) + " under the skin (at most " +
             Mm(planners::kMaxPivotDepth) + ")");
      if (rcm.empty()) continue;
      ++claims_;
      const double off =
          (kinematics::FramePose(nominal, robot_->GetFrame(rcm)).translation() - rcm_W).norm();
      if (off > kPortTolerance)
        Fail(tag + arm_name + ": RCM frame '" + rcm + "' is " + Mm(off) + " from its pivot");
    }
    return pivots;
  }

  // `nominal` with a sample's recorded joints (plans[].samples[].q): active joints of the robot.
  robot::RobotState AtSample(const planners::StoredReach& r,
                             const robot::RobotState& nominal) const {
    robot::RobotState st = nominal;
    for (const auto& [name, value] : r.q) {
      const int j = robot_->GetJoint(name);
      TROCAR_THROW_UNLESS(robot_->joint(j).q_index >= 0,
                          file_.path << ": plans[].samples[].q names '" << name
                                     << "': expected an active joint of the robot");
      st.q[robot_->joint(j).q_index] = value;
    }
    return st;
  }

  // Every sample the plan calls reached (an instrument) or seen (an endoscope).
  void Reaches(const planners::StoredPlan& plan, const robot::RobotState& nominal,
               const std::vector<Eigen::Vector3d>& pivots, const std::string& tag) {
    for (const planners::StoredReach& r : plan.reaches) {
      const int sample = r.sample;
      TROCAR_THROW_UNLESS(sample >= 0 && sample < static_cast<int>(aims_.size()),
                          file_.path << ": sample index " << sample << " out of range");
      const int a = ArmIndex(r.arm, "sample");
      const std::string where = tag + r.arm + " at sample " + std::to_string(sample) + ": ";
      if (!r.reached) continue;
      ++claims_;
      if (arms_[a].role == "endoscope") {
        ScopeSees(plan, r, a, nominal, pivots, where);
      } else {
        InstrumentReaches(r, a, nominal, pivots, where);
      }
    }
  }

  // The camera the plan says the scope looks from, and its view axis in that frame: a frame of
  // this arm (the tool, or one of its frames named like it), along a unit axis of it, the
  // straight scope's shaft in its tool frame; from the pose the plan records for the sample (its
  // docking pose, or moved to look at it), within the limits and free of collisions, the sample
  // within the field of view and working distances, with a clear line of sight.
  void ScopeSees(const planners::StoredPlan& plan, const planners::StoredReach& r, int a,
                 const robot::RobotState& nominal, const std::vector<Eigen::Vector3d>& pivots,
                 const std::string& where) {
    const std::string& arm_name = r.arm;
    const robot::Frame& tool = robot_->GetFrame(arms_[a].tool_frame);
    const robot::Frame* camera = &tool;
    Eigen::Vector3d axis_F = Eigen::Vector3d::UnitZ();
    bool have_view = false;
    for (const planners::StoredView& v : plan.views) {
      if (v.arm != arm_name) continue;
      const std::string& frame = v.frame;
      axis_F = v.axis_F;
      const std::string prefix = arm_name + "_";
      TROCAR_THROW_UNLESS(
          frame == tool.name || frame.rfind(prefix, 0) == 0,
          file_.path << ": view frame '" << frame << "' is not on arm " << arm_name);
      TROCAR_THROW_UNLESS(
          std::abs(axis_F.norm() - 1.0) < 1e-9 && axis_F.cwiseAbs().maxCoeff() > 1.0 - 1e-9,
          file_.path << ": view axis of " << arm_name << " is not a unit axis of its frame");
      camera = &robot_->GetFrame(frame);
      have_view = true;
    }
    TROCAR_THROW_UNLESS(have_view, file_.path << ": no view recorded for endoscope " << arm_name);
    {
      // The axis is the straight scope's: along the shaft in the tool frame.
      const Eigen::Isometry3d X_WT = kinematics::FramePose(nominal, tool);
      const Eigen::Vector3d shaft = (X_WT.translation() - pivots[a]).normalized();
      if ((X_WT.linear() * axis_F).dot(shaft) < 0.99)
        Fail(where + "the view axis is not the scope's shaft axis in its tool frame");
    }
    robot::RobotState state = AtSample(r, nominal);
    if (const auto limits = kinematics::LimitViolations(*robot_, state.q); !limits.empty()) {
      Fail(where + limits.front());
      return;
    }
    if (const auto f = kinematics::ForwardKinematics(*robot_, state.q, &state); !f.ok()) {
      Fail(where + f.message);
      return;
    }
    if (const auto [n, which] = Collisions(state, pivots, nullptr); n > 0) {
      Fail(where + "claimed in view, but " + std::to_string(n) + " pairs collide: " + which);
      return;
    }
    const Eigen::Isometry3d X_WC = kinematics::FramePose(state, *camera);
    const Eigen::Vector3d tip = X_WC.translation();
    const Eigen::Vector3d axis = X_WC.linear() * axis_F;
    const Eigen::Vector3d d = sample_points_[r.sample] - tip;
    const double angle = std::acos(std::clamp(axis.dot(d.normalized()), -1.0, 1.0));
    if (angle > half_fov_ + 1e-6 || d.norm() < scope_min_ - kSlack ||
        d.norm() > scope_max_ + kSlack) {
      Fail(where + "claimed in view, but it is " + std::to_string(angle * 180 / M_PI) +
           " deg off the axis at " + Mm(d.norm()));
    } else if (const collision::SightLine sight =
                   world_->FirstAcross(tip, sample_points_[r.sample], planners::kSightMargin);
               !sight.clear()) {
      Fail(where + "claimed in view, but hidden behind the " + world_->bodies()[sight.body].name);
    }
  }

  // The recorded joints within their limits, the tool tip at the target, a software-RCM shaft
  // through its pivot, and no collision but the jaws' contact with the organ at the sample.
  void InstrumentReaches(const planners::StoredReach& r, int a, const robot::RobotState& nominal,
                         const std::vector<Eigen::Vector3d>& pivots, const std::string& where) {
    const robot::Frame& tool = robot_->GetFrame(arms_[a].tool_frame);
    robot::RobotState state = AtSample(r, nominal);
    const auto limits = kinematics::LimitViolations(*robot_, state.q);
    if (!limits.empty()) {
      Fail(where + limits.front());
      return;
    }
    const auto f = kinematics::ForwardKinematics(*robot_, state.q, &state);
    if (!f.ok()) {
      Fail(where + f.message);
      return;
    }
    const double tip_error =
        (kinematics::FramePose(state, tool).translation() - aims_[r.sample]).norm();
    if (tip_error > ik_tolerance_ + kSlack)
      Fail(where + "the tool tip is " + Mm(tip_error) + " from the target");
    if (arms_[a].rcm_frame.empty()) {
      const int link = robot_->GetLink(arms_[a].shaft_link);
      const Eigen::Vector3d A = state.X_WL[link] * arms_[a].shaft_a_L;
      const Eigen::Vector3d B = state.X_WL[link] * arms_[a].shaft_b_L;
      const Eigen::Vector3d u = (B - A).normalized(), d = pivots[a] - A;
      const double off = (d - d.dot(u) * u).norm();
      if (off > ik_tolerance_ + kSlack)
        Fail(where + "the shaft passes " + Mm(off) + " from its pivot");
    }
    const auto [n, which] = Collisions(state, pivots, &sample_points_.at(r.sample));
    if (n > 0)
      Fail(where + "claimed reached, but " + std::to_string(n) + " pairs collide: " + which);
  }

  // Verified motions (trocar verify): each solved path starts at the nominal pose, ends at its
  // target, and is collision-free and within limits at every state of its segments cut at the
  // re-check step — checked here with this file's own checker, not the planner's; the verified
  // coverage is the share of motions solved.
  void Motions(const planners::StoredPlan& plan, const robot::RobotState& nominal,
               const std::vector<Eigen::Vector3d>& pivots, const std::string& tag) {
    const double step = plan.verification_run.recheck_step;
    const double weight = plan.verification_run.prismatic_weight_per_m;
    TROCAR_THROW_UNLESS(step >= 1e-4 && step <= 1.0 && weight > 0 && weight <= 1000,
                        file_.path << ": verification recheck_step " << step
                                   << " (expected 1e-4..1) or prismatic_weight_per_m " << weight
                                   << " (expected (0, 1000]) out of range");
    int solved = 0, total = 0;
    for (const planners::StoredMotion& m : plan.motions) {
      ++total;
      if (!m.solved) continue;
      ++solved;
      ++claims_;
      Motion(m, step, weight, nominal, pivots, tag);
    }
    ++claims_;
    const double coverage = plan.verified_coverage;
    if (total > 0 && std::abs(coverage - static_cast<double>(solved) / total) > 1e-9)
      Fail(tag + "verified coverage " + std::to_string(coverage) + " is not " +
           std::to_string(solved) + " of " + std::to_string(total) + " motions");
  }

  void Motion(const planners::StoredMotion& m, double step, double weight,
              const robot::RobotState& nominal, const std::vector<Eigen::Vector3d>& pivots,
              const std::string& tag) {
    const int sample = m.sample;
    TROCAR_THROW_UNLESS(sample >= 0 && sample < static_cast<int>(aims_.size()),
                        file_.path << ": motion sample " << sample << " out of range");
    const std::string where = tag + m.arm + " motion to sample " + std::to_string(sample) + ": ";
    const int a = ArmIndex(m.arm, "motion");
    std::vector<int> qi;
    std::vector<double> scale;
    for (const std::string& name : m.joints) {
      const robot::Joint& joint = robot_->joint(robot_->GetJoint(name));
      TROCAR_THROW_UNLESS(joint.q_index >= 0,
                          file_.path << ": motion joint \"" << name << "\" is not an active joint");
      qi.push_back(joint.q_index);
      scale.push_back(joint.type == robot::JointType::kPrismatic ? weight : 1.0);
    }
    // Sized as the joints and finite: the reader checked.
    const std::vector<Eigen::VectorXd>& waypoints = m.waypoints;
    if (waypoints.size() < 2) {
      Fail(where + "solved, but its path has fewer than two waypoints");
      return;
    }
    double start_off = 0.0;
    for (std::size_t c = 0; c < qi.size(); ++c)
      start_off = std::max(start_off, std::abs(waypoints[0][c] - nominal.q[qi[c]]));
    if (start_off > 1e-6) Fail(where + "does not start at the nominal pose");
    const robot::Frame& tool = robot_->GetFrame(arms_[a].tool_frame);
    // Waypoints within the limits before any segment is cut (a far-off waypoint would make a
    // segment of billions of states).
    std::string first_failure;
    for (std::size_t k = 0; k < waypoints.size() && first_failure.empty(); ++k) {
      Eigen::VectorXd q = nominal.q;
      for (std::size_t c = 0; c < qi.size(); ++c) q[qi[c]] = waypoints[k][c];
      const auto limits = kinematics::LimitViolations(*robot_, q);
      if (!limits.empty()) first_failure = "waypoint " + std::to_string(k) + ": " + limits.front();
    }
    long states = 0;
    for (std::size_t k = 1; k < waypoints.size() && first_failure.empty(); ++k) {
      double largest = 0.0;
      for (std::size_t c = 0; c < qi.size(); ++c)
        largest = std::max(largest, std::abs(waypoints[k][c] - waypoints[k - 1][c]) * scale[c]);
      states += static_cast<long>(std::min(largest / step, 1e9)) + 1;
    }
    if (first_failure.empty() && states > 2000000)
      first_failure =
          "its path has " + std::to_string(states) + " states to re-check (at most 2000000)";
    robot::RobotState state = nominal;
    auto check_state = [&](const Eigen::VectorXd& q_arm) {
      state = nominal;
      for (std::size_t c = 0; c < qi.size(); ++c) state.q[qi[c]] = q_arm[c];
      const auto limits = kinematics::LimitViolations(*robot_, state.q);
      if (!limits.empty()) return limits.front();
      const auto f = kinematics::ForwardKinematics(*robot_, state.q, &state);
      if (!f.ok()) return f.message;
      const auto [n, which] = Collisions(state, pivots, &sample_points_.at(sample));
      return n > 0 ? "collision: " + which : std::string();
    };
    for (std::size_t k = 1; k < waypoints.size() && first_failure.empty(); ++k) {
      double largest = 0.0;
      for (std::size_t c = 0; c < qi.size(); ++c)
        largest = std::max(largest, std::abs(waypoints[k][c] - waypoints[k - 1][c]) * scale[c]);
      const int n = std::max(1, static_cast<int>(std::ceil(std::min(largest / step, 1e7))));
      for (int i = (k == 1 ? 0 : 1); i <= n && first_failure.empty(); ++i) {
        const double t = static_cast<double>(i) / n;
        first_failure = check_state((1 - t) * waypoints[k - 1] + t * waypoints[k]);
        if (!first_failure.empty())
          first_failure = "segment " + std::to_string(k) + ": " + first_failure;
      }
    }
    if (!first_failure.empty()) {
      Fail(where + "claimed verified, but " + first_failure);
      return;
    }
    check_state(waypoints.back());
    const double tip_error =
        (kinematics::FramePose(state, tool).translation() - aims_[sample]).norm();
    if (tip_error > ik_tolerance_ + kSlack)
      Fail(where + "ends with the tool tip " + Mm(tip_error) + " from the target");
  }

  const planners::PlanFile& file_;
  const std::vector<planners::StoredArm>& arms_;
  std::vector<std::string>* failures_;
  std::shared_ptr<const robot::RobotModel> robot_;
  patient::PatientModel patient_;
  std::shared_ptr<const collision::CollisionWorld> world_;
  std::unique_ptr<collision::TriangleBvh> skin_bvh_;
  std::unique_ptr<collision::CollisionChecker> checker_;
  std::vector<int> world_port_;  // per arm, its port in the world (-1: none)
  Eigen::Isometry3d X_PW_ = Eigen::Isometry3d::Identity();
  std::vector<Eigen::Vector3d> aims_, sample_points_;  // per target sample
  std::vector<Eigen::Vector3d> incisions_W_;           // per arm, of the plan being checked
  double ik_tolerance_ = 0.0, half_fov_ = 0.0, scope_min_ = 0.0, scope_max_ = 0.0;
  int claims_ = 0;
};

}  // namespace

int CheckPlanFile(const std::string& path, std::ostream& out) {
  // Through the plan file's one reader (every field's type, size and range, the cart's one
  // pose); what it claims is then re-checked here independently of the code that made it.
  const planners::PlanFile file = planners::ReadPlanFile(path);
  std::vector<std::string> failures;
  ClaimCheck check(file, &failures);
  // The ranked plans, then the baselines beside them (the template, a surgeon's ports): every
  // claim of each is checked the same way.
  std::vector<std::pair<const planners::StoredPlan*, std::string>> to_check;
  for (const planners::StoredPlan& plan : file.plans)
    to_check.push_back({&plan, "plan " + std::to_string(plan.rank) + ": "});
  for (const planners::StoredBaseline& b : file.baselines) {
    if (b.placed) to_check.push_back({&b.plan, "baseline " + b.kind + ": "});
  }
  for (const auto& [plan, tag] : to_check) {
    const std::size_t failures_before = failures.size();
    check.Check(*plan, tag);
    out << tag
        << (failures.size() == failures_before
                ? "every claim holds"
                : std::to_string(failures.size() - failures_before) + " claims fail")
        << "\n";
  }
  if (failures.empty()) {
    out << path << ": " << check.claims() << " claims checked, all hold\n";
    return 0;
  }
  out << path << ": " << failures.size() << " of " << check.claims() << " claims fail:\n";
  for (const auto& f : failures) out << "  " << f << "\n";
  return 3;
}

}  // namespace trocar::apps
