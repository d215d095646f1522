#include "control/device_input.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <iomanip>
#include <sstream>

#include "common/error.hpp"
#include "common/file_util.hpp"

namespace trocar::control {

ScriptedMotion::Kind ParseScriptedMotion(const std::string& name) {
  if (name == "sinusoid") return ScriptedMotion::Kind::kSinusoid;
  if (name == "circle") return ScriptedMotion::Kind::kCircle;
  if (name == "step") return ScriptedMotion::Kind::kStep;
  if (name == "roll") return ScriptedMotion::Kind::kRoll;
  TROCAR_THROW("unknown scripted input '" << name << "' (expected sinusoid, circle, step, roll or "
                                                     "a .csv file)");
}

std::string ScriptedInput::name() const {
  switch (motion_.kind) {
    case ScriptedMotion::Kind::kSinusoid: return "sinusoid";
    case ScriptedMotion::Kind::kCircle: return "circle";
    case ScriptedMotion::Kind::kStep: return "step";
    case ScriptedMotion::Kind::kRoll: return "roll";
  }
  return "?";
}

DeviceSample ScriptedInput::Sample(double t) {
  DeviceSample s;
  s.t = t;
  // Smootherstep envelope 6x^5 - 15x^4 + 10x^3: zero velocity and acceleration at the start.
  const double x = motion_.fade_in > 0 ? std::clamp(t / motion_.fade_in, 0.0, 1.0) : 1.0;
  const double envelope = x * x * x * (x * (6.0 * x - 15.0) + 10.0);
  const double A = motion_.amplitude * envelope;
  switch (motion_.kind) {
    case ScriptedMotion::Kind::kSinusoid:
      for (int i = 0; i < 3; ++i) {
        s.X_DH.translation()[i] = A * std::sin(2.0 * M_PI * t / motion_.periods[i]);
      }
      break;
    case ScriptedMotion::Kind::kCircle: {
      const double phase = 2.0 * M_PI * t / motion_.period;
      s.X_DH.translation() << A * (std::cos(phase) - 1.0), A * std::sin(phase), 0.0;
      break;
    }
    case ScriptedMotion::Kind::kStep:
      if (t >= motion_.step_time) {
        s.X_DH.translation() = motion_.step;
        s.X_DH.linear() = Eigen::AngleAxisd(motion_.step_angle, Eigen::Vector3d::UnitZ()).toRotationMatrix();
      }
      break;
    case ScriptedMotion::Kind::kRoll:
      s.X_DH.linear() = Eigen::AngleAxisd(motion_.roll_rate * t, Eigen::Vector3d::UnitZ()).toRotationMatrix();
      break;
  }
  return s;
}

namespace {

std::vector<std::string> SplitCsv(const std::string& line) {
  std::vector<std::string> fields;
  std::string field;
  std::stringstream stream(line);
  while (std::getline(stream, field, ',')) fields.push_back(field);
  if (!line.empty() && line.back() == ',') fields.push_back("");
  return fields;
}

std::string Trim(std::string s) {
  const auto b = s.find_first_not_of(" \t\r");
  const auto e = s.find_last_not_of(" \t\r");
  return b == std::string::npos ? "" : s.substr(b, e - b + 1);
}

}  // namespace

CsvReplayInput::CsvReplayInput(const std::string& path) : path_(path) {
  const std::string text = ReadTextFile(path);
  std::stringstream stream(text);
  std::string line;
  int line_number = 0;
  std::vector<std::string> header;
  const std::vector<std::string> required = {"t", "x", "y", "z", "qw", "qx", "qy", "qz"};
  while (std::getline(stream, line)) {
    ++line_number;
    line = Trim(line);
    if (line.empty() || line[0] == '#') continue;
    std::vector<std::string> fields = SplitCsv(line);
    for (auto& f : fields) f = Trim(f);
    if (header.empty()) {
      header = fields;
      for (std::size_t i = 0; i < required.size(); ++i) {
        TROCAR_THROW_UNLESS(i < header.size() && header[i] == required[i],
                            path << ":" << line_number << ": header column " << i + 1
                                 << " must be '" << required[i]
                                 << "' (expected t,x,y,z,qw,qx,qy,qz[,clutch,present])");
      }
      for (std::size_t i = required.size(); i < header.size(); ++i) {
        TROCAR_THROW_UNLESS(header[i] == "clutch" || header[i] == "present",
                            path << ":" << line_number << ": unknown column " << i + 1 << " '"
                                 << header[i] << "' (expected clutch or present)");
      }
      continue;
    }
    TROCAR_THROW_UNLESS(fields.size() == header.size(),
                        path << ":" << line_number << ": " << fields.size() << " columns, expected "
                             << header.size());
    std::vector<double> values(fields.size());
    for (std::size_t i = 0; i < fields.size(); ++i) {
      char* end = nullptr;
      values[i] = std::strtod(fields[i].c_str(), &end);
      TROCAR_THROW_UNLESS(!fields[i].empty() && end == fields[i].c_str() + fields[i].size(),
                          path << ":" << line_number << ": column " << i + 1 << " ('"
                               << header[i] << "'): '" << fields[i] << "' is not a number");
    }
    DeviceSample s;
    s.t = values[0];
    TROCAR_THROW_UNLESS(std::isfinite(s.t), path << ":" << line_number
                                                 << ": column 1 ('t'): time must be finite");
    TROCAR_THROW_UNLESS(samples_.empty() || s.t >= samples_.back().t,
                        path << ":" << line_number << ": column 1 ('t'): time " << s.t
                             << " goes back from " << samples_.back().t);
    s.X_DH.translation() << values[1], values[2], values[3];
    const Eigen::Quaterniond q(values[4], values[5], values[6], values[7]);
    // A zero or non-finite quaternion is garbage from the device: keep it as NaN so the mapping
    // drops the sample and marks it.
    s.X_DH.linear() = q.norm() > 1e-9 && q.coeffs().allFinite()
                          ? q.normalized().toRotationMatrix()
                          : Eigen::Matrix3d::Constant(NAN);
    for (std::size_t i = required.size(); i < header.size(); ++i) {
      const bool on = values[i] != 0.0;
      if (header[i] == "clutch") s.clutch = on;
      if (header[i] == "present") s.operator_present = on;
    }
    samples_.push_back(s);
  }
  TROCAR_THROW_UNLESS(!header.empty(), path << ": empty device file (expected a header "
                                               "t,x,y,z,qw,qx,qy,qz and rows)");
  TROCAR_THROW_UNLESS(!samples_.empty(), path << ": no samples after the header");
}

DeviceSample CsvReplayInput::Sample(double t) {
  if (next_ > 0 && samples_[next_ - 1].t > t) next_ = 0;  // time went back: rewind
  while (next_ < samples_.size() && samples_[next_].t <= t) ++next_;
  DeviceSample s = samples_[next_ == 0 ? 0 : next_ - 1];
  s.t = t;
  return s;
}

void WriteDeviceCsv(const std::string& path, const std::vector<DeviceSample>& samples) {
  std::ostringstream out;
  out << std::setprecision(12) << "t,x,y,z,qw,qx,qy,qz,clutch,present\n";
  for (const DeviceSample& s : samples) {
    const Eigen::Quaterniond q(s.X_DH.linear());
    const Eigen::Vector3d p = s.X_DH.translation();
    out << s.t << "," << p.x() << "," << p.y() << "," << p.z() << "," << q.w() << "," << q.x()
        << "," << q.y() << "," << q.z() << "," << (s.clutch ? 1 : 0) << ","
        << (s.operator_present ? 1 : 0) << "\n";
  }
  WriteFileAtomically(path, out.str());
}

std::vector<Eigen::Matrix<double, 6, 1>> ToolVelocities(DeviceInput* input, double duration,
                                                        double dt, const TeleopOptions& options) {
  TROCAR_THROW_UNLESS(dt > 0.0 && std::isfinite(duration) && duration >= 0.0,
                      "ToolVelocities: dt " << dt << ", duration " << duration);
  std::vector<Eigen::Matrix<double, 6, 1>> out;
  DeviceSample previous = input->Sample(0.0);
  const int steps = static_cast<int>(std::floor(duration / dt));
  out.reserve(static_cast<std::size_t>(std::max(0, steps)));
  for (int k = 1; k <= steps; ++k) {
    const DeviceSample sample = input->Sample(k * dt);
    const bool moving = !previous.clutch && !sample.clutch && previous.operator_present &&
                        sample.operator_present && sample.X_DH.matrix().allFinite() &&
                        previous.X_DH.matrix().allFinite() &&
                        (sample.X_DH.translation() - previous.X_DH.translation()).norm() <= options.max_jump;
    if (moving) {
      const Eigen::AngleAxisd turn(sample.X_DH.linear() * previous.X_DH.linear().transpose());
      Eigen::Matrix<double, 6, 1> V;
      V.head<3>() = options.R_WC * (turn.angle() / dt * turn.axis());
      V.tail<3>() = options.R_WC * ((sample.X_DH.translation() - previous.X_DH.translation()) /
                                    (dt * options.scale));
      if (options.position_only) V.head<3>().setZero();
      out.push_back(V);
    }
    previous = sample;
  }
  return out;
}

}  // namespace trocar::control
