#include "motion/verify.hpp"

#include <omp.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <exception>
#include <limits>
#include <map>
#include <numeric>
#include <sstream>

#include "common/error.hpp"
#include "patient/patient_model.hpp"

namespace trocar::planners {

PlanVerification VerifyPlan(const PortPlacementProblem& problem, const RankedPlan& plan,
                            const MotionOptions& options, double suitable_fraction,
                            int threads, const std::function<void(int, int)>& progress) {
  ValidateMotionOptions(options);
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  PlanVerification v;
  v.options = options;
  const Evaluation& ev = plan.evaluation;
  const int ns = static_cast<int>(problem.samples().size());
  std::vector<int> instruments, scopes;
  for (int a = 0; a < static_cast<int>(problem.arms().size()); ++a)
    (problem.arms()[a].role == ArmRole::kInstrument ? instruments : scopes).push_back(a);
  const int queries = static_cast<int>(instruments.size()) * ns;
  v.motions.resize(queries);
  if (const ScoreTerm* coverage = ev.Find("coverage")) v.claimed_coverage = coverage->value;
  const bool placed = ev.status == PlacementStatus::kPlaced && ev.q_nominal.size() > 0;
  if (!placed) {
    for (int k = 0; k < queries; ++k) {
      TargetMotion& m = v.motions[k];
      m.arm = instruments[k / ns];
      m.sample = k % ns;
      m.status = MotionStatus::kInvalidStart;
      m.outcome = "invalid start";
      m.reason = ev.status == PlacementStatus::kInCollision
                     ? "the plan's nominal pose is in collision"
                     : "the plan's arms are not placed at their ports";
    }
  } else {
    const MotionProblem motion_problem(problem, plan.placement, ev);
    const int n_threads = threads > 0 ? threads : omp_get_max_threads();
    v.threads = std::max(1, std::min(n_threads, std::max(queries, 1)));
    std::vector<long> checks(v.threads, 0);
    // The failure of the lowest query, rethrown as it was (a bad input stays trocar::Error, a
    // fault stays trocar::InternalError), whatever the threads' timing.
    std::exception_ptr error;
    int error_query = queries;
    std::atomic<int> planned{0};
#pragma omp parallel num_threads(v.threads)
    {
      MotionContext context(motion_problem);
#pragma omp for schedule(dynamic, 1)
      for (int k = 0; k < queries; ++k) {
        try {
          v.motions[k] = context.Plan(instruments[k / ns], k % ns, options);
          const int done = planned.fetch_add(1) + 1;
          if (progress && omp_get_thread_num() == 0) progress(done, queries);
        } catch (...) {
#pragma omp critical(trocar_verify_error)
          if (k < error_query) {
            error = std::current_exception();
            error_query = k;
          }
        }
      }
      checks[omp_get_thread_num()] = context.checks();
    }
    if (error) std::rethrow_exception(error);
    v.states_checked = std::accumulate(checks.begin(), checks.end(), 0L);
  }
  int solved = 0;
  for (const auto& m : v.motions) solved += m.solved;
  v.verified_coverage = queries > 0 ? static_cast<double>(solved) / queries : 0.0;
  // Served: every instrument moves there, and an endoscope sees it (from the plan's evaluation).
  v.served.assign(ns, placed);
  for (int s = 0; s < ns; ++s) {
    for (std::size_t i = 0; i < instruments.size(); ++i)
      v.served[s] = v.served[s] && v.motions[i * ns + s].solved;
    if (!scopes.empty()) {
      bool seen = false;
      for (const auto& r : ev.reaches) {
        if (r.sample == s && problem.arms()[r.arm].role == ArmRole::kEndoscope) seen |= r.seen;
      }
      v.served[s] = v.served[s] && seen;
    }
  }
  v.served_fraction =
      ns > 0 ? static_cast<double>(std::count(v.served.begin(), v.served.end(), true)) / ns : 0.0;
  const ScoreWeights& w = problem.options().weights;
  const std::vector<bool>& claimed = plan.evaluation.served;
  const double claimed_served =
      claimed.empty() ? 0.0
                      : static_cast<double>(std::count(claimed.begin(), claimed.end(), true)) /
                            static_cast<double>(claimed.size());
  v.rank_score = plan.rank_score -
                 (w.coverage * (v.claimed_coverage - v.verified_coverage) +
                  w.served * (claimed_served - v.served_fraction)) /
                     w.sum();
  // The verdict from verified motions: each target served on its share of samples.
  const auto& targets = problem.patient().targets;
  v.suitable = placed && ns > 0;
  for (int t = 0; t < static_cast<int>(targets.size()); ++t) {
    int total = 0, served = 0;
    for (int s = 0; s < ns; ++s) {
      if (problem.samples()[s].target != t) continue;
      ++total;
      served += v.served[s];
    }
    if (total == 0) continue;
    if (served < suitable_fraction * total) {
      v.suitable = false;
      std::ostringstream why;
      why << targets[t].name << ": " << served << " of " << total
          << " samples served by verified motions (needs "
          << std::lround(suitable_fraction * 100) << " %)";
      // The most common reason among its failed motions.
      std::map<std::string, int> reasons;
      for (const auto& m : v.motions) {
        if (!m.solved && problem.samples()[m.sample].target == t) ++reasons[m.outcome + ": " + m.reason];
      }
      if (!reasons.empty()) {
        const auto most = std::max_element(
            reasons.begin(), reasons.end(),
            [](const auto& a, const auto& b) { return a.second < b.second; });
        why << "; most often " << most->first;
      }
      v.reasons.push_back(why.str());
    }
  }
  v.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  return v;
}

std::vector<std::size_t> VerifiedOrder(const std::vector<PlanVerification>& verifications) {
  std::vector<std::size_t> order(verifications.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) {
    return verifications[a].rank_score > verifications[b].rank_score;
  });
  return order;
}

