#pragma once
/// @file
/// The score terms of a placement (docs/plan-format.md, "Score terms and default weights"): each
/// a name, the unit of its value, its weight in ScoreWeights, how its value is measured, and its
/// evaluation from what the placement's evaluation found (reach and views per arm and sample,
/// clearances at the nominal pose). A new term is one entry in ScoreTermDefinitions
/// (score_terms.cpp) and its weight in ScoreWeights: the evaluation, the plan settings
/// (plan_config.cpp, `plan.weights`), the plan file and `trocar verify` name the terms and their
/// weights from this table.

#include <string>
#include <vector>

#include "port_placement/problem.hpp"

namespace trocar::planners {

/// What the terms are computed from: one placement's evaluation.
struct TermInputs {
  const Placement& placement;
  const std::vector<TargetSample>& samples;
  /// Per arm (the problem's order), per sample.
  const std::vector<std::vector<SampleReach>>& reach;
  const std::vector<bool>& served;      ///< per sample (Evaluation::served)
  const std::vector<int>& instruments;  ///< arm indices of the instrument arms
  const std::vector<int>& scopes;       ///< and of the endoscope arms
  const ProblemOptions& options;
  /// m, at the nominal pose; +inf when there is no such pair (one arm; no ribs).
  double clearance_arm_arm, clearance_arm_patient, clearance_instrument_rib;
};

/// A term's value and score (not yet clamped to [0, 1]); or why it does not apply to this
/// placement (then value 0, score 1, weight 0, and the reason as its note).
struct TermValue {
  double value = 0.0;
  double score = 0.0;
  std::string not_applicable;
};

struct ScoreTermDefinition {
  const char* name;              ///< "coverage"; also its weight's name in `plan.weights`
  const char* unit;              ///< of the value: "fraction", "deg", "m", "1"
  double ScoreWeights::*weight;  ///< its weight
  const char* note;              ///< how the value is measured and scored
  TermValue (*evaluate)(const TermInputs&);
};

/// Every score term, in the order a plan lists them.
const std::vector<ScoreTermDefinition>& ScoreTermDefinitions();

/// The terms of one placement, in ScoreTermDefinitions' order, each with its weight from
/// `weights` (0 where it does not apply) and its score clamped to [0, 1].
std::vector<ScoreTerm> EvaluateTerms(const TermInputs& in, const ScoreWeights& weights);

}  // namespace trocar::planners
