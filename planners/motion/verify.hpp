#pragma once
/// @file
/// Verifying a plan by real motions: every instrument arm to every target sample from its start
/// pose (motion.hpp), the verified coverage, the samples served by verified motions, and a
/// verdict from them; the plan file's verification part (docs/plan-format.md) and the ranking
/// with the verified coverage in place of the claimed one.

#include <functional>
#include <string>
#include <vector>

#include "motion/motion.hpp"
#include "plan/plan_file.hpp"
#include "port_placement/optimizer.hpp"

namespace trocar::planners {

struct PlanVerification {
  MotionOptions options;
  std::vector<TargetMotion> motions;  ///< per instrument arm (in arm order), then per sample
  double claimed_coverage = 0.0;      ///< the plan's coverage term (inverse kinematics alone)
  double verified_coverage = 0.0;     ///< share of (instrument, sample) pairs with a motion
  /// Per sample: every instrument has a verified motion to it and an endoscope sees it.
  std::vector<bool> served;
  double served_fraction = 0.0;
  /// The plan's rank score with the verified coverage in place of the claimed one.
  double rank_score = 0.0;
  bool suitable = false;  ///< every target served on at least the suitable fraction of its samples
  std::vector<std::string> reasons;  ///< per target that is not
  double seconds = 0.0;              ///< wall-clock time of the verification
  int threads = 1;
  long states_checked = 0;
};

/// Verifies one ranked plan. Queries run on `threads` OpenMP threads (0: all cores), one
/// MotionContext each; each query has its own seed, so the result does not depend on the
/// thread count (motion.hpp, "Determinism").
/// `progress` (optional) is called from the calling thread with the motions planned so far and
/// the number of motions.
PlanVerification VerifyPlan(const PortPlacementProblem& problem, const RankedPlan& plan,
                            const MotionOptions& options, double suitable_fraction,
                            int threads = 0,
                            const std::function<void(int, int)>& progress = nullptr);

/// Plan indices by verified rank score, best first (stable: ties keep their order).
std::vector<std::size_t> VerifiedOrder(const std::vector<PlanVerification>& verifications);

/// Re-orders `result.plans` (and `verifications` with them) by the verified rank score, best
/// first (stable: ties keep their order).
void RankByVerification(PortPlacementResult* result, std::vector<PlanVerification>* verifications);

/// Adds each plan's verification (motions with their waypoints, coverage, verdict) to a plan
/// document made by MakePlanFile (port_placement/plan_io.hpp) or read back, plans in the same
/// order as `verifications` (a verification already there is replaced), and the verified verdict
/// to its verdict. `baselines` (optional): the verifications of the document's placed baselines,
/// in order (an entry per baseline; those not placed are skipped).
void AddVerification(PlanFile* file, const PortPlacementProblem& problem,
                     const std::vector<PlanVerification>& verifications,
                     const std::vector<PlanVerification>& baselines = {});

}  // namespace trocar::planners
