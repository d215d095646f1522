#include "port_placement/optimizer.hpp"

#include <omp.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <functional>
#include <limits>
#include <map>
#include <nlopt.hpp>
#include <numeric>
#include <sstream>

#include "collision/collision_world.hpp"
#include "common/error.hpp"
#include "patient/patient_model.hpp"
#include "plan/reachability.hpp"
#include "port_placement/fixed_ports.hpp"
#include "port_placement/port_rules.hpp"
#include "port_placement/remedies.hpp"

namespace trocar::planners {

namespace {

using Clock = std::chrono::steady_clock;

struct Sample {
  std::vector<double> x;
  double score = -std::numeric_limits<double>::infinity();
};

std::string JoinNames(const std::vector<std::string>& names) {
  std::ostringstream s;
  for (std::size_t i = 0; i < names.size(); ++i) s << (i ? ", " : "") << names[i];
  return s.str();
}

nlopt::algorithm GlobalAlgorithm(const std::string& name) {
  if (name == "direct-l") return nlopt::GN_DIRECT_L;
  if (name == "crs2-lm") return nlopt::GN_CRS2_LM;
  if (name == "isres") return nlopt::GN_ISRES;
  return nlopt::G_MLSL_LDS;
}

nlopt::algorithm LocalAlgorithm(const std::string& name) {
  if (name == "subplex") return nlopt::LN_SBPLX;
  if (name == "cobyla") return nlopt::LN_COBYLA;
  return nlopt::LN_BOBYQA;
}

// Whether two placements differ enough to be a real choice: some arm's ports farther apart than d.
bool Distinct(const Placement& a, const Placement& b, double d) {
  for (std::size_t i = 0; i < a.sites.size(); ++i) {
    if ((a.sites[i].p_W - b.sites[i].p_W).norm() > d) return true;
  }
  return false;
}

// Runs one NLopt optimisation; records every evaluation in `archive`.
void RunNlopt(const PortPlacementProblem& problem, nlopt::algorithm algorithm,
              const std::vector<double>& lb, const std::vector<double>& ub, std::vector<double> x0,
              int max_evaluations, unsigned seed, Clock::time_point deadline, Workspace* ws,
              std::vector<Sample>* archive, std::atomic<int>* counter,
              std::atomic<bool>* out_of_time, const std::string& local_name = "bobyqa",
              const std::function<void(int)>* tick = nullptr) {
  if (max_evaluations <= 0) return;
  nlopt::srand(seed);
  const unsigned n = static_cast<unsigned>(lb.size());
  nlopt::opt opt(algorithm, n);
  opt.set_lower_bounds(lb);
  opt.set_upper_bounds(ub);
  opt.set_maxeval(max_evaluations);
  if (algorithm == nlopt::GN_ISRES) opt.set_population(30);
  if (algorithm == nlopt::GN_CRS2_LM) opt.set_population(10 * (n + 1));
  nlopt::opt local(LocalAlgorithm(local_name == "none" ? "bobyqa" : local_name), n);
  if (algorithm == nlopt::G_MLSL_LDS) {
    local.set_maxeval(std::max(10, max_evaluations / 12));
    local.set_xtol_rel(1e-3);
    opt.set_local_optimizer(local);
    opt.set_population(4);
  }
  if (algorithm == nlopt::LN_BOBYQA || algorithm == nlopt::LN_SBPLX ||
      algorithm == nlopt::LN_COBYLA) {
    std::vector<double> step(n);
    // A coordinate held (equal bounds: the table at the case's height) takes any nonzero step:
    // NLopt refuses a zero one and leaves a held coordinate where it is.
    for (unsigned i = 0; i < n; ++i) step[i] = ub[i] > lb[i] ? 0.25 * (ub[i] - lb[i]) : 1.0;
    opt.set_initial_step(step);
    opt.set_xtol_rel(1e-4);
  }
  struct Context {
    const PortPlacementProblem* problem;
    Workspace* ws;
    std::vector<Sample>* archive;
    std::atomic<int>* counter;
    std::atomic<bool>* out_of_time;
    Clock::time_point deadline;
    int budget;
    const std::function<void(int)>* tick;  // after each evaluation, with the count so far
  } context{&problem, ws, archive, counter, out_of_time, deadline, max_evaluations, tick};
  auto objective = [](unsigned, const double* x, double*, void* data) -> double {
    auto* c = static_cast<Context*>(data);
    if (static_cast<int>(c->archive->size()) >= c->budget) throw nlopt::forced_stop();
    if (Clock::now() > c->deadline) {
      c->out_of_time->store(true);
      throw nlopt::forced_stop();
    }
    std::vector<double> v(x, x + c->problem->dimension());
    const Evaluation ev = c->problem->Evaluate(c->problem->Decode(v), c->ws);
    c->archive->push_back({v, ev.score});
    const int done = c->counter->fetch_add(1) + 1;
    if (c->tick && *c->tick) (*c->tick)(done);
    return ev.score;
  };
  opt.set_max_objective(objective, &context);
  for (unsigned i = 0; i < n; ++i) x0[i] = std::clamp(x0[i], lb[i], ub[i]);
  double best = 0.0;
  try {
    opt.optimize(x0, best);
  } catch (const nlopt::forced_stop&) {
  } catch (const nlopt::roundoff_limited&) {
  } catch (const std::runtime_error& e) {
    // NLopt's generic failure (e.g. a degenerate box): the archive holds what was evaluated.
    (void)e;
  }
}

}  // namespace

SiteAccess SiteLines(const PortPlacementProblem& problem, const PortSite& site) {
  const auto& samples = problem.samples();
  const ProblemOptions& o = problem.options();
  const collision::CollisionWorld& world = *problem.world();
  SiteAccess out;
  out.shaft.resize(samples.size());
  out.sight.resize(samples.size());
  const Eigen::Vector3d axis = (problem.aim_W() - site.p_W).normalized();
  const Eigen::Vector3d tip = problem.aim_W() - o.scope_working_distance * axis;
  for (std::size_t s = 0; s < samples.size(); ++s) {
    const Eigen::Vector3d aim = samples[s].p_W + o.standoff * samples[s].n_W;
    out.shaft[s] = world.FirstAcross(site.p_rcm_W, aim, kWorkSiteRadius).body < 0;
    out.sight[s] = world.FirstAcross(tip, samples[s].p_W, kSightMargin).body < 0;
  }
  return out;
}

// The geometric part of the score (no robot): what Cannon et al. 2003 scored exhaustively —
// approach and triangulation angles, the endoscope's view, spacing, and reach by distance — and
// the served share, along clear lines when `access` is given.
double GeometricScore(const PortPlacementProblem& problem, const std::vector<PortSite>& sites,
                      const std::vector<const SiteAccess*>& access) {
  const auto& arms = problem.arms();
  const auto& samples = problem.samples();
  const ProblemOptions& o = problem.options();
  TROCAR_CHECK(access.empty() || access.size() == sites.size(),
               "geometric score: " << access.size() << " access tables for " << sites.size()
                                   << " sites");
  double approach = 0, reach = 0, view = 0, tri = 0, served = 0;
  int instruments = 0, scopes = 0;
  std::vector<int> inst;
  std::vector<char> all(samples.size(), 1);  // every instrument reaches it, a scope sees it
  std::vector<char> seen(samples.size(), 0);
  for (std::size_t a = 0; a < arms.size(); ++a) {
    const Eigen::Vector3d port = sites[a].p_W;
    const SiteAccess* lines = access.empty() ? nullptr : access[a];
    if (arms[a].role == ArmRole::kEndoscope) {
      ++scopes;
      const Eigen::Vector3d axis = (problem.aim_W() - port).normalized();
      const Eigen::Vector3d tip = problem.aim_W() - o.scope_working_distance * axis;
      for (std::size_t s = 0; s < samples.size(); ++s) {
        const Eigen::Vector3d d = samples[s].p_W - tip;
        const double angle = std::acos(std::clamp(axis.dot(d.normalized()), -1.0, 1.0));
        const bool in = angle <= o.scope_half_fov && d.norm() <= o.scope_max_distance &&
                        (!lines || lines->sight[s]);
        view += in ? 1.0 : 0.0;
        seen[s] = seen[s] || in;
      }
      continue;
    }
    ++instruments;
    inst.push_back(static_cast<int>(a));
    for (std::size_t s = 0; s < samples.size(); ++s) {
      const Eigen::Vector3d d = samples[s].p_W - port;
      const bool in = d.norm() <= problem.MaxReach(static_cast<int>(a)) && (!lines || lines->shaft[s]);
      reach += in ? 1.0 : 0.0;
      all[s] = all[s] && in;
      const double angle =
          std::acos(std::clamp(d.normalized().dot(-samples[s].n_W), -1.0, 1.0)) * 180.0 / M_PI;
      approach += std::clamp((90.0 - angle) / 60.0, 0.0, 1.0);
    }
  }
  for (std::size_t s = 0; s < samples.size(); ++s)
    served += all[s] && (scopes == 0 || seen[s]) ? 1.0 : 0.0;
  const double ns = std::max<double>(1, samples.size());
  if (inst.size() >= 2) {
    for (const auto& s : samples) {
      const Eigen::Vector3d a = (sites[inst[0]].p_W - s.p_W).normalized();
      const Eigen::Vector3d b = (sites[inst[1]].p_W - s.p_W).normalized();
      const double off = std::abs(std::acos(std::clamp(a.dot(b), -1.0, 1.0)) * 180.0 / M_PI - 60.0);
      tri += off <= 15 ? 1.0 - off / 30.0 : std::max(0.0, 0.5 - (off - 15) / 60.0);
    }
  }
  double spacing = std::numeric_limits<double>::infinity();
  for (std::size_t a = 0; a < sites.size(); ++a) {
    for (std::size_t b = a + 1; b < sites.size(); ++b)
      spacing = std::min(spacing, (sites[a].p_W - sites[b].p_W).norm());
  }
  const ScoreWeights& w = o.weights;
  const double spacing_score =
      std::isfinite(spacing)
          ? std::clamp((spacing - o.spacing_min) / (o.spacing_ideal - o.spacing_min), 0.0, 1.0)
          : 1.0;
  return w.coverage * reach / std::max(1.0, instruments * ns) + w.served * served / ns +
         w.approach * approach / std::max(1.0, instruments * ns) + w.triangulation * tri / ns +
         w.endoscope * (scopes ? view / (scopes * ns) : 1.0) + w.spacing * spacing_score;
}

namespace {

// The final plans' detailed evaluations and robustness: in the operation's world, over the range
// of the heart's displacement; in the CT's state, the options' shift along each axis. Sets each
// plan's evaluation, shifts, robust and rank scores; returns the evaluations spent.
int ScoreFinalPlans(const PortPlacementProblem& problem, const PortPlacementOptions& options,
                    int threads, const std::function<void(double, const std::string&)>& progress,
                    std::vector<RankedPlan>* finals_out) {
  std::vector<RankedPlan>& finals = *finals_out;
  // Robustness: in the operation's world, over the range of the heart's displacement
  // (patient::OperativeRobustnessShifts); in the CT's state, the option's shift along each axis.
  std::vector<Eigen::Vector3d> shifts;
  if (options.robustness_shift > 0) {
    shifts = patient::OperativeRobustnessShifts(problem.patient());
    if (shifts.empty() && !problem.patient().operation.moves()) {
      for (int axis = 0; axis < 3; ++axis) {
        for (double sign : {1.0, -1.0})
          shifts.push_back(sign * options.robustness_shift * Eigen::Vector3d::Unit(axis));
      }
    }
  }
  const std::vector<bool> moving_target = problem.MovingTargets();
  // One collision world per shift, the organs the targets lie on moved with them.
  std::vector<std::shared_ptr<const collision::CollisionWorld>> shifted_worlds(shifts.size());
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads)
  for (int k = 0; k < static_cast<int>(shifts.size()); ++k)
    shifted_worlds[k] = problem.WorldWithTargetsMoved(shifts[k]);
  int final_evaluations = 0;
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads) reduction(+ : final_evaluations)
  for (int i = 0; i < static_cast<int>(finals.size()); ++i) {
    Workspace ws(problem);
    RankedPlan& plan = finals[i];
    bool use_full = false;
    plan.evaluation = EvaluateFinalPlan(problem, plan.placement, &ws, &use_full);
    final_evaluations += 2;
    double sum = 0;
    for (std::size_t k = 0; k < shifts.size(); ++k) {
      const Eigen::Vector3d& d_P = shifts[k];
      Workspace moved_ws(problem, shifted_worlds[k]);
      std::vector<TargetSample> moved = problem.samples();
      const Eigen::Vector3d d_W = problem.patient().X_WP.linear() * d_P;
      for (auto& s : moved) {
        if (s.target >= 0 && s.target < static_cast<int>(moving_target.size()) &&
            moving_target[s.target])
          s.p_W += d_W;
      }
      PortPlacementProblem::EvaluateOptions shifted;
      shifted.full_solver = use_full;
      shifted.samples = &moved;
      const Evaluation ev = problem.Evaluate(plan.placement, &moved_ws, shifted);
      ++final_evaluations;
      Shift shift;
      shift.d_P = d_P;
      shift.score = ev.score;
      shift.coverage = ev.Find("coverage") ? ev.Find("coverage")->value : 0.0;
      shift.served =
          ev.served.empty()
              ? 0.0
              : static_cast<double>(std::count(ev.served.begin(), ev.served.end(), true)) /
                    ev.served.size();
      plan.shifts.push_back(shift);
      sum += ev.score;
    }
    plan.robust_score = shifts.empty() ? plan.evaluation.score : sum / shifts.size();
    plan.degradation = plan.evaluation.score - plan.robust_score;
    plan.rank_score =
        plan.evaluation.score - options.robustness_weight * std::max(0.0, plan.degradation);
    progress(0.85 + 0.15 * (i + 1) / finals.size(), "robustness");
  }
  return final_evaluations;
}

