#pragma once
/// @file
/// The plan file (`plan.json`, format in docs/plan-format.md) and the ports as 3D Slicer markups.
/// Both are written atomically (temporary name, then rename); `plan.json` last, so a folder that
/// already holds a plan never holds half of a new one.

#include <functional>
#include <string>

#include "port_placement/optimizer.hpp"
#include "port_placement/port_rules.hpp"

namespace trocar::planners {

/// Version of the plan format written by PlanJson.
constexpr int kPlanFormatVersion = 2;

/// What a plan was made from, by path and content hash, so that `trocar check --plan` can tell
/// whether it still describes the same patient and robot.
struct PlanInputs {
  std::string case_dir;    ///< the patient case folder
  std::string robot_file;  ///< the robot description
  std::string case_hash;   ///< of patient.yaml
  std::string robot_hash;  ///< of the robot file
  std::string model_hash;  ///< of the patient model's geometry, targets, candidates and pose
};

/// "fnv1a64:<16 hex digits>" of a file's bytes. @throws trocar::Error when it cannot be read.
std::string HashFile(const std::string& path);
/// The same hash over the model's surfaces, targets, port candidates and X_WP.
std::string HashPatientModel(const patient::PatientModel& model);

/// The plan as JSON text. `run` (threads, timings) is the only part that may differ between two
/// runs with the same inputs and seed.
std::string PlanJson(const PortPlacementProblem& problem, const PortPlacementResult& result,
                     const PortPlacementOptions& options, const PlanInputs& inputs);

/// The ranked plans' ports as one Slicer markups file (a point list per plan, in the patient's
/// frame, LPS mm, labelled by arm).
void WritePortMarkups(const PortPlacementProblem& problem, const PortPlacementResult& result,
                      const std::string& path);

/// Writes `dir/ports.mrk.json` then `dir/plan.json` (each atomically), creating `dir`.
/// `finish`, when given, adds to the plan's JSON text before it is written (the verification).
/// @throws trocar::Error naming the path when the folder cannot be made or a file written.
void WritePlanFolder(const std::string& dir, const PortPlacementProblem& problem,
                     const PortPlacementResult& result, const PortPlacementOptions& options,
                     const PlanInputs& inputs,
                     const std::function<std::string(const std::string&)>& finish = nullptr);

}  // namespace trocar::planners
