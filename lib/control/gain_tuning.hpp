#pragma once
/// @file
/// Gain auto-tuning (thesis §4.4 and §6.3: gains were chosen by hand per robot). NLopt searches the
/// translational and rotational task gains that minimise tracking error on a reference trajectory,
/// penalising step responses that overshoot (oscillation), and the result can be saved into the
/// robot's sidecar file as `controller.gains.<controller>`.

#include <string>

#include <Eigen/Core>

#include "control/device_input.hpp"
#include "control/task_error.hpp"
#include "robot/robot_model.hpp"

namespace trocar::control {

struct GainTuningOptions {
  std::string controller = "jt";
  ScriptedMotion trajectory;  ///< default: the thesis' sinusoid
  double duration = 6.0;      ///< s of trajectory per evaluation
  double rate_hz = 1000.0;
  double scale = 1.0;         ///< device:tool ratio applied to the trajectory
  double min_gain = 1.0;      ///< 1/s
  double max_gain = 3000.0;   ///< 1/s
  int max_evaluations = 80;
  /// Largest accepted step-response overshoot, as a share of the step.
  double max_overshoot = 0.05;
};

struct GainTuningResult {
  Vector6d gains = Vector6d::Zero();  ///< [wx wy wz vx vy vz]
  double rms_position_error = 0.0;    ///< m, on the trajectory
  double max_position_error = 0.0;    ///< m
  double rms_orientation_error = 0.0; ///< rad
  double overshoot = 0.0;             ///< share of the step
  double initial_rms_position_error = 0.0;  ///< with the starting gains, for comparison
  int evaluations = 0;
};

/// @param q0 where each evaluation starts. @throws trocar::Error for bad options.
GainTuningResult TuneGains(const robot::RobotModel& model, const Eigen::VectorXd& q0,
                           const GainTuningOptions& options);

/// Writes the tuned gains into the overlay beside the robot (robot::GainsOverlayPath:
/// `arm.urdf` → `arm.gains.yaml`), keeping the other controllers' entries; the user's own files
/// are never touched. yaml-cpp, full precision, atomic (temporary file, then rename).
/// @returns the file written.
std::string SaveControllerGains(const std::string& description, const std::string& controller,
                                const Vector6d& gains);

}  // namespace trocar::control
