// trocar plan: optimal ports and cart pose per patient; ranked plans with reasons and a verdict.
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <functional>
#include <iomanip>
#include <iostream>
#include <memory>
#include <optional>
#include <sstream>
#include <utility>

#include "apps/trocar/commands.hpp"
#include "apps/trocar/progress.hpp"
#include "common/error.hpp"
#include "common/file_util.hpp"
#include "patient/patient_model.hpp"
#include "plan/reachability.hpp"
#include "port_placement/fixed_ports.hpp"
#include "port_placement/optimizer.hpp"
#include "port_placement/plan_config.hpp"
#include "port_placement/plan_io.hpp"
#include "robot/load_robot.hpp"

namespace trocar::apps {
namespace {

// --table-height: "fixed" (the case's table, not searched) or "LOWEST,HIGHEST" in m.
void SetTableHeights(const std::string& text, planners::ProblemOptions* options) {
  if (text == "fixed") {
    options->table_height_min = options->table_height_max = std::nan("");
    return;
  }
  const std::size_t comma = text.find(',');
  double lo = NAN, hi = NAN;
  try {
    std::size_t used_lo = 0, used_hi = 0;
    if (comma != std::string::npos) {
      lo = std::stod(text.substr(0, comma), &used_lo);
      hi = std::stod(text.substr(comma + 1), &used_hi);
    }
    if (used_lo != comma || used_hi != text.size() - comma - 1) lo = hi = NAN;
  } catch (const std::exception&) {
    lo = hi = NAN;
  }
  TROCAR_THROW_UNLESS(lo >= 0.3 && lo <= hi && hi <= 1.5,
                      "--table-height: '" << text
                                          << "', expected fixed or LOWEST,HIGHEST in m with 0.3 <= "
                                             "LOWEST <= HIGHEST <= 1.5 (e.g. 0.79,1.04)");
  options->table_height_min = lo;
  options->table_height_max = hi;
}

struct PlanOptions {
  std::string case_dir;
  std::string out;
  std::string robot;
  std::vector<std::string> arms;
  std::vector<std::string> roles;
  planners::PortPlacementOptions optimizer;
  int samples = 0;
  /// --table-height: "fixed" or "LOWEST,HIGHEST" (m); empty: the case's plan.table_height.
  std::string table_height;
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

// `trocar plan` as stages: the options checked, the inputs loaded (robot, patient, problem), the
// baseline placed, the search (or the given ports placed), the verified motions, the anatomical
// criteria, the plan folder written, the report printed.
class PlanCommand {
 public:
  explicit PlanCommand(PlanOptions o) : o_(std::move(o)), t0_(Clock::now()), bar_(o_.quiet) {}

  int Run() {
    const planners::ProblemOptions problem_options = CheckOptions();
    LoadInputs(problem_options);
    PrintHeader();
    PlaceBaseline();
    Search();
    Verify();
    MeasureCriteria();
    Write();
    return Report();
  }

 private:
  /// Plan 1's reachability on the targets, from the plan file as written.
  std::optional<planners::Reachability> reach_;
  using Clock = std::chrono::steady_clock;

