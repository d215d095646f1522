#pragma once
/// @file
/// The plan file (`plan.json`, format in docs/plan-format.md) of an optimiser's result, through
/// the plan file's one writer (plan/plan_file.hpp), and the ports as 3D Slicer markups. Both are
/// written atomically (temporary name, then rename); `plan.json` last, so a folder that
/// already holds a plan never holds half of a new one.

#include <functional>
#include <string>

#include "plan/plan_file.hpp"
#include "port_placement/optimizer.hpp"
#include "port_placement/port_rules.hpp"

namespace trocar::planners {

/// What a plan was made from, by path and content hash, so that `trocar check --plan` can tell
/// whether it still describes the same patient and robot.
struct PlanInputs {
  std::string case_dir;    ///< the patient case folder
  std::string robot_file;  ///< the robot description
  std::string case_hash;   ///< of patient.yaml (HashFile)
  std::string robot_hash;  ///< of the robot file (HashFile)
  std::string model_hash;  ///< of the patient model's geometry, targets, candidates and pose
};

/// The plan document of an optimiser's result (plan/plan_file.hpp), without verification.
/// `run` (threads, timings) is the only part that may differ between two runs with the same
/// inputs and seed.
PlanFile MakePlanFile(const PortPlacementProblem& problem, const PortPlacementResult& result,
                      const PortPlacementOptions& options, const PlanInputs& inputs);

/// The problem options a plan file's plans were scored with: the case's plan settings
/// (plan_config.hpp, from `file.case_dir`), then the arms and roles, weights, scoring and seed the
/// file records (a plan written before stop 51 has no served weight: 0; before stop 54 no
/// scope_moves: false). What `trocar verify` rebuilds the problem from.
/// @throws trocar::Error naming the file and field when a weight is missing or a value is out of
/// range.
ProblemOptions PlanProblemOptions(const PlanFile& file);

/// Plan `index` of `file` as the optimiser's RankedPlan in `problem` (built with
/// PlanProblemOptions): its ports from their candidates and `s` (checked against the stored
/// incisions), cart, status, score, rank score, nominal pose, terms and what its endoscope sees.
/// Not scored again: the setup-joint solver lands elsewhere for ports and cart differing in the
/// file's last digits. @throws trocar::Error naming the plan when a port's candidate is not the
/// patient's, a port is not where its candidate puts it, or the nominal pose does not fit the
/// robot.
RankedPlan RestorePlan(const PortPlacementProblem& problem, const PlanFile& file,
                       std::size_t index);

/// The ranked plans' ports as one Slicer markups file (a point list per plan, in the patient's
/// frame, LPS mm, labelled by arm).
void WritePortMarkups(const PortPlacementProblem& problem, const PortPlacementResult& result,
                      const std::string& path);

/// Writes `dir/ports.mrk.json` then `dir/plan.json` (each atomically), creating `dir`.
/// The inputs are stored by absolute paths. `finish`, when given, adds to the document before it
/// is written (the verification).
/// @throws trocar::Error naming the path when the folder cannot be made or a file written.
void WritePlanFolder(const std::string& dir, const PortPlacementProblem& problem,
                     const PortPlacementResult& result, const PortPlacementOptions& options,
                     const PlanInputs& inputs,
                     const std::function<void(PlanFile*)>& finish = nullptr);

}  // namespace trocar::planners
