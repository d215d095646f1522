// Control benchmarks (issue: teleoperation core):
// - one control step (kinematics, Jacobian, error, update, limits, closures) in ns, for the
//   7-DOF PA10 and the da Vinci PSM with its two closures, per controller;
// - tracking the thesis' sinusoid with 1 kHz input (RMS and max position error, as counters);
// - jitter of the 1 kHz runner over 10 s (p99 and max period error, as counters).
#include <chrono>
#include <cmath>
#include <map>
#include <string>
#include <thread>

#include <benchmark/benchmark.h>

#include "control/control_loop.hpp"
#include "control/device_input.hpp"
#include "control/runner.hpp"
#include "control/teleop_session.hpp"
#include "robot/load_robot.hpp"

namespace {

using trocar::robot::RobotModel;

const RobotModel& Load(const std::string& file) {
  static std::map<std::string, RobotModel> cache;
  auto it = cache.find(file);
  if (it == cache.end()) {
    it = cache.emplace(file, trocar::robot::LoadRobot(std::string(TROCAR_SOURCE_DIR) + "/" + file)).first;
  }
  return it->second;
}

const char* kRobots[] = {"robots/pa10/pa10.yaml", "robots/davinci-classic/psm.yaml"};
const char* kControllers[] = {"jt", "dls", "jla"};
const trocar::control::Vector6d kGains = trocar::control::Vector6d::Constant(20);

void BM_ControlStep(benchmark::State& bm) {
  const RobotModel& model = Load(kRobots[bm.range(0)]);
  const std::string controller = kControllers[bm.range(1)];
  trocar::control::ControlLoop loop(model, trocar::control::MakeController(controller, model, kGains),
                                    model.defaults().home);
  trocar::control::TaskTarget target;
  target.X_WD = loop.ToolPose();
  long k = 0;
  for (auto _ : bm) {
    // A small circle so every step has work to do.
    const double phase = 1e-3 * static_cast<double>(k++);
    target.X_WD.translation().x() += 1e-5 * std::cos(phase);
    const auto report = loop.Step(target, 1e-3);
    benchmark::DoNotOptimize(report.position_error);
  }
  bm.SetLabel(model.name() + std::string(" ") + controller);
}
BENCHMARK(BM_ControlStep)->ArgsProduct({{0, 1}, {0, 1, 2}});

void BM_SinusoidTracking(benchmark::State& bm) {
  const RobotModel& model = Load(kRobots[bm.range(0)]);
  const std::string controller = kControllers[bm.range(1)];
  trocar::control::TrackingSummary summary;
  for (auto _ : bm) {
    trocar::control::ControlLoop loop(
        model, trocar::control::MakeController(controller, model, kGains), model.defaults().home);
    trocar::control::ScriptedMotion motion;  // the thesis' sinusoid: 40 mm per axis
    trocar::control::ScriptedInput input(motion);
    trocar::control::TeleopSessionOptions options;
    options.duration = 10.0;
    options.rate_hz = 1000.0;
    options.mapping.scale = bm.range(0) == 0 ? 1.0 : 5.0;  // the PSM at the da Vinci's 5:1
    summary = trocar::control::RunTeleopSession(&loop, &input, options).Summarize();
  }
  bm.counters["rms_mm"] = summary.rms_position_error * 1e3;
  bm.counters["max_mm"] = summary.max_position_error * 1e3;
  bm.counters["rms_deg"] = summary.rms_orientation_error * 180 / M_PI;
  bm.SetLabel(model.name() + std::string(" ") + controller);
}
BENCHMARK(BM_SinusoidTracking)->ArgsProduct({{0, 1}, {0, 1, 2}})->Iterations(1)->Unit(benchmark::kMillisecond);

void BM_RunnerJitter10s(benchmark::State& bm) {
  const RobotModel& model = Load(kRobots[0]);
  trocar::control::RunnerStats stats;
  for (auto _ : bm) {
    trocar::control::ControlLoop loop(model, trocar::control::MakeController("dls", model, kGains),
                                      model.defaults().home);
    trocar::control::TaskTarget target;
    target.X_WD = loop.ToolPose();
    trocar::control::FixedRateRunner runner(1000.0, [&](double, double dt) { loop.Step(target, dt); });
    runner.Start();
    std::this_thread::sleep_for(std::chrono::seconds(10));
    runner.Stop();
    stats = runner.stats();
  }
  bm.counters["steps"] = static_cast<double>(stats.steps);
  bm.counters["p99_us"] = stats.p99_period_error * 1e6;
  bm.counters["max_us"] = stats.max_period_error * 1e6;
  bm.counters["overruns"] = static_cast<double>(stats.overruns);
}
BENCHMARK(BM_RunnerJitter10s)->Iterations(1)->Unit(benchmark::kSecond);

}  // namespace

BENCHMARK_MAIN();