// The verdict on the best of `plans` (ranked): which targets' stretches it does not serve, and why.
Verdict JudgePlans(const PortPlacementProblem& problem, const std::vector<RankedPlan>& plans,
                   const PortPlacementOptions& options) {
  Verdict verdict;
  const auto& targets = problem.patient().targets;
  const auto& samples = problem.samples();
  if (plans.empty() || plans[0].evaluation.status != PlacementStatus::kPlaced) {
    verdict.suitable = false;
    std::ostringstream why;
    if (plans.empty()) {
      why << "no placement was evaluated (time limit " << options.time_limit << " s)";
      verdict.summary = "not suitable: " + why.str();
    } else {
      why << "no placement of the cart puts every arm at a port "
          << (plans[0].evaluation.status == PlacementStatus::kInCollision
                  ? "without collisions"
                  : "within the setup joints' reach");
      verdict.summary = "not suitable: " + why.str();
      // The best attempt's message, one line: each arm's setup, then what collides.
      std::istringstream lines(plans[0].evaluation.message);
      std::string line, joined;
      while (std::getline(lines, line)) {
        const auto first = line.find_first_not_of(' ');
        if (first == std::string::npos) continue;
        joined += (joined.empty() ? "" : "; ") + line.substr(first);
      }
      why << "; the best: " << joined;
    }
    verdict.reasons.push_back(why.str());
  } else {
    const Evaluation& best = plans[0].evaluation;
    verdict.suitable = true;
    for (int t = 0; t < static_cast<int>(targets.size()); ++t) {
      std::vector<int> idx;
      for (int s = 0; s < static_cast<int>(samples.size()); ++s) {
        if (samples[s].target == t) idx.push_back(s);
      }
      int served = 0;
      for (int s : idx) served += best.served[s] ? 1 : 0;
      const double fraction = idx.empty() ? 1.0 : static_cast<double>(served) / idx.size();
      if (fraction >= options.suitable_fraction) continue;
      verdict.suitable = false;
      // Group consecutive unserved samples with the same reason into stretches of the target.
      auto reason_of = [&](int s) {
        for (const auto& r : best.reaches) {
          if (r.sample == s && !r.reached) {
            std::string why = r.reason;
            // "from every candidate port" when no candidate point is within reach
            if (why.rfind("insertion limit", 0) == 0) {
              double nearest = std::numeric_limits<double>::infinity();
              for (const auto& c : problem.patient().port_candidates) {
                for (const auto& p : c.skin)
                  nearest = std::min(nearest, (problem.patient().X_WP * p - samples[s].p_W).norm());
              }
              const double reach = problem.MaxReach(r.arm);
              const auto& joint = problem.robot().joint(
                  problem.robot().active_joints()[problem.arms()[r.arm].insertion_q]);
              std::ostringstream w;
              if (nearest > reach) {
                w << "insertion limit (" << std::lround(joint.limits.upper * 1e3)
                  << " mm) exceeded from every candidate port (the nearest is "
                  << std::lround(nearest * 1e3) << " mm away, the tool reaches "
                  << std::lround(reach * 1e3) << " mm)";
              } else {
                w << "insertion limit (" << std::lround(joint.limits.upper * 1e3)
                  << " mm) exceeded from the chosen port";
              }
              why = w.str();
            }
            return problem.arms()[r.arm].name + ": " + why;
          }
        }
        return std::string("not served");
      };
      auto arm_of = [&](int s) {
        for (const auto& r : best.reaches)
          if (r.sample == s && !r.reached) return r.arm;
        return -1;
      };
      std::size_t i = 0;
      while (i < idx.size()) {
        if (best.served[idx[i]]) {
          ++i;
          continue;
        }
        const std::string why = reason_of(idx[i]);
        std::size_t j = i;
        while (j + 1 < idx.size() && !best.served[idx[j + 1]] && reason_of(idx[j + 1]) == why) ++j;
        // Where along the target, and at the level of which intercostal spaces (when the ribs
        // are numbered): "LIMA 22–67 mm from its first point (its proximal third), at the 2nd to
        // 3rd intercostal spaces".
        std::ostringstream line;
        double length = 0.0;
        for (int k : idx) length = std::max(length, samples[k].arc_length);
        line << targets[t].name << " "
             << AlongTarget(samples[idx[i]].arc_length, samples[idx[j]].arc_length, length);
        std::vector<Eigen::Vector3d> stretch_W;
        for (std::size_t k = i; k <= j; ++k) stretch_W.push_back(samples[idx[k]].p_W);
        const std::string level = SpacesAtLevel(problem.patient(), stretch_W);
        if (!level.empty()) line << ", at the " << level;
        line << ": " << why;
        // What would change that, where a neighbouring port or cart pose can be shown to
        // (issue #43 item 4): tried in full, as a plan is evaluated.
        if (options.remedies) {
          std::vector<int> stretch(idx.begin() + i, idx.begin() + j + 1);
          const Remedy remedy = FindRemedy(problem, plans[0].placement, best, arm_of(idx[i]),
                                           stretch, options.threads > 0 ? options.threads : omp_get_max_threads());
          line << "; " << (remedy.reached > 0 ? remedy.text
                                              : "no port one space up or down or 3 cm along, and no "
                                                "cart move of 10-20 cm, reaches it");
        }
        verdict.reasons.push_back(line.str());
        i = j + 1;
      }
    }
    std::ostringstream summary;
    if (verdict.suitable) {
      // Served is what the plan's arms do: without an endoscope arm, the instruments' reach
      // alone (the scope is the team's, not planned here).
      const bool scoped =
          std::any_of(problem.arms().begin(), problem.arms().end(),
                      [](const PlanArm& a) { return a.role == ArmRole::kEndoscope; });
      summary << "suitable: every target is served ("
              << (scoped ? "every instrument reaches it, the endoscope sees it"
                         : "every instrument reaches it; no endoscope arm was planned")
              << ") on at least " << std::lround(options.suitable_fraction * 100)
              << " % of its length by the best plan";
    } else {
      summary << "not suitable: " << verdict.reasons.size() << " target stretch"
              << (verdict.reasons.size() == 1 ? "" : "es") << " not served by the best plan";
    }
    verdict.summary = summary.str();
  }
  return verdict;
}

}  // namespace

