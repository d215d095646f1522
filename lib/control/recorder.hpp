#pragma once
/// @file
/// Records every control step (time, desired and actual pose, joint values, errors, what happened
/// to the device sample) and summarises tracking like the thesis' figures 5.4–5.15.

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "control/teleop.hpp"

namespace trocar::control {

struct RecordRow {
  double t = 0.0;
  Eigen::Isometry3d X_WD = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d X_WT = Eigen::Isometry3d::Identity();
  Eigen::VectorXd q;
  double position_error = 0.0;     ///< m
  double orientation_error = 0.0;  ///< rad
  SampleStatus status = SampleStatus::kFollowing;
  int limited_joints = 0;          ///< joints a limit changed at this step
};

struct TrackingSummary {
  int steps = 0;
  int dropped = 0;  ///< samples dropped (non-finite or jump)
  int held = 0;     ///< steps with the clutch pressed or the operator away
  double rms_position_error = 0.0;     ///< m
  double max_position_error = 0.0;     ///< m
  double rms_orientation_error = 0.0;  ///< rad
  double max_orientation_error = 0.0;  ///< rad
  /// For a step input: time after the step until the error stays within 0.1 mm and 0.1 deg.
  std::optional<double> settling_time;
};

/// Memory stays bounded over any session length: beyond `capacity` rows the record is thinned
/// (every other row kept, and from then on every 2nd, 4th, ... step recorded), so a long
/// `--duration` keeps a uniformly sampled record of the whole run. `stride()` says how thin.
class Recorder {
 public:
  /// @param capacity most rows kept; 0: `Limits().max_recorded_samples`.
  explicit Recorder(std::size_t capacity = 0);
  void Add(RecordRow row);
  const std::vector<RecordRow>& rows() const { return rows_; }
  /// 1 while every step is recorded; else the number of steps per recorded row.
  std::size_t stride() const { return stride_; }
  std::size_t steps_seen() const { return seen_; }
  /// @param step_time for a step input, when the step happened (enables settling_time);
  /// @param skip_until rows before this time are left out of the error statistics (start-up).
  TrackingSummary Summarize(std::optional<double> step_time = std::nullopt,
                            double skip_until = 0.0) const;
  /// CSV: t, desired x y z qw qx qy qz, actual x y z qw qx qy qz, q..., position and orientation
  /// error, status, limited joints. Written to a temporary name, then renamed.
  void WriteCsv(const std::string& path, const std::vector<std::string>& joint_names) const;
  /// Figures like the thesis' 5.4–5.15: `tracking.png` (desired and actual x, y, z relative to
  /// the start, mm, against time) and `errors.png` (position error in mm and orientation error
  /// in degrees against time), in `folder`. @returns the two paths.
  std::vector<std::string> WritePlots(const std::string& folder, const std::string& title) const;

 private:
  std::vector<RecordRow> rows_;
  std::size_t capacity_ = 0;
  std::size_t stride_ = 1;
  std::size_t seen_ = 0;
  int dropped_ = 0, held_ = 0;  // over every step, recorded or not
};

}  // namespace trocar::control
