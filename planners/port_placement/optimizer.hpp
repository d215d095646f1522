#pragma once
/// @file
/// Choosing ports and the cart's pose: NLopt global algorithms (DIRECT-L, CRS2-LM, ISRES, MLSL)
/// each followed by a local polish (BOBYQA, Subplex or COBYLA), or the exhaustive baseline of
/// Cannon et al. 2003 over a grid of candidate ports; then the top k distinct plans, each scored
/// again with the targets moved (robustness), ranked, and a verdict for the patient.
///
/// Determinism: the global stage is split into a fixed number of starts (sectors of the cart's
/// direction), each with its own seed, evaluation budget and workspace; OpenMP runs the starts in
/// parallel and the results are merged in start order, so the same seed gives the same plans at
/// any thread count. The wall-clock limit is a safety cap: when it cuts a run short, the result
/// says so (and may then depend on the machine's speed).

#include <functional>
#include <string>
#include <vector>

#include "port_placement/fixed_ports.hpp"
#include "port_placement/problem.hpp"
#include "port_placement/selection_criteria.hpp"

namespace trocar::planners {

/// Valid names for PortPlacementOptions::algorithm and ::local.
std::vector<std::string> GlobalAlgorithms();  ///< direct-l, crs2-lm, isres, mlsl, exhaustive
std::vector<std::string> LocalAlgorithms();   ///< bobyqa, subplex, cobyla, none

struct PortPlacementOptions {
  std::string algorithm = "direct-l";
  std::string local = "bobyqa";
  /// Evaluations of the global stage, over all starts.
  int evaluations = 1200;
  /// Independent starts of the global stage (a fixed number: not the thread count).
  int starts = 4;
  /// Evaluations of each local polish.
  int polish_evaluations = 100;
  /// Wall-clock cap for the whole plan, in seconds.
  double time_limit = 120.0;
  /// OpenMP threads; 0: all cores.
  int threads = 0;
  unsigned seed = 1;
  /// Distinct plans returned.
  int top_k = 3;
  /// Two plans are distinct when some arm's ports are farther apart than this (m).
  double distinct_distance = 0.025;
  /// Robustness: targets moved by this distance along ±x, ±y, ±z of the patient (m); 0: skip.
  double robustness_shift = 0.02;
  /// Weight of the robustness loss in the rank: rank = score − weight · (score − mean moved
  /// score)⁺.
  double robustness_weight = 0.5;
  /// Share of each target's samples that must be served (both instruments reach, the scope sees)
  /// for the patient to be suitable.
  double suitable_fraction = 0.8;
  /// Placements evaluated first, before Cannon's grid and the global algorithm, and kept in the
  /// archive the polished plans are chosen from: the search starts from what surgeons do (`trocar
  /// plan` passes the published template's ports with the cart found for them), so the best plan
  /// scores at least as well as they do. Not used by the exhaustive baseline.
  std::vector<Placement> initial;
  /// The verdict says, for each unserved stretch, the neighbouring port or cart pose that would
  /// reach it when one does (remedies.hpp; about 10 full evaluations per stretch). Off by
  /// default (batches and tests do not pay for it); `trocar plan` turns it on.
  bool remedies = false;
  /// Called with the fraction done (0..1) and a stage name, from the calling thread only.
  std::function<void(double, const std::string&)> progress;
};

/// A target moved for the robustness check, and how the plan fares.
struct Shift {
  Eigen::Vector3d d_P = Eigen::Vector3d::Zero();  ///< the move, in the patient frame (m)
  double score = 0.0;
  double coverage = 0.0;
  double served = 0.0;  ///< share of samples served
};

struct RankedPlan {
  Placement placement;
  Evaluation evaluation;  ///< detailed, with the setup-joint solver's full effort
  std::vector<Shift> shifts;
  double robust_score = 0.0;  ///< mean score over the shifts (the score itself when skipped)
  double degradation = 0.0;   ///< score − robust_score
  double rank_score = 0.0;
};

/// What a target needs that no plan gives it.
struct Verdict {
  bool suitable = false;
  std::string summary;               ///< one line
  std::vector<std::string> reasons;  ///< one per failing target stretch
};

/// Best score so far against evaluations, for the convergence figure.
struct TracePoint {
  int evaluations = 0;
  double best = 0.0;
};

struct Baseline;

struct PortPlacementResult {
  std::vector<RankedPlan> plans;  ///< best first
  Verdict verdict;
  std::string algorithm, local;
  int evaluations = 0;  ///< global + polish + final
  int global_evaluations = 0;
  double best_global_score = 0.0;
  std::vector<TracePoint> trace;  ///< global stage, starts interleaved in order
  std::vector<std::pair<std::string, double>> timings;  ///< stage, seconds
  bool time_limit_hit = false;
  int threads = 1;
  std::string grid;  ///< the exhaustive baseline's grid, when it ran
  /// Where the plans' ports came from when they were given, not optimised ("template: ...",
  /// "surgeon: FILE"); empty for the optimiser's.
  std::string ports_given;
  std::vector<std::string> ports_where;  ///< per arm, with ports_given
  /// Plans to compare the optimised ones with (the template placed on this patient, a surgeon's
  /// ports), each searched, scored and judged as the optimiser's are.
  std::vector<Baseline> baselines;
  /// The anatomical selection criteria (selection_criteria.hpp) measured on the CT, at the best
  /// plan's camera port, and their comparison with the verdict that counts; set by the caller
  /// (`trocar plan`), empty otherwise.
  SelectionCriteria criteria;
  std::string criteria_comparison;
};

/// Runs the whole planning job on a problem.
/// @throws trocar::Error for an unknown algorithm or local method (listing the valid names), a
///         non-positive time limit or budget.
PortPlacementResult OptimizePorts(const PortPlacementProblem& problem,
                                  const PortPlacementOptions& options);

/// The detailed evaluation a final plan gets (the better of the optimiser's setup-joint effort
/// and the full effort); what `trocar bench` re-evaluates a recorded placement
/// with. `full_effort` (optional) tells which one it is.
Evaluation EvaluateFinalPlan(const PortPlacementProblem& problem, const Placement& placement,
                             Workspace* workspace, bool* full_effort = nullptr);

/// A plan for ports given by a template or a surgeon (fixed_ports.hpp): the cart's pose searched
/// for them (the ports stay), then evaluated, re-scored for robustness and judged exactly as the
/// optimiser's plans are.
struct FixedPortsPlan {
  RankedPlan plan;
  FixedPorts ports;   ///< the assignment of the ports to the arms that was taken
  int variants = 1;   ///< assignments tried
  int evaluations = 0;
  double seconds = 0.0;
  int threads = 1;
  Verdict verdict;    ///< as if this were the only plan
  std::string search; ///< how the cart was searched
};

/// A plan to compare with: placed (its FixedPortsPlan), or why it could not be placed.
struct Baseline {
  std::string kind;  ///< "template", "surgeon"
  std::string name;
  bool placed = false;
  std::string why_not;
  FixedPortsPlan fixed;
};

/// The best cart pose for each of `variants` (the same ports given to the arms in different
/// ways), the best variant taken. Deterministic: no random numbers.
/// @throws trocar::Error for bad options (as OptimizePorts) or no variants.
FixedPortsPlan PlanFixedPorts(const PortPlacementProblem& problem,
                              const std::vector<FixedPorts>& variants,
                              const PortPlacementOptions& options);

/// Which target samples a straight line reaches from a port site, clear of the patient's
/// structures (CollisionWorld::FirstAcross): `shaft[s]`, the line from the site's pivot to
/// sample s's aim point, its last kWorkSiteRadius left out (the jaws may touch the organ there);
/// `sight[s]`, the line of sight from where an endoscope through the site would be (at the
/// working distance from the targets' centroid, as GeometricScore places it) to the sample, its
/// last kSightMargin left out. No robot: what the port alone allows.
struct SiteAccess {
  std::vector<char> shaft, sight;
};
SiteAccess SiteLines(const PortPlacementProblem& problem, const PortSite& site);

/// The port-only part of the score (no robot), Cannon et al. 2003's grid measure: reach by
/// distance, approach and triangulation angles, the endoscope's view, spacing, and the share of
/// samples every instrument reaches and the endoscope sees (`served`). With `access` (one per arm,
/// SiteLines of its site), a sample counts as reached or seen only along a clear line.
double GeometricScore(const PortPlacementProblem& problem, const std::vector<PortSite>& sites,
                      const std::vector<const SiteAccess*>& access = {});

/// Checks options before any work (same errors as OptimizePorts).
void ValidateOptions(const PortPlacementOptions& options);

}  // namespace trocar::planners