std::vector<std::string> GlobalAlgorithms() {
  return {"direct-l", "crs2-lm", "isres", "mlsl", "exhaustive"};
}
std::vector<std::string> LocalAlgorithms() { return {"bobyqa", "subplex", "cobyla", "none"}; }

void ValidateOptions(const PortPlacementOptions& o) {
  const auto global = GlobalAlgorithms(), local = LocalAlgorithms();
  TROCAR_OPTION_UNLESS(std::find(global.begin(), global.end(), o.algorithm) != global.end(),
                       "algorithm",
                       "unknown '" << o.algorithm << "' (valid: " << JoinNames(global) << ")");
  TROCAR_OPTION_UNLESS(std::find(local.begin(), local.end(), o.local) != local.end(), "local",
                       "unknown '" << o.local << "' (valid: " << JoinNames(local) << ")");
  TROCAR_OPTION_UNLESS(std::isfinite(o.time_limit) && o.time_limit > 0, "time_limit",
                       o.time_limit << " s, expected a positive number of seconds");
  TROCAR_OPTION_UNLESS(o.evaluations >= 1, "evaluations", o.evaluations << ", expected >= 1");
  TROCAR_OPTION_UNLESS(o.starts >= 1 && o.starts <= 64, "starts",
                       o.starts << ", expected 1 to 64");
  TROCAR_OPTION_UNLESS(o.polish_evaluations >= 0, "polish_evaluations",
                       o.polish_evaluations << ", expected >= 0");
  TROCAR_OPTION_UNLESS(o.threads >= 0, "threads", o.threads << ", expected >= 0 (0: all cores)");
  TROCAR_OPTION_UNLESS(o.top_k >= 1 && o.top_k <= 20, "top_k", o.top_k << ", expected 1 to 20");
  TROCAR_THROW_UNLESS(
      std::isfinite(o.robustness_shift) && o.robustness_shift >= 0 && o.robustness_shift <= 0.1,
      "robustness shift: " << o.robustness_shift << " m, expected 0 to 0.1");
  TROCAR_THROW_UNLESS(o.suitable_fraction >= 0 && o.suitable_fraction <= 1,
                      "suitable fraction: " << o.suitable_fraction << ", expected 0 to 1");
}

