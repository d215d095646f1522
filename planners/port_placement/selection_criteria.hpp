#pragma once
/// @file
/// The anatomical selection criteria surgeons use for robotic TECAB, measured on the patient's
/// CT model and reported beside the verdict (issue #41 item 6; sources and definitions in
/// docs/selection-criteria.md): the distance from the heart's left anterior surface (the left
/// ventricle's region) to the chest wall, the chest's front-back to side-to-side ratio, the LAD's
/// depth under the chest wall, and at the plan's camera port the distance from the chest wall to
/// the mediastinum. Each carries its threshold and source, and whether the patient meets it; the
/// comparison with the planner's verdict says when the two disagree.

#include <string>
#include <vector>

#include "port_placement/problem.hpp"

namespace trocar::planners {

struct Criterion {
  std::string name;        ///< "heart_to_chest_wall"
  std::string title;       ///< "left ventricle to the anterior chest wall"
  double value = 0.0;      ///< in `unit`; NaN when it cannot be measured on this model
  std::string unit;        ///< "mm", "%"
  double threshold = 0.0;  ///< the published bound
  bool at_least = true;    ///< favourable when value >= threshold (else when value <= threshold)
  std::string meaning;     ///< what falling short means ("relative contraindication")
  std::string source;
  std::string how;         ///< how it is measured here (the model's proxies)
  bool measured() const;
  bool favourable() const;  ///< measured and on the right side of its threshold
};

struct SelectionCriteria {
  std::vector<Criterion> criteria;
  int measured() const;
  int against() const;  ///< measured and unfavourable
  /// One line comparing them with a verdict: "all 4 favour robotic TECAB: the planner's 'not
  /// suitable' is not supported by the anatomy (look at the robot's setup and the world model)",
  /// or "1 of 4 against: ... although the planner finds a plan", or "agree: ...".
  std::string Compare(bool suitable) const;
};

/// The patient-only criteria, measured on `ct_model` (the CT's state: the published criteria
/// are read on the preoperative CT), and, with a camera port's pivot (patient frame, m; null:
/// no endoscope arm), the pleura-to-mediastinum distance there.
/// Needs the structures the model has: skin, ribs, sternum, heart, the LAD target; a criterion
/// whose structure is missing is reported unmeasured (NaN), with why in `how`.
SelectionCriteria MeasureSelectionCriteria(const patient::PatientModel& ct_model,
                                           const Eigen::Vector3d* camera_pivot_P);

}  // namespace trocar::planners
