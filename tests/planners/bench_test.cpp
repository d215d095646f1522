// trocar bench: the spec checked whole before anything runs; the database in OMPL's schema (as
// OMPL's own parser makes it from our log) with the spec's run count; resumption after a stop
// and after SIGKILL without duplicates or losses; foreign files refused and left untouched.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sqlite3.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <set>
#include <thread>

#include "bench/database.hpp"
#include "bench/runner.hpp"
#include "bench/spec.hpp"
#include "common/error.hpp"
#include "common/file_util.hpp"
#include "motion/motion.hpp"
#include "test_util.hpp"

namespace trocar::planners {
namespace {

using test::SourcePath;
namespace fs = std::filesystem;

std::string TempDir(const std::string& name) {
  const std::string dir = (fs::temp_directory_path() / ("trocar_bench_test_" + name + "_" +
                                                         std::to_string(getpid())))
                              .string();
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

std::string WriteSpec(const std::string& dir, const std::string& body) {
  const std::string path = JoinPath(dir, "spec.yaml");
  std::ofstream(path) << body;
  return path;
}

std::string SmallSpec(const std::string& planners = "[rrtconnect, kpiece1]") {
  return "name: t\npatients: [" + SourcePath("patients/phantom-default") +
         "]\narms: [psm1]\nsamples_per_target: 2\nplacement:\n  algorithms: [crs2-lm+subplex]\n"
         "  evaluations: 60\n  polish_evaluations: 6\n  seeds: [1, 2]\nmotion:\n  planners: " +
         planners + "\n  time_limit: 0.3\n  seeds: [1, 2]\n";
}

std::string Robot() { return SourcePath("robots/davinci-classic/cart.yaml"); }

// Runs in the spec: placements P x A x S; motions P x A x planners x seeds x instruments x
// samples (one instrument, two targets x two samples on the phantom).
constexpr long kSmallRuns = 1 * 1 * 2 + 1 * 1 * 2 * 2 * 1 * 4;

struct Sql {
  explicit Sql(const std::string& path) {
    EXPECT_EQ(sqlite3_open_v2(path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr), SQLITE_OK);
  }
  ~Sql() { sqlite3_close(db); }
  std::vector<std::vector<std::string>> Rows(const std::string& q) const {
    std::vector<std::vector<std::string>> rows;
    sqlite3_stmt* s = nullptr;
    EXPECT_EQ(sqlite3_prepare_v2(db, q.c_str(), -1, &s, nullptr), SQLITE_OK) << q;
    while (s && sqlite3_step(s) == SQLITE_ROW) {
      std::vector<std::string> row;
      for (int c = 0; c < sqlite3_column_count(s); ++c) {
        const unsigned char* t = sqlite3_column_text(s, c);
        row.push_back(t ? reinterpret_cast<const char*>(t) : "NULL");
      }
      rows.push_back(row);
    }
    sqlite3_finalize(s);
    return rows;
  }
  long Count(const std::string& q) const { return std::stol(Rows(q).at(0).at(0)); }
  sqlite3* db = nullptr;
};

std::set<std::string> Schema(const Sql& sql, const std::string& table) {
  std::set<std::string> columns;
  for (const auto& r : sql.Rows("PRAGMA table_info(" + table + ")")) columns.insert(r[1] + " " + r[2]);
  return columns;
}

TEST(BenchSpec, UnknownNamesAreErrorsListingTheValidOnesBeforeAnythingRuns) {
  const std::string dir = TempDir("spec");
  auto error = [&](const std::string& body) {
    try {
      ReadBenchSpec(WriteSpec(dir, body), Robot());
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  std::string e = error(SmallSpec("[rrtconnect, rrt-star]"));
  EXPECT_NE(e.find("unknown planner 'rrt-star'"), std::string::npos) << e;
  EXPECT_NE(e.find("rrtstar"), std::string::npos) << e;
  EXPECT_NE(e.find("bitstar"), std::string::npos) << e;
  std::string body = SmallSpec();
  body.replace(body.find("crs2-lm+subplex"), 15, "direct+bobyqa");
  e = error(body);
  EXPECT_NE(e.find("unknown port-placement algorithm 'direct+bobyqa'"), std::string::npos) << e;
  EXPECT_NE(e.find("direct-l"), std::string::npos) << e;
  body = SmallSpec();
  body.replace(body.find("patients: ["), 11, "patients: [nowhere/case, ");
  e = error(body);
  EXPECT_NE(e.find("unknown patient 'nowhere/case'"), std::string::npos) << e;
  body = SmallSpec();
  body.replace(body.find("phantom-default"), 15, "phantom-defalt");
  e = error(body);
  EXPECT_NE(e.find("unknown patient"), std::string::npos) << e;
  EXPECT_NE(e.find("cases in "), std::string::npos) << e;  // the cases beside it
  EXPECT_NE(e.find("lidc2"), std::string::npos) << e;
  EXPECT_NE(e.find(", phantom-default"), std::string::npos) << e;
  EXPECT_NE(error(SmallSpec() + "moton: {}\n").find("moton"), std::string::npos);
  // A name given twice would run one run twice.
  e = error(SmallSpec("[rrtconnect, kpiece1, rrtconnect]"));
  EXPECT_NE(e.find("'rrtconnect' given twice"), std::string::npos) << e;
  body = SmallSpec();
  body.replace(body.find("seeds: [1, 2]"), 13, "seeds: [2, 2]");
  e = error(body);
  EXPECT_NE(e.find("'2' given twice"), std::string::npos) << e;
  // Nothing was made: the spec failed before the database.
  EXPECT_FALSE(fs::exists(JoinPath(dir, "out.db")));
}

TEST(BenchSpec, TheBundledSpecsRead) {
  for (const char* file : {"bench/specs/ci.yaml", "bench/specs/phantom.yaml"}) {
    const BenchSpec spec = ReadBenchSpec(SourcePath(file), Robot());
    EXPECT_FALSE(spec.patients.empty()) << file;
    EXPECT_FALSE(spec.planners.empty()) << file;
    EXPECT_FALSE(spec.algorithms.empty()) << file;
  }
}

TEST(Bench, TheDatabaseHasOmplsSchemaAndTheSpecsRunsAndOmplsParserReadsTheLog) {
  const std::string dir = TempDir("schema");
  const BenchSpec spec = ReadBenchSpec(WriteSpec(dir, SmallSpec()), Robot());
  const std::string db_path = JoinPath(dir, "out.db");
  const BenchReport report = RunBench(spec, db_path);
  EXPECT_EQ(report.runs, kSmallRuns);
  EXPECT_EQ(report.added, kSmallRuns);
  Sql sql(db_path);
  EXPECT_EQ(sql.Count("SELECT COUNT(*) FROM runs"), kSmallRuns);
  EXPECT_EQ(sql.Rows("PRAGMA integrity_check")[0][0], "ok");
  // Per motion planner: seeds x queries runs in each motion experiment.
  for (const auto& r : sql.Rows(
           "SELECT plannerConfigs.name, COUNT(*) FROM runs JOIN plannerConfigs ON "
           "runs.plannerid = plannerConfigs.id GROUP BY plannerConfigs.name")) {
    EXPECT_EQ(std::stol(r[1]), r[0].rfind("geometric_", 0) == 0 ? 8 : 2) << r[0];
  }
  // Solved runs have a path length and passed the re-check; status is OMPL's enum.
  EXPECT_EQ(sql.Count("SELECT COUNT(*) FROM runs WHERE solved = 1 AND status IS NOT NULL AND "
                      "(correct_solution IS NOT 1 OR simplified_solution_length IS NULL)"),
            0);
  EXPECT_EQ(sql.Count("SELECT COUNT(*) FROM enums WHERE name = 'status'"),
            static_cast<long>(MotionStatusNames().size()));
  // OMPL 1.5.2's own parser on our logs makes the same tables, columns and runs.
  ASSERT_EQ(report.logs.size(), 2u);  // one experiment per file (placement, motions)
  ASSERT_TRUE(IsRegularFile("/usr/bin/ompl_benchmark_statistics"))
      << "install ompl-demos (scripts/install-deps)";
  const std::string ref = JoinPath(dir, "ref.db");
  std::string command = "/usr/bin/ompl_benchmark_statistics";
  for (const auto& log : report.logs) command += " " + log;
  command += " -d " + ref + " > /dev/null 2>&1";
  ASSERT_EQ(std::system(command.c_str()), 0) << command;
  Sql parsed(ref);
  for (const std::string table : {"experiments", "plannerConfigs", "enums", "runs", "progress"})
    EXPECT_EQ(Schema(parsed, table), Schema(sql, table)) << table;
  EXPECT_EQ(parsed.Count("SELECT COUNT(*) FROM runs"), kSmallRuns);
  EXPECT_EQ(parsed.Count("SELECT COUNT(*) FROM runs WHERE solved = 1"),
            sql.Count("SELECT COUNT(*) FROM runs WHERE solved = 1"));
  EXPECT_EQ(parsed.Rows("SELECT SUM(time) FROM runs")[0][0].substr(0, 6),
            sql.Rows("SELECT SUM(time) FROM runs")[0][0].substr(0, 6));
  // The summary reads it back.
  const std::string summary = BenchSummary(db_path, JoinPath(dir, "plots"));
  EXPECT_NE(summary.find("RRTConnect"), std::string::npos) << summary;
  EXPECT_TRUE(IsRegularFile(JoinPath(dir, "plots/t_phantom-default_crs2-lm+subplex_motions.png")))
      << summary;
}

TEST(Bench, AStoppedBenchResumesWithoutRedoingOrLosingRuns) {
  const std::string dir = TempDir("resume");
  const BenchSpec spec = ReadBenchSpec(WriteSpec(dir, SmallSpec()), Robot());
  const std::string db_path = JoinPath(dir, "out.db");
  BenchOptions stop;
  stop.max_new_runs = 5;
  const BenchReport first = RunBench(spec, db_path, stop);
  EXPECT_EQ(first.added, 5);
  EXPECT_EQ(first.in_database, 5);
  const BenchReport second = RunBench(spec, db_path);
  EXPECT_EQ(second.already_done, 5);
  EXPECT_EQ(second.added, kSmallRuns - 5);
  Sql sql(db_path);
  EXPECT_EQ(sql.Count("SELECT COUNT(*) FROM runs"), kSmallRuns);
  EXPECT_EQ(sql.Count("SELECT COUNT(DISTINCT key) FROM trocar_runs"), kSmallRuns);
  EXPECT_EQ(sql.Count("SELECT COUNT(*) FROM experiments"), 2);
  // A third run has nothing to do.
  EXPECT_EQ(RunBench(spec, db_path).added, 0);
}

TEST(Bench, ABenchKilledMidWayLeavesAValidDatabaseAndCompletesOnRerun) {
  const std::string dir = TempDir("kill");
  std::string body = SmallSpec("[rrtconnect, rrt, kpiece1, est]");
  body.replace(body.find("seeds: [1, 2]\n", body.find("motion:")), 14,
               "seeds: [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]\n");
  const std::string spec = WriteSpec(dir, body);
  const std::string db_path = JoinPath(dir, "out.db");
  const long total = 2 + 4 * 10 * 4;
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    const int null = open("/dev/null", O_WRONLY);
    dup2(null, 1);
    dup2(null, 2);
    execl(TROCAR_BINARY, TROCAR_BINARY, "bench", spec.c_str(), "--out", db_path.c_str(),
          "--threads", "2", static_cast<char*>(nullptr));
    _exit(127);
  }
  // Kill it once some runs are in (or after 60 s, whatever it did).
  long seen = 0;
  for (int i = 0; i < 3000 && seen < 8; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
    if (!IsRegularFile(db_path)) continue;
    sqlite3* db = nullptr;
    if (sqlite3_open_v2(db_path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr) == SQLITE_OK) {
      sqlite3_stmt* s = nullptr;
      if (sqlite3_prepare_v2(db, "SELECT COUNT(*) FROM runs", -1, &s, nullptr) == SQLITE_OK &&
          sqlite3_step(s) == SQLITE_ROW)
        seen = sqlite3_column_int64(s, 0);
      sqlite3_finalize(s);
    }
    sqlite3_close(db);
  }
  kill(child, SIGKILL);
  int status = 0;
  waitpid(child, &status, 0);
  ASSERT_TRUE(WIFSIGNALED(status)) << "the bench ended before it was killed";
  long kept = 0;
  {
    Sql sql(db_path);
    EXPECT_EQ(sql.Rows("PRAGMA integrity_check")[0][0], "ok");
    kept = sql.Count("SELECT COUNT(*) FROM runs");
    EXPECT_EQ(sql.Count("SELECT COUNT(*) FROM trocar_runs"), kept);  // no run without its key
  }
  EXPECT_GE(kept, 8);
  EXPECT_LT(kept, total);
  const BenchReport rerun = RunBench(ReadBenchSpec(spec, Robot()), db_path);
  EXPECT_EQ(rerun.already_done, kept);
  EXPECT_EQ(rerun.added, total - kept);
  Sql sql(db_path);
  EXPECT_EQ(sql.Count("SELECT COUNT(*) FROM runs"), total);
  EXPECT_EQ(sql.Count("SELECT COUNT(DISTINCT key) FROM trocar_runs"), total);
}

// Two MPI ranks on this machine (mpirun from Debian's OpenMPI): one database from rank 0 with
// every run once, and the same results as one process with OpenMP for every run that finished
// well inside its time limit (a run stopped by the clock depends on the machine's load).
TEST(Bench, TwoMpiRanksWriteOneDatabaseWithTheSameRunsAsOneProcess) {
  ASSERT_TRUE(IsRegularFile("/usr/bin/mpirun")) << "install openmpi-bin (scripts/install-deps)";
  const std::string dir = TempDir("mpi");
  const std::string spec = WriteSpec(dir, SmallSpec());
  const std::string mpi_db = JoinPath(dir, "mpi.db"), omp_db = JoinPath(dir, "omp.db");
  const std::string command = "mpirun --allow-run-as-root --oversubscribe -np 2 " +
                              std::string(TROCAR_BINARY) + " bench " + spec + " --out " + mpi_db +
                              " --threads 1 --quiet > " + JoinPath(dir, "mpi.txt") + " 2>&1";
  ASSERT_EQ(std::system(command.c_str()), 0) << ReadTextFile(JoinPath(dir, "mpi.txt"));
  EXPECT_NE(ReadTextFile(JoinPath(dir, "mpi.txt")).find("x 2 MPI ranks"), std::string::npos)
      << ReadTextFile(JoinPath(dir, "mpi.txt"));
  RunBench(ReadBenchSpec(spec, Robot()), omp_db);
  Sql mpi(mpi_db), omp(omp_db);
  EXPECT_EQ(mpi.Count("SELECT COUNT(*) FROM runs"), kSmallRuns);
  EXPECT_EQ(mpi.Count("SELECT COUNT(DISTINCT key) FROM trocar_runs"), kSmallRuns);
  const std::string q =
      "SELECT t.key, r.solved, r.simplified_solution_length, r.time FROM runs r JOIN trocar_runs t "
      "ON t.runid = r.id WHERE t.key LIKE 'motion/%' ORDER BY t.key";
  const auto a = mpi.Rows(q), b = omp.Rows(q);
  ASSERT_EQ(a.size(), b.size());
  int compared = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(a[i][0], b[i][0]);
    // Only runs that finished far inside the 0.3 s limit in both (a loaded machine may run one
    // several times slower than the other).
    if (a[i][3] == "NULL" || b[i][3] == "NULL" || std::stod(a[i][3]) > 0.05 ||
        std::stod(b[i][3]) > 0.05)
      continue;
    ++compared;
    EXPECT_EQ(a[i][1], b[i][1]) << a[i][0];
    EXPECT_EQ(a[i][2].substr(0, 8), b[i][2].substr(0, 8)) << a[i][0];
  }
  EXPECT_GT(compared, 4);
}

// #44 item 4: one writer at a time (a second bench on the same database, in this process or
// another, is told it is in use; once the first is done it opens), and a spec that fails before
// its first run (an unknown arm) leaves no database bound to it.
TEST(Bench, OneWriterAtATimeAndASpecThatFailsLeavesNoDatabase) {
  const std::string dir = TempDir("lock");
  const std::string db = JoinPath(dir, "b.db");
  {
    BenchDatabase first(db, "spec");
    try {
      BenchDatabase second(db, "spec");
      ADD_FAILURE() << "two writers";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(db + ": in use by another trocar bench"), std::string::npos)
          << e.what();
    }
    const pid_t child = ::fork();
    if (child == 0) {
      try {
        BenchDatabase other(db, "spec");
        ::_exit(0);
      } catch (const Error& e) {
        ::_exit(std::string(e.what()).find("in use") != std::string::npos ? 3 : 4);
      }
    }
    int status = 0;
    ASSERT_EQ(::waitpid(child, &status, 0), child);
    EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 3) << "another process opened it too";
  }
  EXPECT_NO_THROW(BenchDatabase again(db, "spec"));
  BenchSpec spec = ReadBenchSpec(WriteSpec(dir, SmallSpec()), Robot());
  spec.arms = {"psm1", "no_such_arm"};
  const std::string bad = JoinPath(dir, "bad.db");
  EXPECT_THROW(RunBench(spec, bad), Error);
  EXPECT_FALSE(fs::exists(bad)) << "a spec that cannot run left a database bound to it";
}

TEST(Bench, AFileThatIsNotThisBenchsDatabaseIsRefusedAndLeftUntouched) {
  const std::string dir = TempDir("refuse");
  const BenchSpec spec = ReadBenchSpec(WriteSpec(dir, SmallSpec()), Robot());
  auto refused = [&](const std::string& path, const std::string& words) {
    const std::string before = ReadTextFile(path);
    try {
      RunBench(spec, path);
      ADD_FAILURE() << path << ": accepted";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
    }
    EXPECT_EQ(ReadTextFile(path), before) << path << " was changed";
  };
  const std::string text = JoinPath(dir, "notes.db");
  std::ofstream(text) << "my notes, not a database\n";
  refused(text, "not an SQLite database");
  // An SQLite database of something else.
  const std::string other = JoinPath(dir, "other.db");
  {
    sqlite3* db = nullptr;
    sqlite3_open(other.c_str(), &db);
    sqlite3_exec(db, "CREATE TABLE patients (name TEXT); INSERT INTO patients VALUES ('x');",
                 nullptr, nullptr, nullptr);
    sqlite3_close(db);
  }
  refused(other, "not an OMPL benchmark database");
  // OMPL's own database (its parser's), not made by trocar bench.
  const std::string ompl = JoinPath(dir, "ompl.db");
  {
    BenchSpec one = spec;
    one.planners = {"rrtconnect"};
    one.motion_seeds = {1};
    one.placement_seeds = {1};
    const BenchReport r = RunBench(one, JoinPath(dir, "ours.db"));
    const std::string command = "/usr/bin/ompl_benchmark_statistics " + r.logs[0] + " -d " +
                                ompl + " > /dev/null 2>&1";
    ASSERT_EQ(std::system(command.c_str()), 0);
    // A bench of another spec.
    refused(JoinPath(dir, "ours.db"), "another spec");
  }
  refused(ompl, "did not make");
  EXPECT_THROW(BenchSummary(text), Error);
  EXPECT_THROW(BenchSummary(other), Error);
  EXPECT_NO_THROW(BenchSummary(ompl));
}

}  // namespace
}  // namespace trocar::planners