Evaluation EvaluateFinalPlan(const PortPlacementProblem& problem, const Placement& placement,
                             Workspace* ws, bool* full_effort) {
  // Detailed, once with the setup-joint effort the optimiser scored it with (so that its score
  // is reproduced) and once with the solver's full effort, which may land on another of the
  // setup arms' redundant solutions; the better one is the plan.
  PortPlacementProblem::EvaluateOptions how;
  how.detailed = true;
  Evaluation ev = problem.Evaluate(placement, ws, how);
  how.full_solver = true;
  Evaluation full = problem.Evaluate(placement, ws, how);
  const bool use_full = full.score > ev.score;
  if (full_effort) *full_effort = use_full;
  return use_full ? full : ev;
}

namespace {

// One OptimizePorts run as stages over its shared state (the deadline, the evaluations counted,
// the archive of every global evaluation): the global stage (Cannon's grid as the exhaustive
// baseline, or as the seeds of the global algorithm's starts), the distinct candidates polished
// locally, the final plans scored in detail and for robustness, then the verdict.
class Search {
 public:
  Search(const PortPlacementProblem& problem, const PortPlacementOptions& options)
      : problem_(problem),
        options_(options),
        t0_(Clock::now()),
        deadline_(t0_ + std::chrono::duration_cast<Clock::duration>(
                            std::chrono::duration<double>(options.time_limit))),
        threads_(options.threads > 0 ? options.threads : omp_get_max_threads()),
        dim_(problem.dimension()),
        cart_(problem.cart_index()),
        lb_(problem.lower_bounds()),
        ub_(problem.upper_bounds()) {}

