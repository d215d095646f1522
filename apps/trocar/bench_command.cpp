// trocar bench SPEC.yaml --out DB: patients x port-placement algorithms x OMPL planners x seeds,
// in parallel, into an SQLite database in OMPL's benchmark schema (Planner Arena) and OMPL's
// log format beside it; resumable. trocar bench --summary DB: statistics and plots.
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <memory>

#include "apps/trocar/commands.hpp"
#include "apps/trocar/progress.hpp"
#include "bench/runner.hpp"
#include "bench/spec.hpp"
#include "common/error.hpp"
#include "common/file_util.hpp"

namespace trocar::apps {
namespace {

struct BenchCommandOptions {
  std::string spec;
  std::string out;
  std::string summary;
  std::string plots;
  int threads = -1;
  long max_runs = -1;
  bool quiet = false;
};

std::string DefaultRobotFile() {
  std::string file = "robots/davinci-classic/cart.yaml";
  if (!IsRegularFile(file)) file = std::string(TROCAR_SOURCE_DIR) + "/" + file;
  return file;
}

int RunBenchCommand(const BenchCommandOptions& o) {
  if (!o.summary.empty()) {
    TROCAR_THROW_UNLESS(o.spec.empty(), "--summary reads a database: give no spec with it");
    std::cout << planners::BenchSummary(o.summary, o.plots);
    return 0;
  }
  TROCAR_THROW_UNLESS(!o.spec.empty(), "a bench spec (SPEC.yaml) is required, or --summary DB");
  TROCAR_THROW_UNLESS(!o.out.empty(), "--out: the database file is required");
  const planners::BenchSpec spec = planners::ReadBenchSpec(o.spec, DefaultRobotFile());
  planners::BenchOptions options;
  options.threads = o.threads;
  options.max_new_runs = o.max_runs;
  TerminalProgress bar(o.quiet);
  if (!o.quiet) {
    options.progress = [&bar](const std::string& line) {
      bar.Clear();
      std::cout << line << "\n" << std::flush;
    };
  }
  options.tick = [&bar](long done, long of, const std::string& phase) {
    bar.Update(of > 0 ? static_cast<double>(done) / of : -1.0,
               phase + ": " + std::to_string(done) + " of " + std::to_string(of));
  };
  const planners::BenchReport r = planners::RunBench(spec, o.out, options);
  bar.Clear();
  if (r.rank != 0) return 0;  // MPI: rank 0 reports for all
  std::cout << std::fixed << std::setprecision(1) << "runs: " << r.runs << " in the spec, "
            << r.already_done << " already done, " << r.added << " run now in " << r.seconds
            << " s on " << r.threads << " thread" << (r.threads == 1 ? "" : "s")
            << (r.ranks > 1 ? " x " + std::to_string(r.ranks) + " MPI ranks" : std::string())
            << "; "
            << r.in_database << " in " << o.out << "\n";
  for (const auto& log : r.logs) std::cout << "log: " << log << "\n";
  if (r.in_database < r.runs) {
    std::cout << "incomplete: run the same command again to continue\n";
    return 5;
  }
  if (!o.quiet) std::cout << "\n" << planners::BenchSummary(o.out, o.plots);
  return 0;
}

}  // namespace

void AddBenchCommand(CLI::App* app) {
  auto o = std::make_shared<BenchCommandOptions>();
  CLI::App* cmd = app->add_subcommand(
      "bench",
      "Compare port-placement algorithms and OMPL planners over patients and seeds; results in "
      "an SQLite database in OMPL's benchmark schema (Planner Arena) and OMPL's log format");
  cmd->add_option("spec", o->spec, "bench spec (YAML; bench/specs/*.yaml, docs/bench.md)");
  cmd->add_option("--out", o->out,
                  "database file (created; an interrupted bench continues where it stopped)");
  cmd->add_option("--summary", o->summary,
                  "print success rates and median times of an OMPL benchmark database");
  cmd->add_option("--plots", o->plots, "folder for distribution plots (PNG), one per experiment");
  cmd->add_option("--threads", o->threads, "OpenMP threads (default: the spec's; 0: all cores)");
  cmd->add_option("--max-runs", o->max_runs, "stop after this many new runs (resume later)");
  cmd->add_flag("--quiet", o->quiet, "print only the totals");
  cmd->footer(
      "Exit status: 0 every run of the spec is in the database; 5 stopped early (--max-runs): "
      "run again to continue; 1 bad input; 2 internal error.");
  cmd->callback([o]() {
    const int code = RunBenchCommand(*o);
    if (code != 0) throw CLI::RuntimeError(code);
  });
}

}  // namespace trocar::apps
