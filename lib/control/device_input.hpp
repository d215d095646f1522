#pragma once
/// @file
/// Device inputs behind one interface, so scripted motions, recorded sessions and (later) the
/// network device drive the same teleoperation path.

#include <memory>
#include <string>
#include <vector>

#include "control/teleop.hpp"

namespace trocar::control {

class DeviceInput {
 public:
  virtual ~DeviceInput() = default;
  virtual std::string name() const = 0;
  /// The device's reading at time t (s since the start).
  virtual DeviceSample Sample(double t) = 0;
};

/// The tool velocities (world frame, [ω; v]) a device's motion asks for through a mapping: the
/// input sampled every `dt` over [0, duration], finite differences of the handle pose, the
/// translation scaled, both read in the camera frame (options.R_WC); a pair of samples with the
/// clutch pressed, the operator absent, a non-finite pose or a jump beyond options.max_jump (all
/// of which the mapping drops) moves nothing. Reads `input` from t = 0 (give it a fresh input,
/// not the session's).
std::vector<Eigen::Matrix<double, 6, 1>> ToolVelocities(DeviceInput* input, double duration,
                                                        double dt, const TeleopOptions& options);

/// Scripted handle motions about the handle's start pose (device frame, metres, radians).
struct ScriptedMotion {
  enum class Kind {
    kSinusoid,  ///< the thesis' §5.4.2.1 input: each axis a sinusoid about the start point,
                ///< orientation still
    kCircle,    ///< a circle in the device's x-y plane, orientation still
    kStep,      ///< still, then at `step_time` a step of `step` in position and `step_angle`
                ///< about z
    kRoll,      ///< a steady turn about the handle's z axis (for rotations beyond 180 deg)
  };
  Kind kind = Kind::kSinusoid;
  double amplitude = 0.04;                          ///< m (sinusoid per axis, circle radius)
  Eigen::Vector3d periods{2.0, 2.5, 3.0};          ///< s, sinusoid x, y, z
  double period = 4.0;                              ///< s, circle
  double step_time = 0.5;                           ///< s
  Eigen::Vector3d step{0.01, -0.008, 0.006};        ///< m
  double step_angle = 10.0 * M_PI / 180.0;          ///< rad, about the device z axis
  double roll_rate = M_PI / 4.0;                    ///< rad/s
  /// Sinusoid and circle fade in over this time (s) with a smooth (C2) envelope, so that the
  /// handle starts at rest instead of at full speed.
  double fade_in = 1.0;
};

/// "sinusoid", "circle", "step" or "roll". @throws trocar::Error otherwise.
ScriptedMotion::Kind ParseScriptedMotion(const std::string& name);

class ScriptedInput final : public DeviceInput {
 public:
  explicit ScriptedInput(const ScriptedMotion& motion) : motion_(motion) {}
  std::string name() const override;
  DeviceSample Sample(double t) override;

 private:
  ScriptedMotion motion_;
};

/// Replays recorded device poses: a CSV with the header `t,x,y,z,qw,qx,qy,qz` and optional
/// `clutch,present` columns (0/1). Between rows the last row holds. NaN or Inf values are passed
/// on (the mapping drops them); malformed text is an error naming the line and column.
class CsvReplayInput final : public DeviceInput {
 public:
  /// @throws trocar::Error naming the file, line and column for malformed content.
  explicit CsvReplayInput(const std::string& path);
  std::string name() const override { return path_; }
  DeviceSample Sample(double t) override;
  const std::vector<DeviceSample>& samples() const { return samples_; }
  double duration() const { return samples_.empty() ? 0.0 : samples_.back().t; }

 private:
  std::string path_;
  std::vector<DeviceSample> samples_;
  std::size_t next_ = 0;
};

/// Writes samples in the CsvReplayInput format (atomically).
void WriteDeviceCsv(const std::string& path, const std::vector<DeviceSample>& samples);

}  // namespace trocar::control
