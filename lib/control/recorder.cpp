#include "control/recorder.hpp"

#include <cmath>
#include <iomanip>
#include <sstream>

#include "common/file_util.hpp"

namespace trocar::control {

TrackingSummary Recorder::Summarize(std::optional<double> step_time, double skip_until) const {
  TrackingSummary s;
  double sum_p = 0.0, sum_o = 0.0;
  int counted = 0;
  std::optional<double> last_outside;
  for (const RecordRow& row : rows_) {
    ++s.steps;
    if (row.status == SampleStatus::kDroppedJump || row.status == SampleStatus::kDroppedNonFinite) {
      ++s.dropped;
    }
    if (row.status == SampleStatus::kHeldClutch || row.status == SampleStatus::kHeldAbsent) ++s.held;
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

}  // namespace trocar::control