  PortPlacementResult Run() {
    result_.algorithm = options_.algorithm;
    result_.local = options_.local;
    result_.threads = threads_;
    auto t_stage = Clock::now();
    if (options_.algorithm == "exhaustive") {
      Exhaustive();
    } else {
      Global();
    }
    result_.global_evaluations = static_cast<int>(archive_.size());
    result_.best_global_score = -std::numeric_limits<double>::infinity();
    for (const auto& s : archive_)
      result_.best_global_score = std::max(result_.best_global_score, s.score);
    Stamp("global " + options_.algorithm, t_stage);

    t_stage = Clock::now();
    std::vector<Sample> pool = Candidates();
    const int polished = Polish(&pool);
    Stamp("polish " + options_.local, t_stage);

    t_stage = Clock::now();
    int final_evaluations = 0;
    result_.plans = FinalPlans(pool, &final_evaluations);
    Stamp("final plans and robustness", t_stage);
    result_.evaluations = result_.global_evaluations + polished + final_evaluations;
    result_.time_limit_hit = out_of_time_.load();

    result_.verdict = JudgePlans(problem_, result_.plans, options_);
    Stamp("total", t0_);
    return std::move(result_);
  }

 private:
  void Progress(double fraction, const std::string& stage) const {
    if (options_.progress && omp_get_thread_num() == 0)
      options_.progress(std::clamp(fraction, 0.0, 1.0), stage);
  }
  void Stamp(const std::string& stage, Clock::time_point since) {
    result_.timings.push_back({stage, std::chrono::duration<double>(Clock::now() - since).count()});
  }

  // Cannon et al. 2003's grid: every assignment of grid sites to the arms scored by the port-only
  // (geometric) terms; the best triads with a grid of cart poses, for full evaluation. It is the
  // exhaustive baseline, and the first stage of the default global search (its seeds).
  std::vector<std::vector<double>> CannonGrid(std::string* description) const {
    const int curves = static_cast<int>(problem_.patient().port_candidates.size());
    const std::vector<double> along = {0.1, 0.3, 0.5, 0.7, 0.9};
    std::vector<PortSite> grid;
    for (int c = 0; c < curves; ++c) {
      if (problem_.patient().port_candidates[c].skin.size() < 2) continue;
      for (double s : along) grid.push_back(problem_.Site(c, s));
    }
    // Which samples each site reaches along a clear line (a shaft through the heart or a rib
    // reaches nothing): the triads are ranked by what their ports allow, not by distance alone.
    std::vector<SiteAccess> lines(grid.size());
#pragma omp parallel for num_threads(threads_) schedule(dynamic, 1)
    for (int i = 0; i < static_cast<int>(grid.size()); ++i) lines[i] = SiteLines(problem_, grid[i]);
    const int arms = static_cast<int>(problem_.arms().size());
    std::vector<std::pair<double, std::vector<int>>> assignments;
    std::vector<int> pick(arms, 0);
    const int g = static_cast<int>(grid.size());
    std::function<void(int)> enumerate = [&](int a) {
      if (a == arms) {
        std::vector<PortSite> sites;
        std::vector<const SiteAccess*> access;
        for (int i : pick) {
          sites.push_back(grid[i]);
          access.push_back(&lines[i]);
        }
        assignments.push_back({GeometricScore(problem_, sites, access), pick});
        return;
      }
      for (int i = 0; i < g; ++i) {
        if (std::find(pick.begin(), pick.begin() + a, i) != pick.begin() + a) continue;
        pick[a] = i;
        enumerate(a + 1);
      }
    };
    enumerate(0);
    std::stable_sort(assignments.begin(), assignments.end(),
                     [](const auto& a, const auto& b) { return a.first > b.first; });
    const int keep = std::min<int>(16, static_cast<int>(assignments.size()));
    const std::vector<double> directions = {-M_PI, -3 * M_PI / 4, -M_PI / 2, -M_PI / 4,
                                            0,     M_PI / 4,      M_PI / 2,  3 * M_PI / 4};
    const std::vector<double> distances = {0.6, 0.9, 1.2};
    std::vector<std::vector<double>> xs;
    for (int k = 0; k < keep; ++k) {
      for (double from : directions) {
        for (double d : distances) {
          std::vector<double> x;
          for (int i : assignments[k].second)
            x.insert(x.end(), {grid[i].candidate + 0.5, grid[i].s});
          x.insert(x.end(), {from, std::clamp(d, lb_[cart_ + 1], ub_[cart_ + 1]), 0.0,
                             0.5 * (lb_[cart_ + 3] + ub_[cart_ + 3])});
          xs.push_back(x);
        }
      }
    }
    std::ostringstream grid_text;
    grid_text << along.size() << " sites on each of " << curves
              << " candidate curves (at 10, 30, 50, 70, 90 % of "
              << "its length): " << assignments.size() << " assignments of sites to " << arms
              << " arms scored by the port-only terms along clear lines; the best " << keep
              << " with " << directions.size() << " cart directions x " << distances.size()
              << " distances (0.6, 0.9, 1.2 m), facing the ports: " << xs.size()
              << " full evaluations";
    *description = grid_text.str();
    return xs;
  }

  // Full evaluations of given decisions, in parallel, in their order (those past the deadline
  // left out), each counted toward the progress shown as `stage` out of `total` evaluations.
  std::vector<Sample> EvaluateAll(const std::vector<std::vector<double>>& xs,
                                  const std::string& stage, double total) {
    std::vector<Sample> out(xs.size());
#pragma omp parallel num_threads(threads_)
    {
      Workspace ws(problem_);
#pragma omp for schedule(dynamic, 4)
      for (int i = 0; i < static_cast<int>(xs.size()); ++i) {
        if (Clock::now() > deadline_) {
          out_of_time_.store(true);
          continue;
        }
        out[i] = {xs[i], problem_.Evaluate(problem_.Decode(xs[i]), &ws).score};
        const int done = counter_.fetch_add(1) + 1;
        Progress(0.7 * done / std::max(1.0, total), stage + ": " + std::to_string(done) + " of " +
                                                        std::to_string(std::lround(total)) +
                                                        " evaluations");
      }
    }
    out.erase(std::remove_if(out.begin(), out.end(), [](const Sample& s) { return s.x.empty(); }),
              out.end());
    return out;
  }

