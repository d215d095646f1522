#pragma once
/// @file
/// The case file, `patients/<case>/patient.yaml`, read and checked into a CaseSpec (paths joined
/// to the case folder, every field validated with the file, line and field named). Internal to
/// the patient import: ImportPatient is the public entry.

#include <optional>
#include <string>
#include <vector>

#include "patient/intercostal.hpp"
#include "patient/patient_model.hpp"
#include "patient/phantom.hpp"
#include "patient/segmentation.hpp"
#include "patient/surface.hpp"

namespace trocar::patient {

struct Budgets {
  int skin = 30000, ribs = 40000, sternum = 4000, spine = 12000, heart = 15000, vessels = 8000;
};

// The coarsest grid a structure is contoured on (m): thin bone keeps 2 mm, the skin and the heart
// are smooth and large (their triangles, at the budgets above, are 5-8 mm across anyway).
inline double MaxWorkingSpacing(const std::string& structure) {
  if (structure == "skin") return 0.006;
  if (structure == "heart") return 0.004;
  if (structure == "spine") return 0.003;
  return 0.002;
}

struct TargetSpec {
  std::string name, markups, surface = "heart";
  bool inward = false;
  std::string normals = "auto";  // auto: the file's orientations when present, else surface
};

struct CaseSpec {
  std::string file, dir, name, ct;
  bool has_phantom = false;
  PhantomParameters phantom;
  int units = 0;  // 0 auto, 1 hounsfield, 2 raw
  bool thresholds_given = false;  // thresholds.body or thresholds.bone set (else the defaults)
  SegmentationOptions seg;
  std::string heart_mask;
  double heart_mask_threshold = 0.5;
  std::string labels, label_names;  // a label map (file or folder of masks) and its names' sidecar
  /// heart.contrast: true (a contrast CT: no blood pool is an error), false (no heart), or unset:
  /// detected, and without contrast the heart is approximated from the mediastinum (flagged).
  std::optional<bool> heart_contrast;
  bool check_orientation = true;
  HeartOptions heart;
  double left_side_up = 0.0;
  OperativeState operation;  // the literature's defaults unless `operation:` says otherwise
  Table table;
  std::vector<TargetSpec> targets;
  std::vector<std::string> port_markups;
  IntercostalOptions intercostal;
  Budgets budgets;
  SurfaceOptions surface;
};

/// @throws trocar::Error naming the file, line and field for bad input.
CaseSpec ReadCase(const std::string& case_dir);

}  // namespace trocar::patient
