#pragma once
/// @file
/// A bench specification (`trocar bench SPEC.yaml`): which patients, port-placement algorithms,
/// OMPL planners and seeds to run, and their budgets. Format in docs/bench.md; read and checked
/// whole before anything runs: an unknown planner, algorithm or patient is an error listing the
/// valid names.

#include <string>
#include <vector>

namespace trocar::planners {

/// A port-placement algorithm: a global stage and a local polish ("direct-l+bobyqa").
struct BenchAlgorithm {
  std::string global, local;
  std::string name() const { return global + "+" + local; }
};

struct BenchSpec {
  std::string file;  ///< where it was read from
  std::string name;  ///< the experiment names' prefix
  std::vector<std::string> patients;  ///< case folders, resolved to paths
  std::string robot;                  ///< robot description, resolved
  std::vector<std::string> arms;      ///< arms to place; empty: all
  int samples_per_target = 4;
  // Port placement.
  std::vector<BenchAlgorithm> algorithms;
  int evaluations = 300;
  int polish_evaluations = 30;
  int top_k = 1;
  std::vector<unsigned> placement_seeds = {1};
  // Motions: per (patient, algorithm), the top plan of the first placement seed; each planner
  // runs every (instrument, target sample) query once per motion seed.
  std::vector<std::string> planners;
  double time_limit = 1.0;  ///< s per motion query
  std::vector<unsigned> motion_seeds = {1};
  int threads = 0;  ///< 0: all cores
  /// The spec's content, canonical (for the database: a bench resumes only the same spec).
  std::string Canonical() const;
};

/// Reads and checks a spec. Relative paths are taken from the spec's folder, then the current
/// folder; without `robot:`, `default_robot`.
/// @throws trocar::Error naming the file, line and field, and listing valid names.
BenchSpec ReadBenchSpec(const std::string& path, const std::string& default_robot);

}  // namespace trocar::planners
