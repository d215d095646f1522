#pragma once
/// @file
/// `trocar bench`: runs a spec's patients × port-placement algorithms × placement seeds (one
/// experiment per patient), then, for each patient and algorithm, every OMPL planner × motion
/// seed × (instrument arm, target sample) query on that algorithm's top plan (one experiment
/// each), in parallel with OpenMP: each thread has its own OMPL setup, planner, generator and
/// collision checker (MotionContext) over the shared immutable patient, robot and collision
/// world. Each finished run is committed to the database at once; a rerun skips the runs already
/// there (resumable). Under MPI (mpirun -np N), rank r takes every N-th run and rank 0 writes
/// the database.

#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "bench/spec.hpp"

namespace trocar::planners {

struct BenchReport {
  long runs = 0;          ///< in the spec
  long already_done = 0;  ///< found in the database at the start
  long added = 0;         ///< run now
  long in_database = 0;   ///< at the end
  double seconds = 0.0;
  int threads = 1;                ///< per rank
  int rank = 0, ranks = 1;        ///< MPI; only rank 0 has the database and the logs
  std::vector<std::string> logs;  ///< log files written
};

struct BenchOptions {
  int threads = -1;  ///< overrides the spec's threads when >= 0
  /// Stops after this many new runs (tests of resumption); < 0: no limit.
  long max_new_runs = -1;
  /// Progress lines ("placement runs: 12 to do of 12", ...), from the calling thread.
  std::function<void(const std::string&)> progress;
  /// After each run this process finishes: runs done and to do in the phase, and the phase
  /// ("placement runs", "motion runs"); from the calling thread of rank 0 only.
  std::function<void(long, long, const std::string&)> tick;
};

BenchReport RunBench(const BenchSpec& spec, const std::string& db_path,
                     const BenchOptions& options = {});

/// `trocar bench --summary DB`: per experiment and planner, runs, success rate, median time and
/// median path length, as text; with `plots_dir`, one PNG per experiment of the distribution of
/// solve times and path lengths (the share of runs solved within a time, as Planner Arena's
/// plots show it). @throws trocar::Error when the file is not an OMPL benchmark database.
std::string BenchSummary(const std::string& db_path, const std::string& plots_dir = "");

}  // namespace trocar::planners
