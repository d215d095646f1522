#pragma once
/// @file
/// A headless teleoperation session: device input → mapping → control loop → recorder, stepped
/// on a simulated clock at a fixed rate (so runs are reproducible and faster than real time).

#include "control/control_loop.hpp"
#include "control/device_input.hpp"
#include "control/recorder.hpp"
#include "control/runner.hpp"
#include "control/teleop.hpp"

namespace trocar::control {

/// What a renderer needs from one control step.
struct SessionSnapshot {
  double t = 0.0;
  Eigen::VectorXd q;
  Eigen::Isometry3d X_WD = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d X_WT = Eigen::Isometry3d::Identity();
  SampleStatus status = SampleStatus::kFollowing;
};

struct TeleopSessionOptions {
  double duration = 10.0;  ///< s
  double rate_hz = 1000.0; ///< control (and device) rate
  TeleopOptions mapping;
  /// Feed the desired velocity forward to controllers that use it.
  bool feed_forward = true;
  /// Run in real time in a FixedRateRunner thread, integrating with the measured step time,
  /// instead of on a simulated clock.
  bool realtime = false;
  /// When set, every step is published here for a renderer (never blocks the control thread).
  TripleBuffer<SessionSnapshot>* snapshots = nullptr;
  /// When set (real time only), the runner's timing is written here.
  RunnerStats* runner_stats = nullptr;
};

/// Runs `input` through `loop` for the session's duration and returns the record.
/// @throws trocar::Error for a non-positive duration or rate.
Recorder RunTeleopSession(ControlLoop* loop, DeviceInput* input,
                          const TeleopSessionOptions& options);

}  // namespace trocar::control
