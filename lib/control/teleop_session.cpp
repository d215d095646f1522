#include "control/teleop_session.hpp"

#include <atomic>
#include <chrono>
#include <cmath>
#include <memory>
#include <thread>

#include "common/error.hpp"

namespace trocar::control {

std::vector<int> ArmPositions(const robot::RobotModel& model, int link) {
  std::vector<int> out;
  for (int j : model.movable_path(link)) {
    const robot::Joint& joint = model.joint(j);
    if (joint.q_index >= 0) out.push_back(joint.q_index);
  }
  return out;
}

std::vector<Recorder> RunTeleopSession(const std::vector<SessionChannel>& channels,
                                       const TeleopSessionOptions& options) {
  TROCAR_THROW_UNLESS(std::isfinite(options.duration) && options.duration > 0,
                      "teleop: duration " << options.duration << " s must be positive");
  TROCAR_THROW_UNLESS(std::isfinite(options.rate_hz) && options.rate_hz > 0,
                      "teleop: rate " << options.rate_hz << " Hz must be positive");
  TROCAR_THROW_UNLESS(!channels.empty(), "teleop: no device channel");
  const ControlLoop* first_loop = nullptr;
  std::vector<std::unique_ptr<TeleopMapping>> mappings;
  for (const SessionChannel& c : channels) {
    TROCAR_THROW_UNLESS(c.input != nullptr, "teleop: channel '" << c.name << "' has no device");
    if (c.loop && !first_loop) first_loop = c.loop;
    mappings.push_back(std::make_unique<TeleopMapping>(c.mapping, c.loop ? c.loop->ToolPose() : c.X_WP_start));
  }
  std::vector<Recorder> recorders(channels.size());
  SessionSnapshot snapshot;
  if (first_loop) snapshot.q = first_loop->state().q;
  snapshot.channels.resize(channels.size());
  // One control step at time t, dt after the previous one.
  auto step = [&](double t, double dt) {
    for (std::size_t i = 0; i < channels.size(); ++i) {
      const SessionChannel& c = channels[i];
      TeleopMapping& mapping = *mappings[i];
      const SampleStatus status = mapping.Update(c.input->Sample(t));
      RecordRow row;
      row.t = t;
      row.status = status;
      row.X_WD = mapping.desired();
      if (c.loop) {
        TaskTarget target;
        target.X_WD = mapping.desired();
        target.position_only = c.mapping.position_only;
        if (options.feed_forward) target.V_WD = mapping.desired_velocity();
        if (target.position_only) target.V_WD.head<3>().setZero();
        const StepReport report = c.loop->Step(target, dt);
        row.X_WT = report.X_WT;
        row.q = c.loop->state().q;
        row.position_error = report.position_error;
        row.orientation_error = target.position_only ? 0.0 : report.orientation_error;
        row.limited_joints = report.limits.acceleration_limited + report.limits.velocity_limited +
                             report.limits.position_limited;
        if (c.loop == first_loop && c.positions.empty()) {
          snapshot.q = row.q;
        } else {
          for (int k : c.positions) snapshot.q[k] = row.q[k];
        }
      } else {
        row.X_WT = row.X_WD;  // a pointer is where its device puts it
      }
      snapshot.channels[i] = ChannelSnapshot{row.X_WD, row.X_WT, status};
      recorders[i].Add(std::move(row));
    }
    snapshot.t = t;
    snapshot.X_WD = snapshot.channels[0].X_WD;
    snapshot.X_WT = snapshot.channels[0].X_WT;
    snapshot.status = snapshot.channels[0].status;
    if (options.snapshots != nullptr) options.snapshots->Publish(snapshot);
    if (options.feedback != nullptr) options.feedback->Publish(snapshot);
  };
  if (!options.realtime) {
    const double dt = 1.0 / options.rate_hz;
    const long steps = std::lround(options.duration * options.rate_hz);
    for (long k = 0; k <= steps; ++k) step(k * dt, k == 0 ? 0.0 : dt);
    return recorders;
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
  return recorders;
}

Recorder RunTeleopSession(ControlLoop* loop, DeviceInput* input, const TeleopSessionOptions& options) {
  SessionChannel channel;
  channel.name = "arm";
  channel.loop = loop;
  channel.input = input;
  channel.mapping = options.mapping;
  return std::move(RunTeleopSession({channel}, options).front());
}

}  // namespace trocar::control
