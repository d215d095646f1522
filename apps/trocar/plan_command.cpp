// trocar plan: optimal ports and cart pose per patient; ranked plans with reasons and a verdict.
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <memory>
#include <optional>
#include <sstream>

#include "apps/trocar/commands.hpp"
#include "apps/trocar/progress.hpp"
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
  bool no_remedies = false;
  bool no_verify = false;
  planners::MotionOptions motion;
  int motion_threads = 0;
  bool quiet = false;
  /// "optimise", "template" or a ports file (.mrk.json): where the plans' ports come from.
  std::string ports = "optimise";
  /// Beside optimised plans: "template", a ports file, or "none".
  std::string baseline = "template";
};

// The template or a surgeon's ports file placed on the patient (fixed_ports.hpp).
std::vector<planners::FixedPorts> GivenPorts(const planners::PortPlacementProblem& problem,
                                             const std::string& what) {
  if (what == "template") return planners::PlaceTemplate(problem, planners::TecabTemplate());
  return {planners::ReadPortsFile(problem, what)};
}

std::string DefaultRobot() {
  std::string file = "robots/davinci-classic/cart.yaml";
  if (!IsRegularFile(file)) file = std::string(TROCAR_SOURCE_DIR) + "/" + file;
  return file;
}

int RunPlan(PlanOptions o) {
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  // Everything the command line says is checked before any work.
  WithFlags({{"top_k", "--top"}}, [&] { planners::ValidateOptions(o.optimizer); });
  if (!o.no_verify) WithFlags(MotionFlags(), [&] { planners::ValidateMotionOptions(o.motion); });
  TROCAR_THROW_UNLESS(!o.out.empty(), "--out: an output folder is required");
  TROCAR_THROW_UNLESS(std::filesystem::is_directory(o.case_dir),
                      o.case_dir << ": not a case folder (expected a folder with patient.yaml)");
  if (o.robot.empty()) o.robot = DefaultRobot();
  TROCAR_THROW_UNLESS(IsRegularFile(o.robot), "--robot: " << o.robot << ": no such file");
  TROCAR_THROW_UNLESS(o.ports == "optimise" || o.ports == "template" || IsRegularFile(o.ports),
                      "--ports: '" << o.ports
                                   << "' is neither 'optimise', 'template' nor a ports file "
                                      "(3D Slicer point list .mrk.json) that exists");
  TROCAR_THROW_UNLESS(o.baseline == "none" || o.baseline == "template" || IsRegularFile(o.baseline),
                      "--baseline: '" << o.baseline
                                      << "' is neither 'template', 'none' nor a ports file "
                                         "(3D Slicer point list .mrk.json) that exists");
  planners::ProblemOptions problem_options;
  planners::ReadPlanConfig(o.case_dir, &problem_options);
  if (!o.arms.empty()) problem_options.arms = o.arms;
  for (const auto& r : o.roles) problem_options.roles.push_back(r);
  if (o.samples > 0) problem_options.samples_per_target = o.samples;
  problem_options.seed = o.optimizer.seed;
  if (o.no_robustness) o.optimizer.robustness_shift = 0.0;
  // The verdict says what would reach each unserved stretch (about 10 evaluations a stretch).
  o.optimizer.remedies = !o.no_remedies;
  auto robot = std::make_shared<const robot::RobotModel>(robot::LoadRobot(o.robot));
  // Arms and roles checked against the robot before the patient is imported.
  {
    auto arms = planners::FindArms(*robot, problem_options.roles);
    if (!problem_options.arms.empty()) planners::SelectArms(arms, problem_options.arms);
  }
  TerminalProgress bar(o.quiet);
  patient::ImportOptions import_options;
  import_options.progress = [&bar](const std::string& stage) { bar.Update(-1.0, "importing: " + stage); };
  const patient::ImportedPatient imported = patient::ImportCase(o.case_dir, import_options);
  bar.Clear();
  const std::shared_ptr<const patient::PatientModel> patient = imported.model;
  const planners::PortPlacementProblem problem(patient, robot, problem_options);
  if (!o.quiet) {
    std::cout << "planned in " << patient->operation.Describe() << "\n";
    std::cout << "patient " << patient->name << (imported.report.from_cache ? " (cached model)" : "")
              << ": " << patient->targets.size() << " targets, " << problem.samples().size()
              << " target samples, " << patient->port_candidates.size()
              << " port candidate curves\n";
    // What the import could not find matters to the plan (a missing sternum moves the midline
    // and the LIMA; issue #42 item 3): said before planning, cached loads included.
    for (const auto& w : imported.report.warnings) std::cout << "  warning: " << w << "\n";
    std::cout << "robot " << robot->name() << ": arms";
    for (const auto& a : problem.arms())
      std::cout << " " << a.name << " (" << planners::ToString(a.role) << ")";
    std::cout << "\noptimiser: " << o.optimizer.algorithm << " then " << o.optimizer.local << ", "
              << o.optimizer.evaluations << " evaluations in " << o.optimizer.starts
              << " starts, seed " << o.optimizer.seed << "\n"
              << std::flush;
  }
  // The command's share of time, roughly: the baseline's cart 10 %, the search to 80 %, the
  // verified motions the rest (the search to 100 % without them).
  const double search_end = o.no_verify ? 1.0 : 0.8;
  auto span = [&bar](double lo, double hi, const std::string& prefix) {
    return std::function<void(double, const std::string&)>(
        [&bar, lo, hi, prefix](double f, const std::string& stage) {
          bar.Update(lo + (hi - lo) * f, prefix + stage);
        });
  };
  if (bar.enabled()) o.optimizer.progress = span(0.0, 0.1, "the baseline's cart: ");
  // The plans: the optimiser's, or the ports given (placed before any search: a template that
  // cannot be placed or a bad ports file is an error, nothing written).
  const std::vector<planners::FixedPorts> given =
      o.ports == "optimise" ? std::vector<planners::FixedPorts>{} : GivenPorts(problem, o.ports);
  // A surgeon's ports file as the baseline is read before the search too (its errors are the
  // user's); the template, when it cannot be placed, says why in the plan file instead.
  std::vector<planners::FixedPorts> baseline_ports;
  std::string baseline_why_not;
  if (given.empty() && o.baseline != "none") {
    try {
      baseline_ports = GivenPorts(problem, o.baseline);
    } catch (const Error& e) {
      if (o.baseline != "template") throw;
      baseline_why_not = e.what();
    }
  }
  // Beside optimised plans, the baseline a surgeon would compare them with: the template placed
  // on this patient (when its spaces are named: otherwise why not, in the plan file), or the
  // surgeon's own ports.
  // Placed before the search, which starts from it (PortPlacementOptions::initial): the best
  // plan then scores at least as well as what a surgeon would have done.
  std::vector<planners::Baseline> baselines;
  if (given.empty() && o.baseline != "none") {
    planners::Baseline b;
    b.kind = o.baseline == "template" ? "template" : "surgeon";
    b.name = o.baseline == "template" ? planners::TecabTemplate().title : o.baseline;
    if (baseline_ports.empty()) {
      b.why_not = baseline_why_not;
    } else {
      b.fixed = planners::PlanFixedPorts(problem, baseline_ports, o.optimizer);
      b.placed = true;
      o.optimizer.initial.push_back(b.fixed.plan.placement);
    }
    baselines.push_back(std::move(b));
  }
  planners::PortPlacementResult result;
  if (bar.enabled()) o.optimizer.progress = span(given.empty() ? 0.1 : 0.0, search_end, "");
  if (given.empty()) {
    result = planners::OptimizePorts(problem, o.optimizer);
  } else {
    planners::FixedPortsPlan f = planners::PlanFixedPorts(problem, given, o.optimizer);
    result.algorithm = "fixed ports";
    result.local = o.optimizer.local;
    result.evaluations = result.global_evaluations = f.evaluations;
    result.best_global_score = f.plan.evaluation.score;
    result.threads = f.threads;
    result.grid = f.search;
    result.ports_given = f.ports.kind + ": " + f.ports.name;
    result.ports_where = f.ports.where;
    result.verdict = f.verdict;
    result.plans.push_back(std::move(f.plan));
    for (const auto& n : f.ports.notes) std::cout << "note: " << n << "\n";
  }
  for (auto& b : baselines) {
    if (b.placed) result.evaluations += b.fixed.evaluations;
    result.baselines.push_back(std::move(b));
  }
  // Verified motions for every ranked plan (unless --no-verify), then the plans re-ranked with
  // the verified coverage in place of the claimed one.
  std::vector<planners::PlanVerification> verifications;
  if (!o.no_verify) {
    for (std::size_t k = 0; k < result.plans.size(); ++k) {
      const double n = static_cast<double>(result.plans.size());
      verifications.push_back(planners::VerifyPlan(
          problem, result.plans[k], o.motion, o.optimizer.suitable_fraction, o.motion_threads,
          [&](int done, int of) {
            bar.Update(0.8 + 0.19 * (k + static_cast<double>(done) / of) / n,
                       "verifying motions: plan " + std::to_string(k + 1) + ", " +
                           std::to_string(done) + " of " + std::to_string(of));
          }));
    }
    planners::RankByVerification(&result, &verifications);
  }
  std::vector<planners::PlanVerification> baseline_verifications;
  if (!o.no_verify) {
    for (const auto& b : result.baselines) {
      if (!b.placed) continue;
      baseline_verifications.push_back(planners::VerifyPlan(
          problem, b.fixed.plan, o.motion, o.optimizer.suitable_fraction, o.motion_threads,
          [&](int done, int of) {
            bar.Update(0.99, "verifying motions: the baseline, " + std::to_string(done) + " of " +
                                 std::to_string(of));
          }));
    }
  }
  bar.Clear();
  // The anatomical selection criteria, on the CT (as published), at the best plan's camera port,
  // compared with the verdict that counts (the verified one unless --no-verify).
  {
    const patient::PatientModel& ct = imported.ct_model ? *imported.ct_model : *patient;
    std::optional<Eigen::Vector3d> camera_P;
    if (!result.plans.empty()) {
      for (std::size_t a = 0; a < problem.arms().size(); ++a) {
        if (problem.arms()[a].role == planners::ArmRole::kEndoscope) {
          camera_P = patient->X_WP.inverse() * result.plans.front().placement.sites[a].p_rcm_W;
          break;
        }
      }
    }
    result.criteria = planners::MeasureSelectionCriteria(ct, camera_P ? &*camera_P : nullptr);
    const bool counts = verifications.empty() ? result.verdict.suitable : verifications.front().suitable;
    result.criteria_comparison = result.criteria.Compare(counts);
  }

  planners::PlanInputs inputs;
  inputs.case_dir = o.case_dir;
  inputs.robot_file = o.robot;
  inputs.case_hash = planners::HashFile(JoinPath(o.case_dir, "patient.yaml"));
  inputs.robot_hash = planners::HashFile(o.robot);
  inputs.model_hash = planners::HashPatientModel(*patient);
  planners::WritePlanFolder(o.out, problem, result, o.optimizer, inputs,
                            [&](planners::PlanFile* file) {
                              if (!verifications.empty())
                                planners::AddVerification(file, problem, verifications,
                                                          baseline_verifications);
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
  auto print_plan = [&](const std::string& title, const planners::RankedPlan& plan,
                        const planners::PlanVerification* verification) {
    const auto& ev = plan.evaluation;
    std::cout << "\n" << title << ": score " << std::setprecision(3) << ev.score << " (rank "
              << plan.rank_score << ", " << robustness << ": " << plan.robust_score << "), "
              << planners::ToString(ev.status) << "\n";
    for (std::size_t a = 0; a < plan.placement.sites.size(); ++a) {
      const auto& site = plan.placement.sites[a];
      const Eigen::Vector3d p = site.p_P * 1e3;
      std::cout << "  " << std::left << std::setw(6) << problem.arms()[a].name << std::right
                << " port on " << planners::DescribePort(*patient, site) << std::setprecision(0)
                << "; LPS mm " << p.x() << ", " << p.y() << ", " << p.z() << "\n";
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
    if (verification) PrintVerification(*verification, std::cout);
  };
  if (!result.ports_given.empty()) {
    std::cout << "\nports given: " << result.ports_given << "\n";
    for (std::size_t a = 0; a < result.ports_where.size(); ++a)
      std::cout << "  " << std::left << std::setw(6) << problem.arms()[a].name << std::right << " "
                << result.ports_where[a] << "\n";
  }
  for (std::size_t k = 0; k < result.plans.size(); ++k)
    print_plan("plan " + std::to_string(k + 1), result.plans[k],
               k < verifications.size() ? &verifications[k] : nullptr);
  std::size_t next_baseline = 0;
  for (const auto& b : result.baselines) {
    if (!b.placed) {
      std::cout << "\nbaseline (" << b.kind << "): not placed: " << b.why_not << "\n";
      continue;
    }
    const planners::PlanVerification* v = next_baseline < baseline_verifications.size()
                                              ? &baseline_verifications[next_baseline++]
                                              : nullptr;
    std::cout << "\nbaseline: " << b.name << "\n";
    for (std::size_t a = 0; a < b.fixed.ports.where.size(); ++a)
      std::cout << "  " << std::left << std::setw(6) << problem.arms()[a].name << std::right << " "
                << b.fixed.ports.where[a] << "\n";
    for (const auto& n : b.fixed.ports.notes) std::cout << "  note: " << n << "\n";
    print_plan("baseline " + b.kind, b.fixed.plan, v);
    if (!result.plans.empty()) {
      const auto& best = result.plans.front();
      std::cout << "  plan 1 against the " << b.kind << ": score " << std::setprecision(3)
                << best.evaluation.score << " vs " << b.fixed.plan.evaluation.score;
      if (v && !verifications.empty())
        std::cout << std::setprecision(0) << ", verified motions "
                  << verifications.front().verified_coverage * 100 << " % vs "
                  << v->verified_coverage * 100 << " %, samples served "
                  << verifications.front().served_fraction * 100 << " % vs "
                  << v->served_fraction * 100 << " %";
      std::cout << "\n";
    }
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
  std::cout << "anatomical criteria (on the CT; docs/selection-criteria.md):\n";
  for (const auto& c : result.criteria.criteria) {
    std::cout << "  " << std::left << std::setw(44) << c.title << std::right;
    if (c.measured()) {
      std::cout << std::setprecision(0) << std::setw(5) << c.value << " " << std::left << std::setw(3)
                << c.unit << std::right << " (" << (c.at_least ? ">= " : "<= ") << c.threshold
                << " " << c.unit << ": " << (c.favourable() ? "favourable" : "against") << ")\n";
    } else {
      std::cout << "  " << c.how << "\n";
    }
  }
  std::cout << "  " << result.criteria_comparison << "\n";
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
  cmd->add_option("--ports", o->ports,
                  "where the ports come from: optimise (the default), template (the published "
                  "robotic TECAB template placed on this patient: docs/port-templates.md) or a "
                  "3D Slicer point list FILE.mrk.json with one point per arm labelled with its "
                  "name; given ports keep their place, the cart is searched for them")
      ->capture_default_str();
  cmd->add_option("--baseline", o->baseline,
                  "beside optimised plans: template, a ports FILE.mrk.json, or none; scored and "
                  "verified as the plans are, in the plan file's baselines")
      ->capture_default_str();
  cmd->add_flag("--no-robustness", o->no_robustness, "skip re-scoring with the targets moved");
  cmd->add_flag("--no-remedies", o->no_remedies,
                "do not search for the port or cart change that would reach each unserved stretch");
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
