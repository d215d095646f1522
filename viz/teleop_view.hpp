#pragma once
/// @file
/// The teleoperation window (`trocar teleop --view`): the control thread runs the teleop core at
/// its own rate (1 kHz or more) and publishes each step into a triple buffer; this window reads
/// the newest step on a render timer (30–60 Hz) and never blocks the control thread (the
/// thesis' main problem, §3.4–3.5). Keyboard input drives a device handle (KeyboardInput).

#include <atomic>
#include <functional>
#include <mutex>
#include <optional>
#include <string>

#include "control/device_input.hpp"
#include "control/runner.hpp"
#include "control/teleop_session.hpp"
#include "scene.hpp"

namespace trocar::viz {

struct TeleopViewOptions {
  double fps = 60.0;          ///< render timer rate
  std::string grab_path;      ///< when set: save an image of the window when the session ends
  int width = 960, height = 640;
  /// Called on each frame with the pose shown (after the scene has it): what to add to the status
  /// line (e.g. the pose's collisions, highlighted by the callback).
  std::function<std::string(const robot::RobotState&)> on_frame;
  /// Called on each frame: a status text of its own (e.g. each network device's rate, drops and
  /// latency), shown in the window's overlay.
  std::function<std::string()> overlay;
  /// Index into the snapshots' channels of a teaching pointer (-1: none): drawn where it is.
  int pointer_channel = -1;
  /// When set, an endoscope view beside the external one, from this robot frame.
  std::optional<FrameCamera> endoscope;
};

struct TeleopViewStats {
  long frames = 0;            ///< frames rendered
  double seconds = 0.0;       ///< wall time the window was open
  long snapshots = 0;         ///< new control steps seen by the renderer
  long frames_in_collision = 0;  ///< set by the caller's on_frame, when it counts
};

/// Opens a window on `scene` (its robot moved by the snapshots) and renders at `options.fps`
/// until `finished()` is true, then closes. `keyboard`, when given, receives the window's keys.
/// @throws trocar::Error when no display can be opened.
class KeyboardInput;
TeleopViewStats RunTeleopView(Scene* scene, control::TripleBuffer<control::SessionSnapshot>* snapshots,
                              const std::function<bool()>& finished, const TeleopViewOptions& options,
                              KeyboardInput* keyboard = nullptr);

/// A device handle driven by keys, safe to press from the window's thread while the control
/// thread samples it: arrows move it in x and y, Page Up / Page Down in z, at `speed` (m/s) while
/// held; Q / E roll it about z; Space holds the clutch (the tool stays while the hand moves).
class KeyboardInput final : public control::DeviceInput {
 public:
  explicit KeyboardInput(double speed = 0.02) : speed_(speed) {}
  std::string name() const override { return "keyboard"; }
  control::DeviceSample Sample(double t) override;
  /// Key state from the window (Qt key codes).
  void Press(int qt_key, bool down);

 private:
  double speed_;
  std::atomic<int> vx_{0}, vy_{0}, vz_{0}, roll_{0};
  std::atomic<bool> clutch_{false};
  // Control thread only:
  double last_t_ = 0.0;
  Eigen::Isometry3d X_DH_ = Eigen::Isometry3d::Identity();
};

}  // namespace trocar::viz
