#pragma once
/// @file
/// The bench's results in OMPL's benchmark database schema (the tables and columns OMPL 1.5.2's
/// ompl_benchmark_statistics.py creates: `experiments`, `plannerConfigs`, `enums`, `runs` with one
/// column per run property, `progress`), so Planner Arena and plain SQL read it, plus trocar's own
/// tables (`trocar_bench`: the spec; `trocar_runs`: which runs are done) that make a bench
/// resumable. Each run is committed on its own: a bench killed at any point leaves a valid
/// database holding every run it finished. Beside it, the same runs in OMPL's benchmark log
/// format (`DB.log`; OMPL's parser reads one experiment per file, so experiment k > 1 goes to
/// `DB.k.log`).

#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

struct sqlite3;

namespace trocar::planners {

/// A run property: its name as OMPL writes it ("solution length") and its SQL type (REAL,
/// INTEGER, BOOLEAN, ENUM).
struct RunProperty {
  std::string name, type;
};
/// One run's values, in the order of the properties given with it; nullopt is NULL.
using RunValues = std::vector<std::optional<double>>;

struct ExperimentInfo {
  std::string name;  ///< no spaces (OMPL's log parser keeps the last word)
  double timelimit = 0.0;
  double memorylimit = 0.0;
  int runcount = 0;  ///< runs per planner
  unsigned seed = 0;
  std::string setup;  ///< the problem, in words
};

class BenchDatabase {
 public:
  /// Opens `path`, creating it with the schema when it does not exist. An existing file must be
  /// a trocar bench database of the same spec (`spec`, BenchSpec::Canonical()): anything else —
  /// not SQLite, another program's OMPL database, a bench of another spec — is refused with an
  /// error naming the file, and the file is left untouched. One writer at a time: the database
  /// is locked (an advisory lock on `<path>.lock`) for this object's life, and a second opener
  /// is told plainly that the database is in use.
  BenchDatabase(const std::string& path, const std::string& spec);
  ~BenchDatabase();
  BenchDatabase(const BenchDatabase&) = delete;
  BenchDatabase& operator=(const BenchDatabase&) = delete;

  /// Checks that a file is an OMPL benchmark database (its five tables); for --summary.
  /// @throws trocar::Error naming the file otherwise.
  static void CheckIsOmplDatabase(const std::string& path);

  /// The experiment's id, inserted when new (found by name otherwise).
  int Experiment(const ExperimentInfo& info);
  /// The planner configuration's id, inserted when new.
  int PlannerConfig(const std::string& name, const std::string& settings);
  /// Registers an enum (the `status` values) when not yet there.
  void Enum(const std::string& name, const std::vector<std::string>& values);
  /// Keys of the runs already in the database.
  std::set<std::string> DoneKeys() const;
  /// The payload stored with a run (trocar's own data, e.g. a placement), or "" when none.
  std::string Payload(const std::string& key) const;
  /// Adds one run in its own transaction, with its key (so a resumed bench skips it) and an
  /// optional payload. New properties become columns of `runs`.
  void AddRun(const std::string& key, int experiment, int planner,
              const std::vector<RunProperty>& properties, const RunValues& values,
              const std::string& payload = "");
  /// Sets every experiment's total time to the sum of its runs' `time` and `simplification time`.
  void UpdateTotalTimes();
  /// Runs in the database (all experiments).
  long RunCount() const;
  /// Writes the log files (atomically) beside `db_path`; @return their paths.
  std::vector<std::string> WriteLogs(const std::string& db_path) const;
  const std::string& path() const { return path_; }

 private:
  void Exec(const std::string& sql) const;
  struct Lock {
    int fd = -1;
    ~Lock();
  };
  Lock lock_;  // first: released last, and on a constructor's throw
  std::string path_;
  sqlite3* db_ = nullptr;
  std::map<std::string, std::string> column_types_;  // runs' property columns
};

/// "solution length" → "solution_length" (OMPL's column names).
std::string ColumnName(const std::string& property);

}  // namespace trocar::planners