  // Everything the command line says is checked before any work; the problem's options.
  planners::ProblemOptions CheckOptions() {
    WithFlags({{"top_k", "--top"}}, [&] { planners::ValidateOptions(o_.optimizer); });
    if (!o_.no_verify)
      WithFlags(MotionFlags(), [&] { planners::ValidateMotionOptions(o_.motion); });
    TROCAR_THROW_UNLESS(!o_.out.empty(), "--out: an output folder is required");
    TROCAR_THROW_UNLESS(std::filesystem::is_directory(o_.case_dir),
                        o_.case_dir << ": not a case folder (expected a folder with patient.yaml)");
    if (o_.robot.empty()) o_.robot = DefaultRobot();
    TROCAR_THROW_UNLESS(IsRegularFile(o_.robot), "--robot: " << o_.robot << ": no such file");
    TROCAR_THROW_UNLESS(o_.ports == "optimise" || o_.ports == "template" || IsRegularFile(o_.ports),
                        "--ports: '" << o_.ports
                                     << "' is neither 'optimise', 'template' nor a ports file "
                                        "(3D Slicer point list .mrk.json) that exists");
    TROCAR_THROW_UNLESS(
        o_.baseline == "none" || o_.baseline == "template" || IsRegularFile(o_.baseline),
        "--baseline: '" << o_.baseline
                        << "' is neither 'template', 'none' nor a ports file "
                           "(3D Slicer point list .mrk.json) that exists");
    planners::ProblemOptions problem_options;
    planners::ReadPlanConfig(o_.case_dir, &problem_options);
    if (!o_.arms.empty()) problem_options.arms = o_.arms;
    for (const auto& r : o_.roles) problem_options.roles.push_back(r);
    if (o_.samples > 0) problem_options.samples_per_target = o_.samples;
    if (!o_.table_height.empty()) SetTableHeights(o_.table_height, &problem_options);
    problem_options.seed = o_.optimizer.seed;
    if (o_.no_robustness) o_.optimizer.robustness_shift = 0.0;
    // The verdict says what would reach each unserved stretch (about 10 evaluations a stretch).
    o_.optimizer.remedies = !o_.no_remedies;
    return problem_options;
  }

  // The robot (its arms and roles checked before the patient is imported), the patient, the
  // problem.
  void LoadInputs(const planners::ProblemOptions& problem_options) {
    robot_ = std::make_shared<const robot::RobotModel>(robot::LoadRobot(o_.robot));
    {
      auto arms = planners::FindArms(*robot_, problem_options.roles);
      if (!problem_options.arms.empty()) planners::SelectArms(arms, problem_options.arms);
    }
    patient::ImportOptions import_options;
    import_options.progress = [this](const std::string& stage) {
      bar_.Update(-1.0, "importing: " + stage);
    };
    imported_ = patient::ImportCase(o_.case_dir, import_options);
    bar_.Clear();
    patient_ = imported_.model;
    problem_ =
        std::make_unique<const planners::PortPlacementProblem>(patient_, robot_, problem_options);
  }

  void PrintHeader() const {
    if (o_.quiet) return;
    const planners::PortPlacementProblem& problem = *problem_;
    std::cout << "planned in " << patient_->operation.Describe() << "\n";
    std::cout << "patient " << patient_->name
              << (imported_.report.from_cache ? " (cached model)" : "") << ": "
              << patient_->targets.size() << " targets, " << problem.samples().size()
              << " target samples, " << patient_->port_candidates.size()
              << " port candidate curves\n";
    // What the import could not find matters to the plan (a missing sternum moves the midline
    // and the LIMA; issue #42 item 3): said before planning, cached loads included.
    for (const auto& w : imported_.report.warnings) std::cout << "  warning: " << w << "\n";
    std::cout << "robot " << robot_->name() << ": arms";
    for (const auto& a : problem.arms())
      std::cout << " " << a.name << " (" << planners::ToString(a.role) << ")";
    std::cout << "\noptimiser: " << o_.optimizer.algorithm << " then " << o_.optimizer.local << ", "
              << o_.optimizer.evaluations << " evaluations in " << o_.optimizer.starts
              << " starts, seed " << o_.optimizer.seed << "\n"
              << std::flush;
  }

  // A progress callback drawing `prefix` and the stage over [lo, hi] of the command's bar.
  std::function<void(double, const std::string&)> Span(double lo, double hi,
                                                       const std::string& prefix) {
    return [this, lo, hi, prefix](double f, const std::string& stage) {
      bar_.Update(lo + (hi - lo) * f, prefix + stage);
    };
  }

