#pragma once
/// @file
/// The operation's world (docs/operative-state.md). A CT is taken with both lungs inflated; a
/// robotic TECAB or LIMA harvest is done with the left lung isolated (one-lung ventilation of the
/// right), CO2 insufflated into the left chest and the left side raised. Under those the heart
/// and the mediastinum fall away from the anterior chest wall. This step sits between the
/// imported patient model (the CT's state) and planning: it moves the organs that are not fixed
/// to the chest wall (the heart) and the targets lying on them, by the literature's displacement,
/// along gravity in the operative position. The chest wall, ribs, sternum, spine and skin, and a
/// target in the chest wall (the LIMA), stay where the CT shows them.

#include <Eigen/Geometry>
#include <string>
#include <vector>

namespace trocar::patient {

struct PatientModel;

struct OperativeState {
  /// false: plan in the CT's state (`operation: none` in patient.yaml): nothing moves.
  bool applied = true;
  /// CO2 insufflated into the left chest (mmHg); 0: none. Default 8 mmHg, robotic TECAB (Bonatti
  /// et al., in Sellke's Atlas of Cardiac Surgical Techniques, "Robotic CABG").
  double co2_mmhg = 8.0;
  /// One-lung ventilation, the left lung isolated (double-lumen tube).
  bool left_lung_isolated = true;
  /// How far the heart moves away from the anterior chest wall (m): the planned value and the
  /// range the plans are re-scored over. Default 10-15 mm, planned at 12.5 mm (Linte et al.,
  /// Innovations 2011;6(5):323-330: about 10-15 mm after lung isolation and insufflation).
  double heart_shift = 0.0125, heart_shift_min = 0.010, heart_shift_max = 0.015;
  /// The CT's state: nothing applied.
  static OperativeState CtState() {
    OperativeState s;
    s.applied = false;
    return s;
  }
  /// Whether anything moves: insufflation or lung isolation under an applied state.
  bool moves() const { return applied && (co2_mmhg > 0.0 || left_lung_isolated); }
  /// "operative: CO2 8 mmHg, left lung isolated, heart 12.5 mm (10-15) along gravity" or "the
  /// CT's state".
  std::string Describe() const;
};

/// Physical ranges of the state's values (patient.yaml is checked against them).
constexpr double kMaxCo2Mmhg = 15.0;      ///< above it haemodynamics suffer (docs/operative-state.md)
constexpr double kMaxHeartShift = 0.04;   ///< m

/// What the operative state did to a model.
struct OperativeChange {
  Eigen::Vector3d direction_P = Eigen::Vector3d::Zero();  ///< unit: gravity in the patient frame
  Eigen::Vector3d d_P = Eigen::Vector3d::Zero();          ///< the planned displacement (m)
  std::vector<std::string> structures;  ///< moved structures ("heart")
  std::vector<std::string> targets;     ///< moved targets ("LAD")
};

/// The structures that are not part of the chest wall or the skeleton: they move in the operative
/// state. Skin, ribs, sternum, costal cartilages, spine, clavicles and scapulae never move.
bool IsMobileStructure(const std::string& name);

/// Whether a target lies on a structure: the median distance of its points to the surface is
/// under 1 cm (the LAD on the heart; not the LIMA inside the chest wall).
bool TargetLiesOn(const PatientModel& model, int target, const std::string& structure);

/// Direction of gravity in the patient frame at its pose on the table (X_WP; z_W up).
Eigen::Vector3d GravityInPatient(const PatientModel& model);

/// Moves the mobile structures, and the targets lying on them, by `d_P` (the model's `operation`
/// is left as it is). Returns what moved.
OperativeChange MoveMobile(const Eigen::Vector3d& d_P, PatientModel* model);

/// Puts a CT-state model into the operative state `state` (recorded in model->operation and
/// model->operative_change): the heart and the targets on it moved by `state.heart_shift` along
/// gravity. A state that moves nothing records itself and leaves the geometry.
void ApplyOperativeState(const OperativeState& state, PatientModel* model);

/// The displacements, relative to the planned one, the plans are re-scored under: the heart at
/// either end of the state's range along its direction, and by half the range's width either way
/// across it (the direction is the model's: Linte et al. saw the shift along every axis). Empty
/// when the state moves nothing or its range is a single value.
std::vector<Eigen::Vector3d> OperativeRobustnessShifts(const PatientModel& model);

}  // namespace trocar::patient
