#include "control/teleop_session.hpp"

#include <cmath>

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
  const double dt = 1.0 / options.rate_hz;
  const long steps = std::lround(options.duration * options.rate_hz);
  double t_previous = 0.0;
  for (long k = 0; k <= steps; ++k) {
    const double t = k * dt;
    const SampleStatus status = mapping.Update(input->Sample(t));
    TaskTarget target;
    target.X_WD = mapping.desired();
    target.position_only = options.mapping.position_only;
    if (options.feed_forward) target.V_WD = mapping.desired_velocity();
    if (target.position_only) target.V_WD.head<3>().setZero();
    const StepReport report = loop->Step(target, t - t_previous);
    t_previous = t;
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
    recorder.Add(std::move(row));
  }
  return recorder;
}

}  // namespace trocar::control
