#pragma once
/// @file
/// Teleoperation mapping: device handle poses in, desired tool poses out (thesis §4.6 with the
/// dVRK's habits). Translation is relative and scaled (scale 5 means 5:1, the tool moves a fifth
/// of the hand), orientation relative and unscaled; both are read in the camera (view) frame.
/// Clutch and an operator-present gate re-anchor without a jump; a tremor filter (low-pass or
/// One-Euro) smooths the hand; non-finite samples and jumps are dropped and the tool holds.

#include <cmath>
#include <string>

#include <Eigen/Geometry>

#include "control/task_error.hpp"

namespace trocar::control {

/// One reading of the master device.
struct DeviceSample {
  double t = 0.0;                                          ///< s
  Eigen::Isometry3d X_DH = Eigen::Isometry3d::Identity();  ///< handle pose in the device frame (m)
  bool clutch = false;            ///< pressed: the handle is free, the tool holds
  bool operator_present = true;   ///< false: the tool holds (e.g. head out of the console)
};

enum class TremorFilter { kNone, kLowPass, kOneEuro };
const char* ToString(TremorFilter filter);
/// "none", "lowpass" or "oneeuro". @throws trocar::Error otherwise.
TremorFilter ParseTremorFilter(const std::string& name);

struct TeleopOptions {
  /// Device-to-tool motion ratio: 1 (1:1), 2, 3, 5 (5:1), or any positive value.
  double scale = 1.0;
  /// Position only: the tool keeps its orientation.
  bool position_only = false;
  /// Camera (view) frame in the world: device motions are read in it, so pushing the handle
  /// away moves the tool away in the image.
  Eigen::Matrix3d R_WC = Eigen::Matrix3d::Identity();
  TremorFilter filter = TremorFilter::kNone;
  /// Physiological tremor is 8-12 Hz; deliberate surgical motion mostly below 2 Hz.
  double low_pass_cutoff_hz = 6.0;
  double one_euro_min_cutoff_hz = 2.0;
  double one_euro_beta = 40.0;  ///< s/m: how fast the cutoff rises with the hand's speed
  double one_euro_derivative_cutoff_hz = 1.0;
  /// A sample farther than this from the last accepted one is dropped (m).
  double max_jump = 0.05;
  /// After this many jump drops in a row the stream is taken as genuinely moved on: re-anchor.
  int reanchor_after_drops = 200;
};

/// What happened to a sample; the recorder keeps it.
enum class SampleStatus {
  kFollowing,        ///< mapped onto the tool
  kHeldClutch,       ///< clutch pressed: tool holds
  kHeldAbsent,       ///< operator not present: tool holds
  kDroppedNonFinite, ///< NaN or Inf in the sample: dropped, tool holds
  kDroppedJump,      ///< jump larger than max_jump: dropped, tool holds
};
const char* ToString(SampleStatus status);

class TeleopMapping {
 public:
  /// @param X_WT_initial the tool pose to hold until the first sample anchors.
  /// @throws trocar::Error for a non-positive or non-finite scale or filter parameter.
  TeleopMapping(const TeleopOptions& options, const Eigen::Isometry3d& X_WT_initial);

  SampleStatus Update(const DeviceSample& sample);

  /// Desired tool pose X_WD.
  const Eigen::Isometry3d& desired() const { return X_WD_; }
  /// Desired tool velocity [ω; v] estimated from consecutive desired poses (feed-forward).
  const Vector6d& desired_velocity() const { return V_WD_; }
  /// Anchors the next sample to `X_WT` (e.g. to where the tool really is).
  void Reanchor(const Eigen::Isometry3d& X_WT);

 private:
  Eigen::Isometry3d Filter(const DeviceSample& sample);
  void SetDesired(const Eigen::Isometry3d& X_WD, double t);

  TeleopOptions options_;
  Eigen::Isometry3d X_WD_;
  Vector6d V_WD_ = Vector6d::Zero();
  bool anchored_ = false;
  Eigen::Isometry3d X_DH_anchor_ = Eigen::Isometry3d::Identity();
  Eigen::Isometry3d X_WT_anchor_ = Eigen::Isometry3d::Identity();
  // Last accepted raw sample (jump detection) and filter state.
  bool have_accepted_ = false;
  Eigen::Vector3d p_last_accepted_ = Eigen::Vector3d::Zero();
  int jump_drops_ = 0;
  bool filter_initialised_ = false;
  double t_filter_ = 0.0;
  Eigen::Vector3d p_filtered_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d p_raw_previous_ = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_filtered_ = Eigen::Quaterniond::Identity();
  Eigen::Vector3d speed_filtered_ = Eigen::Vector3d::Zero();
  double t_desired_ = NAN;
};

}  // namespace trocar::control