  // The command's share of time, roughly: the baseline's cart 10 %, the search to 80 %, the
  // verified motions the rest (the search to 100 % without them).
  double SearchEnd() const { return o_.no_verify ? 1.0 : 0.8; }

  // The ports given (placed before any search: a template that cannot be placed or a bad ports
  // file is an error, nothing written); beside optimised plans, the baseline a surgeon would
  // compare them with: the template placed on this patient (when its spaces are named:
  // otherwise why not, in the plan file), or the surgeon's own ports. Placed before the search,
  // which starts from it (PortPlacementOptions::initial): the best plan then scores at least as
  // well as what a surgeon would have done.
  void PlaceBaseline() {
    const planners::PortPlacementProblem& problem = *problem_;
    if (bar_.enabled()) o_.optimizer.progress = Span(0.0, 0.1, "the baseline's cart: ");
    if (o_.ports != "optimise") given_ = GivenPorts(problem, o_.ports);
    if (!given_.empty() || o_.baseline == "none") return;
    // A surgeon's ports file as the baseline is read before the search too (its errors are the
    // user's); the template, when it cannot be placed, says why in the plan file instead.
    std::vector<planners::FixedPorts> baseline_ports;
    std::string baseline_why_not;
    try {
      baseline_ports = GivenPorts(problem, o_.baseline);
    } catch (const Error& e) {
      if (o_.baseline != "template") throw;
      baseline_why_not = e.what();
    }
    planners::Baseline b;
    b.kind = o_.baseline == "template" ? "template" : "surgeon";
    b.name = o_.baseline == "template" ? planners::TecabTemplate().title : o_.baseline;
    if (baseline_ports.empty()) {
      b.why_not = baseline_why_not;
    } else {
      // Its verdict names its unserved stretches and why, without what would reach them: the
      // optimised plans beside it are that answer (the template's remedies were a tenth of a
      // one-thread run on the bundled default, docs/decisions.md). Given ports
      // planned as the answer (--ports) keep theirs.
      planners::PortPlacementOptions baseline_options = o_.optimizer;
      baseline_options.remedies = false;
      b.fixed = planners::PlanFixedPorts(problem, baseline_ports, baseline_options);
      b.placed = true;
      o_.optimizer.initial.push_back(b.fixed.plan.placement);
    }
    baselines_.push_back(std::move(b));
  }

  // The optimiser's plans, or the given ports' plan; the baselines beside them.
  void Search() {
    const planners::PortPlacementProblem& problem = *problem_;
    if (bar_.enabled()) o_.optimizer.progress = Span(given_.empty() ? 0.1 : 0.0, SearchEnd(), "");
    if (given_.empty()) {
      result_ = planners::OptimizePorts(problem, o_.optimizer);
    } else {
      planners::FixedPortsPlan f = planners::PlanFixedPorts(problem, given_, o_.optimizer);
      result_.algorithm = "fixed ports";
      result_.local = o_.optimizer.local;
      result_.evaluations = result_.global_evaluations = f.evaluations;
      result_.best_global_score = f.plan.evaluation.score;
      result_.threads = f.threads;
      result_.grid = f.search;
      result_.ports_given = f.ports.kind + ": " + f.ports.name;
      result_.ports_where = f.ports.where;
      result_.verdict = f.verdict;
      result_.plans.push_back(std::move(f.plan));
      for (const auto& n : f.ports.notes) std::cout << "note: " << n << "\n";
    }
    for (auto& b : baselines_) {
      if (b.placed) result_.evaluations += b.fixed.evaluations;
      result_.baselines.push_back(std::move(b));
    }
  }

