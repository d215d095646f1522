#include "control/teleop_session.hpp"

#include <atomic>
#include <chrono>
#include <cmath>
#include <thread>

#include "common/error.hpp"

namespace trocar::control {

Recorder RunTeleopSession(ControlLoop* loop, DeviceInput* input,
                          const TeleopSessionOptions& options) {
  TROCAR_THROW_UNLESS(std::isfinite(options.duration) && options.duration > 0,
                      "teleop: duration " << options.duration << " s must be positive");
  TROCAR_THROW_UNLESS(std::isfinite(options.rate_hz) && options.rate_hz > 0,
                      "teleop: rate " << options.rate_hz << " Hz must be positive");
  TeleopMapping mapping(options.mapping, loop->ToolPose());
  Recorder recorder;
  // One control step at time t, dt after the previous one.
  auto step = [&](double t, double dt) {
    const SampleStatus status = mapping.Update(input->Sample(t));
    TaskTarget target;
    target.X_WD = mapping.desired();
    target.position_only = options.mapping.position_only;
    if (options.feed_forward) target.V_WD = mapping.desired_velocity();
    if (target.position_only) target.V_WD.head<3>().setZero();
    const StepReport report = loop->Step(target, dt);
    RecordRow row;
    row.t = t;
    row.X_WD = target.X_WD;
    row.X_WT = report.X_WT;
    row.q = loop->state().q;
    row.position_error = report.position_error;
    row.orientation_error = target.position_only ? 0.0 : report.orientation_error;
    row.status = status;
    row.limited_joints = report.limits.acceleration_limited + report.limits.velocity_limited +
                         report.limits.position_limited;
    if (options.snapshots != nullptr) {
      options.snapshots->Publish(SessionSnapshot{t, row.q, row.X_WD, row.X_WT, status});
    }
    recorder.Add(std::move(row));
  };
  if (!options.realtime) {
    const double dt = 1.0 / options.rate_hz;
    const long steps = std::lround(options.duration * options.rate_hz);
    for (long k = 0; k <= steps; ++k) step(k * dt, k == 0 ? 0.0 : dt);
    return recorder;
  }
  std::atomic<bool> done{false};
  FixedRateRunner runner(options.rate_hz, [&](double t, double dt) {
    if (done.load(std::memory_order_relaxed)) return;
    step(t, dt);
    if (t >= options.duration) done = true;
  });
  runner.Start();
  while (!done.load()) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  runner.Stop();
  if (options.runner_stats != nullptr) *options.runner_stats = runner.stats();
  return recorder;
}

}  // namespace trocar::control
