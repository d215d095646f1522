#include "port_placement/port_rules.hpp"

#include <cmath>

#include "collision/triangle_bvh.hpp"

namespace trocar::planners {

double TrackAllowance(const collision::TriangleBvh& skin, double pivot_depth,
                      const Eigen::Vector3d& pivot, const Eigen::Vector3d& incision,
                      const Eigen::Vector3d& tip, double port_radius) {
  const double cut = PortTrackLength(pivot_depth, pivot, incision) + port_radius;
  const Eigen::Vector3d out = pivot - tip;
  if (!(out.norm() > 0.005) || !(pivot_depth > 0.0)) return cut;
  const Eigen::Vector3d u = out.normalized();
  // The crossing lies at most (depth + shift) / sin(angle) out; past kMaxIncisionOffset plus the
  // deepest pivot no track of a sound port reaches.
  const double t = skin.FirstHit(pivot, u, kMaxIncisionOffset + kMaxPivotDepth + pivot_depth);
  if (!std::isfinite(t)) return cut;
  const Eigen::Vector3d crossing = pivot + t * u;
  if ((crossing - incision).norm() > pivot_depth) return cut;
  return std::max(cut, t + port_radius);
}

}  // namespace trocar::planners
