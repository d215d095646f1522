#pragma once
// Helpers shared by the tests: paths, seeded random configurations, matrix comparison.

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <gtest/gtest.h>

#include "common/error.hpp"
#include "common/mesh.hpp"
#include "robot/robot_model.hpp"

namespace trocar::test {

/// A shell command's exit code and its stdout and stderr together.
struct CommandRun {
  int exit_code;
  std::string output;
};

inline CommandRun RunShell(const std::string& command) {
  FILE* pipe = popen((command + " 2>&1").c_str(), "r");
  if (pipe == nullptr) return {-1, "popen failed"};
  std::string output;
  std::array<char, 4096> buffer;
  for (size_t n; (n = fread(buffer.data(), 1, buffer.size(), pipe)) > 0;) output.append(buffer.data(), n);
  const int status = pclose(pipe);
  return {WIFEXITED(status) ? WEXITSTATUS(status) : -1, output};
}

/// A localhost TCP port free now (the kernel's choice), for a server a test starts.
inline int FreePort() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  ::inet_pton(AF_INET, "127.0.0.1", &a.sin_addr);
  ::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a));
  socklen_t len = sizeof(a);
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len);
  ::close(fd);
  return ntohs(a.sin_port);
}

/// A fresh scratch folder's path under the test temporary folder, "trocar_<name>": whatever an
/// earlier run left there is removed; the folder itself is not created.
inline std::string ScratchPath(const std::string& name) {
  const std::string dir = ::testing::TempDir() + "/trocar_" + name;
  std::filesystem::remove_all(dir);
  return dir;
}

/// True in a build under a sanitizer (ASan, TSan; gcc or clang).
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
inline constexpr bool kSanitized = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
inline constexpr bool kSanitized = true;
#else
inline constexpr bool kSanitized = false;
#endif
#else
inline constexpr bool kSanitized = false;
#endif

/// The cases a slow property test runs: all of them in Release; under a sanitizer only those at
/// the positions `sanitized` names (chosen so that every path the cases take still runs
/// instrumented: a table, a label map, a crop...), because each whole-phantom import costs minutes
/// there. The Release run of the same test takes every case.
template <class Case>
std::vector<Case> Cases(std::vector<Case> all, std::initializer_list<std::size_t> sanitized) {
  if (!kSanitized) return all;
  std::vector<Case> kept;
  for (const std::size_t i : sanitized) kept.push_back(all.at(i));
  return kept;
}

/// How many random trials a property test draws: `release` in Release, `sanitized` under a
/// sanitizer (the same seeded sequence, cut short).
constexpr int Trials(int release, int sanitized) { return kSanitized ? sanitized : release; }

inline std::string SourcePath(const std::string& relative) {
  return std::string(TROCAR_SOURCE_DIR) + "/" + relative;
}

/// Distance (m) from p to the polyline through `c`'s points.
inline double DistanceToPolyline(const Eigen::Vector3d& p, const std::vector<Eigen::Vector3d>& c) {
  double best = HUGE_VAL;
  for (std::size_t s = 0; s + 1 < c.size(); ++s) {
    const Eigen::Vector3d d = c[s + 1] - c[s];
    const double t = std::clamp((p - c[s]).dot(d) / d.squaredNorm(), 0.0, 1.0);
    best = std::min(best, (c[s] + t * d - p).norm());
  }
  return best;
}

/// The message of the trocar::Error `f` throws, or `none` when it throws none (any other
/// exception propagates: the test fails on it).
inline std::string ErrorMessage(const std::function<void()>& f, const std::string& none = "") {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return none;
}

/// A polyline with its bounding box, for tests that measure every voxel of a volume against
/// many polylines (the generated ribs): Distance(p, at_most) is the exact distance when the box
/// lies within `at_most` of p, and otherwise the box's distance, which is then larger than
/// `at_most` and no larger than the exact one; so `Distance(p, r) < r` (or `<= r`) is the exact
/// comparison, and `best = std::min(best, Distance(p, best))` the exact minimum.
class Polyline {
 public:
  explicit Polyline(std::vector<Eigen::Vector3d> points) : points_(std::move(points)) {
    lo_ = hi_ = points_.empty() ? Eigen::Vector3d::Zero() : points_.front();
    for (const auto& q : points_) {
      lo_ = lo_.cwiseMin(q);
      hi_ = hi_.cwiseMax(q);
    }
  }
  double Distance(const Eigen::Vector3d& p, double at_most = HUGE_VAL) const {
    const double box = (p - p.cwiseMax(lo_).cwiseMin(hi_)).norm();
    return box > at_most ? box : DistanceToPolyline(p, points_);
  }
  const std::vector<Eigen::Vector3d>& points() const { return points_; }

