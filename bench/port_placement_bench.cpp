// Port-placement benchmark (issue 13), every figure from one run on one machine:
//  - the full plan (global stage, polish, top 3, robustness) with the default options, 2 threads;
//  - per global algorithm (DIRECT-L, CRS2-LM, ISRES, MLSL): best score against evaluations (a PNG
//    plot and a table), evaluations per second of the global stage, the final best score;
//  - the OpenMP speed-up of the global stage on 2 threads against 1 (same seed, same plan);
//  - the exhaustive baseline of Cannon et al. 2003: its time and score beside them;
//  - the setup-joint memo against solving every time (the global stage; the same plan).
//   port_placement_bench [case_dir=patients/phantom-default] [out_dir=out/bench] [evaluations=1200]
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <limits>
#include <string>
#include <vector>

#include "common/error.hpp"
#include "common/plot.hpp"
#include "patient/patient_model.hpp"
#include "port_placement/optimizer.hpp"
#include "robot/load_robot.hpp"

namespace {

using namespace trocar;
using Clock = std::chrono::steady_clock;

double Seconds(const planners::PortPlacementResult& r, const std::string& stage) {
  for (const auto& [name, s] : r.timings) {
    if (name == stage) return s;
  }
  return std::numeric_limits<double>::quiet_NaN();
}

double BestAt(const planners::PortPlacementResult& r, int evaluations) {
  double best = std::numeric_limits<double>::quiet_NaN();
  for (const auto& p : r.trace) {
    if (p.evaluations > evaluations) break;
    best = p.best;
  }
  return best;
}

}  // namespace