  // The exhaustive baseline: Cannon's grid, every placement of it evaluated.
  void Exhaustive() {
    const std::vector<std::vector<double>> xs = CannonGrid(&result_.grid);
    archive_ = EvaluateAll(xs, "exhaustive grid", static_cast<double>(xs.size()));
    grid_samples_.resize(archive_.size());
    std::iota(grid_samples_.begin(), grid_samples_.end(), 0);
    double best = -std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i < archive_.size(); ++i) {
      best = std::max(best, archive_[i].score);
      result_.trace.push_back({static_cast<int>(i + 1), best});
    }
  }

  // Seeds: Cannon's grid evaluated first (the port-only terms choose the triads at no robot
  // cost), so that the search never ends below the exhaustive baseline; then the global
  // algorithm's own starts over the whole box. A third of the global budget at most (the grid is
  // ordered best triad first), the rest to the algorithm: the evaluations in all stay the
  // option's. The given initial placements (the template's) come first, inside the same budget.
  void Global() {
    std::vector<std::vector<double>> seeds = CannonGrid(&result_.grid);
    // The given placements are evaluated even when a third of a tiny budget cannot hold them.
    const std::size_t seed_budget = std::max(
        static_cast<std::size_t>(std::max(0, options_.evaluations / 3)), options_.initial.size());
    for (auto it = options_.initial.rbegin(); it != options_.initial.rend(); ++it)
      seeds.insert(seeds.begin(), problem_.Encode(*it));
    if (seeds.size() > seed_budget) seeds.resize(seed_budget);
    result_.grid = "seeds (the first " + std::to_string(seeds.size()) +
                   (options_.initial.empty() ? std::string()
                                             : ", " + std::to_string(options_.initial.size()) +
                                                   " given placements first") +
                   "): " + result_.grid;
    archive_ = EvaluateAll(seeds, "seeds: Cannon's grid", options_.evaluations);
    for (int i = 0; i < static_cast<int>(archive_.size()); ++i) {
      bool given = false;
      for (const Placement& p : options_.initial)
        given = given || archive_[i].x == problem_.Encode(p);
      if (!given) grid_samples_.push_back(i);
    }
    const int starts = options_.starts;
    std::vector<std::vector<Sample>> archives(starts);
    const int per_start =
        std::max(1, (options_.evaluations - static_cast<int>(seeds.size())) / starts);
    // Progress after every 10th evaluation (the counter holds the seeds' too).
    const std::function<void(int)> global_tick = [&](int n) {
      if (n % 10 != 0) return;
      Progress(0.7 * n / std::max(1, options_.evaluations),
               "global " + options_.algorithm + ": " + std::to_string(n) + " of " +
                   std::to_string(options_.evaluations) + " evaluations");
    };
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads_)
    for (int s = 0; s < starts; ++s) {
      Workspace ws(problem_);
      std::vector<double> slb = lb_, sub = ub_;
      // Start s searches its own sector of directions the cart comes from.
      slb[cart_] = -M_PI + 2 * M_PI * s / starts;
      sub[cart_] = -M_PI + 2 * M_PI * (s + 1) / starts;
      std::vector<double> x0(dim_);
      for (int i = 0; i < dim_; ++i) x0[i] = 0.5 * (slb[i] + sub[i]);
      RunNlopt(problem_, GlobalAlgorithm(options_.algorithm), slb, sub, x0, per_start,
               options_.seed * 7919u + static_cast<unsigned>(s), deadline_, &ws, &archives[s],
               &counter_, &out_of_time_, options_.local, &global_tick);
      Progress(0.7 * counter_.load() / (per_start * starts), "global " + options_.algorithm);
    }
    // Merge in start order after the seeds; the trace interleaves the starts round-robin (as if
    // run side by side).
    double best = -std::numeric_limits<double>::infinity();
    int total = 0;
    for (const auto& s : archive_) {
      best = std::max(best, s.score);
      result_.trace.push_back({++total, best});
    }
    std::size_t longest = 0;
    for (const auto& a : archives) longest = std::max(longest, a.size());
    for (std::size_t i = 0; i < longest; ++i) {
      for (const auto& a : archives) {
        if (i >= a.size()) continue;
        best = std::max(best, a[i].score);
        result_.trace.push_back({++total, best});
      }
    }
    for (auto& a : archives) archive_.insert(archive_.end(), a.begin(), a.end());
  }

  // The best distinct placements of `from` (archive indices, best first), top_k + 2 at most.
  std::vector<Sample> DistinctBest(const std::vector<int>& from) const {
    const int pool_size = options_.top_k + 2;
    std::vector<Sample> chosen;
    std::vector<Placement> placements;
    for (int i : from) {
      if (static_cast<int>(chosen.size()) >= pool_size) break;
      const Placement p = problem_.Decode(archive_[i].x);
      bool distinct = true;
      for (const auto& q : placements)
        distinct = distinct && Distinct(p, q, options_.distinct_distance);
      if (!distinct) continue;
      chosen.push_back(archive_[i]);
      placements.push_back(p);
    }
    return chosen;
  }

  // The candidates to polish: the archive's best distinct placements, and the exhaustive
  // baseline's own (polished from the same starts with the same seeds, a polish's seed being a
  // function of its start: the final plans then hold every plan the baseline would end with, and
  // the search never ends below it. The global search's best placements can crowd the grid's out
  // of the pool, and the polish is local: a grid placement scoring a little lower can polish to
  // more).
  std::vector<Sample> Candidates() const {
    std::vector<int> order(archive_.size());
    std::iota(order.begin(), order.end(), 0);
    std::stable_sort(order.begin(), order.end(),
                     [&](int a, int b) { return archive_[a].score > archive_[b].score; });
    std::vector<Sample> pool = DistinctBest(order);
    std::vector<int> grid_order;
    for (int i : order)
      if (std::binary_search(grid_samples_.begin(), grid_samples_.end(), i))
        grid_order.push_back(i);
    for (const Sample& g : DistinctBest(grid_order)) {
      bool in_pool = false;
      for (const Sample& p : pool) in_pool = in_pool || p.x == g.x;
      if (!in_pool) pool.push_back(g);
    }
    return pool;
  }

  // A polish's seed: the run's seed and its start (FNV-1a over the start's bytes).
  unsigned PolishSeed(const std::vector<double>& x) const {
    std::uint64_t h = 1469598103934665603ull;
    for (double v : x) {
      std::uint64_t bits;
      std::memcpy(&bits, &v, sizeof bits);
      h = (h ^ bits) * 1099511628211ull;
    }
    return options_.seed * 104729u + static_cast<unsigned>(h ^ (h >> 32));
  }

  // Each candidate polished locally (its ports moved along their curves, within 15 % of the box
  // around it), kept when better. @return the evaluations spent.
  int Polish(std::vector<Sample>* pool_out) {
    std::vector<Sample>& pool = *pool_out;
    std::vector<int> polish_counts(pool.size(), 0);
    if (options_.local != "none" && options_.polish_evaluations > 0) {
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads_)
      for (int i = 0; i < static_cast<int>(pool.size()); ++i) {
        Workspace ws(problem_);
        std::vector<double> plb(dim_), pub(dim_);
        for (int k = 0; k < dim_; ++k) {
          const double span = 0.15 * (ub_[k] - lb_[k]);
          plb[k] = std::max(lb_[k], pool[i].x[k] - span);
          pub[k] = std::min(ub_[k], pool[i].x[k] + span);
        }
        // The curve coordinates stay on their curve: the polish moves ports along it.
        for (int a = 0; a < cart_; a += 2) {
          const double c = std::floor(pool[i].x[a]);
          plb[a] = c + 0.25;
          pub[a] = c + 0.75;
        }
        std::vector<double> x0 = pool[i].x;
        for (int a = 0; a < cart_; a += 2) x0[a] = std::floor(x0[a]) + 0.5;
        std::vector<Sample> local_archive;
        RunNlopt(problem_, LocalAlgorithm(options_.local), plb, pub, x0,
                 options_.polish_evaluations, PolishSeed(pool[i].x), deadline_, &ws, &local_archive,
                 &counter_, &out_of_time_);
        polish_counts[i] = static_cast<int>(local_archive.size());
        for (const auto& s : local_archive) {
          if (s.score > pool[i].score) pool[i] = s;
        }
        Progress(0.7 + 0.15 * (i + 1) / pool.size(), "polish " + options_.local);
      }
    }
    return std::accumulate(polish_counts.begin(), polish_counts.end(), 0);
  }

  // The polished candidates, best first and distinct, scored in detail and for robustness, ranked
  // by their rank score: the top_k. `evaluations` gets the evaluations spent.
  std::vector<RankedPlan> FinalPlans(const std::vector<Sample>& pool, int* evaluations) const {
    std::vector<int> pool_order(pool.size());
    std::iota(pool_order.begin(), pool_order.end(), 0);
    std::stable_sort(pool_order.begin(), pool_order.end(),
                     [&](int a, int b) { return pool[a].score > pool[b].score; });
    std::vector<RankedPlan> finals;
    for (int i : pool_order) {
      RankedPlan plan;
      plan.placement = problem_.Decode(pool[i].x);
      bool distinct = true;
      for (const auto& f : finals)
        distinct = distinct && Distinct(plan.placement, f.placement, options_.distinct_distance);
      if (distinct) finals.push_back(std::move(plan));
    }
    *evaluations = ScoreFinalPlans(
        problem_, options_, threads_,
        [this](double fraction, const std::string& stage) { Progress(fraction, stage); }, &finals);
    std::stable_sort(finals.begin(), finals.end(), [](const RankedPlan& a, const RankedPlan& b) {
      return a.rank_score > b.rank_score;
    });
    if (static_cast<int>(finals.size()) > options_.top_k) finals.resize(options_.top_k);
    return finals;
  }

  const PortPlacementProblem& problem_;
  const PortPlacementOptions& options_;
  const Clock::time_point t0_, deadline_;
  const int threads_, dim_, cart_;  // cart_: the first of the cart's decision coordinates
  const std::vector<double> lb_, ub_;
  std::atomic<int> counter_{0};  // evaluations done, for the progress
  std::atomic<bool> out_of_time_{false};
  PortPlacementResult result_;
  std::vector<Sample> archive_;  // every global evaluation
  // The exhaustive grid's evaluations within the archive (all of it for "exhaustive"; the seeds
  // after the given placements otherwise), for the polish.
  std::vector<int> grid_samples_;
};

}  // namespace