void RankByVerification(PortPlacementResult* result,
                        std::vector<PlanVerification>* verifications) {
  TROCAR_CHECK(result->plans.size() == verifications->size(),
                      "ranking: " << verifications->size() << " verifications for "
                                  << result->plans.size() << " plans");
  const std::vector<std::size_t> order = VerifiedOrder(*verifications);
  std::vector<RankedPlan> plans;
  std::vector<PlanVerification> ver;
  for (std::size_t i : order) {
    plans.push_back(result->plans[i]);
    ver.push_back((*verifications)[i]);
  }
  result->plans = std::move(plans);
  *verifications = std::move(ver);
}

namespace {

// A plan's verification as the plan file stores it (`plans[].verification`).
void StoreVerification(const PortPlacementProblem& problem, const PlanVerification& v,
                       StoredPlan* plan) {
  const robot::RobotModel& robot = problem.robot();
  plan->verified = true;
  StoredVerificationRun& run = plan->verification_run;
  run.planner = OmplPlannerName(v.options.planner);
  run.time_limit = v.options.time_limit;
  run.check_step = v.options.check_step;
  run.recheck_step = v.options.recheck_step;
  run.prismatic_weight_per_m = 10.0;
  run.seed = v.options.seed;
  run.rank_score = v.rank_score;
  run.states_checked = v.states_checked;
  run.seconds = v.seconds;
  run.threads = v.threads;
  plan->claimed_coverage = v.claimed_coverage;
  plan->verified_coverage = v.verified_coverage;
  plan->verified_served = v.served;
  plan->served_fraction = v.served_fraction;
  plan->verified_suitable = v.suitable;
  plan->verification_reasons = v.reasons;
  plan->motions.clear();
  for (const auto& m : v.motions) {
    const PlanArm& arm = problem.arms()[m.arm];
    StoredMotion s;
    s.arm = arm.name;
    s.sample = m.sample;
    s.outcome = m.outcome;
    s.status = ToString(m.status);
    s.solved = m.solved;
    s.planning_time = m.planning_time;
    s.simplification_time = m.simplification_time;
    s.graph_states = m.graph_states;
    s.reason = m.reason;
    s.has_path = !m.path.empty();
    if (s.has_path) {
      s.path_length = m.path_length;
      s.raw_path_length = m.raw_path_length;
      s.tip_path_length = m.tip_path_length;
      s.rechecked_states = m.rechecked_states;
      s.min_clearance = std::isfinite(m.min_clearance) ? m.min_clearance
                                                       : std::numeric_limits<double>::quiet_NaN();
      for (int i : arm.q_indices) s.joints.push_back(robot.joint(robot.active_joints()[i]).name);
      s.waypoints = m.path;
    }
    if (!m.solved && m.failure_q.size() == static_cast<Eigen::Index>(arm.q_indices.size())) {
      if (s.joints.empty())
        for (int i : arm.q_indices) s.joints.push_back(robot.joint(robot.active_joints()[i]).name);
      s.failure_pose = m.failure_q;
    }
    plan->motions.push_back(std::move(s));
  }
}

}  // namespace

void AddVerification(PlanFile* file, const PortPlacementProblem& problem,
                     const std::vector<PlanVerification>& verifications,
                     const std::vector<PlanVerification>& baselines) {
  if (!baselines.empty()) {
    std::size_t next = 0;
    for (StoredBaseline& b : file->baselines) {
      if (!b.placed) continue;
      TROCAR_CHECK(next < baselines.size(), "plan file: more placed baselines than verifications");
      const PlanVerification& v = baselines[next++];
      StoreVerification(problem, v, &b.plan);
      b.verified = StoredVerdict{v.suitable, "", v.reasons};
    }
  }
  TROCAR_CHECK(file->plans.size() == verifications.size(),
               "plan file: " << file->plans.size() << " plans, " << verifications.size()
                             << " verifications");
  for (std::size_t k = 0; k < verifications.size(); ++k)
    StoreVerification(problem, verifications[k], &file->plans[k]);
  if (!verifications.empty()) {
    const PlanVerification& best = verifications.front();
    std::ostringstream summary;
    summary << (best.suitable ? "suitable" : "not suitable") << " by verified motions: plan 1 "
            << std::lround(best.verified_coverage * 100) << " % of instrument motions verified, "
            << std::lround(best.served_fraction * 100) << " % of target samples served";
    file->has_verified_verdict = true;
    file->verified_suitable = best.suitable;
    file->verified_summary = summary.str();
    file->verified_reasons = best.reasons;
  }
}

}  // namespace trocar::planners
