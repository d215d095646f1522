#include "control/teleop.hpp"

#include <algorithm>

#include "common/error.hpp"

namespace trocar::control {

const char* ToString(TremorFilter filter) {
  switch (filter) {
    case TremorFilter::kNone: return "none";
    case TremorFilter::kLowPass: return "lowpass";
    case TremorFilter::kOneEuro: return "oneeuro";
  }
  return "?";
}

TremorFilter ParseTremorFilter(const std::string& name) {
  if (name == "none") return TremorFilter::kNone;
  if (name == "lowpass") return TremorFilter::kLowPass;
  if (name == "oneeuro") return TremorFilter::kOneEuro;
  TROCAR_THROW("unknown tremor filter '" << name << "' (expected none, lowpass or oneeuro)");
}

const char* ToString(SampleStatus status) {
  switch (status) {
    case SampleStatus::kFollowing: return "following";
    case SampleStatus::kHeldClutch: return "clutch";
    case SampleStatus::kHeldAbsent: return "absent";
    case SampleStatus::kDroppedNonFinite: return "dropped_nonfinite";
    case SampleStatus::kDroppedJump: return "dropped_jump";
  }
  return "?";
}

TeleopMapping::TeleopMapping(const TeleopOptions& options, const Eigen::Isometry3d& X_WT_initial)
    : options_(options), X_WD_(X_WT_initial), X_WT_anchor_(X_WT_initial) {
  TROCAR_THROW_UNLESS(std::isfinite(options.scale) && options.scale > 0,
                      "teleop: scale " << options.scale << " must be a positive number");
  // A motion scaling a hand can drive (the device file's range): 1e-300 ran a session to
  // infinite errors with every joint at its limit.
  TROCAR_THROW_UNLESS(options.scale >= 0.01 && options.scale <= 100,
                      "teleop: scale " << options.scale
                                       << " must be a motion scaling (device:tool) from 0.01 to 100");
  TROCAR_THROW_UNLESS(std::isfinite(options.max_jump) && options.max_jump > 0,
                      "teleop: max_jump " << options.max_jump << " must be positive");
  for (double v : {options.low_pass_cutoff_hz, options.one_euro_min_cutoff_hz,
                   options.one_euro_derivative_cutoff_hz}) {
    TROCAR_THROW_UNLESS(std::isfinite(v) && v > 0,
                        "teleop: filter cutoff " << v << " Hz must be positive");
  }
  TROCAR_THROW_UNLESS((options.R_WC.transpose() * options.R_WC - Eigen::Matrix3d::Identity())
                              .cwiseAbs()
                              .maxCoeff() < 1e-6,
                      "teleop: the camera frame R_WC is not a rotation");
}

void TeleopMapping::Reanchor(const Eigen::Isometry3d& X_WT) {
  X_WD_ = X_WT;
  anchored_ = false;
  V_WD_.setZero();
  t_desired_ = NAN;
}

namespace {
double Alpha(double cutoff_hz, double dt) {
  const double tau = 1.0 / (2.0 * M_PI * cutoff_hz);
  return 1.0 / (1.0 + tau / dt);
}
}  // namespace

Eigen::Isometry3d TeleopMapping::Filter(const DeviceSample& sample) {
  const Eigen::Vector3d p = sample.X_DH.translation();
  const Eigen::Quaterniond q(sample.X_DH.linear());
  if (options_.filter == TremorFilter::kNone || !filter_initialised_) {
    filter_initialised_ = true;
    t_filter_ = sample.t;
    p_filtered_ = p;
    p_raw_previous_ = p;
    q_filtered_ = q;
    speed_filtered_.setZero();
    return sample.X_DH;
  }
  const double dt = sample.t - t_filter_;
  t_filter_ = sample.t;
  if (dt <= 0) {
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.linear() = q_filtered_.toRotationMatrix();
    X.translation() = p_filtered_;
    return X;
  }
  double a = 0.0;
  if (options_.filter == TremorFilter::kLowPass) {
    a = Alpha(options_.low_pass_cutoff_hz, dt);
  } else {  // One-Euro: the cutoff rises with the (filtered) speed, so slow motion is smooth and
            // fast motion has little lag.
    // Speed from consecutive raw samples, low-passed: a tremor's back-and-forth averages out
    // instead of reading as speed and opening the filter.
    const Eigen::Vector3d speed = (p - p_raw_previous_) / dt;
    speed_filtered_ += Alpha(options_.one_euro_derivative_cutoff_hz, dt) * (speed - speed_filtered_);
    a = Alpha(options_.one_euro_min_cutoff_hz + options_.one_euro_beta * speed_filtered_.norm(), dt);
  }
  p_raw_previous_ = p;
  p_filtered_ += a * (p - p_filtered_);
  q_filtered_ = q_filtered_.slerp(a, q).normalized();
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = q_filtered_.toRotationMatrix();
  X.translation() = p_filtered_;
  return X;
}

void TeleopMapping::SetDesired(const Eigen::Isometry3d& X_WD, double t) {
  if (std::isfinite(t_desired_) && t > t_desired_) {
    const double dt = t - t_desired_;
    V_WD_.head<3>() = 0.5 * OrientationError(X_WD.linear(), X_WD_.linear()) / dt;
    V_WD_.tail<3>() = (X_WD.translation() - X_WD_.translation()) / dt;
  } else {
    V_WD_.setZero();
  }
  X_WD_ = X_WD;
  t_desired_ = t;
}

SampleStatus TeleopMapping::Update(const DeviceSample& sample) {
  if (!std::isfinite(sample.t) || !sample.X_DH.matrix().allFinite()) {
    V_WD_.setZero();
    return SampleStatus::kDroppedNonFinite;
  }
  const Eigen::Vector3d p = sample.X_DH.translation();
  if (have_accepted_ && (p - p_last_accepted_).norm() > options_.max_jump) {
    V_WD_.setZero();
    if (++jump_drops_ < options_.reanchor_after_drops) return SampleStatus::kDroppedJump;
    anchored_ = false;  // the hand really is elsewhere now: take it from here, without a jump
    filter_initialised_ = false;
  }
  jump_drops_ = 0;
  have_accepted_ = true;
  p_last_accepted_ = p;
  const Eigen::Isometry3d X_DH = Filter(sample);
  if (sample.clutch || !sample.operator_present) {
    anchored_ = false;  // re-anchor when the operator takes the tool back
    V_WD_.setZero();
    t_desired_ = NAN;
    return sample.clutch ? SampleStatus::kHeldClutch : SampleStatus::kHeldAbsent;
  }
  if (!anchored_) {
    anchored_ = true;
    X_DH_anchor_ = X_DH;
    X_WT_anchor_ = X_WD_;
  }
  const Eigen::Matrix3d& R_WC = options_.R_WC;
  Eigen::Isometry3d X_WD = X_WT_anchor_;
  X_WD.translation() += R_WC * (X_DH.translation() - X_DH_anchor_.translation()) / options_.scale;
  if (!options_.position_only) {
    const Eigen::Matrix3d R_rel = X_DH.linear() * X_DH_anchor_.linear().transpose();
    X_WD.linear() = R_WC * R_rel * R_WC.transpose() * X_WT_anchor_.linear();
  }
  SetDesired(X_WD, sample.t);
  return SampleStatus::kFollowing;
}

}  // namespace trocar::control