int main(int argc, char** argv) {
  const std::string case_dir =
      argc > 1 ? argv[1] : std::string(TROCAR_SOURCE_DIR) + "/patients/phantom-default";
  const std::string out_dir = argc > 2 ? argv[2] : "out/bench";
  const int evaluations = argc > 3 ? std::stoi(argv[3]) : 1200;
  try {
    std::filesystem::create_directories(out_dir);
    auto robot = std::make_shared<const robot::RobotModel>(
        robot::LoadRobot(std::string(TROCAR_SOURCE_DIR) + "/robots/davinci-classic/cart.yaml"));
    auto patient =
        patient::ImportCase(case_dir).model;
    const planners::PortPlacementProblem problem(patient, robot, {});
    std::printf("port placement benchmark: %s, %zu arms, %zu target samples, %zu curves\n",
                case_dir.c_str(), problem.arms().size(), problem.samples().size(),
                patient->port_candidates.size());

    // 1. The full plan, default options, 2 threads.
    planners::PortPlacementOptions full;
    full.threads = 2;
    full.evaluations = evaluations;
    auto t0 = Clock::now();
    const auto plan = planners::OptimizePorts(problem, full);
    const double full_s = std::chrono::duration<double>(Clock::now() - t0).count();
    std::printf("\nfull plan (direct-l + bobyqa, top 3, robustness), 2 threads: %.1f s, "
                "%d evaluations, best score %.3f, verdict: %s\n",
                full_s, plan.evaluations, plan.plans.empty() ? NAN : plan.plans[0].evaluation.score,
                plan.verdict.summary.c_str());

    // 2. Per algorithm: the global stage and its polish only (top 1, no robustness).
    const std::vector<std::array<std::uint8_t, 3>> colours = {
        {31, 119, 180}, {214, 39, 40}, {44, 160, 44}, {148, 103, 189}, {0, 0, 0}};
    PlotPanel panel{"best score", "evaluations (" + patient->name + ", global stage)", "", {}};
    std::printf("\n%-10s %10s %10s %10s %10s %10s %12s %10s\n", "algorithm", "best@100",
                "best@300", "best@600", "best@all", "final", "global s", "evals/s");
    std::string csv = "algorithm,evaluations,best_at_100,best_at_300,best_at_600,best_global,"
                      "final_score,global_seconds,evaluations_per_second,threads\n";
    const std::vector<std::string> algorithms = {"direct-l", "crs2-lm", "isres", "mlsl",
                                                 "exhaustive"};
    double exhaustive_score = NAN;
    for (std::size_t k = 0; k < algorithms.size(); ++k) {
      planners::PortPlacementOptions o;
      o.algorithm = algorithms[k];
      o.threads = 2;
      o.evaluations = evaluations;
      o.top_k = 1;
      o.robustness_shift = 0.0;
      const auto r = planners::OptimizePorts(problem, o);
      const double global_s = Seconds(r, "global " + o.algorithm);
      const double final_score = r.plans.empty() ? NAN : r.plans[0].evaluation.score;
      if (o.algorithm == "exhaustive") exhaustive_score = final_score;
      std::printf("%-10s %10.3f %10.3f %10.3f %10.3f %10.3f %12.1f %10.1f\n", o.algorithm.c_str(),
                  BestAt(r, 100), BestAt(r, 300), BestAt(r, 600), r.best_global_score,
                  final_score, global_s, r.global_evaluations / global_s);
      char line[512];
      std::snprintf(line, sizeof line, "%s,%d,%.6f,%.6f,%.6f,%.6f,%.6f,%.3f,%.2f,%d\n",
                    o.algorithm.c_str(), r.global_evaluations, BestAt(r, 100), BestAt(r, 300),
                    BestAt(r, 600), r.best_global_score, final_score, global_s,
                    r.global_evaluations / global_s, r.threads);
      csv += line;
      PlotSeries series{o.algorithm, {}, {}, colours[k]};
      for (const auto& p : r.trace) {
        series.x.push_back(p.evaluations);
        series.y.push_back(p.best);
      }
      panel.series.push_back(series);
    }
    std::printf("exhaustive grid: %s\n", "5 sites per curve, 8 cart directions x 3 distances");

    // 3. OpenMP speed-up of the global stage: 1 thread against 2, same seed and budget.
    double seconds[2] = {0, 0};
    double scores[2] = {0, 0};
    for (int t = 1; t <= 2; ++t) {
      planners::PortPlacementOptions o;
      o.threads = t;
      o.evaluations = evaluations;
      o.local = "none";
      o.top_k = 1;
      o.robustness_shift = 0.0;
      const auto r = planners::OptimizePorts(problem, o);
      seconds[t - 1] = Seconds(r, "global " + o.algorithm);
      scores[t - 1] = r.best_global_score;
    }
    std::printf("\nOpenMP, global stage direct-l (%d evaluations, 4 starts): 1 thread %.2f s, "
                "2 threads %.2f s, speed-up %.2fx; best score %.4f and %.4f (must be equal)\n",
                evaluations, seconds[0], seconds[1], seconds[0] / seconds[1], scores[0],
                scores[1]);
    csv += "openmp_speedup," + std::to_string(seconds[0] / seconds[1]) + "\n";

    // 4. The setup-joint memo (ProblemOptions::setup_joint_memo) against solving every time: the
    // global stage, 2 threads, same seed and budget; the plans must be the same.
    double memo_s[2] = {0, 0}, memo_score[2] = {0, 0};
    int memo_evaluations[2] = {0, 0};
    for (int with = 0; with <= 1; ++with) {
      planners::ProblemOptions po;
      po.setup_joint_memo = with == 1;
      const planners::PortPlacementProblem p(patient, robot, po);
      planners::PortPlacementOptions o;
      o.threads = 2;
      o.evaluations = evaluations;
      o.local = "none";
      o.top_k = 1;
      o.robustness_shift = 0.0;
      const auto r = planners::OptimizePorts(p, o);
      memo_s[with] = Seconds(r, "global " + o.algorithm);
      memo_score[with] = r.best_global_score;
      memo_evaluations[with] = r.global_evaluations;
    }
    std::printf(
        "setup-joint memo, global stage direct-l (%d evaluations, 2 threads): without "
        "%.2f s (%.1f evaluations/s), with %.2f s (%.1f evaluations/s), speed-up %.2fx; "
        "best score %.4f and %.4f (must be equal)\n",
        evaluations, memo_s[0], memo_evaluations[0] / memo_s[0], memo_s[1],
        memo_evaluations[1] / memo_s[1], memo_s[0] / memo_s[1], memo_score[0], memo_score[1]);
    csv += "setup_joint_memo_speedup," + std::to_string(memo_s[0] / memo_s[1]) + "\n";
    csv += "full_plan_seconds," + std::to_string(full_s) + "\n";
    csv += "exhaustive_final_score," + std::to_string(exhaustive_score) + "\n";

    const std::string png = out_dir + "/port_placement_convergence.png";
    WritePlot(png, {panel}, 1200, 360);
    const std::string table = out_dir + "/port_placement.csv";
    {
      std::FILE* f = std::fopen((table + ".tmp").c_str(), "w");
      TROCAR_THROW_UNLESS(f != nullptr, table << ": cannot write");
      std::fputs(csv.c_str(), f);
      std::fclose(f);
      std::filesystem::rename(table + ".tmp", table);
    }
    std::printf("written: %s, %s\n", png.c_str(), table.c_str());
  } catch (const std::exception& e) {
    std::cerr << "port_placement_bench: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
