// trocar verify PLAN.json: verified motions (OMPL, collision world) for every ranked plan of a
// plan file, the verified coverage, the plans re-ranked with it and a verified verdict, written
// back into the plan (atomically).
#include <algorithm>
#include <cmath>
#include <iomanip>
#include <iostream>
#include <map>
#include <memory>
#include <numeric>

#include "apps/trocar/commands.hpp"
#include "apps/trocar/progress.hpp"
#include "common/error.hpp"
#include "common/file_util.hpp"
#include "motion/verify.hpp"
#include "patient/markups.hpp"
#include "patient/patient_model.hpp"
#include "plan/plan_file.hpp"
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

struct VerifyOptions {
  std::string plan;
  planners::MotionOptions motion;
  int threads = 0;
  bool quiet = false;
};

int RunVerify(const VerifyOptions& o) {
  WithFlags(MotionFlags(), [&] { planners::ValidateMotionOptions(o.motion); });
  // The typed reader (every field checked, the cart's one pose), before anything is rebuilt or
  // rewritten; the plan is rewritten through its one writer.
  planners::PlanFile file = planners::ReadPlanFile(o.plan);
  // The inputs, and whether they still fit by the one shared check.
  const std::string robot_mismatch = planners::RobotFileMismatch(file);
  TROCAR_THROW_UNLESS(robot_mismatch.empty(), o.plan << ": " << robot_mismatch << ": plan again");
  auto robot = std::make_shared<const robot::RobotModel>(robot::LoadRobot(file.robot_file));
  std::shared_ptr<const patient::PatientModel> patient = patient::ImportCase(file.case_dir).model;
  const std::string patient_mismatch =
      planners::PatientModelMismatch(file, *patient, file.case_dir);
  TROCAR_THROW_UNLESS(patient_mismatch.empty(),
                      o.plan << ": " << patient_mismatch << ": plan again");
  // The problem as the plan was scored, and its plans as written.
  const planners::PortPlacementProblem problem(patient, robot, planners::PlanProblemOptions(file));
  TROCAR_THROW_UNLESS(problem.samples().size() == file.samples.size(),
                      o.plan << ": " << file.samples.size() << " target samples, the patient gives "
                             << problem.samples().size());
  std::vector<planners::RankedPlan> plans;
  for (std::size_t k = 0; k < file.plans.size(); ++k)
    plans.push_back(planners::RestorePlan(problem, file, k));
  const double suitable_fraction = file.scoring.suitable_fraction;
  std::vector<planners::PlanVerification> verifications;
  TerminalProgress bar(o.quiet);
  for (std::size_t k = 0; k < plans.size(); ++k) {
    verifications.push_back(planners::VerifyPlan(
        problem, plans[k], o.motion, suitable_fraction, o.threads, [&](int done, int of) {
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
  std::vector<planners::StoredPlan> reordered;
  std::vector<planners::PlanVerification> ordered;
  std::vector<patient::Markup> markups;
  for (std::size_t r = 0; r < order.size(); ++r) {
    planners::StoredPlan p = file.plans[order[r]];
    p.rank_before_verification = p.rank;
    p.rank = static_cast<int>(r) + 1;
    ordered.push_back(verifications[order[r]]);
    patient::Markup m;
    m.name = "plan " + std::to_string(r + 1) + " ports";
    m.type = "Fiducial";
    for (const auto& port : p.ports) {
      m.points.push_back(port.p_P);
      m.labels.push_back(port.arm);
    }
    markups.push_back(m);
    reordered.push_back(std::move(p));
  }
  file.plans = std::move(reordered);
  planners::AddVerification(&file, problem, ordered);
  const std::string markups_path = JoinPath(ParentDirectory(o.plan), "ports.mrk.json");
  if (IsRegularFile(markups_path)) patient::WriteMarkups(markups, markups_path);
  planners::WritePlanFile(o.plan, file);
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