 private:
  std::vector<Eigen::Vector3d> points_;
  Eigen::Vector3d lo_, hi_;
};

inline std::string SharedDataPath(const std::string& relative) {
  return std::string(TROCAR_SHARED_DATA_DIR) + "/" + relative;
}

/// Skips the calling test, saying which shared file is missing, when it is absent.
#define TROCAR_REQUIRE_SHARED_FILE(path)                                                  \
  do {                                                                                    \
    if (!std::filesystem::exists(path)) {                                                 \
      GTEST_SKIP() << "shared data file " << (path)                                       \
                   << " is absent (../shared/data beside the repository); test skipped"; \
    }                                                                                     \
  } while (false)

/// A closed UV-sphere surface with 2·rings·segments triangles, wound outward: `at(phi, theta)`
/// gives the vertex at polar angle phi (0 at the top pole, pi at the bottom) and azimuth theta;
/// ring r and segment s ask for phi = pi·r/rings and theta = 2·pi·s/segments.
inline TriangleMesh UvSphere(int rings, int segments, const std::function<Eigen::Vector3d(int r, int s)>& at) {
  TriangleMesh m;
  m.vertices.push_back(at(0, 0));
  for (int r = 1; r < rings; ++r) {
    for (int s = 0; s < segments; ++s) m.vertices.push_back(at(r, s));
  }
  m.vertices.push_back(at(rings, 0));
  const int last = static_cast<int>(m.vertices.size()) - 1;
  auto index = [&](int r, int s) { return 1 + (r - 1) * segments + (s % segments); };
  for (int s = 0; s < segments; ++s) m.triangles.emplace_back(0, index(1, s), index(1, s + 1));
  for (int r = 1; r < rings - 1; ++r) {
    for (int s = 0; s < segments; ++s) {
      m.triangles.emplace_back(index(r, s), index(r + 1, s), index(r + 1, s + 1));
      m.triangles.emplace_back(index(r, s), index(r + 1, s + 1), index(r, s + 1));
    }
  }
  for (int s = 0; s < segments; ++s) m.triangles.emplace_back(last, index(rings - 1, s + 1), index(rings - 1, s));
  return m;
}

/// Uniform within the active joints' limits; unbounded joints in [-pi, pi].
inline Eigen::VectorXd RandomConfiguration(const robot::RobotModel& model, std::mt19937* rng) {
  Eigen::VectorXd q(model.num_positions());
  for (int i = 0; i < q.size(); ++i) {
    const auto& limits = model.joint(model.active_joints()[i]).limits;
    const double lo = std::isfinite(limits.lower) ? limits.lower : -M_PI;
    const double hi = std::isfinite(limits.upper) ? limits.upper : M_PI;
    q[i] = std::uniform_real_distribution<double>(lo, hi)(*rng);
  }
  return q;
}

/// Drake-style comparison: reports the worst element; NaN never compares equal.
inline ::testing::AssertionResult CompareMatrices(const Eigen::MatrixXd& a,
                                                  const Eigen::MatrixXd& b, double tolerance) {
  if (a.rows() != b.rows() || a.cols() != b.cols()) {
    return ::testing::AssertionFailure() << "sizes differ: " << a.rows() << "x" << a.cols()
                                         << " vs " << b.rows() << "x" << b.cols();
  }
  double worst = 0.0;
  Eigen::Index wr = 0, wc = 0;
  for (Eigen::Index r = 0; r < a.rows(); ++r) {
    for (Eigen::Index c = 0; c < a.cols(); ++c) {
      const double diff = std::abs(a(r, c) - b(r, c));
      if (std::isnan(diff) || diff > worst) {
        worst = std::isnan(diff) ? HUGE_VAL : diff;
        wr = r;
        wc = c;
      }
    }
  }
  if (worst <= tolerance) return ::testing::AssertionSuccess();
  std::ostringstream out;
  out << "worst element (" << wr << ", " << wc << "): " << a(wr, wc) << " vs " << b(wr, wc)
      << ", difference " << worst << " > tolerance " << tolerance << "\n"
      << a << "\nvs\n"
      << b;
  return ::testing::AssertionFailure() << out.str();
}

}  // namespace trocar::test