  // Verified motions for every ranked plan (unless --no-verify), then the plans re-ranked with
  // the verified coverage in place of the claimed one; the baselines' too.
  void Verify() {
    if (o_.no_verify) {
      bar_.Clear();
      return;
    }
    const planners::PortPlacementProblem& problem = *problem_;
    for (std::size_t k = 0; k < result_.plans.size(); ++k) {
      const double n = static_cast<double>(result_.plans.size());
      verifications_.push_back(planners::VerifyPlan(
          problem, result_.plans[k], o_.motion, o_.optimizer.suitable_fraction, o_.motion_threads,
          [&](int done, int of) {
            bar_.Update(0.8 + 0.19 * (k + static_cast<double>(done) / of) / n,
                        "verifying motions: plan " + std::to_string(k + 1) + ", " +
                            std::to_string(done) + " of " + std::to_string(of));
          }));
    }
    planners::RankByVerification(&result_, &verifications_);
    for (const auto& b : result_.baselines) {
      if (!b.placed) continue;
      baseline_verifications_.push_back(planners::VerifyPlan(
          problem, b.fixed.plan, o_.motion, o_.optimizer.suitable_fraction, o_.motion_threads,
          [&](int done, int of) {
            bar_.Update(0.99, "verifying motions: the baseline, " + std::to_string(done) + " of " +
                                  std::to_string(of));
          }));
    }
    bar_.Clear();
  }

  // The anatomical selection criteria, on the CT (as published), at the best plan's camera port,
  // compared with the verdict that counts (the verified one unless --no-verify).
  void MeasureCriteria() {
    const patient::PatientModel& ct = imported_.ct_model ? *imported_.ct_model : *patient_;
    std::optional<Eigen::Vector3d> camera_P;
    if (!result_.plans.empty()) {
      for (std::size_t a = 0; a < problem_->arms().size(); ++a) {
        if (problem_->arms()[a].role == planners::ArmRole::kEndoscope) {
          camera_P = patient_->X_WP.inverse() * result_.plans.front().placement.sites[a].p_rcm_W;
          break;
        }
      }
    }
    result_.criteria = planners::MeasureSelectionCriteria(ct, camera_P ? &*camera_P : nullptr);
    const bool counts =
        verifications_.empty() ? result_.verdict.suitable : verifications_.front().suitable;
    result_.criteria_comparison = result_.criteria.Compare(counts);
  }

  void Write() {
    planners::PlanInputs inputs;
    inputs.case_dir = o_.case_dir;
    inputs.robot_file = o_.robot;
    inputs.case_hash = planners::HashFile(JoinPath(o_.case_dir, "patient.yaml"));
    inputs.robot_hash = planners::HashFile(o_.robot);
    inputs.model_hash = planners::HashPatientModel(*patient_);
    planners::WritePlanFolder(
        o_.out, *problem_, result_, o_.optimizer, inputs, [&](planners::PlanFile* file) {
          if (!verifications_.empty())
            planners::AddVerification(file, *problem_, verifications_, baseline_verifications_);
          // Which arm reaches which stretch of each target, as the file says it (issue #43 item
          // 5): printed with the verdict.
          if (!file->plans.empty())
            reach_ = planners::TargetReachability(
                *file, 0, [&](const std::vector<Eigen::Vector3d>& p_W) {
                  const std::string spaces = planners::SpacesAtLevel(*patient_, p_W);
                  return spaces.empty() ? spaces : "at the " + spaces;
                });
        });
  }

  void PrintReachability() const {
    if (!reach_) return;
    std::cout << "reachability on the targets, plan 1 ("
              << (reach_->verified ? "verified motions" : "its own reach check") << "):\n";
    for (const planners::TargetStretch& st : reach_->stretches) {
      std::cout << "  " << st.target << " " << planners::StretchText(st)
                << (st.level.empty() ? "" : ", " + st.level) << ": "
                << (st.served                                   ? "served"
                    : st.reach == planners::ReachClass::kPartly ? "partly"
                                                                : "not reached")
                << " (";
      for (std::size_t a = 0; a < st.arms.size(); ++a)
        std::cout << (a ? ", " : "") << st.arms[a].arm << " "
                  << (st.arms[a].reaches ? (st.arms[a].endoscope ? "sees" : "reaches")
                                         : "no: " + st.arms[a].why_not);
      std::cout << ")\n";
    }
  }

