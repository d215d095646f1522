#include "control/recorder.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <iomanip>
#include <sstream>

#include "common/file_util.hpp"
#include "common/limits.hpp"
#include "common/plot.hpp"

namespace trocar::control {

Recorder::Recorder(std::size_t capacity)
    : capacity_(std::max<std::size_t>(
          2, capacity > 0 ? capacity : static_cast<std::size_t>(Limits().max_recorded_samples))) {}

void Recorder::Add(RecordRow row) {
  const std::size_t step = seen_++;
  if (row.status == SampleStatus::kDroppedJump || row.status == SampleStatus::kDroppedNonFinite) {
    ++dropped_;
  }
  if (row.status == SampleStatus::kHeldClutch || row.status == SampleStatus::kHeldAbsent) ++held_;
  if (step % stride_ != 0) return;
  if (rows_.size() >= capacity_) {
    // Keep rows 0, 2, 4, ... (steps 0, 2·stride, ...): the record stays uniform in time.
    std::size_t kept = 0;
    for (std::size_t i = 0; i < rows_.size(); i += 2) rows_[kept++] = std::move(rows_[i]);
    rows_.resize(kept);
    stride_ *= 2;
    if (step % stride_ != 0) return;
  }
  rows_.push_back(std::move(row));
}

TrackingSummary Recorder::Summarize(std::optional<double> step_time, double skip_until) const {
  TrackingSummary s;
  double sum_p = 0.0, sum_o = 0.0;
  int counted = 0;
  std::optional<double> last_outside;
  s.steps = static_cast<int>(seen_);
  s.dropped = dropped_;
  s.held = held_;
  for (const RecordRow& row : rows_) {
    if (row.t < skip_until) continue;
    ++counted;
    sum_p += row.position_error * row.position_error;
    sum_o += row.orientation_error * row.orientation_error;
    s.max_position_error = std::max(s.max_position_error, row.position_error);
    s.max_orientation_error = std::max(s.max_orientation_error, row.orientation_error);
    if (step_time && row.t >= *step_time &&
        (row.position_error > 1e-4 || row.orientation_error > 0.1 * M_PI / 180.0)) {
      last_outside = row.t;
    }
  }
  if (counted > 0) {
    s.rms_position_error = std::sqrt(sum_p / counted);
    s.rms_orientation_error = std::sqrt(sum_o / counted);
  }
  if (step_time && !rows_.empty()) {
    // Settled only if the last rows are within the band.
    if (!last_outside) {
      s.settling_time = 0.0;
    } else if (*last_outside < rows_.back().t) {
      s.settling_time = *last_outside - *step_time;
    }
  }
  return s;
}

void Recorder::WriteCsv(const std::string& path,
                        const std::vector<std::string>& joint_names) const {
  std::ostringstream out;
  out << std::setprecision(10);
  out << "t,xd,yd,zd,qwd,qxd,qyd,qzd,x,y,z,qw,qx,qy,qz";
  for (const std::string& name : joint_names) out << ",q_" << name;
  out << ",position_error,orientation_error,status,limited_joints\n";
  for (const RecordRow& row : rows_) {
    auto pose = [&](const Eigen::Isometry3d& X) {
      const Eigen::Quaterniond q(X.linear());
      const Eigen::Vector3d p = X.translation();
      out << "," << p.x() << "," << p.y() << "," << p.z() << "," << q.w() << "," << q.x() << ","
          << q.y() << "," << q.z();
    };
    out << row.t;
    pose(row.X_WD);
    pose(row.X_WT);
    for (Eigen::Index i = 0; i < row.q.size(); ++i) out << "," << row.q[i];
    out << "," << row.position_error << "," << row.orientation_error << ","
        << ToString(row.status) << "," << row.limited_joints << "\n";
  }
  WriteFileAtomically(path, out.str());
}

std::vector<std::string> Recorder::WritePlots(const std::string& folder,
                                             const std::string& title) const {
  const std::array<std::uint8_t, 3> desired{40, 90, 200}, actual{220, 80, 30};
  std::vector<PlotPanel> tracking(3);
  const char* axes = "xyz";
  const Eigen::Vector3d origin =
      rows_.empty() ? Eigen::Vector3d::Zero() : Eigen::Vector3d(rows_.front().X_WT.translation());
  for (int a = 0; a < 3; ++a) {
    PlotPanel& panel = tracking[a];
    panel.title = title + ": " + axes[a] + " of the tool";
    panel.y_label = "mm from start";
    panel.x_label = "time (s)";
    PlotSeries d{"desired", {}, {}, desired}, c{"actual", {}, {}, actual};
    for (const RecordRow& row : rows_) {
      d.x.push_back(row.t);
      c.x.push_back(row.t);
      d.y.push_back(1e3 * (row.X_WD.translation()[a] - origin[a]));
      c.y.push_back(1e3 * (row.X_WT.translation()[a] - origin[a]));
    }
    panel.series = {d, c};
  }
  std::vector<PlotPanel> errors(2);
  errors[0].title = title + ": position error";
  errors[0].y_label = "mm";
  errors[1].title = title + ": orientation error";
  errors[1].y_label = "deg";
  PlotSeries p{"position", {}, {}, {200, 40, 40}}, o{"orientation", {}, {}, {40, 140, 60}};
  for (const RecordRow& row : rows_) {
    p.x.push_back(row.t);
    o.x.push_back(row.t);
    p.y.push_back(1e3 * row.position_error);
    o.y.push_back(row.orientation_error * 180.0 / M_PI);
  }
  errors[0].series = {p};
  errors[1].series = {o};
  errors[0].x_label = errors[1].x_label = "time (s)";
  const std::string tracking_path = JoinPath(folder, "tracking.png");
  const std::string errors_path = JoinPath(folder, "errors.png");
  WritePlot(tracking_path, tracking);
  WritePlot(errors_path, errors);
  return {tracking_path, errors_path};
}

}  // namespace trocar::control
