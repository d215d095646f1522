// trocar plan: optimal ports and cart pose per patient; ranked plans with reasons and a verdict.
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <memory>
#include <sstream>

#include "apps/trocar/commands.hpp"
#include "common/error.hpp"
#include "common/file_util.hpp"
#include "patient/patient_model.hpp"
#include "port_placement/optimizer.hpp"
#include "port_placement/plan_config.hpp"
#include "port_placement/plan_io.hpp"
#include "robot/load_robot.hpp"

namespace trocar::apps {
namespace {

struct PlanOptions {
  std::string case_dir;
  std::string out;
  std::string robot;
  std::vector<std::string> arms;
  std::vector<std::string> roles;
  planners::PortPlacementOptions optimizer;
  int samples = 0;
  bool no_robustness = false;
  bool no_verify = false;
  planners::MotionOptions motion;
  int motion_threads = 0;
  bool quiet = false;
};

std::string DefaultRobot() {
  std::string file = "robots/davinci-classic/cart.yaml";
  if (!IsRegularFile(file)) file = std::string(TROCAR_SOURCE_DIR) + "/" + file;
  return file;
}

int RunPlan(PlanOptions o) {
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  // Everything the command line says is checked before any work.
  planners::ValidateOptions(o.optimizer);
  if (!o.no_verify) planners::ValidateMotionOptions(o.motion);
  TROCAR_THROW_UNLESS(!o.out.empty(), "--out: an output folder is required");
  TROCAR_THROW_UNLESS(std::filesystem::is_directory(o.case_dir),
                      o.case_dir << ": not a case folder (expected a folder with patient.yaml)");
  if (o.robot.empty()) o.robot = DefaultRobot();
  TROCAR_THROW_UNLESS(IsRegularFile(o.robot), "--robot: " << o.robot << ": no such file");
  planners::ProblemOptions problem_options;
  planners::ReadPlanConfig(o.case_dir, &problem_options);
  if (!o.arms.empty()) problem_options.arms = o.arms;
  for (const auto& r : o.roles) problem_options.roles.push_back(r);
  if (o.samples > 0) problem_options.samples_per_target = o.samples;
  problem_options.seed = o.optimizer.seed;
  if (o.no_robustness) o.optimizer.robustness_shift = 0.0;
  auto robot = std::make_shared<const robot::RobotModel>(robot::LoadRobot(o.robot));
  // Arms and roles checked against the robot before the patient is imported.
  {
    auto arms = planners::FindArms(*robot, problem_options.roles);
    if (!problem_options.arms.empty()) planners::SelectArms(arms, problem_options.arms);
  }
  const patient::ImportedPatient imported = patient::ImportCase(o.case_dir);
  const std::shared_ptr<const patient::PatientModel> patient = imported.model;
  const planners::PortPlacementProblem problem(patient, robot, problem_options);
  const bool terminal = !o.quiet && isatty(STDERR_FILENO);
  if (!o.quiet) {
    std::cout << "planned in " << patient->operation.Describe() << "\n";
    std::cout << "patient " << patient->name << (imported.report.from_cache ? " (cached model)" : "")
              << ": " << patient->targets.size() << " targets, " << problem.samples().size()
              << " target samples, " << patient->port_candidates.size()
              << " port candidate curves\n";
    std::cout << "robot " << robot->name() << ": arms";
    for (const auto& a : problem.arms())
      std::cout << " " << a.name << " (" << planners::ToString(a.role) << ")";
    std::cout << "\noptimiser: " << o.optimizer.algorithm << " then " << o.optimizer.local << ", "
              << o.optimizer.evaluations << " evaluations in " << o.optimizer.starts
              << " starts, seed " << o.optimizer.seed << "\n"
              << std::flush;
  }
  if (terminal) {
    o.optimizer.progress = [](double f, const std::string& stage) {
      const int width = 30, filled = static_cast<int>(f * width);
      std::cerr << "\r[" << std::string(filled, '#') << std::string(width - filled, ' ') << "] "
                << std::setw(3) << static_cast<int>(f * 100) << "% " << stage << "          "
                << std::flush;
    };
  }
  planners::PortPlacementResult result = planners::OptimizePorts(problem, o.optimizer);
  // Verified motions for every ranked plan (unless --no-verify), then the plans re-ranked with
  // the verified coverage in place of the claimed one.
  std::vector<planners::PlanVerification> verifications;
  if (!o.no_verify) {
    for (std::size_t k = 0; k < result.plans.size(); ++k) {
      if (o.optimizer.progress) o.optimizer.progress(static_cast<double>(k) / result.plans.size(), "verifying motions");
      verifications.push_back(planners::VerifyPlan(problem, result.plans[k], o.motion,
                                                   o.optimizer.suitable_fraction,
                                                   o.motion_threads));
    }
    planners::RankByVerification(&result, &verifications);
  }
  if (terminal) std::cerr << "\r" << std::string(70, ' ') << "\r" << std::flush;

  planners::PlanInputs inputs;
  inputs.case_dir = o.case_dir;
  inputs.robot_file = o.robot;
  inputs.case_hash = planners::HashFile(JoinPath(o.case_dir, "patient.yaml"));
  inputs.robot_hash = planners::HashFile(o.robot);
  inputs.model_hash = planners::HashPatientModel(*patient);
  planners::WritePlanFolder(o.out, problem, result, o.optimizer, inputs,
                            [&](const std::string& text) {
                              return verifications.empty()
                                         ? text
                                         : planners::AddVerificationJson(text, problem,
                                                                         verifications);
                            });

  std::cout << std::fixed;
  // What the robustness score is the mean over (optimizer.cpp): the heart over its operative range,
  // or, in the CT's state, the targets moved along each axis.
  std::string robustness = "not re-scored";
  if (o.optimizer.robustness_shift > 0) {
    std::ostringstream r;
    const patient::OperativeState& op = patient->operation;
    if (op.moves()) {
      r << std::fixed << std::setprecision(1) << "heart " << op.heart_shift_min * 1e3 << "-"
        << op.heart_shift_max * 1e3 << " mm";
    } else {
      r << std::fixed << std::setprecision(0) << "targets moved " << o.optimizer.robustness_shift * 1e3 << " mm";
    }
    robustness = r.str();
  }
  for (std::size_t k = 0; k < result.plans.size(); ++k) {
    const auto& plan = result.plans[k];
    const auto& ev = plan.evaluation;
    std::cout << "\nplan " << k + 1 << ": score " << std::setprecision(3) << ev.score << " (rank "
              << plan.rank_score << ", " << robustness << ": " << plan.robust_score << "), "
              << planners::ToString(ev.status) << "\n";
    for (std::size_t a = 0; a < plan.placement.sites.size(); ++a) {
      const auto& site = plan.placement.sites[a];
      const Eigen::Vector3d p = site.p_P * 1e3;
      std::cout << "  " << std::left << std::setw(6) << problem.arms()[a].name << std::right
                << " port on " << patient->port_candidates[site.candidate].name << " at "
                << std::setprecision(0) << site.s * 100 << " % (LPS mm " << p.x() << ", " << p.y()
                << ", " << p.z() << ")\n";
    }
    std::cout << "  cart at (" << std::setprecision(2) << plan.placement.cart_x << ", "
              << plan.placement.cart_y << ") m, heading " << std::setprecision(0)
              << plan.placement.cart_yaw * 180 / M_PI << " deg\n";
    for (const auto& t : ev.terms) {
      std::cout << "    " << std::left << std::setw(26) << t.name << std::right
                << std::setprecision(3) << std::setw(8) << t.value << " " << std::left
                << std::setw(9) << t.unit << std::right << " score " << t.score << "  x "
                << std::setprecision(2) << t.weight << "\n";
    }
    if (k < verifications.size()) PrintVerification(verifications[k], std::cout);
  }
  std::cout << "\nverdict: " << result.verdict.summary << "\n";
  for (const auto& r : result.verdict.reasons) std::cout << "  " << r << "\n";
  bool suitable = result.verdict.suitable;
  if (!verifications.empty()) {
    // The verdict that counts is the one from verified motions.
    suitable = verifications.front().suitable;
    std::cout << "verified verdict: " << (suitable ? "suitable" : "not suitable")
              << " (plan 1: " << std::setprecision(0)
              << verifications.front().verified_coverage * 100
              << " % of instrument motions verified)\n";
    for (const auto& r : verifications.front().reasons) std::cout << "  " << r << "\n";
  }
  std::cout << std::setprecision(1) << "evaluations: " << result.evaluations << " in "
            << std::chrono::duration<double>(Clock::now() - t0).count() << " s on "
            << result.threads << " thread" << (result.threads == 1 ? "" : "s")
            << (result.time_limit_hit ? " (time limit reached)" : "") << "\n";
  std::cout << "written: " << JoinPath(o.out, "plan.json") << ", "
            << JoinPath(o.out, "ports.mrk.json") << "\n";
  return suitable ? 0 : 4;
}

}  // namespace

void AddPlanCommand(CLI::App* app) {
  auto o = std::make_shared<PlanOptions>();
  CLI::App* cmd = app->add_subcommand("plan",
                                      "Choose ports and the cart's pose for a patient: ranked "
                                      "plans with score breakdowns and a verdict");
  cmd->add_option("case", o->case_dir, "patient case folder (patients/<case>)")->required();
  cmd->add_option("--out", o->out, "output folder: plan.json and ports.mrk.json (3D Slicer)")
      ->required();
  cmd->add_option("--robot", o->robot,
                  "robot description (default: robots/davinci-classic/cart.yaml)");
  cmd->add_option("--algorithm", o->optimizer.algorithm,
                  "global stage: direct-l, crs2-lm, isres, mlsl or exhaustive")
      ->capture_default_str();
  cmd->add_option("--local", o->optimizer.local, "local polish: bobyqa, subplex, cobyla or none")
      ->capture_default_str();
  cmd->add_option("--time-limit", o->optimizer.time_limit, "wall-clock cap in seconds")
      ->capture_default_str();
  cmd->add_option("--evaluations", o->optimizer.evaluations, "evaluations of the global stage")
      ->capture_default_str();
  cmd->add_option("--starts", o->optimizer.starts, "independent starts of the global stage")
      ->capture_default_str();
  cmd->add_option("--polish-evaluations", o->optimizer.polish_evaluations,
                  "evaluations of each local polish")
      ->capture_default_str();
  cmd->add_option("--threads", o->optimizer.threads,
                  "OpenMP threads (0: all cores); results do not depend on it")
      ->capture_default_str();
  cmd->add_option("--seed", o->optimizer.seed, "seed: the same seed gives the same plans")
      ->capture_default_str();
  cmd->add_option("--top", o->optimizer.top_k, "distinct plans to return")->capture_default_str();
  cmd->add_option("--arms", o->arms,
                  "arms to place (names or RCM frames; default: the case's plan.arms, else all)");
  cmd->add_option("--role", o->roles,
                  "NAME=instrument|endoscope: an arm's role (default: from its frames)");
  cmd->add_option("--samples", o->samples,
                  "target samples per target (default: the case's, else 8)");
  cmd->add_flag("--no-robustness", o->no_robustness, "skip re-scoring with the targets moved");
  cmd->add_flag("--no-verify", o->no_verify,
                "skip the verified motions (OMPL) to every target sample of each plan");
  AddMotionOptions(cmd, &o->motion, &o->motion_threads);
  cmd->add_flag("--quiet", o->quiet, "print only the verdict");
  cmd->footer(
      "Exit status: 0 a plan serves the patient (by verified motions, unless --no-verify); 4 no "
      "plan serves the patient (plans and verdict are written); "
      "1 bad input; 2 internal error.");
  cmd->callback([o]() {
    const int code = RunPlan(*o);
    if (code != 0) throw CLI::RuntimeError(code);
  });
}

}  // namespace trocar::apps