  // What the robustness score is the mean over (optimizer.cpp): the heart over its operative
  // range, or, in the CT's state, the targets moved along each axis.
  std::string Robustness() const {
    if (o_.optimizer.robustness_shift <= 0) return "not re-scored";
    std::ostringstream r;
    const patient::OperativeState& op = patient_->operation;
    if (op.moves()) {
      r << std::fixed << std::setprecision(1) << "heart " << op.heart_shift_min * 1e3 << "-"
        << op.heart_shift_max * 1e3 << " mm";
    } else {
      r << std::fixed << std::setprecision(0) << "targets moved "
        << o_.optimizer.robustness_shift * 1e3 << " mm";
    }
    return r.str();
  }

  void PrintPlan(const std::string& title, const planners::RankedPlan& plan,
                 const planners::PlanVerification* verification) const {
    const auto& ev = plan.evaluation;
    std::cout << "\n"
              << title << ": score " << std::setprecision(3) << ev.score << " (rank "
              << plan.rank_score << ", " << Robustness() << ": " << plan.robust_score << "), "
              << planners::ToString(ev.status) << "\n";
    for (std::size_t a = 0; a < plan.placement.sites.size(); ++a) {
      const auto& site = plan.placement.sites[a];
      const Eigen::Vector3d p = site.p_P * 1e3;
      std::cout << "  " << std::left << std::setw(6) << problem_->arms()[a].name << std::right
                << " port on " << planners::DescribePort(*patient_, site) << std::setprecision(0)
                << "; LPS mm " << p.x() << ", " << p.y() << ", " << p.z() << "\n";
    }
    std::cout << "  cart at (" << std::setprecision(2) << plan.placement.cart_x << ", "
              << plan.placement.cart_y << ") m, heading " << std::setprecision(0)
              << plan.placement.cart_yaw * 180 / M_PI << " deg; table top at "
              << std::lround((problem_->patient().table.height + plan.placement.table_raise) * 1e3)
              << " mm\n";
    for (const auto& t : ev.terms) {
      std::cout << "    " << std::left << std::setw(26) << t.name << std::right
                << std::setprecision(3) << std::setw(8) << t.value << " " << std::left
                << std::setw(9) << t.unit << std::right << " score " << t.score << "  x "
                << std::setprecision(2) << t.weight << "\n";
    }
    if (verification) PrintVerification(*verification, std::cout);
  }

  void PrintBaselines() const {
    std::size_t next_baseline = 0;
    for (const auto& b : result_.baselines) {
      if (!b.placed) {
        std::cout << "\nbaseline (" << b.kind << "): not placed: " << b.why_not << "\n";
        continue;
      }
      const planners::PlanVerification* v = next_baseline < baseline_verifications_.size()
                                                ? &baseline_verifications_[next_baseline++]
                                                : nullptr;
      std::cout << "\nbaseline: " << b.name << "\n";
      for (std::size_t a = 0; a < b.fixed.ports.where.size(); ++a)
        std::cout << "  " << std::left << std::setw(6) << problem_->arms()[a].name << std::right
                  << " " << b.fixed.ports.where[a] << "\n";
      for (const auto& n : b.fixed.ports.notes) std::cout << "  note: " << n << "\n";
      PrintPlan("baseline " + b.kind, b.fixed.plan, v);
      if (!result_.plans.empty()) {
        const auto& best = result_.plans.front();
        std::cout << "  plan 1 against the " << b.kind << ": score " << std::setprecision(3)
                  << best.evaluation.score << " vs " << b.fixed.plan.evaluation.score;
        if (v && !verifications_.empty())
          std::cout << std::setprecision(0) << ", verified motions "
                    << verifications_.front().verified_coverage * 100 << " % vs "
                    << v->verified_coverage * 100 << " %, samples served "
                    << verifications_.front().served_fraction * 100 << " % vs "
                    << v->served_fraction * 100 << " %";
        std::cout << "\n";
      }
    }
  }

