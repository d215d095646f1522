#pragma once
// Where a point lands in a rendered view, for the viewer's pixel tests.
#include <Eigen/Core>
#include <cmath>

#include "scene.hpp"

namespace trocar::viz::test_projection {

/// Where a point lands in a view (pixels, y down) by a pinhole camera with a vertical view angle,
/// as VTK's; false when it is behind the camera.
inline bool Project(const CameraPose& c, int width, int height, const Eigen::Vector3d& p_W,
                    Eigen::Vector2d* px) {
  const Eigen::Vector3d f = (c.focal_point - c.position).normalized();
  const Eigen::Vector3d r = f.cross(c.view_up).normalized();
  const Eigen::Vector3d u = r.cross(f);
  const Eigen::Vector3d d = p_W - c.position;
  const double z = d.dot(f);
  if (z <= 1e-6) return false;
  const double t = std::tan(c.view_angle_deg / 2 * M_PI / 180);
  const double aspect = static_cast<double>(width) / height;
  const double nx = d.dot(r) / (z * t * aspect), ny = d.dot(u) / (z * t);
  *px = Eigen::Vector2d((nx + 1) / 2 * width, (1 - ny) / 2 * height);
  return true;
}

}  // namespace trocar::viz::test_projection