PortPlacementResult OptimizePorts(const PortPlacementProblem& problem,
                                  const PortPlacementOptions& options) {
  ValidateOptions(options);
  for (const Placement& p : options.initial)
    TROCAR_CHECK(p.sites.size() == problem.arms().size(),
                 "initial placement: " << p.sites.size() << " ports for " << problem.arms().size()
                                       << " arms");
  return Search(problem, options).Run();
}

FixedPortsPlan PlanFixedPorts(const PortPlacementProblem& problem,
                              const std::vector<FixedPorts>& variants,
                              const PortPlacementOptions& options) {
  ValidateOptions(options);
  TROCAR_THROW_UNLESS(!variants.empty(), "fixed ports: no ports to place");
  const auto t0 = Clock::now();
  const auto deadline = t0 + std::chrono::duration_cast<Clock::duration>(
                                 std::chrono::duration<double>(options.time_limit));
  const int threads = options.threads > 0 ? options.threads : omp_get_max_threads();
  const int cart = problem.cart_index();
  constexpr int kCart = PortPlacementProblem::kCartCoordinates;
  const std::vector<double> lb = problem.lower_bounds(), ub = problem.upper_bounds();
  auto progress = [&](double fraction, const std::string& stage) {
    if (options.progress && omp_get_thread_num() == 0)
      options.progress(std::clamp(fraction, 0.0, 1.0), stage);
  };
  // The ports' part of the decision vector, per variant.
  std::vector<std::vector<double>> bases;
  for (const FixedPorts& v : variants) {
    TROCAR_THROW_UNLESS(v.sites.size() == problem.arms().size(),
                        "fixed ports: " << v.sites.size() << " ports for "
                                        << problem.arms().size() << " arms");
    Placement p;
    p.sites = v.sites;
    std::vector<double> x = problem.Encode(p);
    x.resize(cart);
    bases.push_back(x);
  }
  // A grid of cart poses for each variant: the direction it comes from every 30 degrees, three
  // distances across the options' range, facing the ports and turned either way by half the
  // allowed offset.
  std::vector<double> directions;
  for (int k = 0; k < 12; ++k) directions.push_back(-M_PI + k * M_PI / 6);
  const std::vector<double> distances = {
      lb[cart + 1], 0.5 * (lb[cart + 1] + ub[cart + 1]), ub[cart + 1]};
  const std::vector<double> offsets = {0.0, -0.5 * ub[cart + 2], 0.5 * ub[cart + 2]};
  // The table at both ends of the heights the team may set it to (once when they are one).
  std::vector<double> raises = {lb[cart + 3]};
  if (ub[cart + 3] > lb[cart + 3]) raises.push_back(ub[cart + 3]);
  std::vector<std::pair<int, std::vector<double>>> xs;  // variant, decision
  for (std::size_t v = 0; v < bases.size(); ++v) {
    for (double from : directions) {
      for (double d : distances) {
        for (double o : offsets) {
          for (double r : raises) {
            std::vector<double> x = bases[v];
            x.insert(x.end(), {from, d, o, r});
            xs.push_back({static_cast<int>(v), x});
          }
        }
      }
    }
  }
  std::vector<double> scores(xs.size(), -std::numeric_limits<double>::infinity());
  std::atomic<int> done{0};
#pragma omp parallel num_threads(threads)
  {
    Workspace ws(problem);
#pragma omp for schedule(dynamic, 4)
    for (int i = 0; i < static_cast<int>(xs.size()); ++i) {
      if (Clock::now() > deadline) continue;
      scores[i] = problem.Evaluate(problem.Decode(xs[i].second), &ws).score;
      progress(0.6 * (done.fetch_add(1) + 1) / xs.size(), "cart for the fixed ports");
    }
  }
  int evaluations = static_cast<int>(xs.size());
  const int best = static_cast<int>(std::max_element(scores.begin(), scores.end()) - scores.begin());
  const int variant = xs[best].first;
  std::vector<double> x_best = xs[best].second;
  double score_best = scores[best];
  // The cart's coordinates polished locally (the ports stay where they were given).
  if (options.local != "none" && options.polish_evaluations > 0 && Clock::now() < deadline) {
    Workspace ws(problem);
    struct Context {
      const PortPlacementProblem* problem;
      Workspace* ws;
      std::vector<double> x;
      int cart, evaluations, budget;
      double best;
      std::vector<double> x_best;
      Clock::time_point deadline;
    } c{&problem, &ws, x_best, cart, 0, options.polish_evaluations, score_best, x_best, deadline};
    nlopt::opt opt(LocalAlgorithm(options.local), kCart);
    std::vector<double> plb(kCart), pub(kCart), x0(kCart), step(kCart);
    for (int k = 0; k < kCart; ++k) {
      const double span = 0.15 * (ub[cart + k] - lb[cart + k]);
      x0[k] = x_best[cart + k];
      plb[k] = std::max(lb[cart + k], x0[k] - span);
      pub[k] = std::min(ub[cart + k], x0[k] + span);
      step[k] = pub[k] > plb[k] ? 0.25 * (pub[k] - plb[k]) : 1.0;  // held: any nonzero step
    }
    opt.set_lower_bounds(plb);
    opt.set_upper_bounds(pub);
    opt.set_initial_step(step);
    opt.set_maxeval(options.polish_evaluations);
    opt.set_xtol_rel(1e-4);
    opt.set_max_objective(
        [](unsigned, const double* v, double*, void* data) -> double {
          auto* c = static_cast<Context*>(data);
          if (c->evaluations >= c->budget || Clock::now() > c->deadline) throw nlopt::forced_stop();
          for (int k = 0; k < kCart; ++k) c->x[c->cart + k] = v[k];
          const double score = c->problem->Evaluate(c->problem->Decode(c->x), c->ws).score;
          ++c->evaluations;
          if (score > c->best) {
            c->best = score;
            c->x_best = c->x;
          }
          return score;
        },
        &c);
    double value = 0.0;
    try {
      opt.optimize(x0, value);
    } catch (const nlopt::forced_stop&) {
    } catch (const nlopt::roundoff_limited&) {
    } catch (const std::runtime_error&) {
    }
    evaluations += c.evaluations;
    x_best = c.x_best;
    score_best = c.best;
  }
  progress(0.7, "robustness");
  FixedPortsPlan out;
  out.ports = variants[variant];
  out.variants = static_cast<int>(variants.size());
  std::ostringstream search;
  search << "cart searched for the given ports: " << xs.size() << " poses (" << variants.size()
         << " assignment" << (variants.size() == 1 ? "" : "s") << " of the ports to the arms x "
         << directions.size() << " directions x " << distances.size() << " distances x "
         << offsets.size() << " headings x " << raises.size() << " table heights), then "
         << options.local << " on the best";
  out.search = search.str();
  std::vector<RankedPlan> finals(1);
  finals[0].placement = problem.Decode(x_best);
  // The sites as given (Decode recomputes them from the curve position: the same sites).
  finals[0].placement.sites = variants[variant].sites;
  evaluations += ScoreFinalPlans(problem, options, threads, progress, &finals);
  out.plan = std::move(finals[0]);
  out.evaluations = evaluations;
  out.verdict = JudgePlans(problem, {out.plan}, options);
  out.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  out.threads = threads;
  return out;
}

}  // namespace trocar::planners
