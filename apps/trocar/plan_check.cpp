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

}  // namespace

int CheckPlanFile(const std::string& path, std::ostream& out) {
  // The typed reader first: every field's type, size and range, the cart's one pose; then the
  // independent re-check of what the plan claims.
  // Through the plan file's one reader (every field's type, size and range, the cart's one
  // pose); what it claims is then re-checked here independently of the code that made it.
  const planners::PlanFile typed = planners::ReadPlanFile(path);
  {
    // The inputs (resolved against the plan's folder as every reader does), and whether they
    // still fit by the one shared check.
    const std::string& robot_file = typed.robot_file;
    const std::string& case_dir = typed.case_dir;
    std::vector<std::string> failures;
    auto fail = [&](const std::string& what) { failures.push_back(what); };
    if (const std::string m = planners::RobotFileMismatch(typed); !m.empty()) fail(m);
    TROCAR_THROW_UNLESS(IsRegularFile(robot_file), path << ": its robot " << robot_file << " does not exist");
    auto robot = std::make_shared<const robot::RobotModel>(robot::LoadRobot(robot_file));
    const patient::PatientModel patient = patient::ImportPatient(case_dir);
    if (const std::string m = planners::PatientModelMismatch(typed, patient, case_dir); !m.empty()) fail(m);
    const std::vector<planners::StoredArm>& arms = typed.arms;
    // Every arm's tool frame is a frame of the robot (a tampered or foreign plan file is named,
    // before any pose is checked with it).
    for (std::size_t i = 0; i < arms.size(); ++i) {
      const std::string& tool = arms[i].tool_frame;
      if (tool.empty()) continue;
      try {
        (void)robot->GetFrame(tool);
      } catch (const Error& e) {
        TROCAR_THROW(path << ": robot.arms[" << i << "].tool_frame: " << e.what());
      }
    }
    const planners::StoredScoring& scoring = typed.scoring;
    const double ik_tolerance = scoring.ik_tolerance_m;
    const double half_fov = scoring.scope_half_fov_deg * M_PI / 180;
    const double scope_min = scoring.scope_min_distance_m;
    const double scope_max = scoring.scope_max_distance_m;
    collision::WorldOptions world_options;
    for (const auto& arm : arms) {
      if (arm.rcm_frame.empty()) world_options.shaft_ports.push_back(arm.shaft_link);
    }
    const auto world = collision::CollisionWorld::Build(&patient, robot, world_options);
    std::unique_ptr<collision::TriangleBvh> skin_bvh;
    if (const patient::Structure* skin = patient.Find("skin"); skin && !skin->mesh.triangles.empty())
      skin_bvh = std::make_unique<collision::TriangleBvh>(skin->mesh);
    collision::CollisionChecker checker(world);
    const auto& bodies = world->bodies();
    // Each arm's port in the world: RCM ports by frame, shaft ports after them in arm order. A
    // shaft may touch the skin within its pivot's depth under the skin plus the port radius of
    // the pivot (docs/plan-format.md, "Ports"), recomputed here from the skin mesh.
    std::vector<int> world_port;
    {
      int shaft = 0;
      for (const auto& port : world->ports()) shaft += port.frame.empty() ? 0 : 1;
      for (const auto& arm : arms) {
        const std::string& rcm = arm.rcm_frame;
        int index = rcm.empty() ? shaft++ : -1;
        for (std::size_t p = 0; p < world->ports().size() && !rcm.empty(); ++p) {
          if (world->ports()[p].frame == rcm) index = static_cast<int>(p);
        }
        world_port.push_back(index);
      }
    }
    const Eigen::Isometry3d X_PW = patient.X_WP.inverse();
    // The pivot's depth under the skin, and the port rule's allowance (port_rules.hpp).
    auto depth = [&](const Eigen::Vector3d& pivot_W) {
      if (!skin_bvh) return 0.0;
      const auto c = skin_bvh->Closest(X_PW * pivot_W, X_PW * pivot_W);
      return c.found() ? c.distance : 0.0;
    };
    std::vector<Eigen::Vector3d> incisions_W;  // per arm, of the plan being checked
    // An instrument's allowance follows its cannula's track in the pose checked
    // (planners::TrackAllowance).
    auto allowance = [&](std::size_t a, const Eigen::Vector3d& pivot_W,
                         const robot::RobotState& state) {
      const double d = depth(pivot_W);
      const double r = world->options().port_radius;
      if (a >= incisions_W.size()) return d + r;
      const double cut = planners::PortTrackLength(d, pivot_W, incisions_W[a]) + r;
      const std::string& tool = arms[a].tool_frame;
      if (!skin_bvh || arms[a].role != "instrument" || tool.empty()) return cut;
      const Eigen::Vector3d tip_W =
          kinematics::FramePose(state, robot->GetFrame(tool)).translation();
      return planners::TrackAllowance(*skin_bvh, d, X_PW * pivot_W, X_PW * incisions_W[a],
                                      X_PW * tip_W, r);
    };
    // The contact rule at the target (port_rules.hpp, kWorkSiteRadius): with `work_W` (the
    // sample being worked on), each instrument's wrist and jaws may touch the organ there.
    auto collisions = [&](const robot::RobotState& state,
                          const std::vector<Eigen::Vector3d>& pivots_W,
                          const Eigen::Vector3d* work_W = nullptr) {
      checker.SetRobotState(state);
      checker.ClearWorkSites();
      for (std::size_t a = 0; a < world_port.size() && a < pivots_W.size(); ++a) {
        if (world_port[a] < 0) continue;
        checker.SetPortPosition(world_port[a], pivots_W[a], allowance(a, pivots_W[a], state));
        if (work_W && arms[a].role == "instrument")
          checker.SetWorkSite(world_port[a], *work_W, planners::kWorkSiteRadius);
      }
      const collision::CollisionReport report = checker.Check();
      std::string text;
      for (std::size_t i = 0; i < std::min<std::size_t>(3, report.contacts.size()); ++i) {
        text += (i ? ", " : "") + bodies[report.contacts[i].a].name + " - " +
                bodies[report.contacts[i].b].name;
      }
      return std::make_pair(static_cast<int>(report.contacts.size()), text);
    };
    std::vector<Eigen::Vector3d> aims, sample_points;
    for (const planners::StoredSample& s : typed.samples) {
      aims.push_back(s.aim_W);
      sample_points.push_back(s.p_W);
    }
    // A sample's recorded joints (plans[].samples[].q): active joints of the robot.
    auto set_sample_joints = [&](const planners::StoredReach& r, robot::RobotState* st) {
      for (const auto& [name, value] : r.q) {
        const int j = robot->GetJoint(name);
        TROCAR_THROW_UNLESS(robot->joint(j).q_index >= 0,
                            path << ": plans[].samples[].q names '" << name
                                 << "': expected an active joint of the robot");
        st->q[robot->joint(j).q_index] = value;
      }
    };
    int claims = 0;
    // The ranked plans, then the baselines beside them (the template, a surgeon's ports): every
    // claim of each is checked the same way.
    std::vector<std::pair<const planners::StoredPlan*, std::string>> to_check;
    for (const planners::StoredPlan& plan : typed.plans)
      to_check.push_back({&plan, "plan " + std::to_string(plan.rank) + ": "});
    for (const planners::StoredBaseline& b : typed.baselines) {
      if (b.placed) to_check.push_back({&b.plan, "baseline " + b.kind + ": "});
    }
    for (const auto& [plan_ptr, tag] : to_check) {
      const planners::StoredPlan& plan = *plan_ptr;
      const std::size_t failures_before = failures.size();
      robot::RobotState state(*robot);
      // Cart on the floor.
      const double yaw = plan.cart_yaw_deg * M_PI / 180;
      state.X_WB = Eigen::Isometry3d::Identity();
      state.X_WB.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
      state.X_WB.translation() = Eigen::Vector3d(plan.cart_x, plan.cart_y, 0);
      ++claims;
      // Setup joints: held, inside their limits.
      for (const auto& [name, value] : plan.setup_joints) {
        ++claims;
        try {
          const auto r = kinematics::SetHeldJoint(*robot, name, value, &state);
          if (!r.ok()) fail(tag + "setup joint '" + name + "': " + r.message);
        } catch (const Error& e) {
          fail(tag + "setup joint '" + name + "': " + e.what());
        }
      }
      // Nominal configuration.
      for (const auto& [name, value] : plan.q_nominal) {
        const int j = robot->GetJoint(name);
        TROCAR_THROW_UNLESS(robot->joint(j).q_index >= 0,
                            path << ": q_nominal names '" << name << "', not an active joint");
        state.q[robot->joint(j).q_index] = value;
      }
      ++claims;
      for (const auto& v : kinematics::LimitViolations(*robot, state.q))
        fail(tag + "nominal pose: " + v);
      const auto fk = kinematics::ForwardKinematics(*robot, state.q, &state);
      if (!fk.ok()) fail(tag + "nominal pose: " + fk.message);
      const robot::RobotState nominal = state;
      // Ports: on their candidate curve, RCMs at them.
      std::vector<Eigen::Vector3d> pivots;
      incisions_W.clear();
      const std::vector<planners::StoredPort>& ports = plan.ports;
      TROCAR_THROW_UNLESS(ports.size() == arms.size(), path << ": " << tag << ports.size()
                                                            << " ports for " << arms.size()
                                                            << " arms");
      for (std::size_t a = 0; a < arms.size(); ++a) {
        const planners::StoredPort& port = ports[a];
        const Eigen::Vector3d p_W = port.p_W;
        const Eigen::Vector3d p_P = port.p_P;
        const std::string& arm_name = arms[a].name;
        incisions_W.push_back(p_W);
        claims += 2;
        if ((patient.X_WP * p_P - p_W).norm() > kSlack)
          fail(tag + arm_name + ": port p_W is not X_WP p_P");
        const std::string& candidate = port.candidate;
        const patient::PortCandidate* curve = nullptr;
        for (const auto& c : patient.port_candidates) {
          if (c.name == candidate) curve = &c;
        }
        if (!curve) {
          fail(tag + arm_name + ": port candidate '" + candidate + "' is not one of the patient's");
        } else {
          const Eigen::Vector3d curve_P = port.curve_P;
          ++claims;
          if (DistanceToPolyline(curve_P, curve->skin) > kPortTolerance)
            fail(tag + arm_name + ": port site is " + Mm(DistanceToPolyline(curve_P, curve->skin)) +
                 " off its curve " + candidate);
          if ((curve_P - p_P).norm() > planners::kMaxIncisionOffset + kSlack)
            fail(tag + arm_name + ": the incision is " + Mm((curve_P - p_P).norm()) +
                 " from its site on " + candidate);
        }
        if (skin_bvh) {
          ++claims;
          const double off = skin_bvh->Closest(p_P, p_P).distance;
          if (off > kPortTolerance) fail(tag + arm_name + ": the incision is " + Mm(off) + " off the skin");
        }
        const std::string& rcm = arms[a].rcm_frame;
        const Eigen::Vector3d rcm_W = port.rcm_W;
        pivots.push_back(rcm_W);
        ++claims;
        if ((rcm_W - p_W).norm() > 0.1)
          fail(tag + arm_name + ": the pivot is " + Mm((rcm_W - p_W).norm()) +
               " from the skin port");
        ++claims;
        if (depth(rcm_W) > planners::kMaxPivotDepth + kSlack)
          fail(tag + arm_name + ": the pivot is " + Mm(depth(rcm_W)) + " under the skin (at most " +
               Mm(planners::kMaxPivotDepth) + ")");
        if (rcm.empty()) continue;
        ++claims;
        const double off =
            (kinematics::FramePose(nominal, robot->GetFrame(rcm)).translation() - rcm_W).norm();
        if (off > kPortTolerance)
          fail(tag + arm_name + ": RCM frame '" + rcm + "' is " + Mm(off) + " from its pivot");
      }
      // Nominal pose collision-free when the plan says "placed".
      if (plan.status == "placed") {
        ++claims;
        const auto [n, which] = collisions(nominal, pivots);
        if (n > 0)
          fail(tag + "claims a collision-free placement, but " + std::to_string(n) +
               " pairs collide at the nominal pose: " + which);
      }
      // Every sample the plan calls reached or seen.
      for (const planners::StoredReach& r : plan.reaches) {
        const int sample = r.sample;
        TROCAR_THROW_UNLESS(sample >= 0 && sample < static_cast<int>(aims.size()),
                            path << ": sample index " << sample << " out of range");
        const std::string& arm_name = r.arm;
        int a = -1;
        for (std::size_t i = 0; i < arms.size(); ++i) {
          if (arms[i].name == arm_name) a = static_cast<int>(i);
        }
        TROCAR_THROW_UNLESS(a >= 0, path << ": sample names unknown arm '" << arm_name << "'");
        const bool scope = arms[a].role == "endoscope";
        const std::string where = tag + arm_name + " at sample " + std::to_string(sample) + ": ";
        if (!r.reached) continue;
        ++claims;
        const robot::Frame& tool = robot->GetFrame(arms[a].tool_frame);
        if (scope) {
          // The camera the plan says the scope looks from, and its view axis in that frame: a
          // frame of this arm (the tool, or one of its frames named like it), along a unit axis.
          const robot::Frame* camera = &tool;
          Eigen::Vector3d axis_F = Eigen::Vector3d::UnitZ();
          bool have_view = false;
          for (const planners::StoredView& v : plan.views) {
            if (v.arm != arm_name) continue;
            const std::string& frame = v.frame;
            axis_F = v.axis_F;
            const std::string prefix = arm_name + "_";
            TROCAR_THROW_UNLESS(frame == tool.name || frame.rfind(prefix, 0) == 0,
                                path << ": view frame '" << frame << "' is not on arm "
                                     << arm_name);
            TROCAR_THROW_UNLESS(std::abs(axis_F.norm() - 1.0) < 1e-9 &&
                                    axis_F.cwiseAbs().maxCoeff() > 1.0 - 1e-9,
                                path << ": view axis of " << arm_name
                                     << " is not a unit axis of its frame");
            camera = &robot->GetFrame(frame);
            have_view = true;
          }
          TROCAR_THROW_UNLESS(have_view, path << ": no view recorded for endoscope " << arm_name);
          {
            // The axis is the straight scope's: along the shaft in the tool frame.
            const Eigen::Isometry3d X_WT = kinematics::FramePose(nominal, tool);
            const Eigen::Vector3d shaft = (X_WT.translation() - pivots[a]).normalized();
            if ((X_WT.linear() * axis_F).dot(shaft) < 0.99)
              fail(where + "the view axis is not the scope's shaft axis in its tool frame");
          }
          // Where the scope looks from: the pose the plan records for this sample (its docking
          // pose, or moved to look at the sample), within the limits and free of collisions.
          state = nominal;
          set_sample_joints(r, &state);
          if (const auto limits = kinematics::LimitViolations(*robot, state.q); !limits.empty()) {
            fail(where + limits.front());
            continue;
          }
          if (const auto f = kinematics::ForwardKinematics(*robot, state.q, &state); !f.ok()) {
            fail(where + f.message);
            continue;
          }
          if (const auto [n, which] = collisions(state, pivots, nullptr); n > 0) {
            fail(where + "claimed in view, but " + std::to_string(n) + " pairs collide: " + which);
            continue;
          }
          const Eigen::Isometry3d X_WC = kinematics::FramePose(state, *camera);
          const Eigen::Vector3d tip = X_WC.translation();
          const Eigen::Vector3d axis = X_WC.linear() * axis_F;
          const Eigen::Vector3d d = sample_points[sample] - tip;
          const double angle = std::acos(std::clamp(axis.dot(d.normalized()), -1.0, 1.0));
          if (angle > half_fov + 1e-6 || d.norm() < scope_min - kSlack ||
              d.norm() > scope_max + kSlack) {
            fail(where + "claimed in view, but it is " + std::to_string(angle * 180 / M_PI) +
                 " deg off the axis at " + Mm(d.norm()));
          } else if (const collision::SightLine sight =
                         world->FirstAcross(tip, sample_points[sample], planners::kSightMargin);
                     !sight.clear()) {
            fail(where + "claimed in view, but hidden behind the " + bodies[sight.body].name);
          }
          continue;
        }
        state = nominal;
        set_sample_joints(r, &state);
        const auto limits = kinematics::LimitViolations(*robot, state.q);
        if (!limits.empty()) {
          fail(where + limits.front());
          continue;
        }
        const auto f = kinematics::ForwardKinematics(*robot, state.q, &state);
        if (!f.ok()) {
          fail(where + f.message);
          continue;
        }
        const double tip_error =
            (kinematics::FramePose(state, tool).translation() - aims[sample]).norm();
        if (tip_error > ik_tolerance + kSlack)
          fail(where + "the tool tip is " + Mm(tip_error) + " from the target");
        const std::string& shaft = arms[a].shaft_link;
        if (arms[a].rcm_frame.empty()) {
          const int link = robot->GetLink(shaft);
          const Eigen::Vector3d A = state.X_WL[link] * arms[a].shaft_a_L;
          const Eigen::Vector3d B = state.X_WL[link] * arms[a].shaft_b_L;
          const Eigen::Vector3d u = (B - A).normalized(), d = pivots[a] - A;
          const double off = (d - d.dot(u) * u).norm();
          if (off > ik_tolerance + kSlack)
            fail(where + "the shaft passes " + Mm(off) + " from its pivot");
        }
        const auto [n, which] = collisions(state, pivots, &sample_points.at(sample));
        if (n > 0)
          fail(where + "claimed reached, but " + std::to_string(n) + " pairs collide: " + which);
      }
      // Verified motions (trocar verify): each solved path starts at the nominal pose, ends at
      // its target, and is collision-free and within limits at every state of its segments cut
      // at the re-check step — checked here with this file's own checker, not the planner's.
      if (plan.verified) {
        const double step = plan.verification_run.recheck_step;
        const double weight = plan.verification_run.prismatic_weight_per_m;
        TROCAR_THROW_UNLESS(step >= 1e-4 && step <= 1.0 && weight > 0 && weight <= 1000,
                            path << ": verification recheck_step " << step
                                 << " (expected 1e-4..1) or prismatic_weight_per_m " << weight
                                 << " (expected (0, 1000]) out of range");
        int solved = 0, total = 0;
        for (const planners::StoredMotion& m : plan.motions) {
          ++total;
          if (!m.solved) continue;
          ++solved;
          ++claims;
          const std::string& arm_name = m.arm;
          const int sample = m.sample;
          TROCAR_THROW_UNLESS(sample >= 0 && sample < static_cast<int>(aims.size()),
                              path << ": motion sample " << sample << " out of range");
          const std::string where =
              tag + arm_name + " motion to sample " + std::to_string(sample) + ": ";
          int a = -1;
          for (std::size_t i = 0; i < arms.size(); ++i) {
            if (arms[i].name == arm_name) a = static_cast<int>(i);
          }
          TROCAR_THROW_UNLESS(a >= 0, path << ": motion names unknown arm '" << arm_name << "'");
          std::vector<int> qi;
          std::vector<double> scale;
          for (const std::string& name : m.joints) {
            const robot::Joint& joint = robot->joint(robot->GetJoint(name));
            TROCAR_THROW_UNLESS(joint.q_index >= 0, path << ": motion joint " << name
                                                         << " is not an active joint");
            qi.push_back(joint.q_index);
            scale.push_back(joint.type == robot::JointType::kPrismatic ? weight : 1.0);
          }
          // Sized as the joints and finite: the reader checked.
          const std::vector<Eigen::VectorXd>& waypoints = m.waypoints;
          if (waypoints.size() < 2) {
            fail(where + "solved, but its path has fewer than two waypoints");
            continue;
          }
          double start_off = 0.0;
          for (std::size_t c = 0; c < qi.size(); ++c)
            start_off = std::max(start_off, std::abs(waypoints[0][c] - nominal.q[qi[c]]));
          if (start_off > 1e-6) fail(where + "does not start at the nominal pose");
          const robot::Frame& tool = robot->GetFrame(arms[a].tool_frame);
          // Waypoints within the limits before any segment is cut (a far-off waypoint would make a
          // segment of billions of states).
          std::string first_failure;
          for (std::size_t k = 0; k < waypoints.size() && first_failure.empty(); ++k) {
            Eigen::VectorXd q = nominal.q;
            for (std::size_t c = 0; c < qi.size(); ++c) q[qi[c]] = waypoints[k][c];
            const auto limits = kinematics::LimitViolations(*robot, q);
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
            first_failure = "its path has " + std::to_string(states) + " states to re-check (at most 2000000)";
          auto check_state = [&](const Eigen::VectorXd& q_arm) {
            state = nominal;
            for (std::size_t c = 0; c < qi.size(); ++c) state.q[qi[c]] = q_arm[c];
            const auto limits = kinematics::LimitViolations(*robot, state.q);
            if (!limits.empty()) return limits.front();
            const auto f = kinematics::ForwardKinematics(*robot, state.q, &state);
            if (!f.ok()) return f.message;
            const auto [n, which] = collisions(state, pivots, &sample_points.at(sample));
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
            fail(where + "claimed verified, but " + first_failure);
            continue;
          }
          check_state(waypoints.back());
          const double tip_error =
              (kinematics::FramePose(state, tool).translation() - aims[sample]).norm();
          if (tip_error > ik_tolerance + kSlack)
            fail(where + "ends with the tool tip " + Mm(tip_error) + " from the target");
        }
        ++claims;
        const double coverage = plan.verified_coverage;
        if (total > 0 && std::abs(coverage - static_cast<double>(solved) / total) > 1e-9)
          fail(tag + "verified coverage " + std::to_string(coverage) + " is not " +
               std::to_string(solved) + " of " + std::to_string(total) + " motions");
      }
      out << tag
          << (failures.size() == failures_before
                  ? "every claim holds"
                  : std::to_string(failures.size() - failures_before) + " claims fail")
          << "\n";
    }
    if (failures.empty()) {
      out << path << ": " << claims << " claims checked, all hold\n";
      return 0;
    }
    out << path << ": " << failures.size() << " of " << claims << " claims fail:\n";
    for (const auto& f : failures) out << "  " << f << "\n";
    return 3;
  }
}

}  // namespace trocar::apps
