// trocar check --plan: re-checks every claim a plan file makes through the robot model, the joint
// limits and the collision checker only — none of the optimiser's code (planners/port_placement's
// problem and optimizer) is used, so a bug there cannot vouch for itself.
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>

#include "apps/trocar/commands.hpp"
#include "collision/collision_world.hpp"
#include "collision/triangle_bvh.hpp"
#include "common/error.hpp"
#include "common/json_util.hpp"
#include "port_placement/plan_file.hpp"
#include "common/file_util.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "patient/patient_model.hpp"
#include "port_placement/plan_io.hpp"
#include "port_placement/port_rules.hpp"
#include "robot/load_robot.hpp"

namespace trocar::apps {
namespace {

using nlohmann::json;

constexpr double kPortTolerance = 0.001;  // m: an RCM at its port, a port on its curve
constexpr double kSlack = 1e-4;           // m: beyond the tolerance the plan claims

Eigen::Vector3d Vec(const json& j, const std::string& what) {
  TROCAR_THROW_UNLESS(
      j.is_array() && j.size() == 3 && j[0].is_number() && j[1].is_number() && j[2].is_number(),
      what << ": expected [x, y, z]");
  return Eigen::Vector3d(j[0].get<double>(), j[1].get<double>(), j[2].get<double>());
}

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
  const planners::PlanFile typed = planners::ReadPlanFile(path);
  json doc;
  try {
    doc = ReadJsonFile(path, "a plan");
  } catch (const json::exception& e) {
    TROCAR_THROW(path << ": not a plan (JSON: " << e.what() << ")");
  }
  auto field = [&](const json& j, const std::string& name) -> const json& {
    TROCAR_THROW_UNLESS(j.is_object() && j.contains(name),
                        path << ": missing field '" << name << "'");
    return j.at(name);
  };
  // Every field is read inside the try: a field of the wrong type ("version": "2") is a malformed
  // plan named by its file, never an internal error.
  try {
  TROCAR_THROW_UNLESS(doc.is_object() && doc.contains("format") && doc["format"].is_string() &&
                          doc["format"].get<std::string>() == "trocar-plan",
                      path << ": not a trocar plan (field 'format' is not \"trocar-plan\")");
  const int version = JsonInt(field(doc, "version"), path, "version");
  TROCAR_THROW_UNLESS(version == planners::kPlanFormatVersion,
                      path << ": plan format version " << version << ", this trocar reads version "
                           << planners::kPlanFormatVersion);
    // The inputs through the typed reader (resolved against the plan's folder as every reader
    // does), and whether they still fit by the one shared check.
    const std::string& robot_file = typed.robot_file;
    const std::string& case_dir = typed.case_dir;
    std::vector<std::string> failures;
    auto fail = [&](const std::string& what) { failures.push_back(what); };
    if (const std::string m = planners::RobotFileMismatch(typed); !m.empty()) fail(m);
    TROCAR_THROW_UNLESS(IsRegularFile(robot_file), path << ": its robot " << robot_file << " does not exist");
    auto robot = std::make_shared<const robot::RobotModel>(robot::LoadRobot(robot_file));
    const patient::PatientModel patient = patient::ImportPatient(case_dir);
    if (const std::string m = planners::PatientModelMismatch(typed, patient, case_dir); !m.empty()) fail(m);
    const json& arms = field(field(doc, "robot"), "arms");
    // Every arm's tool frame is a frame of the robot (a tampered or foreign plan file is named,
    // before any pose is checked with it).
    for (std::size_t i = 0; i < arms.size(); ++i) {
      const std::string tool = field(arms[i], "tool_frame").get<std::string>();
      if (tool.empty()) continue;
      try {
        (void)robot->GetFrame(tool);
      } catch (const Error& e) {
        TROCAR_THROW(path << ": robot.arms[" << i << "].tool_frame: " << e.what());
      }
    }
    const json& scoring = field(doc, "scoring");
    const double ik_tolerance = field(scoring, "ik_tolerance_m").get<double>();
    const double half_fov = field(scoring, "scope_half_fov_deg").get<double>() * M_PI / 180;
    const double scope_min = field(scoring, "scope_min_distance_m").get<double>();
    const double scope_max = field(scoring, "scope_max_distance_m").get<double>();
    collision::WorldOptions world_options;
    for (const auto& arm : arms) {
      if (field(arm, "rcm_frame").get<std::string>().empty())
        world_options.shaft_ports.push_back(field(arm, "shaft_link"));
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
        const std::string rcm = field(arm, "rcm_frame").get<std::string>();
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
      const std::string tool = field(arms[a], "tool_frame").get<std::string>();
      if (!skin_bvh || field(arms[a], "role").get<std::string>() != "instrument" || tool.empty())
        return cut;
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
        if (work_W && field(arms[a], "role").get<std::string>() == "instrument")
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
    for (const auto& s : field(doc, "target_samples")) {
      aims.push_back(Vec(field(s, "aim_W"), "target_samples[].aim_W"));
      sample_points.push_back(Vec(field(s, "p_W"), "target_samples[].p_W"));
    }
    // A sample's recorded joints (plans[].samples[].q): active joints of the robot, numbers.
    auto set_sample_joints = [&](const json& r, robot::RobotState* st) {
      const json& q = field(r, "q");
      TROCAR_THROW_UNLESS(q.is_object(), path << ": plans[].samples[].q: expected an object of joint values");
      for (const auto& [name, value] : q.items()) {
        const int j = robot->GetJoint(name);
        TROCAR_THROW_UNLESS(robot->joint(j).q_index >= 0 && value.is_number(),
                            path << ": plans[].samples[].q names '" << name
                                 << "': expected an active joint of the robot with a number");
        st->q[robot->joint(j).q_index] = value.get<double>();
      }
    };
    int claims = 0;
    // The ranked plans, then the baselines beside them (the template, a surgeon's ports): every
    // claim of each is checked the same way.
    std::vector<std::pair<const json*, std::string>> to_check;
    TROCAR_THROW_UNLESS(field(doc, "plans").is_array() && !doc["plans"].empty(),
                        path << ": plans: expected an array of at least one plan, found "
                             << doc["plans"].dump().substr(0, 40));
    for (const auto& plan : field(doc, "plans"))
      to_check.push_back({&plan, "plan " + std::to_string(JsonInt(field(plan, "rank"), path, "plans[].rank", 1)) + ": "});
    if (doc.contains("baselines")) {
      TROCAR_THROW_UNLESS(doc["baselines"].is_array(), path << ": baselines: expected an array");
      for (const auto& b : doc["baselines"]) {
        TROCAR_THROW_UNLESS(b.is_object(), path << ": baselines[]: expected an object");
        TROCAR_THROW_UNLESS(b.contains("placed") && b["placed"].is_boolean(),
                            path << ": baselines[].placed: expected true or false");
        TROCAR_THROW_UNLESS(b.contains("kind") && b["kind"].is_string(),
                            path << ": baselines[].kind: expected a string");
        if (b["placed"].get<bool>())
          to_check.push_back({&field(b, "plan"), "baseline " + b["kind"].get<std::string>() + ": "});
      }
    }
    for (const auto& [plan_ptr, tag] : to_check) {
      const json& plan = *plan_ptr;
      const std::size_t failures_before = failures.size();
      robot::RobotState state(*robot);
      // Cart on the floor.
      const json& cart = field(plan, "cart");
      const double yaw = field(cart, "yaw_deg").get<double>() * M_PI / 180;
      state.X_WB = Eigen::Isometry3d::Identity();
      state.X_WB.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
      state.X_WB.translation() =
          Eigen::Vector3d(field(cart, "x").get<double>(), field(cart, "y").get<double>(), 0);
      ++claims;
      // Setup joints: held, inside their limits.
      for (const auto& [name, value] : field(plan, "setup_joints").items()) {
        ++claims;
        try {
          const auto r = kinematics::SetHeldJoint(*robot, name, value.get<double>(), &state);
          if (!r.ok()) fail(tag + "setup joint '" + name + "': " + r.message);
        } catch (const Error& e) {
          fail(tag + "setup joint '" + name + "': " + e.what());
        }
      }
      // Nominal configuration.
      for (const auto& [name, value] : field(plan, "q_nominal").items()) {
        const int j = robot->GetJoint(name);
        TROCAR_THROW_UNLESS(robot->joint(j).q_index >= 0,
                            path << ": q_nominal names '" << name << "', not an active joint");
        state.q[robot->joint(j).q_index] = value.get<double>();
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
      const json& ports = field(plan, "ports");
      TROCAR_THROW_UNLESS(ports.size() == arms.size(), path << ": " << tag << ports.size()
                                                            << " ports for " << arms.size()
                                                            << " arms");
      for (std::size_t a = 0; a < arms.size(); ++a) {
        const json& port = ports[a];
        const Eigen::Vector3d p_W = Vec(field(port, "p_W"), "ports[].p_W");
        const Eigen::Vector3d p_P = Vec(field(port, "p_P"), "ports[].p_P");
        const std::string arm_name = field(arms[a], "name").get<std::string>();
        incisions_W.push_back(p_W);
        claims += 2;
        if ((patient.X_WP * p_P - p_W).norm() > kSlack)
          fail(tag + arm_name + ": port p_W is not X_WP p_P");
        const std::string candidate = field(port, "candidate").get<std::string>();
        const patient::PortCandidate* curve = nullptr;
        for (const auto& c : patient.port_candidates) {
          if (c.name == candidate) curve = &c;
        }
        if (!curve) {
          fail(tag + arm_name + ": port candidate '" + candidate + "' is not one of the patient's");
        } else {
          const Eigen::Vector3d curve_P = Vec(field(port, "curve_P"), "ports[].curve_P");
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
        const std::string rcm = field(arms[a], "rcm_frame").get<std::string>();
        const Eigen::Vector3d rcm_W = Vec(field(port, "rcm_W"), "ports[].rcm_W");
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
      if (field(plan, "status").get<std::string>() == "placed") {
        ++claims;
        const auto [n, which] = collisions(nominal, pivots);
        if (n > 0)
          fail(tag + "claims a collision-free placement, but " + std::to_string(n) +
               " pairs collide at the nominal pose: " + which);
      }
      // Every sample the plan calls reached or seen.
      for (const auto& r : field(plan, "samples")) {
        const int sample = JsonInt(field(r, "sample"), path, "plans[].samples[].sample", 0);
        TROCAR_THROW_UNLESS(sample >= 0 && sample < static_cast<int>(aims.size()),
                            path << ": sample index " << sample << " out of range");
        const std::string arm_name = field(r, "arm").get<std::string>();
        int a = -1;
        for (std::size_t i = 0; i < arms.size(); ++i) {
          if (arms[i].at("name") == arm_name) a = static_cast<int>(i);
        }
        TROCAR_THROW_UNLESS(a >= 0, path << ": sample names unknown arm '" << arm_name << "'");
        const bool scope = field(arms[a], "role").get<std::string>() == "endoscope";
        const std::string where = tag + arm_name + " at sample " + std::to_string(sample) + ": ";
        if (!field(r, "reached").get<bool>()) continue;
        ++claims;
        const robot::Frame& tool = robot->GetFrame(field(arms[a], "tool_frame").get<std::string>());
        if (scope) {
          // The camera the plan says the scope looks from, and its view axis in that frame: a
          // frame of this arm (the tool, or one of its frames named like it), along a unit axis.
          const robot::Frame* camera = &tool;
          Eigen::Vector3d axis_F = Eigen::Vector3d::UnitZ();
          bool have_view = false;
          for (const auto& v : plan.value("views", json::array())) {
            if (v.value("arm", "") != arm_name) continue;
            const std::string frame = field(v, "frame").get<std::string>();
            axis_F = Vec(field(v, "axis_F"), "views[].axis_F");
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
        const std::string shaft = field(arms[a], "shaft_link").get<std::string>();
        if (field(arms[a], "rcm_frame").get<std::string>().empty()) {
          const int link = robot->GetLink(shaft);
          const Eigen::Vector3d A =
              state.X_WL[link] * Vec(field(arms[a], "shaft_a_L"), "shaft_a_L");
          const Eigen::Vector3d B =
              state.X_WL[link] * Vec(field(arms[a], "shaft_b_L"), "shaft_b_L");
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
      if (plan.contains("verification")) {
        const json& v = plan["verification"];
        const double step = field(v, "recheck_step").get<double>();
        const double weight = field(v, "prismatic_weight_per_m").get<double>();
        TROCAR_THROW_UNLESS(step >= 1e-4 && step <= 1.0 && weight > 0 && weight <= 1000,
                            path << ": verification recheck_step " << step
                                 << " (expected 1e-4..1) or prismatic_weight_per_m " << weight
                                 << " (expected (0, 1000]) out of range");
        int solved = 0, total = 0;
        for (const auto& m : field(v, "motions")) {
          ++total;
          if (!field(m, "solved").get<bool>()) continue;
          ++solved;
          ++claims;
          const std::string arm_name = field(m, "arm").get<std::string>();
          const int sample = JsonInt(field(m, "sample"), path, "plans[].verification.motions[].sample", 0);
          TROCAR_THROW_UNLESS(sample >= 0 && sample < static_cast<int>(aims.size()),
                              path << ": motion sample " << sample << " out of range");
          const std::string where =
              tag + arm_name + " motion to sample " + std::to_string(sample) + ": ";
          int a = -1;
          for (std::size_t i = 0; i < arms.size(); ++i) {
            if (arms[i].at("name") == arm_name) a = static_cast<int>(i);
          }
          TROCAR_THROW_UNLESS(a >= 0, path << ": motion names unknown arm '" << arm_name << "'");
          std::vector<int> qi;
          std::vector<double> scale;
          for (const auto& name : field(m, "joints")) {
            const robot::Joint& joint = robot->joint(robot->GetJoint(name.get<std::string>()));
            TROCAR_THROW_UNLESS(joint.q_index >= 0, path << ": motion joint " << name
                                                         << " is not an active joint");
            qi.push_back(joint.q_index);
            scale.push_back(joint.type == robot::JointType::kPrismatic ? weight : 1.0);
          }
          std::vector<Eigen::VectorXd> waypoints;
          for (const auto& w : field(m, "waypoints")) {
            TROCAR_THROW_UNLESS(w.is_array() && w.size() == qi.size(),
                                path << ": " << where << "a waypoint of the wrong size");
            Eigen::VectorXd q(qi.size());
            for (std::size_t c = 0; c < qi.size(); ++c) q[c] = w[c].get<double>();
            TROCAR_THROW_UNLESS(q.allFinite(), path << ": " << where << "a waypoint is not finite");
            waypoints.push_back(q);
          }
          if (waypoints.size() < 2) {
            fail(where + "solved, but its path has fewer than two waypoints");
            continue;
          }
          double start_off = 0.0;
          for (std::size_t c = 0; c < qi.size(); ++c)
            start_off = std::max(start_off, std::abs(waypoints[0][c] - nominal.q[qi[c]]));
          if (start_off > 1e-6) fail(where + "does not start at the nominal pose");
          const robot::Frame& tool =
              robot->GetFrame(field(arms[a], "tool_frame").get<std::string>());
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
        const double coverage = field(v, "verified_coverage").get<double>();
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
  } catch (const json::exception& e) {
    TROCAR_THROW(path << ": malformed plan (" << e.what() << ")");
  }
}

}  // namespace trocar::apps