  void PrintCriteria() const {
    std::cout << "anatomical criteria (on the CT; docs/selection-criteria.md):\n";
    for (const auto& c : result_.criteria.criteria) {
      std::cout << "  " << std::left << std::setw(44) << c.title << std::right;
      if (c.measured()) {
        std::cout << std::setprecision(0) << std::setw(5) << c.value << " " << std::left
                  << std::setw(3) << c.unit << std::right << " (" << (c.at_least ? ">= " : "<= ")
                  << c.threshold << " " << c.unit << ": "
                  << (c.favourable() ? "favourable" : "against") << ")\n";
      } else {
        std::cout << "  " << c.how << "\n";
      }
    }
    std::cout << "  " << result_.criteria_comparison << "\n";
  }

  // The plans, the baselines, the verdicts (the verified one counts), the criteria, the totals.
  // @return the exit status: 0 suitable, 4 not.
  int Report() const {
    std::cout << std::fixed;
    if (!result_.ports_given.empty()) {
      std::cout << "\nports given: " << result_.ports_given << "\n";
      for (std::size_t a = 0; a < result_.ports_where.size(); ++a)
        std::cout << "  " << std::left << std::setw(6) << problem_->arms()[a].name << std::right
                  << " " << result_.ports_where[a] << "\n";
    }
    for (std::size_t k = 0; k < result_.plans.size(); ++k)
      PrintPlan("plan " + std::to_string(k + 1), result_.plans[k],
                k < verifications_.size() ? &verifications_[k] : nullptr);
    PrintBaselines();
    std::cout << "\nverdict: " << result_.verdict.summary << "\n";
    for (const auto& r : result_.verdict.reasons) std::cout << "  " << r << "\n";
    bool suitable = result_.verdict.suitable;
    if (!verifications_.empty()) {
      // The verdict that counts is the one from verified motions.
      suitable = verifications_.front().suitable;
      std::cout << "verified verdict: " << (suitable ? "suitable" : "not suitable")
                << " (plan 1: " << std::setprecision(0)
                << verifications_.front().verified_coverage * 100
                << " % of instrument motions verified)\n";
      for (const auto& r : verifications_.front().reasons) std::cout << "  " << r << "\n";
    }
    PrintReachability();
    PrintCriteria();
    std::cout << std::setprecision(1) << "evaluations: " << result_.evaluations << " in "
              << std::chrono::duration<double>(Clock::now() - t0_).count() << " s on "
              << result_.threads << " thread" << (result_.threads == 1 ? "" : "s")
              << (result_.time_limit_hit ? " (time limit reached)" : "") << "\n";
    std::cout << "written: " << JoinPath(o_.out, "plan.json") << ", "
              << JoinPath(o_.out, "ports.mrk.json") << "\n";
    return suitable ? 0 : 4;
  }

  PlanOptions o_;
  const Clock::time_point t0_;
  TerminalProgress bar_;
  std::shared_ptr<const robot::RobotModel> robot_;
  patient::ImportedPatient imported_;
  std::shared_ptr<const patient::PatientModel> patient_;
  std::unique_ptr<const planners::PortPlacementProblem> problem_;
  std::vector<planners::FixedPorts> given_;  // --ports: the ports given instead of a search
  std::vector<planners::Baseline> baselines_;
  planners::PortPlacementResult result_;
  std::vector<planners::PlanVerification> verifications_, baseline_verifications_;
};

int RunPlan(PlanOptions o) { return PlanCommand(std::move(o)).Run(); }

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
  cmd->add_option(
      "--table-height", o->table_height,
      "the heights the search may set the table's top to before docking, LOWEST,HIGHEST "
      "in m, or fixed (the case's table.height) (default: the case's plan.table_height, "
      "else 0.79,1.04: docs/operative-state.md)");
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
