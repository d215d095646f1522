#pragma once
/// @file
/// 3D Slicer markups (`.mrk.json`): points and curves for targets (LAD, LIMA, any named target)
/// and port candidate curves, read into the patient frame (LPS, metres) whatever the file's
/// coordinate system (LPS or RAS) and units (mm or m).

#include <string>
#include <vector>

#include "patient/curve.hpp"

namespace trocar::patient {

struct Markup {
  std::string name;
  std::string type;      ///< "Curve", "ClosedCurve", "Fiducial", "Line", ...
  Curve points;          ///< control points in the patient frame (m)
  std::vector<std::string> labels;
  /// Per-point unit normals from the control points' `orientation` (the z column of the 3x3
  /// matrix, as Slicer orients points); empty when the file gives no orientations.
  std::vector<Eigen::Vector3d> normals;
};

/// @throws trocar::Error naming the file and the field: not JSON, no `markups`, unknown
///         `coordinateSystem` or `coordinateUnits`, a control point without a 3-number
///         `position`, non-finite coordinates.
std::vector<Markup> LoadMarkups(const std::string& path);

/// Writes markups that 3D Slicer opens (schema v1.0.3, LPS, millimetres), with orientations when
/// `normals` are given, atomically.
void WriteMarkups(const std::vector<Markup>& markups, const std::string& path);

}  // namespace trocar::patient
