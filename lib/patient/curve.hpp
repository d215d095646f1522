#pragma once
/// @file
/// The patient model's polyline: targets (the LAD, the LIMA), port-candidate curves, markups.
/// Its own header, so that the model and the readers do not include the phantom generator.

#include <vector>

#include <Eigen/Core>

namespace trocar::patient {

/// A polyline in the patient frame (m).
using Curve = std::vector<Eigen::Vector3d>;

}  // namespace trocar::patient
