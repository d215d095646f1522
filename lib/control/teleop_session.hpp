#pragma once
/// @file
/// A teleoperation session: device inputs → mappings → control loops → recorders, stepped on a
/// simulated clock at a fixed rate (reproducible, faster than real time) or in real time. One
/// session drives one arm, or several arms of one robot at once (two PSMs and the ECM, each from
/// its own device), and may carry pointers: devices whose pose is only shown (thesis §6.3.3).

#include <string>
#include <vector>

#include "control/control_loop.hpp"
#include "control/device_input.hpp"
#include "control/recorder.hpp"
#include "control/runner.hpp"
#include "control/teleop.hpp"

namespace trocar::control {

/// One channel's part of a control step.
struct ChannelSnapshot {
  Eigen::Isometry3d X_WD = Eigen::Isometry3d::Identity();  ///< desired (a pointer: its pose)
  Eigen::Isometry3d X_WT = Eigen::Isometry3d::Identity();  ///< actual tool pose
  SampleStatus status = SampleStatus::kFollowing;
};

/// What a renderer needs from one control step.
struct SessionSnapshot {
  double t = 0.0;
  Eigen::VectorXd q;  ///< the robot's joints, each arm's from its own loop
  Eigen::Isometry3d X_WD = Eigen::Isometry3d::Identity();  ///< the first channel's
  Eigen::Isometry3d X_WT = Eigen::Isometry3d::Identity();
  SampleStatus status = SampleStatus::kFollowing;
  std::vector<ChannelSnapshot> channels;  ///< in the session's channel order
};

struct TeleopSessionOptions {
  double duration = 10.0;  ///< s
  double rate_hz = 1000.0; ///< control (and device) rate
  TeleopOptions mapping;   ///< the single-arm overload's mapping
  /// Feed the desired velocity forward to controllers that use it.
  bool feed_forward = true;
  /// Run in real time in a FixedRateRunner thread, integrating with the measured step time,
  /// instead of on a simulated clock.
  bool realtime = false;
  /// When set, every step is published here for a renderer (never blocks the control thread).
  TripleBuffer<SessionSnapshot>* snapshots = nullptr;
  /// A second reader's buffer (force feedback, pose streaming), published like `snapshots`.
  TripleBuffer<SessionSnapshot>* feedback = nullptr;
  /// When set (real time only), the runner's timing is written here.
  RunnerStats* runner_stats = nullptr;
};

/// A device driving an arm (`loop`), or a pointer (`loop` null: the device's pose mapped into
/// the world from `X_WP_start`, nothing moved).
struct SessionChannel {
  std::string name;
  ControlLoop* loop = nullptr;
  DeviceInput* input = nullptr;
  TeleopOptions mapping;
  Eigen::Isometry3d X_WP_start = Eigen::Isometry3d::Identity();  ///< pointers only
  /// Indices into q of the joints this arm moves (its tool's movable path); empty: all. Each
  /// loop owns a whole copy of the robot's state; the session's q takes each arm's joints from
  /// that arm's loop, so arms of one robot move independently.
  std::vector<int> positions;
};

/// Runs every channel for the session's duration (the channels' loops share one clock).
/// @returns one record per channel. @throws trocar::Error for a non-positive duration or rate,
/// or a channel without an input.
std::vector<Recorder> RunTeleopSession(const std::vector<SessionChannel>& channels,
                                       const TeleopSessionOptions& options);

/// One arm: `input` through `loop` with `options.mapping`.
Recorder RunTeleopSession(ControlLoop* loop, DeviceInput* input,
                          const TeleopSessionOptions& options);

/// The indices into q of the active joints on the path from the base to `link`: what an arm
/// whose tool is on `link` moves.
std::vector<int> ArmPositions(const robot::RobotModel& model, int link);

}  // namespace trocar::control
