// trocar verify PLAN.json: verified motions (OMPL, collision world) for every ranked plan of a
// plan file, the verified coverage, the plans re-ranked with it and a verified verdict, written
// back into the plan (atomically).
#include <algorithm>
#include <cmath>
#include <iomanip>
#include <iostream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <numeric>

#include "apps/trocar/commands.hpp"
#include "apps/trocar/progress.hpp"
#include "common/error.hpp"
#include "common/json_util.hpp"
#include "port_placement/plan_file.hpp"
#include "common/file_util.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "motion/verify.hpp"
#include "patient/markups.hpp"
#include "patient/patient_model.hpp"
#include "port_placement/plan_config.hpp"
#include "port_placement/plan_io.hpp"
#include "robot/load_robot.hpp"

namespace trocar::apps {

void AddMotionOptions(CLI::App* cmd, planners::MotionOptions* o, int* threads) {
  cmd->add_option("--planner", o->planner,
                  "OMPL planner for the verified motions (rrtconnect, rrt, rrtstar, prm, "
                  "lazyprm, kpiece1, bkpiece1, est, sbl, bitstar, ...)")
      ->capture_default_str();
  cmd->add_option("--motion-time", o->time_limit, "planning time limit per target sample (s)")
      ->capture_default_str();
  cmd->add_option("--motion-seed", o->seed, "seed of the motion queries")->capture_default_str();
  cmd->add_option("--motion-threads", *threads, "threads for the motion queries (0: all cores)")
      ->capture_default_str();
}

const std::map<std::string, std::string>& MotionFlags() {
  static const std::map<std::string, std::string> flags = {
      {"planner", "--planner"}, {"time_limit", "--motion-time"}, {"seed", "--motion-seed"}};
  return flags;
}

void PrintVerification(const planners::PlanVerification& v, std::ostream& out) {
  int solved = 0;
  std::vector<double> times;
  for (const auto& m : v.motions) {
    solved += m.solved;
    // The median over the queries that reached the planner (not those without a goal).
    if (m.status == planners::MotionStatus::kExactSolution ||
        m.status == planners::MotionStatus::kApproximateSolution ||
        m.status == planners::MotionStatus::kTimeout)
      times.push_back(m.planning_time);
  }
  std::sort(times.begin(), times.end());
  out << std::fixed << std::setprecision(0) << "  verified motions: " << solved << " of "
      << v.motions.size() << " (" << v.verified_coverage * 100 << " %, claimed "
      << v.claimed_coverage * 100 << " %, " << std::showpos
      << (v.verified_coverage - v.claimed_coverage) * 100 << std::noshowpos
      << " points by verification), samples served " << v.served_fraction * 100
      << " %, median planning " << std::setprecision(1)
      << (times.empty() ? 0.0 : times[times.size() / 2] * 1e3) << " ms, " << std::setprecision(2)
      << v.seconds << " s on " << v.threads << " thread" << (v.threads == 1 ? "" : "s") << "\n";
  std::map<std::string, int> failures;
  for (const auto& m : v.motions) {
    if (!m.solved) ++failures[m.outcome + ": " + m.reason];
  }
  // The most frequent reasons first.
  std::vector<std::pair<int, std::string>> ranked;
  for (const auto& [why, count] : failures) ranked.emplace_back(count, why);
  std::stable_sort(ranked.begin(), ranked.end(),
                   [](const auto& a, const auto& b) { return a.first > b.first; });
  for (std::size_t i = 0; i < ranked.size() && i < 4; ++i)
    out << "    " << ranked[i].first << " x " << ranked[i].second << "\n";
  if (ranked.size() > 4) out << "    (" << ranked.size() - 4 << " other reasons: see the plan file)\n";
}

namespace {

using nlohmann::json;

struct VerifyOptions {
  std::string plan;
  planners::MotionOptions motion;
  int threads = 0;
  bool quiet = false;
};

Eigen::Vector3d Vec3(const json& j) {
  return Eigen::Vector3d(j.at(0).get<double>(), j.at(1).get<double>(), j.at(2).get<double>());
}

int RunVerify(const VerifyOptions& o) {
  WithFlags(MotionFlags(), [&] { planners::ValidateMotionOptions(o.motion); });
  // The typed reader first (every field checked, the cart's one pose), before anything is
  // rebuilt or rewritten.
  const planners::PlanFile typed = planners::ReadPlanFile(o.plan);
  json doc;
  try {
    doc = ReadJsonFile(o.plan, "a plan");
  } catch (const json::exception& e) {
    TROCAR_THROW(o.plan << ": not a plan (JSON: " << e.what() << ")");
  }
  std::shared_ptr<const robot::RobotModel> robot;
  std::shared_ptr<const patient::PatientModel> patient;
  std::unique_ptr<planners::PortPlacementProblem> problem;
  std::vector<planners::RankedPlan> plans;
  double suitable_fraction = 0.8;
  try {
    TROCAR_THROW_UNLESS(doc.is_object() && doc.value("format", "") == "trocar-plan",
                        o.plan << ": not a trocar plan (field 'format' is not \"trocar-plan\")");
    TROCAR_THROW_UNLESS(JsonInt(doc.at("version"), o.plan, "version") == planners::kPlanFormatVersion,
                        o.plan << ": plan format version " << doc.at("version")
                               << ", this trocar reads version " << planners::kPlanFormatVersion);
    // The inputs through the typed reader, and whether they still fit by the one shared check.
    const std::string robot_file = typed.robot_file;
    const std::string case_dir = typed.case_dir;
    const std::string robot_mismatch = planners::RobotFileMismatch(typed);
    TROCAR_THROW_UNLESS(robot_mismatch.empty(), o.plan << ": " << robot_mismatch << ": plan again");
    robot = std::make_shared<const robot::RobotModel>(robot::LoadRobot(robot_file));
    patient = patient::ImportCase(case_dir).model;
    const std::string patient_mismatch = planners::PatientModelMismatch(typed, *patient, case_dir);
    TROCAR_THROW_UNLESS(patient_mismatch.empty(), o.plan << ": " << patient_mismatch << ": plan again");
    // The problem as the plan was scored: the case's plan settings, then what the file records.
    planners::ProblemOptions po;
    planners::ReadPlanConfig(case_dir, &po);
    po.arms.clear();
    po.roles.clear();
    for (const auto& arm : doc.at("robot").at("arms")) {
      po.arms.push_back(arm.at("name").get<std::string>());
      po.roles.push_back(arm.at("name").get<std::string>() + "=" +
                         arm.at("role").get<std::string>());
    }
    const json& scoring = doc.at("scoring");
    const json& weights = scoring.at("weights");
    po.weights.coverage = weights.at("coverage").get<double>();
    // Plans written before stop 51 have no served term: scored without it.
    po.weights.served = weights.contains("served") ? weights.at("served").get<double>() : 0.0;
    po.weights.dexterity = weights.at("dexterity").get<double>();
    po.weights.approach = weights.at("approach").get<double>();
    po.weights.triangulation = weights.at("triangulation").get<double>();
    po.weights.endoscope = weights.at("endoscope").get<double>();
    po.weights.spacing = weights.at("spacing").get<double>();
    po.weights.clearance_arm_arm = weights.at("clearance_arm_arm").get<double>();
    po.weights.clearance_arm_patient = weights.at("clearance_arm_patient").get<double>();
    po.weights.clearance_instrument_rib = weights.at("clearance_instrument_rib").get<double>();
    po.standoff = scoring.at("standoff_m").get<double>();
    po.rcm_depth = scoring.at("rcm_depth_m").get<double>();
    po.gap_search_depth = scoring.at("gap_search_depth_m").get<double>();
    po.ik_tolerance = scoring.at("ik_tolerance_m").get<double>();
    po.scope_half_fov = scoring.at("scope_half_fov_deg").get<double>() * M_PI / 180;
    po.scope_min_distance = scoring.at("scope_min_distance_m").get<double>();
    po.scope_max_distance = scoring.at("scope_max_distance_m").get<double>();
    po.scope_working_distance = scoring.at("scope_working_distance_m").get<double>();
    // Plans written before stop 54 judged the scope from its docking pose only.
    po.scope_moves = false;
    if (scoring.contains("scope_moves")) {
      TROCAR_THROW_UNLESS(scoring.at("scope_moves").is_boolean(),
                          o.plan << ": scoring.scope_moves: expected true or false, found "
                                 << scoring.at("scope_moves").dump());
      po.scope_moves = scoring.at("scope_moves").get<bool>();
    }
    po.samples_per_target = JsonInt(scoring.at("samples_per_target"), o.plan, "scoring.samples_per_target", 1, 100000);
    po.seed = static_cast<unsigned>(JsonInt(doc.at("algorithm").at("seed"), o.plan, "algorithm.seed", 0));
    suitable_fraction = scoring.at("suitable_fraction").get<double>();
    problem = std::make_unique<planners::PortPlacementProblem>(patient, robot, po);
    TROCAR_THROW_UNLESS(problem->samples().size() == doc.at("target_samples").size(),
                        o.plan << ": " << doc.at("target_samples").size()
                               << " target samples, the patient gives " << problem->samples().size());
    std::map<std::string, int> candidate;
    for (int c = 0; c < static_cast<int>(patient->port_candidates.size()); ++c)
      candidate[patient->port_candidates[c].name] = c;
    TROCAR_THROW_UNLESS(doc.at("plans").is_array() && !doc["plans"].empty(),
                        o.plan << ": plans: expected an array of at least one plan, found "
                               << doc["plans"].dump().substr(0, 40));
    int k = 0;
    for (const auto& p : doc.at("plans")) {
      ++k;
      planners::RankedPlan plan;
      const json& ports = p.at("ports");
      TROCAR_THROW_UNLESS(ports.size() == problem->arms().size(),
                          o.plan << ": plan " << k << " has " << ports.size() << " ports for "
                                 << problem->arms().size() << " arms");
      for (std::size_t a = 0; a < ports.size(); ++a) {
        const std::string name = ports[a].at("candidate").get<std::string>();
        TROCAR_THROW_UNLESS(candidate.count(name),
                            o.plan << ": plan " << k << ": port candidate '" << name
                                   << "' is not one of the patient's");
        plan.placement.sites.push_back(problem->Site(candidate[name], ports[a].at("s").get<double>()));
        TROCAR_THROW_UNLESS(
            (plan.placement.sites.back().p_W - Vec3(ports[a].at("p_W"))).norm() < 1e-4,
            o.plan << ": plan " << k << ": the port of " << ports[a].at("arm")
                   << " is not where its candidate curve puts it");
      }
      plan.placement.cart_x = p.at("cart").at("x").get<double>();
      plan.placement.cart_y = p.at("cart").at("y").get<double>();
      plan.placement.cart_yaw = p.at("cart").at("yaw_deg").get<double>() * M_PI / 180;
      plan.rank_score = p.at("rank_score").get<double>();
      // The plan as written: its status, its nominal pose (setup joints and active joints by
      // name), its coverage term and what its endoscope sees. Not scored again: the setup-joint
      // solver lands elsewhere for ports and cart differing in the file's last digits. A nominal
      // pose that is not valid makes every motion an "invalid start", named.
      planners::Evaluation& ev = plan.evaluation;
      const std::string status = p.at("status").get<std::string>();
      ev.status = status == planners::ToString(planners::PlacementStatus::kPlaced)
                      ? planners::PlacementStatus::kPlaced
                      : status == planners::ToString(planners::PlacementStatus::kInCollision)
                            ? planners::PlacementStatus::kInCollision
                            : planners::PlacementStatus::kUnreachable;
      ev.score = p.at("score").get<double>();
      robot::RobotState state(*robot);
      state.X_WB = plan.placement.X_WB();
      for (const auto& [name, value] : p.at("setup_joints").items()) {
        try {
          kinematics::SetHeldJoint(*robot, name, value.get<double>(), &state);
        } catch (const Error& e) {
          TROCAR_THROW(o.plan << ": plan " << k << ": setup joint '" << name << "': " << e.what());
        }
      }
      for (const auto& [name, value] : p.at("q_nominal").items()) {
        const int j = robot->FindJoint(name);
        TROCAR_THROW_UNLESS(j >= 0 && robot->joint(j).q_index >= 0,
                            o.plan << ": plan " << k << ": q_nominal names '" << name
                                   << "', not an active joint of " << robot->name());
        state.q[robot->joint(j).q_index] = value.get<double>();
      }
      TROCAR_THROW_UNLESS(state.q.allFinite(), o.plan << ": plan " << k << ": q_nominal is not finite");
      const auto fk = kinematics::ForwardKinematics(*robot, state.q, &state);
      TROCAR_THROW_UNLESS(fk.ok(), o.plan << ": plan " << k << ": nominal pose: " << fk.message);
      ev.q_nominal = state.q;
      ev.joint_values = state.joint_values;
      for (const auto& t : p.at("terms")) {
        planners::ScoreTerm term;
        term.name = t.at("name").get<std::string>();
        term.value = t.at("value").get<double>();
        term.score = t.at("score").get<double>();
        ev.terms.push_back(term);
      }
      for (const auto& r : p.at("samples")) {
        if (!r.contains("seen")) continue;
        planners::SampleReach reach;
        reach.sample = JsonInt(r.at("sample"), o.plan, "plans[].samples[].sample", 0);
        const std::string arm = r.at("arm").get<std::string>();
        for (std::size_t a = 0; a < problem->arms().size(); ++a) {
          if (problem->arms()[a].name == arm) reach.arm = static_cast<int>(a);
        }
        TROCAR_THROW_UNLESS(reach.arm >= 0 && reach.sample >= 0 &&
                                reach.sample < static_cast<int>(problem->samples().size()),
                            o.plan << ": plan " << k << ": a sample names arm '" << arm
                                   << "' or index " << reach.sample << " that the plan has not");
        reach.seen = reach.reached = r.at("seen").get<bool>();
        ev.reaches.push_back(reach);
      }
      plans.push_back(plan);
    }
  } catch (const json::exception& e) {
    TROCAR_THROW(o.plan << ": malformed plan (" << e.what() << ")");
  }
  std::vector<planners::PlanVerification> verifications;
  TerminalProgress bar(o.quiet);
  for (std::size_t k = 0; k < plans.size(); ++k) {
    verifications.push_back(planners::VerifyPlan(
        *problem, plans[k], o.motion, suitable_fraction, o.threads, [&](int done, int of) {
          bar.Update((k + static_cast<double>(done) / of) / plans.size(),
                     "verifying motions: plan " + std::to_string(k + 1) + " of " +
                         std::to_string(plans.size()) + ", " + std::to_string(done) + " of " +
                         std::to_string(of));
        }));
    bar.Clear();
    if (!o.quiet) {
      std::cout << "plan " << k + 1 << ":\n";
      PrintVerification(verifications.back(), std::cout);
    }
  }
  // Re-rank: plans by their verified rank score, the file's plans with them.
  const std::vector<std::size_t> order = planners::VerifiedOrder(verifications);
  json reordered = json::array();
  std::vector<planners::PlanVerification> ordered;
  std::vector<patient::Markup> markups;
  for (std::size_t r = 0; r < order.size(); ++r) {
    json p = doc["plans"][order[r]];
    p["rank_before_verification"] = p["rank"];
    p["rank"] = r + 1;
    ordered.push_back(verifications[order[r]]);
    patient::Markup m;
    m.name = "plan " + std::to_string(r + 1) + " ports";
    m.type = "Fiducial";
    for (const auto& port : p["ports"]) {
      m.points.push_back(Vec3(port.at("p_P")));
      m.labels.push_back(port.at("arm").get<std::string>());
    }
    markups.push_back(m);
    reordered.push_back(p);
  }
  doc["plans"] = reordered;
  const std::string text = planners::AddVerificationJson(doc.dump(), *problem, ordered);
  const std::string markups_path = JoinPath(ParentDirectory(o.plan), "ports.mrk.json");
  if (IsRegularFile(markups_path)) patient::WriteMarkups(markups, markups_path);
  WriteFileAtomically(o.plan, text);
  const bool suitable = !ordered.empty() && ordered.front().suitable;
  std::cout << "verified verdict: " << (suitable ? "suitable" : "not suitable") << "\n";
  if (!ordered.empty()) {
    for (const auto& r : ordered.front().reasons) std::cout << "  " << r << "\n";
  }
  std::cout << "written: " << o.plan << "\n";
  return suitable ? 0 : 4;
}

}  // namespace

void AddVerifyCommand(CLI::App* app) {
  auto o = std::make_shared<VerifyOptions>();
  CLI::App* cmd = app->add_subcommand(
      "verify",
      "Verify a plan by collision-free motions (OMPL) to every target sample; adds the verified "
      "motions, coverage and verdict to the plan file and re-ranks its plans");
  cmd->add_option("plan", o->plan, "plan.json written by trocar plan")->required();
  AddMotionOptions(cmd, &o->motion, &o->threads);
  cmd->add_flag("--quiet", o->quiet, "print only the verdict");
  cmd->footer(
      "Exit status: 0 the best plan serves the patient by verified motions; 4 it does not; 1 bad "
      "input; 2 internal error.");
  cmd->callback([o]() {
    const int code = RunVerify(*o);
    if (code != 0) throw CLI::RuntimeError(code);
  });
}

}  // namespace trocar::apps
