#pragma once
/// @file
/// A headless teleoperation session: device input → mapping → control loop → recorder, stepped
/// on a simulated clock at a fixed rate (so runs are reproducible and faster than real time).

#include "control/control_loop.hpp"
#include "control/device_input.hpp"
#include "control/recorder.hpp"
#include "control/teleop.hpp"

namespace trocar::control {

struct TeleopSessionOptions {
  double duration = 10.0;  ///< s
  double rate_hz = 1000.0; ///< control (and device) rate
  TeleopOptions mapping;
  /// Feed the desired velocity forward to controllers that use it.
  bool feed_forward = true;
};

/// Runs `input` through `loop` for the session's duration and returns the record.
/// @throws trocar::Error for a non-positive duration or rate.
Recorder RunTeleopSession(ControlLoop* loop, DeviceInput* input,
                          const TeleopSessionOptions& options);

}  // namespace trocar::control
